"""Helpers shared by the scan formats: scanner-frame coordinates and grid angles."""

from __future__ import annotations

import warnings

import numpy as np

from tlssim.errors import ScanError
from tlssim.pattern import ScannerPose, beam_frame
from tlssim.scan import Scan


def local_points(scan: Scan) -> np.ndarray:
    """Points of every grid cell in the scanner frame, m; cells without a return get their unit beam direction."""
    measured = (scan.xyz - scan.pose.position) @ scan.pose.rotation
    direction, _, _ = beam_frame(scan.theta, scan.psi)
    return np.where(scan.valid[..., None], measured, direction)


def angles_of(local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth ``theta`` (continued along each row) and zenith ``psi`` of scanner-frame vectors, rad."""
    theta = np.arctan2(local[..., 1], local[..., 0])
    psi = np.arccos(np.clip(local[..., 2] / np.linalg.norm(local, axis=-1), -1.0, 1.0))
    return _unwrap_rows(theta), psi


def complete_angles(theta: np.ndarray, psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fill cells of unknown direction (NaN) from the grid's column azimuths and row zeniths.

    A scan grid has one azimuth per column and one zenith per row; missing
    columns or rows (no direction anywhere in them) are filled from a
    straight-line fit of the known ones against their index.

    Parameters
    ----------
    theta : ndarray
        Azimuth per grid cell, rad, shape ``(rows, cols)``; NaN where unknown.
    psi : ndarray
        Zenith angle per grid cell, rad, same shape; NaN where unknown.

    Returns
    -------
    tuple of ndarray
        ``(theta, psi)`` with the unknown cells filled, rad.
    """
    if not (np.isnan(theta).any() or np.isnan(psi).any()):
        return theta, psi
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns or rows
        column_theta = fill_line(np.nanmedian(theta, axis=0))
        row_psi = fill_line(np.nanmedian(psi, axis=1))
    return (np.where(np.isnan(theta), column_theta[None, :], theta),
            np.where(np.isnan(psi), row_psi[:, None], psi))


#: Largest share of points that may fall into an already occupied cell of a gridded cloud.
MAX_SHARED_CELLS = 0.01
#: Largest grid an unstructured cloud is gridded into, cells.
MAX_GRID_CELLS = 200_000_000


def grid_indices(local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grid rows and columns of an unstructured single-station cloud, from its angles.

    A phase-shift scanner samples a regular (psi, theta) grid; exports often
    drop the row and column indices. In (theta, psi) the points of such a
    scan form a rectangular lattice: the step along each axis is the median
    offset, along that axis, of the nearest neighbours that lie along it; a
    point's row and column are its zenith and azimuth in steps, rounded.

    Parameters
    ----------
    local : ndarray, (n, 3)
        Points (or beam directions) in the scanner frame, m.

    Returns
    -------
    row, col : ndarray of int64, (n,)
        Grid indices from 0.

    Raises
    ------
    ScanError
        If the points do not lie on one station's regular angular grid (more
        than :data:`MAX_SHARED_CELLS` of them share a cell, or the grid would
        exceed :data:`MAX_GRID_CELLS`); the message says which.
    """
    from scipy.spatial import cKDTree

    theta, psi = angles_of(local[None, :, :])
    theta, psi = theta[0], psi[0]
    if len(local) < 4 or not (np.isfinite(theta).all() and np.isfinite(psi).all()):
        raise ScanError("its points cannot be gridded: fewer than 4 points or points at the scanner's origin")
    order = np.argsort(theta)
    theta[order] = np.unwrap(theta[order])  # a window across +-180 deg becomes one interval
    angles = np.column_stack([theta, psi])
    _, neighbours = cKDTree(angles).query(angles, k=min(5, len(angles)))
    offset = np.abs(angles[neighbours[:, 1:]] - angles[:, None, :]).reshape(-1, 2)
    along_theta = offset[:, 1] < 0.25 * offset[:, 0]
    along_psi = offset[:, 0] < 0.25 * offset[:, 1]
    if not (along_theta.any() and along_psi.any()):
        raise ScanError("its points cannot be gridded: no rows and columns of directions (not a scan grid)")
    step_theta, step_psi = float(np.median(offset[along_theta, 0])), float(np.median(offset[along_psi, 1]))
    if not (step_theta > 0 and step_psi > 0):
        raise ScanError("its points cannot be gridded: repeated directions (no angular step)")
    row = np.rint((psi - psi.min()) / step_psi).astype(np.int64)
    col = np.rint((theta - theta.min()) / step_theta).astype(np.int64)
    steps = f"{np.degrees(step_theta):.3g} x {np.degrees(step_psi):.3g} deg"
    cells = (int(row.max()) + 1) * (int(col.max()) + 1)
    if cells > MAX_GRID_CELLS:
        raise ScanError(f"its angular steps {steps} give a {cells:,}-cell grid: it is not one station's scan "
                        f"(read it as a point cloud, e.g. with woody)")
    shared = 1.0 - len(np.unique(row * (int(col.max()) + 1) + col)) / len(row)
    if shared > MAX_SHARED_CELLS:
        raise ScanError(f"its points do not lie on one station's regular angular grid ({100 * shared:.1f} % share "
                        f"a cell at the {steps} steps): read it as a point cloud (e.g. woody)")
    return row, col


def scan_from_local(local: np.ndarray, valid: np.ndarray, intensity: np.ndarray, pose: ScannerPose,
                    theta: np.ndarray, psi: np.ndarray, meta: dict) -> Scan:
    """A truth-less :class:`Scan` from scanner-frame points on the grid.

    Parameters
    ----------
    local : ndarray
        Points in the scanner frame, m, shape ``(rows, cols, 3)``.
    valid : ndarray of bool
        Cells with a return, shape ``(rows, cols)``.
    intensity : ndarray
        Intensity per cell, DN.
    pose : ScannerPose
        Scanner position (m) and orientation in the world frame.
    theta : ndarray
        Azimuth per cell, rad.
    psi : ndarray
        Zenith angle per cell, rad.
    meta : dict
        Scan metadata stored with the scan.

    Returns
    -------
    Scan
        Range in m (NaN without return), world coordinates in m, no truth.
    """
    range_m = np.where(valid, np.linalg.norm(local, axis=-1), np.nan)
    xyz = np.where(valid[..., None], local @ pose.rotation.T + pose.position, np.nan)
    intensity = np.where(valid, intensity, np.nan).astype(np.float32)
    return Scan(range=range_m, intensity=intensity, theta=theta, psi=psi, xyz=xyz, pose=pose, meta=meta)


def _unwrap_rows(theta: np.ndarray) -> np.ndarray:
    known = np.where(np.isnan(theta), np.nanmedian(theta) if np.isfinite(theta).any() else 0.0, theta)
    return np.where(np.isnan(theta), np.nan, np.unwrap(known, axis=-1))


def fill_line(values: np.ndarray) -> np.ndarray:
    """Fill the NaN entries of a row's or column's values from a straight-line fit of the known ones on their index.

    Parameters
    ----------
    values : ndarray
        One value per row or column (e.g. zenith or azimuth medians, rad); NaN where unknown.

    Returns
    -------
    ndarray
        ``values`` with the NaN entries filled (a single known value is repeated; none known: unchanged).
    """
    known = np.isfinite(values)
    if known.all() or not known.any():
        return values
    index = np.arange(len(values))
    if known.sum() == 1:
        return np.where(known, values, values[known][0])
    slope, intercept = np.polyfit(index[known], values[known], 1)
    return np.where(known, values, intercept + slope * index)


def unwrap_columns(theta: np.ndarray, carry) -> tuple[np.ndarray, tuple]:
    """``numpy.unwrap`` along each row of a tile of columns, continued from the previous tile's ``carry``.

    The same arithmetic as ``numpy.unwrap`` on the whole rows: the corrections are summed in column
    order, the sum carried from tile to tile.

    Parameters
    ----------
    theta : ndarray
        Azimuths of the tile's columns, rad, shape ``(rows, cols)``.
    carry : tuple or None
        What the previous tile returned; ``None`` for the first tile.

    Returns
    -------
    unwrapped : ndarray
        The tile's azimuths unwrapped along the rows, rad.
    carry : tuple
        The last raw azimuths and summed corrections, for the next tile.
    """
    period = 2.0 * np.pi
    if carry is None:
        previous, total = theta[:, :1], np.zeros((len(theta), 1))
        steps = theta[:, 1:]
    else:
        (previous, total), steps = carry, theta
    dd = np.diff(np.concatenate([previous, steps], axis=1), axis=1)
    ddmod = np.mod(dd + period / 2, period) - period / 2
    np.copyto(ddmod, period / 2, where=(ddmod == -period / 2) & (dd > 0))
    correct = ddmod - dd
    np.copyto(correct, 0, where=np.abs(dd) < period / 2)
    summed = np.cumsum(np.concatenate([total, correct], axis=1), axis=1)[:, 1:]
    unwrapped = steps + summed
    if carry is None:
        unwrapped = np.concatenate([theta[:, :1], unwrapped], axis=1)
    last = summed[:, -1:] if summed.shape[1] else total
    return unwrapped, (theta[:, -1:], last)


#: Values a streamed median sorts at once; above it the candidates' interval is narrowed by another pass.
MEDIAN_SORT_VALUES = 1 << 22
#: Bins of each counting pass of a streamed median.
_MEDIAN_BINS = 4096


def streamed_median(passes) -> float:
    """The median of values too many for memory, exactly as ``numpy.median`` of all of them gives it.

    Each pass counts the values in bins of the interval that holds the two
    middle ones (one chunk in memory at a time), until the values of the
    bins holding them are few enough to sort; the result is the mean of
    the two middle values as ``numpy.median`` computes it.

    Parameters
    ----------
    passes : callable
        Returns a fresh iterator over the chunks (1-D float arrays, no NaN) of the values.

    Returns
    -------
    float
        The median; NaN when there are no values.
    """
    total, low, high = 0, np.inf, -np.inf
    for chunk in passes():
        if len(chunk):
            total, low, high = total + len(chunk), min(low, float(chunk.min())), max(high, float(chunk.max()))
    if total == 0:
        return float("nan")
    ranks, below = [(total - 1) // 2, total // 2], 0  # below: values under ``low``
    while True:
        if low == high:
            picked = [low, low]
            break
        edges = np.linspace(low, high, _MEDIAN_BINS + 1)
        counts = np.zeros(_MEDIAN_BINS, np.int64)
        for chunk in passes():
            inside = chunk[(chunk >= low) & (chunk <= high)]
            counts += np.bincount(np.searchsorted(edges[1:-1], inside, "right"), minlength=_MEDIAN_BINS)
        ends = below + np.cumsum(counts)
        first, last = (int(np.searchsorted(ends, rank, "right")) for rank in ranks)
        start = below + (ends[first - 1] - below if first else 0)
        if ends[last] - start <= MEDIAN_SORT_VALUES:
            top = edges[last + 1] if last + 1 < _MEDIAN_BINS else np.inf
            values = np.sort(np.concatenate([c[(c >= edges[first]) & (c < top) & (c <= high)] for c in passes()]))
            picked = [values[rank - start] for rank in ranks]
            break
        below, low = int(start), float(edges[first])
        high = float(np.nextafter(edges[last + 1], -np.inf)) if last + 1 < _MEDIAN_BINS else high
    return float(np.mean(np.array(picked, dtype=np.float64)))

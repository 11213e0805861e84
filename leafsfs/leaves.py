"""Split a scan into leaf regions at range discontinuities that the intensity does not explain.

Between two neighbouring pulses on one smooth surface, the range changes by
at most ``r * dtheta * tan(alpha)`` (``dtheta`` the angle between the beams,
``alpha`` the incidence). The intensity gives ``alpha``; a range step larger
than that slope allows (plus a margin and the range noise) is where the
intensity and the geometry disagree: an object edge, or the mixed
("outlier") points of a phase-shift scanner that lie between two surfaces
(thesis ch.1 §2.3 and its general conclusion). Without an alpha image a fixed
steepest slope is used.

Pixels joined by plausible steps (4-neighbour links) form connected
regions. Mixed points, whose ranges lie between the surfaces, end up alone or
in small groups; pixels of groups smaller than ``min_pixels`` join, among
the regions within ``band_px`` pixels, the one nearest to the scanner (a
mixed footprint straddles an edge of the foreground object, whose distance
it is meant to have; ``band_px`` is about a footprint diameter). Regions touching
the scan window's border (the background behind the leaves) are dropped by
default.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from leafsfs.errors import SfsError
from tlssim.pattern import beam_frame

_SHIFTS = ((1, 0), (-1, 0), (0, 1), (0, -1))


def _shift(image: np.ndarray, di: int, dj: int, fill):
    """``out[i, j] = image[i + di, j + dj]`` (``fill`` outside)."""
    out = np.full_like(image, fill)
    rows, cols = image.shape[:2]
    out[max(-di, 0):rows - max(di, 0), max(-dj, 0):cols - max(dj, 0)] = \
        image[max(di, 0):rows + min(di, 0) or None, max(dj, 0):cols + min(dj, 0) or None]
    return out


def link_components(range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray, alpha: np.ndarray | None = None, *,
                    max_slope_deg: float = 80.0, alpha_margin_deg: float = 25.0, noise_m: float = 0.002) -> np.ndarray:
    """Connected components of the valid pixels joined by plausible range steps (labels 1.., 0 = no return).

    Parameters are those of :func:`segment_leaves`.
    """
    if not 0 < max_slope_deg < 90:
        raise SfsError(f"max_slope_deg must lie in ]0, 90[ degrees, got {max_slope_deg!r}")
    valid = np.isfinite(range_m)
    axis = beam_frame(theta, psi)[0]
    limit = math.radians(max_slope_deg)
    slope = np.full(range_m.shape, limit) if alpha is None else \
        np.minimum(np.nan_to_num(alpha, nan=limit) + math.radians(alpha_margin_deg), limit)
    r = np.where(valid, range_m, np.nan)
    index = np.arange(r.size).reshape(r.shape)
    rows, cols = [], []
    for di, dj in ((1, 0), (0, 1)):
        other = _shift(r, di, dj, np.nan)
        angle = np.arccos(np.clip(np.sum(axis * _shift(axis, di, dj, 0.0), axis=-1), -1, 1))
        allowed = np.fmin(r, other) * angle * np.tan(np.minimum(slope, _shift(slope, di, dj, limit))) + noise_m
        with np.errstate(invalid="ignore"):
            ok = valid & np.isfinite(other) & (np.abs(r - other) <= allowed)
        rows.append(index[ok])
        cols.append(_shift(index, di, dj, -1)[ok])
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(r.size, r.size))
    _, component = csgraph.connected_components(graph, directed=False)
    return np.where(valid.ravel(), component + 1, 0).reshape(r.shape)


def edge_pixels(range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray, alpha: np.ndarray | None = None, *,
                min_pixels: int = 100, **limits) -> np.ndarray:
    """Valid pixels outside every linked region of at least ``min_pixels``: mixed points and small fragments.

    Their range is not that of a smooth surface and their intensity, corrected
    with that range, is not that of one either; PROP-SFS uses neither (they
    join the outermost iso-alpha domain and get distances by propagation).
    """
    component = link_components(range_m, theta, psi, alpha, **limits)
    sizes = np.bincount(component.ravel())
    return (component > 0) & (sizes[component] < min_pixels)


def segment_leaves(range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray, alpha: np.ndarray | None = None, *,
                   min_pixels: int = 100, max_slope_deg: float = 80.0, alpha_margin_deg: float = 25.0,
                   noise_m: float = 0.002, drop_border: bool = True, band_px: int = 6) -> np.ndarray:
    """Label the leaf regions of a scan.

    Parameters
    ----------
    range_m, theta, psi : ndarray, 2-D
        Scan grids (m, rad; NaN range = no return).
    alpha : ndarray, 2-D, optional
        Intensity-derived incidence, rad; sets the steepest plausible slope
        per pixel to ``alpha + alpha_margin_deg`` (capped at ``max_slope_deg``).
    min_pixels : int
        Smallest linked region kept as a region of its own.
    max_slope_deg : float
        Steepest plausible slope without (or beyond) alpha, degrees.
    alpha_margin_deg : float
        Tolerance on the intensity-derived incidence, degrees.
    noise_m : float
        Range noise allowance per step, m (assumption: a few sigma of the
        FARO-class range noise at 1-5 m).
    drop_border : bool
        Drop regions touching the window's border (the background).
    band_px : int
        Largest distance, pixels, at which a mixed point joins a region.

    Returns
    -------
    ndarray of int, 2-D
        Region label per pixel, 1..K, 0 for none.
    """
    valid = np.isfinite(range_m)
    if not valid.any():
        raise SfsError("the scan has no valid pixels (no returns) to segment")
    component = link_components(range_m, theta, psi, alpha, max_slope_deg=max_slope_deg,
                                alpha_margin_deg=alpha_margin_deg, noise_m=noise_m)
    sizes = np.bincount(component.ravel())
    large = sizes >= min_pixels
    large[0] = False
    labels = _attach(np.where(large[component], component, 0), np.where(valid, range_m, np.nan), valid, band_px)
    sizes = np.bincount(labels.ravel())
    keep = np.zeros(len(sizes), dtype=bool)
    keep[np.unique(labels[labels > 0])] = True
    if drop_border:
        keep[np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))] = False
    keep[0] = False
    lookup = np.zeros(len(sizes), dtype=int)
    lookup[keep] = np.arange(1, keep.sum() + 1)
    return lookup[labels]


def _attach(labels: np.ndarray, r: np.ndarray, valid: np.ndarray, band_px: int) -> np.ndarray:
    """Give each unlabelled valid pixel the label of the nearest-to-the-scanner region within ``band_px``.

    "Nearest to the scanner" compares the ranges of each region's pixel
    closest to the unlabelled one.
    """
    todo = valid & (labels == 0)
    best = np.full(labels.shape, np.inf)
    out = labels.copy()
    for k in np.unique(labels[labels > 0]):
        distance, (ii, jj) = ndimage.distance_transform_edt(labels != k, return_indices=True)
        near = todo & (distance <= band_px)
        candidate = np.where(near, r[ii, jj], np.inf)
        better = near & (candidate < best)
        best[better] = candidate[better]
        out[better] = k
    return out

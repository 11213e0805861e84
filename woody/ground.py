"""The ground under a point cloud, found from its lowest points.

A grid of square cells over x, y holds the third-lowest height of each
cell's points (a robust minimum: one or two isolated points below the
ground, such as multipath returns, do not pull it down; a percentile would
rise with the number of stem points in a cell). Cells that see no ground
(under a dense crown, behind a stem) hold a value far above the ground
around them: a cell is dropped when it lies above the cone of slope
``max_rise_m`` per cell (chessboard distance) standing on any other cell,
and every dropped or empty cell takes the value of the nearest kept one.
This is the slope-based filter of airborne lidar (Vosselman 2000) on the
cells; a plateau of crown cells goes too, however wide, so on a cloud
without ground points (a tree cut out of a scan, as the example clouds of
TreeQSM, aRchi or rTwig) the ground is the lowest part of the stem.

:func:`local_ground_z` gives the ground height at one place, e.g. under a
stem: a plane fitted with a robust loss to the cells around it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from woody.cloud import check_points
from woody.errors import WoodyError

#: Rank (0 = lowest) of the height in a cell taken as its ground height.
GROUND_RANK = 2
#: Largest rise of the ground per cell (0.5 m) of distance, m: a cell higher above any other sees no ground
#: (assumption: steeper than any
#: slope under a tree at the default 0.5 m cells, lower than a crown or a stem's height).
MAX_RISE_M = 0.5


#: Cells more than this above the local ground plane are not ground, m (assumption: rougher than a forest floor
#: within a cell, lower than the lowest branches).
ENVELOPE_M = 0.2


@dataclass(frozen=True)
class GroundGrid:
    """Ground heights on a regular x, y grid.

    Attributes
    ----------
    origin : ndarray, (2,)
        x, y of the corner of cell (0, 0), m.
    cell_m : float
        Cell size, m.
    z : ndarray, (nx, ny)
        Ground height of every cell, m (filled everywhere).
    seen : ndarray, (nx, ny), bool
        Cells whose height comes from their own points (not filled from a
        neighbour).
    """

    origin: np.ndarray
    cell_m: float
    z: np.ndarray
    seen: np.ndarray

    def at(self, xy) -> np.ndarray:
        """Ground height at x, y positions, m: bilinear between cell centres (the nearest edge value outside)."""
        coords = (np.asarray(xy, float).reshape(-1, 2) - self.origin) / self.cell_m - 0.5
        return ndimage.map_coordinates(self.z, coords.T, order=1, mode="nearest")

    def heights(self, points) -> np.ndarray:
        """Height of points above the ground under them, m."""
        points = np.asarray(points, float)
        return points[:, 2] - self.at(points[:, :2])


def ground_grid(points, cell_m: float = 0.5, max_rise_m: float = MAX_RISE_M) -> GroundGrid:
    """Ground heights of a point cloud on a grid of square cells.

    Parameters
    ----------
    points : array_like, (n, 3)
        Coordinates, m (z up).
    cell_m : float
        Cell size, m.
    max_rise_m : float
        Largest rise of the ground per cell of distance (chessboard: a
        neighbour, diagonal ones too, is one cell away), m.

    Returns
    -------
    GroundGrid

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> xy = rng.uniform(0, 4, (4000, 2))
    >>> crown = np.column_stack([rng.uniform(1, 2, (500, 2)), rng.uniform(3, 4, 500)])
    >>> grid = ground_grid(np.concatenate([np.column_stack([xy, 0.1 * xy[:, 0]]), crown]))
    >>> bool(abs(grid.at([[1.5, 1.5]])[0] - 0.15) < 0.05)
    True
    """
    points = check_points(points)
    if not (np.isfinite(cell_m) and cell_m > 0 and np.isfinite(max_rise_m) and max_rise_m > 0):
        raise WoodyError(f"ground cell_m and max_rise_m must be positive lengths in metres, got {cell_m}, "
                         f"{max_rise_m}")
    origin = points[:, :2].min(axis=0)
    index = np.floor((points[:, :2] - origin) / cell_m).astype(np.int64)
    shape = index.max(axis=0) + 1
    if shape.prod() > 5e7:
        raise WoodyError(f"a {shape[0]} x {shape[1]} ground grid of {cell_m} m cells is too large: give a larger "
                         "cell or a cloud of one plot")
    cell = index[:, 0] * shape[1] + index[:, 1]
    order = np.lexsort((points[:, 2], cell))
    cells, first, counts = np.unique(cell[order], return_index=True, return_counts=True)
    pick = first + np.minimum(GROUND_RANK, counts - 1)
    z = np.full(int(shape.prod()), np.inf)
    z[cells] = points[order[pick], 2]
    z = z.reshape(shape)
    cone = z.copy()  # lowest cone over each cell: min over cells j of z_j + max_rise_m * chessboard distance
    while True:
        lower = np.minimum(cone, ndimage.minimum_filter(cone, size=3, mode="constant", cval=np.inf) + max_rise_m)
        if (lower == cone).all():
            break
        cone = lower
    z[z > cone] = np.inf
    seen = np.isfinite(z)
    if not seen.all():
        kept = np.argwhere(seen)
        _, nearest = cKDTree(kept).query(np.argwhere(~seen))
        z[~seen] = z[tuple(kept[nearest].T)]
    return GroundGrid(origin=origin, cell_m=float(cell_m), z=z, seen=seen)


def local_ground_z(grid: GroundGrid, xy, radius_m: float = 1.5) -> float:
    """Ground height at one place: a robust plane through the lowest seen cells around it.

    The plane starts from the lowest quarter of the cells and is fitted
    again without the cells more than 0.2 m above it until none is left
    out, so that cells which saw only branches (a crown over a cloud
    without ground points) do not lift it.

    Parameters
    ----------
    grid : GroundGrid
        The cloud's ground grid.
    xy : array_like, (2,)
        Place, m.
    radius_m : float
        Cells whose centres lie within this distance are used, m.

    Returns
    -------
    float
        Ground height at ``xy``, m (the grid's height there when fewer than
        three seen cells are near).

    Notes
    -----
    A cell's height is its lowest points', which on a slope lie at its
    downhill edge: the plane's height is raised by ``(|gx| + |gy|) cell / 2``
    (``gx``, ``gy`` its gradients), the difference between the centre and
    the lowest corner of a cell.
    """
    xy = np.asarray(xy, float).reshape(2)
    centres = grid.origin + (np.argwhere(np.ones_like(grid.seen)) + 0.5) * grid.cell_m
    values = grid.z.ravel()
    near = (np.linalg.norm(centres - xy, axis=1) <= radius_m) & grid.seen.ravel()
    if near.sum() < 3:
        return float(grid.at(xy)[0])
    design = np.column_stack([np.ones(near.sum()), centres[near] - xy])
    values = values[near]
    kept = values <= np.quantile(values, 0.25) + ENVELOPE_M  # start from the lowest cells, not the mean of all
    if kept.sum() < 3:
        kept = values <= np.sort(values)[2]
    for _ in range(20):  # lower envelope: cells well above the plane (branches, no ground seen) are left out
        start = np.linalg.lstsq(design[kept], values[kept], rcond=None)[0]
        below = values - design @ start <= ENVELOPE_M
        if (below == kept).all() or below.sum() < 3:
            break
        kept = below
    fit = least_squares(lambda p: design[kept] @ p - values[kept], start, loss="soft_l1", f_scale=0.05)
    return float(fit.x[0] + 0.5 * grid.cell_m * np.abs(fit.x[1:]).sum())

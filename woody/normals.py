"""Surface normals of point clouds by local principal component analysis.

STEP needs one normal per point (Ravaglia et al. 2017, Computers & Graphics
66, Sect. 3.1; the paper used MeshLab's normal plugin, whose settings it does
not give). Here the normal of a point is the eigenvector of smallest
eigenvalue of the covariance of its ``k`` nearest neighbours. When the
position of the scanner that saw a point is known, the normal is flipped to
face it, which on convex stems makes it point outwards (the condition of the
paper's oriented voting rule, its eq. 5).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from woody.cloud import check_points, check_viewpoints
from woody.errors import WoodyError

#: Points per vectorised block (bounds the (block, k, 3) neighbour array).
_BLOCK = 100_000


def pca_normals(points, k: int = 16, viewpoints=None) -> np.ndarray:
    """Unit normals of a point cloud by PCA of the ``k`` nearest neighbours.

    Parameters
    ----------
    points : array_like, (n, 3)
        Coordinates, m.
    k : int
        Neighbours per point, the point itself included (assumption: 10 to 30
        suits TLS stems, the range recommended for this project; the paper
        gives no value).
    viewpoints : array_like, (3,) or (n, 3), optional
        Scanner position(s), m. When given, each normal is flipped to face the
        scanner that saw its point; otherwise the sign is arbitrary.

    Returns
    -------
    ndarray, (n, 3)
        Unit normals.

    Examples
    --------
    >>> import numpy as np
    >>> xy = np.random.default_rng(0).uniform(-1, 1, (200, 2))
    >>> n = pca_normals(np.column_stack([xy, np.zeros(200)]), viewpoints=(0, 0, 5))
    >>> bool(np.allclose(n, (0, 0, 1)))
    True
    """
    points = check_points(points)
    if not 3 <= k <= 200:
        raise WoodyError(f"normal neighbourhood k must be between 3 and 200 points, got {k}")
    if len(points) < k:
        raise WoodyError(f"{len(points)} points are too few for normals from k={k} neighbours")
    viewpoints = check_viewpoints(viewpoints, len(points))
    _, neighbours = cKDTree(points).query(points, k=k)
    normals = np.empty_like(points)
    for start in range(0, len(points), _BLOCK):
        block = points[neighbours[start:start + _BLOCK]]
        block = block - block.mean(axis=1, keepdims=True)
        _, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", block, block))
        normals[start:start + _BLOCK] = vectors[:, :, 0]
    if viewpoints is not None:
        away = np.einsum("ij,ij->i", normals, viewpoints - points) < 0
        normals[away] *= -1.0
    return normals


def orient_outward(points, normals, scale_m: float = 0.1) -> np.ndarray:
    """Flip normals to point away from the local centre of mass: outwards on stems and branches, no scanner needed.

    The centre of mass of the points in the 3 x 3 x 3 block of cubic cells
    of edge ``scale_m`` around a point lies on the concave side of a convex
    surface (inside a stem or branch, towards its axis) when the block
    spans enough of the surface for its curvature to exceed the noise: the
    sagitta of a patch of half-width ``w`` on a stem of radius ``r`` is
    ``w² / (2 r)``, 2.7 cm for the default 0.1 m cells on a 0.5 m stem.
    Normals at forks and on leaves may come out either way.

    Parameters
    ----------
    points : array_like, (n, 3)
        Coordinates, m.
    normals : array_like, (n, 3)
        Unit normals of any sign.
    scale_m : float
        Cell edge, m (of the order of the stems' radii).

    Returns
    -------
    ndarray, (n, 3)
        The normals, each flipped or not.

    Examples
    --------
    >>> import numpy as np
    >>> angle = np.linspace(0, np.pi, 200)  # half a stem of radius 0.3 m, seen from +x
    >>> ring = np.column_stack([0.3 * np.sin(angle), 0.3 * np.cos(angle)])
    >>> points = np.column_stack([np.tile(ring, (5, 1)), np.repeat(np.linspace(0, 0.2, 5), 200)])
    >>> normals = np.column_stack([points[:, :2] / 0.3, np.zeros(1000)]) * np.where(angle % 0.2 < 0.1, 1, -1)[
    ...     np.tile(np.arange(200), 5)][:, None]
    >>> bool((np.einsum("ij,ij->i", orient_outward(points, normals), points * [1, 1, 0]) > 0).all())
    True
    """
    points = check_points(points)
    normals = check_points(normals, "normals")
    if len(normals) != len(points):
        raise WoodyError(f"normals has {len(normals)} rows but there are {len(points)} points")
    if not (np.isfinite(scale_m) and scale_m > 0):
        raise WoodyError(f"scale_m must be a positive length in metres, got {scale_m}")
    index = np.floor((points - points.min(axis=0)) / scale_m).astype(np.int64) + 1
    shape = index.max(axis=0) + 2
    key = (index[:, 0] * shape[1] + index[:, 1]) * shape[2] + index[:, 2]
    cells, inverse = np.unique(key, return_inverse=True)
    inverse = inverse.reshape(-1)
    sums = np.zeros((len(cells), 3))
    np.add.at(sums, inverse, points)
    counts = np.bincount(inverse, minlength=len(cells)).astype(float)
    block_sum, block_count = np.zeros_like(sums), np.zeros_like(counts)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                other = cells + (dx * shape[1] + dy) * shape[2] + dz
                where = np.clip(np.searchsorted(cells, other), 0, len(cells) - 1)
                found = cells[where] == other
                block_sum[found] += sums[where[found]]
                block_count[found] += counts[where[found]]
    centre = block_sum / block_count[:, None]
    outward = np.einsum("ij,ij->i", normals, points - centre[inverse]) >= 0
    return np.where(outward[:, None], normals, -normals)

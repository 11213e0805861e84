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

"""Surface normals of point clouds by local principal component analysis.

STEP needs one normal per point (Ravaglia et al. 2017, Computers & Graphics
66, Sect. 3.1; the paper used MeshLab's normal plugin, whose settings it does
not give). Here the normal of a point is the eigenvector of smallest
eigenvalue of the covariance of its ``k`` nearest neighbours. When the
position of the scanner that saw a point is known, the normal is flipped to
face it, which on convex stems makes it point outwards (the condition of the
paper's oriented voting rule, its eq. 5).

On noisy clouds a fixed ``k`` fails: once the noise reaches the
``k``-neighbour scale the neighbourhood is a thick, nearly isotropic slab and
its smallest eigenvector is random (DS1c, 3 pts/cm^2: median error 23 / 38 /
51 deg at 1 / 2 / 5 cm of uniform noise with ``k = 16``).
:func:`multiscale_normals` therefore also fits planes over balls 2, 4, 8 and
16 times the ``k``-neighbour radius and keeps, per point, the scale of least
surface variation ``l0 / (l0 + l1 + l2)`` (Pauly, Keiser & Gross 2003,
Eurographics, "Multi-scale feature extraction on point-sampled surfaces"):
noise makes small balls vary, curvature and nearby structures large ones. A
coarser ball must be at least twice as flat as the plane it replaces: on
clean thin branches a ball wider than the branch is flatter by chance or
because its width grows while its thickness stops at the branch's radius
(the quick suite's leafy tree at 0.08 deg: 20 % of the wood points took a
coarser ball, 8 % with the factor of two).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from woody.cloud import check_points, check_viewpoints
from woody.errors import WoodyError

#: Points per vectorised block (bounds the (block, k, 3) neighbour array).
_BLOCK = 100_000
#: Second moments kept per voxel, as (row, column) of the covariance.
_PAIRS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
#: Voxels per ball radius of the coarse scales (assumption: 3 keeps the ball
#: round to a third of its radius; chosen with ``_BALL_VOXELS`` on the DS1c
#: cylinder, seed 0, for a run time of about three times the k = 16 PCA).
_VOXELS_PER_RADIUS = 3.0
#: Least ratio of the middle to the largest covariance eigenvalue of a
#: coarse ball for its plane to be used: a ball within a surface spreads its
#: points as a disc (ratio 1); one that reaches past the surface's edge, e.g.
#: across the visible arc of a stem (a strip) or at a scan's border (a half
#: disc: 0.28), is no patch of it (assumption: 0.5, between the two; checked
#: on the 120-deg arc of tests/test_woody_step.py and the DS1c cylinder).
_DISC = 0.5
#: Factor by which a coarse ball's surface variation must be below that of the plane a point has so far for the
#: ball to replace it. On a plane with noise the variation falls with the ball's area (a quarter per doubling of
#: the radius) while a noise-free patch keeps its own, so a ball merely as varied as the smaller one is no sign
#: of noise; on a clean, curved or cluttered cloud (thin branches, forks, leaves) the scales' variations are
#: about equal and the least of them is a matter of chance, often a ball that reaches a neighbouring surface
#: (assumption: 2, the geometric middle of 1, any decrease, and 4, the noise's quarter).
_FLATTER = 2.0
#: Nearest voxels summed per point at a coarse scale (a ball of 3 voxel radii
#: on a surface holds about 28 per layer of voxels).
_BALL_VOXELS = 32


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
    points, viewpoints = _checked(points, k, viewpoints)
    return _facing(_knn_pca(points, k)[0], points, viewpoints)


def multiscale_normals(points, k: int = 16, viewpoints=None, levels: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals by PCA at the scale of least surface variation, and the noise about each fitted plane.

    Scale 0 is :func:`pca_normals` (the ``k`` nearest neighbours, radius
    ``r0``: the median distance to the ``k``-th neighbour). Scale ``j``
    (1 to ``levels``) sums the moments of the points over a ball of radius
    ``r0 2^j``: the points are binned in cubic voxels of edge a third of
    that radius and the moments of the (at most 32) voxels whose centroid
    lies within the radius are added. Going from fine to coarse, a scale's
    plane replaces a point's plane when its surface variation
    ``l0 / (l0 + l1 + l2)`` (eigenvalues of the covariance, ascending) is at
    most half as large (noise alone quarters it per doubling of the radius;
    on a clean patch the scales vary about alike and the least is chance),
    and only where its points spread as a disc (``l1 >= 0.5 l2``), not as
    the strip of a stem's visible arc or a surface's edge. With
    noise of s.d. ``s`` a plane patch of radius ``R`` has a variation of about
    ``s^2 / (R^2 / 2)``, which falls with ``R``; the sagitta of a surface of
    radius of curvature ``c`` adds about ``(R^2 / c)^2 / (12 R^2 / 2)``, which
    grows with it, so the chosen radius is about ``(s c)^(1/2)`` and a clean
    cloud keeps scale 0. The geometric steps of 2 and the 4 levels
    (up to 16 ``r0``) were chosen on the DS1c cylinder (r = 0.5 m, 3
    pts/cm^2, uniform noise 0-5 cm, seed 0: median angle error 0.14 / 0.53 /
    0.77 / 1.40 / 2.08 / 3.33 deg at 0 / 0.5 / 1 / 2 / 3 / 5 cm of noise,
    against 0.1 / 9.9 / 23 / 38 / 45 / 51 deg for ``k = 16`` alone) and
    checked on seed 1 (the same to 0.01 deg).

    Parameters
    ----------
    points : array_like, (n, 3)
        Coordinates, m.
    k : int
        Neighbours of scale 0, the point itself included (see :func:`pca_normals`).
    viewpoints : array_like, (3,) or (n, 3), optional
        Scanner position(s), m: each normal is flipped to face its scanner.
    levels : int
        Coarse scales tried, 0 to 8 (0: :func:`pca_normals` alone).

    Returns
    -------
    normals : ndarray, (n, 3)
        Unit normals.
    noise_m : ndarray, (n,)
        Root mean square distance of the points of the chosen neighbourhood
        from its fitted plane, m (``sqrt(l0)``): the noise, plus the
        sagitta of the patch on a curved surface.

    Examples
    --------
    A plane with 2 cm of Gaussian noise, 1 point per cm^2: the 16-neighbour
    planes are noise, the coarse scales are not.

    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> xy = rng.uniform(-0.5, 0.5, (10_000, 2))
    >>> points = np.column_stack([xy, rng.normal(0, 0.02, 10_000)])
    >>> normals, noise = multiscale_normals(points, viewpoints=(0, 0, 5))
    >>> bool(np.median(normals[:, 2]) > 0.99), round(float(np.median(noise)), 2)
    (True, 0.02)
    """
    if not 0 <= levels <= 8:
        raise WoodyError(f"levels must be between 0 and 8, got {levels}")
    points, viewpoints = _checked(points, k, viewpoints)
    normals, values, reach = _knn_pca(points, k)
    variation, noise = _variation_noise(values / k)
    radius = float(np.median(reach))
    relative = points - points.min(axis=0)
    for level in range(1, levels + 1):
        if radius <= 0:
            break
        coarse, coarse_variation, coarse_noise, disc = _ball_normals(relative, radius * 2.0 ** level)
        better = (_FLATTER * coarse_variation < variation) & disc
        normals[better], variation[better], noise[better] = coarse[better], coarse_variation[better], \
            coarse_noise[better]
    return _facing(normals, points, viewpoints), noise


def _checked(points, k: int, viewpoints) -> tuple[np.ndarray, np.ndarray | None]:
    """The points and viewpoints as arrays, with ``k`` checked against them (:func:`pca_normals`)."""
    points = check_points(points)
    if not 3 <= k <= 200:
        raise WoodyError(f"normal neighbourhood k must be between 3 and 200 points, got {k}")
    if len(points) < k:
        raise WoodyError(f"{len(points)} points are too few for normals from k={k} neighbours")
    return points, check_viewpoints(viewpoints, len(points))


def _knn_pca(points: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smallest eigenvector and ascending eigenvalues of each point's ``k``-neighbour scatter matrix (m^2; the
    covariance times ``k``), and the distance to its ``k``-th neighbour (m)."""
    distances, neighbours = cKDTree(points).query(points, k=k)
    normals, values = np.empty_like(points), np.empty_like(points)
    for start in range(0, len(points), _BLOCK):
        block = points[neighbours[start:start + _BLOCK]]
        block = block - block.mean(axis=1, keepdims=True)
        values[start:start + _BLOCK], vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", block, block))
        normals[start:start + _BLOCK] = vectors[:, :, 0]
    return normals, values, distances[:, -1]


def _facing(normals: np.ndarray, points: np.ndarray, viewpoints: np.ndarray | None) -> np.ndarray:
    """The normals flipped in place to face their viewpoints (unchanged without)."""
    if viewpoints is not None:
        away = np.einsum("ij,ij->i", normals, viewpoints - points) < 0
        normals[away] *= -1.0
    return normals


def _variation_noise(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Surface variation ``l0 / sum(l)`` and ``sqrt(l0)`` (m) of ascending covariance eigenvalues (m^2)."""
    smallest = np.maximum(values[:, 0], 0.0)
    total = values.sum(axis=1)
    return np.where(total > 0, smallest / np.where(total > 0, total, 1.0), 0.0), np.sqrt(smallest)


def _ball_normals(relative: np.ndarray, radius_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Smallest eigenvector, surface variation, ``sqrt(l0)`` and disc test of the points within about ``radius_m``.

    The moments (count, sums, second moments) are binned in voxels of edge
    ``radius_m / _VOXELS_PER_RADIUS`` and summed over the nearest
    ``_BALL_VOXELS`` voxel centroids within ``radius_m``.
    """
    index = np.floor(relative / (radius_m / _VOXELS_PER_RADIUS)).astype(np.int64)
    shape = index.max(axis=0) + 1
    _, voxel = np.unique((index[:, 0] * shape[1] + index[:, 1]) * shape[2] + index[:, 2], return_inverse=True)
    voxel = voxel.reshape(-1)
    count = int(voxel.max()) + 1
    moments = np.column_stack([np.ones(len(relative)), relative]
                              + [relative[:, i] * relative[:, j] for i, j in _PAIRS])
    sums = np.column_stack([np.bincount(voxel, moments[:, c], minlength=count) for c in range(moments.shape[1])])
    voxels = cKDTree(sums[:, 1:4] / sums[:, :1])
    normals, variation, noise = np.empty_like(relative), np.empty(len(relative)), np.empty(len(relative))
    disc = np.empty(len(relative), bool)
    block_size = max(1, _BLOCK // 2)
    for start in range(0, len(relative), block_size):
        stop = start + block_size
        distance, near = voxels.query(relative[start:stop], k=min(_BALL_VOXELS, count), distance_upper_bound=radius_m)
        distance, near = distance.reshape(len(distance), -1), near.reshape(len(near), -1)
        inside = np.isfinite(distance)
        total = np.einsum("nk,nkc->nc", inside.astype(float), sums[np.where(inside, near, 0)])
        mean = total[:, 1:4] / total[:, :1]
        covariance = np.empty((len(total), 3, 3))
        for c, (i, j) in enumerate(_PAIRS):
            covariance[:, i, j] = covariance[:, j, i] = total[:, 4 + c] / total[:, 0] - mean[:, i] * mean[:, j]
        values, vectors = np.linalg.eigh(covariance)
        normals[start:stop] = vectors[:, :, 0]
        variation[start:stop], noise[start:stop] = _variation_noise(values)
        disc[start:stop] = values[:, 1] >= _DISC * values[:, 2]
    return normals, variation, noise, disc


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

"""Point spacing of a cloud and voxel subsampling, so that the methods see about the same density at any scan density.

A terrestrial scan's density spans two orders of magnitude (0.75 pts/cm²
at 10 m with a coarse step, 30 pts/cm² and more at 2 m with a fine one);
the methods' scales (Hough cells, neighbourhoods) are set in metres, so a
cloud far denser than those scales only costs time and memory. Subsampling
keeps one point per voxel: the point nearest the voxel's centroid, which
stays on the surface (a centroid of a curved patch does not).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from woody.cloud import check_points
from woody.errors import WoodyError

#: Points sampled to estimate the spacing of large clouds.
SPACING_SAMPLE = 20000


def point_spacing(points, seed: int = 0) -> float:
    """Typical distance between neighbouring points of a surface cloud, m.

    The median distance of a point to its sixth neighbour times
    ``sqrt(pi / 6)``: on a surface sampled at ``lambda`` points per m², the
    sixth neighbour lies at about ``sqrt(6 / (pi lambda))``, so the result
    is about ``1 / sqrt(lambda)`` for random and grid-like sampling alike
    (the sixth neighbour is not fooled by duplicated points or scan lines).

    Parameters
    ----------
    points : array_like, (n, 3)
        Coordinates, m.
    seed : int
        Seed of the random subset used on clouds of more than 20,000 points.

    Returns
    -------
    float
        Spacing, m (0 if the points coincide).

    Examples
    --------
    >>> import numpy as np
    >>> xy = np.random.default_rng(0).uniform(0, 1, (40000, 2))  # 4 points per cm²
    >>> round(point_spacing(np.column_stack([xy, np.zeros(len(xy))])), 3)
    0.005
    """
    points = check_points(points)
    if len(points) < 7:
        raise WoodyError(f"{len(points)} points are too few to estimate a point spacing (at least 7)")
    tree = cKDTree(points)
    probe = points
    if len(points) > SPACING_SAMPLE:
        probe = points[np.random.default_rng(seed).choice(len(points), SPACING_SAMPLE, replace=False)]
    distance, _ = tree.query(probe, k=7)
    return float(np.median(distance[:, 6]) * np.sqrt(np.pi / 6.0))


def voxel_subsample(points, voxel_m: float) -> np.ndarray:
    """Indices of one point per occupied cubic voxel: the one nearest the voxel's centroid.

    Parameters
    ----------
    points : array_like, (n, 3)
        Coordinates, m.
    voxel_m : float
        Voxel edge, m.

    Returns
    -------
    ndarray of int
        Sorted indices into ``points``.

    Examples
    --------
    >>> import numpy as np
    >>> voxel_subsample(np.array([[0.0, 0, 0], [0.01, 0, 0], [0.3, 0, 0], [0.02, 0, 0]]), 0.1).tolist()
    [1, 2]
    """
    points = check_points(points)
    if not (np.isfinite(voxel_m) and voxel_m > 0):
        raise WoodyError(f"voxel_m must be a positive length in metres, got {voxel_m}")
    voxel, centroid = voxel_centroids(points, voxel_m)
    distance = np.linalg.norm(points - centroid[voxel], axis=1)
    order = np.lexsort((distance, voxel))
    first = np.ones(len(order), bool)
    first[1:] = voxel[order][1:] != voxel[order][:-1]
    return np.sort(order[first])


def voxel_centroids(points: np.ndarray, voxel_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Each point's cubic voxel and the centroid of every occupied voxel.

    Parameters
    ----------
    points : ndarray, (n, 3)
        Coordinates, m.
    voxel_m : float
        Voxel edge, m (positive).

    Returns
    -------
    voxel : ndarray of int, (n,)
        Each point's voxel, an index into ``centroid``.
    centroid : ndarray, (v, 3)
        The mean of each occupied voxel's points, m.
    """
    index = np.floor((points - points.min(axis=0)) / voxel_m).astype(np.int64)
    shape = index.max(axis=0) + 1
    if float(np.prod(shape.astype(float))) >= 2.0**62:
        raise WoodyError(f"voxels of {voxel_m} m over a cloud this large overflow the voxel index; use larger voxels")
    key = (index[:, 0] * shape[1] + index[:, 1]) * shape[2] + index[:, 2]
    _, voxel, counts = np.unique(key, return_inverse=True, return_counts=True)
    voxel = voxel.reshape(-1)
    centroid = np.zeros((len(counts), 3))
    np.add.at(centroid, voxel, points)
    return voxel, centroid / counts[:, None]


def thin_to_spacing(points, spacing_m: float, seed: int = 0) -> np.ndarray:
    """Indices of a random subset whose point spacing is about ``spacing_m``: a fraction ``(s / spacing_m)^2`` of
    the points, ``s`` their spacing (:func:`point_spacing`); all of them when ``s >= spacing_m``.

    Unlike one point per voxel (:func:`voxel_subsample`), a random subset keeps the cloud's mix of surface points
    and scatter (range noise, mixed pulses along the beam): voxels thin a surface but keep every isolated stray
    point, so the denser the scan, the larger the strays' share of what is kept.

    Parameters
    ----------
    points : array_like, (n, 3)
        Coordinates, m.
    spacing_m : float
        Point spacing sought, m.
    seed : int
        Seed of the draw (same seed, same subset).

    Returns
    -------
    ndarray of int
        Sorted indices into ``points`` (at least 7).

    Examples
    --------
    >>> import numpy as np
    >>> xy = np.random.default_rng(0).uniform(0, 1, (40000, 2))  # 4 points per cm², 5 mm apart
    >>> plane = np.column_stack([xy, np.zeros(len(xy))])
    >>> kept = thin_to_spacing(plane, 0.01)
    >>> len(kept) in range(9000, 11000), round(point_spacing(plane[kept]), 3)
    (True, 0.01)
    """
    points = check_points(points)
    if not (np.isfinite(spacing_m) and spacing_m > 0):
        raise WoodyError(f"spacing_m must be a positive length in metres, got {spacing_m}")
    spacing = point_spacing(points, seed)
    count = max(7, int(round(len(points) * min(1.0, (spacing / spacing_m) ** 2))))
    return np.sort(np.random.default_rng(seed).choice(len(points), count, replace=False))

"""Benchmark metrics, defined once: point-to-surface distances, ROP, losses, leaf-trait errors.

Definitions (tls-physics digest §3 and §7.10; prior-art digest §2.3):

- A returned point is an **outlier** when its distance to the true surface of
  the object it is attributed to (the scan's ``truth_id``: the object that
  returned most of the pulse's power) exceeds τ. Two thresholds are
  reported: τ = max(3·σ_range, 2 mm) (:func:`auto_tau`), with σ_range the
  range noise measured on the leaf's pure returns (:func:`robust_sigma`), and
  τ = 1 cm, the "true" outliers that visibly distort a leaf.
- **ROP** (ratio of outliers to points) of a leaf = outliers / points, over
  the returned points with at least 10 % of their footprint power from the
  leaf (:func:`leaf_power_share`; the share is configurable).
- After a variant: ROP after = outliers / points among the points the
  variant kept (moved points are judged at their new place); **ROP
  reduction** = 1 − ROP after / ROP before; **good points lost** = share of
  the non-outliers the variant dropped; **outliers restored** = share of the
  outliers that the variant kept and moved to within τ of the truth.
- Leaf traits: relative area error, and elevation / azimuth errors of the
  midrib compared as undirected axes (:func:`axis_angle_errors`).

All functions take and return plain numpy data; lengths in metres.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree
from trimesh.triangles import closest_point

#: Floor of the automatic outlier threshold, m (tls-physics digest §7.10).
TAU_FLOOR_M = 0.002
#: Threshold of the "true" outliers, m (digest §7.10, after the thesis' subtle/true split).
TAU_TRUE_M = 0.01
#: Smallest footprint power share from a leaf for a point to count on that leaf (digest §7.10).
MIN_POWER_SHARE = 0.1
#: Consistency factor of the median absolute deviation for a normal distribution.
MAD_TO_SIGMA = 1.4826

#: Work sizes of :func:`surface_distance` (memory bounds).
_CHUNK_PAIRS = 2_000_000
#: Smallest cluster size of :func:`surface_distance` (clusters hold up to max(16, sqrt(F)) triangles,
#: which balances the box tests, points x clusters, against the triangle tests inside kept clusters).
_CLUSTER_SIZE = 16


def surface_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                     signed: bool = False) -> np.ndarray:
    """Exact distance from points to a triangle mesh.

    The triangles are grouped into compact clusters (recursive median splits
    of their centroids, about √F triangles each) with an oriented bounding
    box each. The distance to the triangle of the nearest
    centroid is an upper bound ``u`` of a point's answer; a cluster whose box
    lies farther than ``u`` cannot hold a closer triangle, so only the
    triangles of the other clusters are tested exactly with
    :func:`trimesh.triangles.closest_point`. Oriented boxes keep the bound
    tight for points far from a flat or gently curved surface (mixed points
    behind a leaf), where bounding spheres would keep the whole mesh. Within
    the kept clusters, a cheap per-triangle bound (plane distance and
    in-plane distance to the triangle's circumscribing disc) leaves only a
    few triangles per point to test exactly.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Query points, m.
    vertices : ndarray, shape (V, 3)
        Mesh vertices, m.
    faces : ndarray, shape (F, 3)
        Triangles.
    signed : bool
        Return the distance signed by the side of the closest triangle
        (positive on the side its normal points to).

    Returns
    -------
    ndarray, shape (n,)
        Distance, m.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0)
    triangles = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    centroids = triangles.mean(axis=1)
    radius = np.linalg.norm(triangles - centroids[:, None], axis=2).max(axis=1)
    cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    length = np.linalg.norm(cross, axis=1, keepdims=True)
    unit_normal = np.divide(cross, length, out=np.zeros_like(cross), where=length > 0)
    _, nearest = cKDTree(centroids).query(points)
    best = np.linalg.norm(closest_point(triangles[nearest], points) - points, axis=1)
    best_face = nearest.copy()
    order, starts, counts, center, axes, half = _clusters(triangles, centroids)
    step = max(1, _CHUNK_PAIRS // len(starts))
    for lo in range(0, len(points), step):
        chunk = np.arange(lo, min(lo + step, len(points)))
        # Distance to every box: per box axis j, |p·a_j - c·a_j| beyond the half extent (three GEMMs).
        gap2 = np.zeros((len(chunk), len(starts)))
        for j in range(3):
            along = points[chunk] @ axes[:, j].T - np.einsum("ck,ck->c", center, axes[:, j])
            gap2 += np.maximum(np.abs(along) - half[:, j], 0.0) ** 2
        p, c = np.nonzero(gap2 <= (best[chunk, None] * (1 + 1e-9) + 1e-12) ** 2)
        # Expand (point, cluster) pairs to (point, triangle) pairs ...
        p = np.repeat(chunk[p], counts[c])
        offsets = np.arange(len(p)) - np.repeat(np.cumsum(counts[c]) - counts[c], counts[c])
        f = order[np.repeat(starts[c], counts[c]) + offsets]
        # ... and keep those whose triangle may be closer: sqrt(h² + max(0, l - R)²) bounds the
        # distance (h: to the triangle's plane, l: in-plane to its centroid, R: its radius).
        offset = points[p] - centroids[f]
        h = np.einsum("ij,ij->i", offset, unit_normal[f])
        lateral = np.sqrt(np.maximum(np.einsum("ij,ij->i", offset, offset) - h * h, 0.0))
        keep = h * h + np.maximum(lateral - radius[f], 0.0) ** 2 <= (best[p] * (1 + 1e-9) + 1e-12) ** 2
        p, f = p[keep], f[keep]
        for sub in range(0, len(p), _CHUNK_PAIRS):
            pp, ff = p[sub:sub + _CHUNK_PAIRS], f[sub:sub + _CHUNK_PAIRS]
            d = np.linalg.norm(closest_point(triangles[ff], points[pp]) - points[pp], axis=1)
            first = np.lexsort((d, pp))
            first = first[np.r_[True, pp[first][1:] != pp[first][:-1]]]
            better = d[first] < best[pp[first]]
            best[pp[first][better]] = d[first][better]
            best_face[pp[first][better]] = ff[first][better]
    if not signed:
        return best
    side = np.einsum("ij,ij->i", points - closest_point(triangles[best_face], points), cross[best_face])
    return np.where(side < 0, -best, best)


def _clusters(triangles: np.ndarray, centroids: np.ndarray):
    """Clusters of triangles with oriented bounding boxes.

    Returns
    -------
    order : ndarray of int
        Triangle ids grouped by cluster.
    starts, counts : ndarray of int
        Where each cluster's ids start in ``order`` and how many there are.
    center, axes, half : ndarray
        Box centre (C, 3), axes as rows (C, 3, 3) and half extents (C, 3).
    """
    size = max(_CLUSTER_SIZE, int(math.sqrt(len(triangles))))
    groups, stack = [], [np.arange(len(triangles))]
    while stack:
        ids = stack.pop()
        if len(ids) <= size:
            groups.append(ids)
            continue
        c = centroids[ids]
        split = np.argsort(c[:, np.argmax(np.ptp(c, axis=0))])
        stack += [ids[split[: len(ids) // 2]], ids[split[len(ids) // 2:]]]
    counts = np.array([len(g) for g in groups])
    starts = np.cumsum(counts) - counts
    center, axes, half = np.zeros((len(groups), 3)), np.zeros((len(groups), 3, 3)), np.zeros((len(groups), 3))
    for k, ids in enumerate(groups):
        corners = triangles[ids].reshape(-1, 3)
        mean = corners.mean(axis=0)
        frame = np.linalg.eigh(np.cov((corners - mean).T) if len(corners) > 1 else np.eye(3))[1].T
        local = (corners - mean) @ frame.T
        low, high = local.min(axis=0), local.max(axis=0)
        center[k] = mean + ((low + high) / 2) @ frame
        axes[k] = frame
        half[k] = (high - low) / 2
    return np.concatenate(groups), starts, counts, center, axes, half


def robust_sigma(values: np.ndarray) -> float:
    """Standard deviation estimated as 1.4826 × the median absolute deviation (NaN when empty)."""
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    if len(values) == 0:
        return math.nan
    return float(MAD_TO_SIGMA * np.median(np.abs(values - np.median(values))))


def auto_tau(sigma_range_m: float) -> float:
    """Outlier threshold τ = max(3·σ_range, 2 mm), m (2 mm when σ is unknown)."""
    return TAU_FLOOR_M if not np.isfinite(sigma_range_m) else max(3.0 * sigma_range_m, TAU_FLOOR_M)


def leaf_power_share(truth_id: np.ndarray, mixed_fraction: np.ndarray, object_id: int,
                     reach_px: int) -> np.ndarray:
    """Share of each pulse's returned power that came from one object.

    The scan records the dominant object of each pulse (``truth_id``) and
    the power share of all others (``mixed_fraction``). On pulses dominated
    by the object the share is ``1 − mixed_fraction``; on pulses dominated by
    another object but within ``reach_px`` pixels of the object's own pulses
    (the footprint can reach it) the minority power is attributed to the
    object, which is exact where two objects meet and an upper bound where a
    third one shares the footprint.

    Parameters
    ----------
    truth_id : ndarray of int, (rows, cols)
        Dominant object of each pulse (-1: none).
    mixed_fraction : ndarray, (rows, cols)
        Power share not from the dominant object.
    object_id : int
        The object.
    reach_px : int
        How far (pixels) the footprint of a pulse reaches.

    Returns
    -------
    ndarray, (rows, cols)
        Power share in [0, 1].
    """
    own = truth_id == object_id
    mixed = np.nan_to_num(np.asarray(mixed_fraction, dtype=np.float64), nan=0.0)
    size = 2 * max(int(reach_px), 0) + 1
    near = ndimage.maximum_filter(own, size=size) & ~own & (truth_id >= 0)
    return np.where(own, 1.0 - mixed, np.where(near, mixed, 0.0))


def outlier_scores(outlier_before: np.ndarray, kept: np.ndarray, outlier_after: np.ndarray) -> dict:
    """ROP before and after a variant, and what the variant did to good points and outliers.

    Parameters
    ----------
    outlier_before : ndarray of bool, (n,)
        Measured points that are outliers.
    kept : ndarray of bool, (n,)
        Points the variant kept (possibly moved).
    outlier_after : ndarray of bool, (n,)
        Kept points that are outliers at their output position (ignored where not kept).

    Returns
    -------
    dict
        ``n_points``, ``n_outliers``, ``rop_before``, ``rop_after``,
        ``rop_reduction``, ``good_points_lost``, ``outliers_removed``,
        ``outliers_restored``, ``good_points_damaged`` (NaN where a
        denominator is zero, except ``rop_after``, which is 0 when the
        variant kept no point: no outlier remains, and ``good_points_lost``
        shows the cost).
    """
    before = np.asarray(outlier_before, dtype=bool)
    kept = np.asarray(kept, dtype=bool)
    after = np.asarray(outlier_after, dtype=bool) & kept
    n, n_out = len(before), int(before.sum())
    n_good, n_kept = n - n_out, int(kept.sum())
    rop_before = _ratio(n_out, n)
    rop_after = _ratio(int(after.sum()), n_kept) if n_kept else 0.0
    return {
        "n_points": n,
        "n_outliers": n_out,
        "rop_before": rop_before,
        "rop_after": rop_after,
        "rop_reduction": 1.0 - rop_after / rop_before if rop_before > 0 and np.isfinite(rop_after) else math.nan,
        "good_points_lost": _ratio(int((~before & ~kept).sum()), n_good),
        "outliers_removed": _ratio(int((before & ~kept).sum()), n_out),
        "outliers_restored": _ratio(int((before & kept & ~after).sum()), n_out),
        "good_points_damaged": _ratio(int((~before & after).sum()), n_good),
    }


def _ratio(numerator: int, denominator: int) -> float:
    return numerator / denominator if denominator else math.nan


def relative_error(estimate: float, truth: float) -> float:
    """Signed relative error ``(estimate − truth) / truth``."""
    return (estimate - truth) / truth


def direction_from_angles(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """Unit vector of a direction given by elevation above the horizontal and azimuth from +x, degrees."""
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def axis_angle_errors(elevation_deg: float, azimuth_deg: float, true_elevation_deg: float,
                      true_azimuth_deg: float) -> tuple[float, float]:
    """Elevation and azimuth errors of an axis whose sense is unknown, degrees.

    A direction estimated from points (e.g. a principal axis) has no sense:
    the estimate is flipped when it points away from the truth before the
    angles are compared. The azimuth error is wrapped into [0, 180].

    Returns
    -------
    elevation_error_deg, azimuth_error_deg : float
        Absolute errors.
    """
    estimate = direction_from_angles(elevation_deg, azimuth_deg)
    truth = direction_from_angles(true_elevation_deg, true_azimuth_deg)
    if np.dot(estimate, truth) < 0:
        estimate = -estimate
    el = math.degrees(math.asin(float(np.clip(estimate[2], -1, 1))))
    az = math.degrees(math.atan2(estimate[1], estimate[0]))
    az_err = abs((az - true_azimuth_deg + 180.0) % 360.0 - 180.0)
    return abs(el - true_elevation_deg), az_err


def rms(values: np.ndarray) -> float:
    """Root mean square (NaN when empty)."""
    values = np.asarray(values, dtype=np.float64)
    return float(np.sqrt(np.mean(values ** 2))) if len(values) else math.nan

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
from scipy.spatial import cKDTree
from trimesh.triangles import closest_point

#: Floor of the automatic outlier threshold, m (tls-physics digest §7.10).
TAU_FLOOR_M = 0.002
#: Threshold of the "true" outliers, m (digest §7.10, after the thesis' subtle/true split).
TAU_TRUE_M = 0.01
#: Smallest footprint power share from a leaf for a point to count on that leaf (digest §7.10).
MIN_POWER_SHARE = 0.1
#: Leaves with at least this share of their silhouette unhidden count as visible: their area is scored (issue 16).
MIN_VISIBILITY = 0.8
#: Consistency factor of the median absolute deviation for a normal distribution.
MAD_TO_SIGMA = 1.4826

#: Work sizes of :func:`surface_distance` (memory bounds).
_CHUNK_PAIRS = 2_000_000
#: Triangles per leaf of the hierarchy of :class:`SurfaceDistance`, and points per chunk of a query.
_LEAF_SIZE = 8
_CHUNK_POINTS = 32768


class SurfaceDistance:
    """Exact distance from points to one triangle mesh (the mesh is prepared once, queried often).

    The mesh gets a bounding-volume hierarchy: recursive median splits of
    the triangle centroids down to :data:`_LEAF_SIZE` triangles, with an
    oriented bounding box per node (oriented boxes stay tight around flat
    or gently curved patches, so points far from a leaf, such as mixed
    points behind it, prune as well as points on it). A point starts from
    the exact distance ``u`` to the triangle of its nearest centroid and
    descends the hierarchy level by level, keeping only the nodes whose box
    lies within ``u``; in the leaves it keeps only triangles whose bound
    ``sqrt(h² + max(0, l − R)²)`` (``h``: distance to the triangle's plane,
    ``l``: in-plane distance to its centroid, ``R``: its radius) is within
    ``u``, and tests those exactly with :func:`trimesh.triangles.closest_point`.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        Mesh vertices, m.
    faces : ndarray, shape (F, 3)
        Triangles.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.triangles = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
        self.centroids = self.triangles.mean(axis=1)
        self.radius = np.linalg.norm(self.triangles - self.centroids[:, None], axis=2).max(axis=1)
        self.cross = np.cross(self.triangles[:, 1] - self.triangles[:, 0], self.triangles[:, 2] - self.triangles[:, 0])
        length = np.linalg.norm(self.cross, axis=1, keepdims=True)
        self.unit_normal = np.divide(self.cross, length, out=np.zeros_like(self.cross), where=length > 0)
        self.centroid_tree = cKDTree(self.centroids)
        self.order, self.start, self.count, self.children, level = _hierarchy(self.centroids)
        self.axes, self.offset, self.half = _oriented_boxes(self.triangles[self.order], self.start, self.count, level)

    def __call__(self, points: np.ndarray, signed: bool = False) -> np.ndarray:
        """Distance of ``points`` (n, 3) to the mesh, m; signed by the side of the closest triangle if asked."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        _, face = self.centroid_tree.query(points)
        face = np.asarray(face, dtype=np.int64).reshape(-1)
        best = np.linalg.norm(closest_point(self.triangles[face], points) - points, axis=1)
        for lo in range(0, len(points), _CHUNK_POINTS):
            p = np.arange(lo, min(lo + _CHUNK_POINTS, len(points)))
            node = np.zeros(len(p), dtype=np.int64)
            while len(p):
                local = np.einsum("ij,ikj->ik", points[p], self.axes[node]) - self.offset[node]
                near = (np.maximum(np.abs(local) - self.half[node], 0.0) ** 2).sum(axis=1) <= _slack(best[p]) ** 2
                p, node = p[near], node[near]
                leaf = self.children[node, 0] < 0
                positions, owner = _ranges(self.start[node[leaf]], self.start[node[leaf]] + self.count[node[leaf]])
                self._test(points, p[leaf][owner], self.order[positions], best, face)
                p = np.repeat(p[~leaf], 2)
                node = self.children[node[~leaf]].ravel()
        if not signed:
            return best
        side = np.einsum("ij,ij->i", points - closest_point(self.triangles[face], points), self.cross[face])
        return np.where(side < 0, -best, best)

    def _test(self, points, p, f, best, face) -> None:
        """Test triangles ``f`` for points ``p`` (pairs); update ``best`` and ``face`` in place."""
        offset = points[p] - self.centroids[f]
        h = np.einsum("ij,ij->i", offset, self.unit_normal[f])
        lateral = np.sqrt(np.maximum(np.einsum("ij,ij->i", offset, offset) - h * h, 0.0))
        keep = h * h + np.maximum(lateral - self.radius[f], 0.0) ** 2 <= _slack(best[p]) ** 2
        p, f = p[keep], f[keep]
        if len(p) == 0:
            return
        d = np.linalg.norm(closest_point(self.triangles[f], points[p]) - points[p], axis=1)
        first = np.lexsort((d, p))
        first = first[np.r_[True, p[first][1:] != p[first][:-1]]]
        better = d[first] < best[p[first]]
        best[p[first][better]] = d[first][better]
        face[p[first][better]] = f[first][better]


def _ranges(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Concatenated positions ``lo[i] .. hi[i] - 1`` and the index ``i`` of each."""
    counts = hi - lo
    owner = np.repeat(np.arange(len(lo)), counts)
    return np.repeat(lo, counts) + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts), owner


def _reduce(ufunc, values: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """``ufunc`` reduced over consecutive runs of ``counts`` rows of ``values`` (every count >= 1)."""
    return ufunc.reduceat(values, np.cumsum(counts) - counts, axis=0)


def _hierarchy(centroids: np.ndarray):
    """Median-split hierarchy of triangles, built level by level (one sort per level).

    Returns
    -------
    order : ndarray of int, (F,)
        Triangle ids; every node covers a contiguous range of it.
    start, count : ndarray of int, (N,)
        Range of each node in ``order`` (node 0 is the root).
    children : ndarray of int, (N, 2)
        Child nodes (-1 for leaves).
    level : ndarray of int, (N,)
        Depth of each node (nodes of one level cover disjoint ranges).
    """
    n = len(centroids)
    order = np.arange(n)
    start, count, level = [np.array([0])], [np.array([n])], [np.array([0])]
    children = [np.full((1, 2), -1)]
    total = 1
    active = np.array([0]) if n > _LEAF_SIZE else np.zeros(0, dtype=int)
    depth = 0
    while len(active):
        s, c = np.concatenate(start)[active], np.concatenate(count)[active]
        positions, owner = _ranges(s, s + c)
        points = centroids[order[positions]]
        axis = np.argmax(_reduce(np.maximum, points, c) - _reduce(np.minimum, points, c), axis=1)
        order[positions] = order[positions[np.lexsort((points[np.arange(len(owner)), axis[owner]], owner))]]
        half = c // 2
        ids = total + np.arange(2 * len(active))
        all_children = np.concatenate(children)
        all_children[active] = ids.reshape(-1, 2)
        child_start = np.stack([s, s + half], axis=1).ravel()
        child_count = np.stack([half, c - half], axis=1).ravel()
        children = [all_children, np.full((len(ids), 2), -1)]
        start.append(child_start)
        count.append(child_count)
        depth += 1
        level.append(np.full(len(ids), depth))
        total += len(ids)
        active = ids[child_count > _LEAF_SIZE]
    return order, np.concatenate(start), np.concatenate(count), np.concatenate(children), np.concatenate(level)


def _oriented_boxes(triangles: np.ndarray, start: np.ndarray, count: np.ndarray, level: np.ndarray):
    """Oriented bounding box of every node from the vertices of its triangles (in hierarchy order).

    The axes are the principal axes of the node's vertices (from prefix sums
    of coordinates and their products); the extents are exact.

    Returns
    -------
    axes : ndarray, (N, 3, 3)
        Box axes as rows.
    offset : ndarray, (N, 3)
        Box centre along each axis.
    half : ndarray, (N, 3)
        Half extents.
    """
    corners = triangles.reshape(-1, 3)
    first = np.concatenate([np.zeros((1, 3)), np.cumsum(corners, axis=0)])
    second = np.concatenate([np.zeros((1, 3, 3)), np.cumsum(corners[:, :, None] * corners[:, None, :], axis=0)])
    lo, hi = 3 * start, 3 * (start + count)
    size = (hi - lo)[:, None]
    mean = (first[hi] - first[lo]) / size
    covariance = (second[hi] - second[lo]) / size[:, :, None] - mean[:, :, None] * mean[:, None, :]
    axes = np.swapaxes(np.linalg.eigh(covariance)[1], 1, 2)
    low, high = np.zeros((len(start), 3)), np.zeros((len(start), 3))
    for depth in range(level.max() + 1):  # nodes of one level hold disjoint vertices
        nodes = np.nonzero(level == depth)[0]
        positions, owner = _ranges(lo[nodes], hi[nodes])
        along = np.einsum("ij,ikj->ik", corners[positions], axes[nodes[owner]])
        low[nodes] = _reduce(np.minimum, along, hi[nodes] - lo[nodes])
        high[nodes] = _reduce(np.maximum, along, hi[nodes] - lo[nodes])
    return axes, (low + high) / 2, (high - low) / 2


def _slack(bound):
    """An upper bound widened by rounding error, so that ties are always tested exactly."""
    return bound * (1 + 1e-9) + 1e-12


def surface_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                     signed: bool = False) -> np.ndarray:
    """Exact distance from points to a triangle mesh, m (see :class:`SurfaceDistance`).

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
    """
    return SurfaceDistance(vertices, faces)(points, signed)


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


def leaf_power_share(truth_id: np.ndarray, mixed_fraction: np.ndarray, second_id: np.ndarray,
                     second_fraction: np.ndarray, object_id: int) -> np.ndarray:
    """Share of each pulse's returned power that came from one object.

    A simulated scan records, per pulse, the object that returned the most
    power (``truth_id``) and the share of all others (``mixed_fraction``),
    and the object with the next largest power (layer ``truth_second_id``)
    with its share (layer ``second_fraction``). The object's share is
    ``1 − mixed_fraction`` where it dominates, ``second_fraction`` where it
    comes second and 0 elsewhere: exact wherever at most two objects share
    a footprint (where three or more do, an object ranked third or lower
    gets 0, at most ``mixed_fraction − second_fraction`` too little).

    Parameters
    ----------
    truth_id : ndarray of int, (rows, cols)
        Dominant object of each pulse (-1: none).
    mixed_fraction : ndarray, (rows, cols)
        Power share not from the dominant object (NaN where nothing returned).
    second_id : ndarray of int, (rows, cols)
        Object with the second largest returned power (-1: none).
    second_fraction : ndarray, (rows, cols)
        Its power share.
    object_id : int
        The object.

    Returns
    -------
    ndarray, (rows, cols)
        Power share in [0, 1].
    """
    mixed = np.nan_to_num(np.asarray(mixed_fraction, dtype=np.float64), nan=0.0)
    second = np.nan_to_num(np.asarray(second_fraction, dtype=np.float64), nan=0.0)
    return np.where(truth_id == object_id, 1.0 - mixed, np.where(second_id == object_id, second, 0.0))


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
    rop_before = ratio(n_out, n)
    rop_after = ratio(int(after.sum()), n_kept) if n_kept else 0.0
    return {
        "n_points": n,
        "n_outliers": n_out,
        "rop_before": rop_before,
        "rop_after": rop_after,
        "rop_reduction": 1.0 - rop_after / rop_before if rop_before > 0 and np.isfinite(rop_after) else math.nan,
        "good_points_lost": ratio(int((~before & ~kept).sum()), n_good),
        "outliers_removed": ratio(int((before & ~kept).sum()), n_out),
        "outliers_restored": ratio(int((before & kept & ~after).sum()), n_out),
        "good_points_damaged": ratio(int((~before & after).sum()), n_good),
    }


def ratio(numerator: int, denominator: int) -> float:
    """``numerator / denominator``, NaN when the denominator is zero.

    Parameters
    ----------
    numerator : int
        Count above the fraction bar.
    denominator : int
        Count below it.

    Returns
    -------
    float
        The ratio (dimensionless), or NaN.
    """
    return numerator / denominator if denominator else math.nan


def height_errors(estimate: np.ndarray, truth: np.ndarray, mask: np.ndarray, tolerance: float = 0.05) -> dict:
    """Errors of a reconstructed height image, relative to the surface's height range (thesis ch.5 eqs 3.1-3.2).

    ``eps = (estimate - truth) / h_tot`` with ``h_tot = h_max - h_min`` of
    the true surface, over the reconstructed pixels of ``mask``.

    Parameters
    ----------
    estimate : ndarray
        Reconstructed heights (NaN where not reconstructed), in the unit of ``truth``.
    truth : ndarray
        True heights, same shape and unit.
    mask : ndarray of bool
        Pixels of the surface.
    tolerance : float
        Relative error counted as within (fraction of ``h_tot``, dimensionless).

    Returns
    -------
    dict
        ``eps_mean`` (signed mean, eq 3.1), ``abs_eps_mean`` and
        ``abs_eps_median`` (eq 3.2), ``within_5pct`` (share of reconstructed
        pixels with ``|eps| < tolerance``; the thesis' "95 % of the points
        within 5 % of the radius" criterion), ``completeness`` (share of the
        surface's pixels reconstructed).
    """
    mask = np.asarray(mask, dtype=bool)
    h_tot = float(np.ptp(truth[mask]))
    done = mask & np.isfinite(estimate)
    eps = (estimate[done] - truth[done]) / h_tot if h_tot > 0 else np.zeros(int(done.sum()))
    if len(eps) == 0:
        return {"eps_mean": math.nan, "abs_eps_mean": math.nan, "abs_eps_median": math.nan,
                "within_5pct": math.nan, "completeness": 0.0}
    return {"eps_mean": float(eps.mean()), "abs_eps_mean": float(np.abs(eps).mean()),
            "abs_eps_median": float(np.median(np.abs(eps))), "within_5pct": float(np.mean(np.abs(eps) < tolerance)),
            "completeness": float(done.sum() / mask.sum())}


def relative_error(estimate: float, truth: float) -> float:
    """Signed relative error ``(estimate − truth) / truth``.

    Parameters
    ----------
    estimate : float
        Estimated value.
    truth : float
        True value, same unit, non-zero.

    Returns
    -------
    float
        Relative error (dimensionless).
    """
    return (estimate - truth) / truth


def direction_from_angles(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """Unit vector of a direction given by elevation above the horizontal and azimuth from +x, degrees.

    Parameters
    ----------
    elevation_deg : float
        Elevation above the horizontal, degrees.
    azimuth_deg : float
        Azimuth from +x towards +y, degrees.

    Returns
    -------
    ndarray
        Unit vector, shape ``(3,)``.
    """
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def aligned_axis_angles(elevation_deg: float, azimuth_deg: float, true_elevation_deg: float,
                        true_azimuth_deg: float) -> tuple[float, float]:
    """Elevation and azimuth of an axis whose sense is unknown, expressed next to the true axis, degrees.

    A direction estimated from points (e.g. a principal axis) has no sense:
    the estimate is flipped when it points away from the truth. Its azimuth
    is then unwrapped to within 180 deg of the true azimuth, so that
    estimated and true angles can be regressed against each other.

    Parameters
    ----------
    elevation_deg, azimuth_deg : float
        The estimated axis.
    true_elevation_deg, true_azimuth_deg : float
        The true axis.

    Returns
    -------
    elevation_deg, azimuth_deg : float
        The estimate, aligned.
    """
    estimate = direction_from_angles(elevation_deg, azimuth_deg)
    if np.dot(estimate, direction_from_angles(true_elevation_deg, true_azimuth_deg)) < 0:
        estimate = -estimate
    el = math.degrees(math.asin(float(np.clip(estimate[2], -1, 1))))
    az = math.degrees(math.atan2(estimate[1], estimate[0]))
    return el, true_azimuth_deg + (az - true_azimuth_deg + 180.0) % 360.0 - 180.0


def axis_angle_errors(elevation_deg: float, azimuth_deg: float, true_elevation_deg: float,
                      true_azimuth_deg: float) -> tuple[float, float]:
    """Absolute elevation and azimuth errors of an axis whose sense is unknown (:func:`aligned_axis_angles`), degrees.

    Parameters
    ----------
    elevation_deg, azimuth_deg : float
        The estimated axis.
    true_elevation_deg, true_azimuth_deg : float
        The true axis.

    Returns
    -------
    elevation_error_deg, azimuth_error_deg : float
        Absolute errors (the azimuth error in [0, 180]).
    """
    el, az = aligned_axis_angles(elevation_deg, azimuth_deg, true_elevation_deg, true_azimuth_deg)
    return abs(el - true_elevation_deg), abs(az - true_azimuth_deg)


def linear_fit(truth: np.ndarray, estimate: np.ndarray) -> dict:
    """Least-squares line of estimated against true values (thesis ch.7), with its R².

    Parameters
    ----------
    truth : ndarray, (n,)
        True values (the regressor).
    estimate : ndarray, (n,)
        Estimated values.

    Returns
    -------
    dict
        ``slope``, ``intercept`` (in the unit of the values) and ``r2``
        (``1 - SS_res / SS_tot`` of the estimates about the line: the share
        of their variance the line explains); NaN with fewer than two
        points or no spread of the truth (``r2`` NaN without spread of the
        estimates).
    """
    x, y = np.asarray(truth, dtype=np.float64), np.asarray(estimate, dtype=np.float64)
    if len(x) < 2 or np.ptp(x) == 0:
        return {"slope": math.nan, "intercept": math.nan, "r2": math.nan}
    slope, intercept = np.polyfit(x, y, 1)
    total = float(np.sum((y - y.mean()) ** 2))
    residual = float(np.sum((y - (slope * x + intercept)) ** 2))
    return {"slope": float(slope), "intercept": float(intercept),
            "r2": 1.0 - residual / total if total > 0 else math.nan}


def area_bias(estimate: np.ndarray, truth: np.ndarray) -> float:
    """The additive leaf-area BIAS of the thesis (ch.7 eq 2.1): the constant that zeroes the mean relative error.

    ``MRE = (1/n) sum(((a_est + BIAS) - a_true) / a_true) = 0`` gives
    ``BIAS = -sum((a_est - a_true) / a_true) / sum(1 / a_true)``.

    Parameters
    ----------
    estimate : ndarray, (n,)
        Estimated areas (any unit).
    truth : ndarray, (n,)
        True areas (the same unit, positive).

    Returns
    -------
    float
        BIAS in the unit of the areas (NaN when empty): positive when the
        estimates are too small.
    """
    a_est, a_true = np.asarray(estimate, dtype=np.float64), np.asarray(truth, dtype=np.float64)
    if len(a_true) == 0:
        return math.nan
    return float(-np.sum((a_est - a_true) / a_true) / np.sum(1.0 / a_true))


def precision(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Precision of estimates: the standard deviation of their errors ``estimate - truth`` (NaN under two values).

    Parameters
    ----------
    estimate, truth : ndarray, (n,)
        Estimated and true values.
    """
    errors = np.asarray(estimate, dtype=np.float64) - np.asarray(truth, dtype=np.float64)
    return float(np.std(errors, ddof=1)) if len(errors) > 1 else math.nan


def rms(values: np.ndarray) -> float:
    """Root mean square (NaN when empty)."""
    values = np.asarray(values, dtype=np.float64)
    return float(np.sqrt(np.mean(values ** 2))) if len(values) else math.nan

"""Scoring a variant's output on the leaves of a simulated scan against the scene truth.

:func:`prepare_leaves` computes, once per case, what every variant is scored
against: for each target leaf its points (the pulses with at least 10 % of
their power from it), the distance of each measured point to the true
surface of the object it is attributed to, the range noise and the outlier
thresholds. :func:`score_leaf` then scores one variant's output on one leaf
with the definitions of :mod:`benchmarks.metrics`. A variant that runs once
on the whole scan and segments it into leaves itself is scored by
:func:`score_scan`: every true leaf is matched to the output region that
covers most of its visible pulses (the pulses it dominates), is scored on
that match, and is *found* when the match covers at least half of them;
regions that match no leaf are false leaves. Woody objects
(:func:`prepare_wood`, :func:`score_wood`) are scored with the woody
package's own :func:`woody.score`. :mod:`benchmarks.summary` aggregates the
scores over a suite.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from skimage.draw import polygon

from benchmarks import metrics
from benchmarks.errors import BenchError
from benchmarks.registry import VariantOutput
from tlssim.scan import GRID_KEYS, TRUTH_KEYS

#: Pure returns (used for the range noise and the intensity) have less than this power share from other objects.
PURE_MIXED_FRACTION = 1e-3
#: Pixels kept around a leaf's points when its part of the scan is cut out for the variants.
CROP_MARGIN_PX = 8
#: Footprint radii (1/e²) added to that margin, so that pure background lies beyond the mixed band.
CROP_MARGIN_FOOTPRINTS = 2.0
#: Truth layers of a simulated scan naming each pulse's second object and its power share.
SECOND_LAYERS = ("truth_second_id", "second_fraction")


@dataclass
class Target:
    """An object of a simulated scan that variants are scored on.

    Attributes
    ----------
    object_id : int
        Scene object id.
    name, object_type : str
        Object name and type.
    truth : dict
        The object's truth fields (``area_m2``, ``elevation_deg``, ... for
        leaves; ``cylinders`` and ``volume_m3`` for woody objects).
    scan : tlssim.Scan
        The scan, or the part of it that the variants receive.
    mask : ndarray of bool, shape of ``scan``
        The object's points in ``scan``.
    """

    object_id: int
    name: str
    object_type: str
    truth: dict
    scan: object
    mask: np.ndarray


@dataclass
class LeafTruth(Target):
    """What the variants are scored against on one leaf (or analytic surface).

    ``scan`` is the part of the scan around the leaf (its points plus
    :func:`crop_margin_px` pixels); ``mask`` selects the leaf's points: the
    returns with at least ``min_share`` of their power from it.

    Attributes
    ----------
    own : ndarray of bool, (n,)
        Which of the masked points the leaf dominates (``truth_id`` is the leaf).
    attributed : ndarray of int, (n,)
        Object each masked point is attributed to (its ``truth_id``).
    distance : ndarray, (n,)
        Signed distance of each measured point to its object's true surface, m.
    taus : dict of str to float
        Outlier thresholds by label (``auto``: max(3 σ, 2 mm); ``1cm``), m.
    scan_stats : dict
        Properties of the scan on this leaf (range, incidence, noise, intensity, density, visibility).
    surfaces : TruthSurfaces
        Distances to the scene's true surfaces (shared by the leaves of a scan).
    window : tuple of slice
        Where ``scan`` lies in the whole scan (rows, columns).
    """

    own: np.ndarray
    attributed: np.ndarray
    distance: np.ndarray
    taus: dict
    scan_stats: dict
    surfaces: "TruthSurfaces"
    window: tuple

    def own_pixels(self) -> tuple[np.ndarray, np.ndarray]:
        """Rows and columns, in the whole scan, of the pulses the leaf dominates (its visible pulses)."""
        rows, cols = np.nonzero(self.mask)
        return rows[self.own] + self.window[0].start, cols[self.own] + self.window[1].start


def crop_scan(scan, rows: slice, cols: slice):
    """The part ``[rows, cols]`` of a scan's grid, as a scan (arrays are views, not copies).

    Parameters
    ----------
    scan : Scan
        The scan to crop.
    rows : slice
        Grid rows to keep.
    cols : slice
        Grid columns to keep.

    Returns
    -------
    Scan
        The cropped scan (grid, truth and extra layers).
    """
    window = (rows, cols)
    arrays = {key: getattr(scan, key)[window] for key in GRID_KEYS + TRUTH_KEYS if getattr(scan, key) is not None}
    return dataclasses.replace(scan, **arrays, layers={k: v[window] for k, v in scan.layers.items()})


def _window(grid: np.ndarray, margin: int, origin: tuple[int, int], shape: tuple[int, int]) -> tuple[slice, slice]:
    """Bounding box of the true pixels of ``grid`` (a part of a scan starting at pixel ``origin``), widened by
    ``margin`` pixels and kept within the scan's ``shape``, in the scan's pixels."""
    rows, cols = np.nonzero(grid)
    rows, cols = rows + origin[0], cols + origin[1]
    return (slice(max(rows.min() - margin, 0), min(rows.max() + margin + 1, shape[0])),
            slice(max(cols.min() - margin, 0), min(cols.max() + margin + 1, shape[1])))


def grid_steps(scan) -> tuple[float, float]:
    """Angular steps ``(theta, psi)`` of a simulated scan's grid, rad."""
    theta_deg, psi_deg = scan.scanner.window.step_deg
    return math.radians(theta_deg), math.radians(psi_deg)


def crop_margin_px(scan, distance_m: float) -> int:
    """Pixels kept around a leaf's points at ``distance_m``: :data:`CROP_MARGIN_PX` plus
    :data:`CROP_MARGIN_FOOTPRINTS` beam radii (1/e², ``w0 + d tan(divergence)``) in pixels.

    The leaf's points end where its power share falls below 10 %, but pulses
    beyond are still mixed for about two radii; a fixed margin would give a
    method only a sliver of pure background near the scanner (about 7 pixels
    per radius at 0.8 m and 0.018 deg), where the footprint spans many pixels.

    Parameters
    ----------
    scan : Scan
        The scan (its scanner gives the beam radius and angular steps).
    distance_m : float
        Distance of the leaf from the scanner, m.

    Returns
    -------
    int
        Margin, pixels.
    """
    radius_m = scan.scanner.model.beam_radius_m(distance_m)
    radius_px = radius_m / (distance_m * min(grid_steps(scan)))
    return CROP_MARGIN_PX + math.ceil(CROP_MARGIN_FOOTPRINTS * radius_px)


def _require_second_layers(scan) -> None:
    """Raise :class:`BenchError` when ``scan`` lacks the second-object truth layers."""
    missing = [k for k in SECOND_LAYERS if k not in scan.layers]
    if missing:
        raise BenchError(f"the scan lacks the truth layers {missing} (simulated by an older tlssim): re-simulate it")


def object_boxes(scan) -> dict[int, tuple[slice, slice]]:
    """Bounding box of every object's pulses in a simulated scan: those it dominates or comes second in (every pulse
    with a power share from it), by object id.

    Raises
    ------
    BenchError
        If the scan lacks the second-object truth layers.
    """
    _require_second_layers(scan)
    boxes: dict[int, tuple[slice, slice]] = {}
    for ids in (scan.truth_id, scan.layers["truth_second_id"]):
        for index, box in enumerate(ndimage.find_objects(np.where(ids >= 0, ids + 1, 0))):
            if box is None:
                continue
            if index in boxes:
                old = boxes[index]
                box = tuple(slice(min(a.start, b.start), max(a.stop, b.stop)) for a, b in zip(old, box))
            boxes[index] = box
    return boxes


def power_share(scan, object_id: int) -> np.ndarray:
    """Power share of one object in every pulse of a simulated scan (:func:`benchmarks.metrics.leaf_power_share`).

    Parameters
    ----------
    scan : Scan
        A simulated scan with truth and the second-object layers.
    object_id : int
        Scene object index.

    Returns
    -------
    ndarray
        Share of the pulse's power on the object, 0..1, one per grid cell.

    Raises
    ------
    BenchError
        If the scan lacks the second-object truth layers.
    """
    _require_second_layers(scan)
    return metrics.leaf_power_share(scan.truth_id, scan.mixed_fraction, scan.layers["truth_second_id"],
                                    scan.layers["second_fraction"], object_id)


#: Barycentric coordinates of the points at which each triangle of a leaf's blade is tested for visibility: the
#: 4-point rule (centroid and three points towards the corners), each standing for a quarter of the triangle. Leaf
#: meshes have millimetre triangles, finer than the curls and occluders that hide a leaf's parts.
VISIBILITY_SAMPLES = np.array([[1, 1, 1], [4, 1, 1], [1, 4, 1], [1, 1, 4]]) / np.array([[3.0], [6.0], [6.0], [6.0]])
#: A sample point is seen when the first surface along the ray to it lies at most this much nearer, m (float32
#: tracing of points a few metres from the scanner is precise to micrometres; a curl or a leaf in front lies farther).
SEEN_TOLERANCE_M = 5e-4
#: Rays traced at once for the visible areas (bounds the memory to some hundred MB).
_VISIBILITY_CHUNK = 1 << 21


def visible_areas(scene, scan, object_ids) -> dict[int, float]:
    """Area of each object's surface in the scanner's line of sight and inside the scan's window, m².

    Every triangle of the object (of a leaf's blade only, where its faces are
    labelled) is sampled at :data:`VISIBILITY_SAMPLES`; a sample point is
    seen when the ray from the scanner to it meets no other surface, nor
    another part of the same object, more than :data:`SEEN_TOLERANCE_M` in
    front of it, and its direction lies in the scan's grid (to half a step).
    Unlike a sum of per-pulse footprints ``r² dθ dψ / cos(incidence)`` this
    does not diverge where the surface turns edge-on, and it counts the parts
    seen at up to 90 deg, which pulses barely sample.

    Parameters
    ----------
    scene : Scene
        The scanned scene (world coordinates, m).
    scan : tlssim.Scan
        The simulated scan (its pose and angular grid).
    object_ids : iterable of int
        Objects to measure.

    Returns
    -------
    dict
        Object id to its visible one-sided area, m².
    """
    import mitsuba as mi

    from tlssim.backend import TraceScene, select_backend

    if mi.variant() is None:
        select_backend()
    points, weights, owner = [], [], []
    for oid in object_ids:
        obj = scene.objects[oid]
        faces = obj.faces
        labels = obj.truth.get("labels", [])
        if obj.face_labels is not None and "blade" in labels:
            faces = faces[obj.face_labels == labels.index("blade")]
        tri = obj.vertices[faces]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        points.append(np.einsum("sk,fkd->fsd", VISIBILITY_SAMPLES, tri).reshape(-1, 3))
        weights.append(np.repeat(area / len(VISIBILITY_SAMPLES), len(VISIBILITY_SAMPLES)))
        owner.append(np.full(len(weights[-1]), oid))
    if not points:
        return {}
    points, weights, owner = np.concatenate(points), np.concatenate(weights), np.concatenate(owner)
    traced = TraceScene(*scene.merged_mesh(), np.ones(len(scene.objects)), scan.pose.position)
    seen = np.zeros(len(points), dtype=bool)
    for start in range(0, len(points), _VISIBILITY_CHUNK):
        offset = points[start:start + _VISIBILITY_CHUNK] - scan.pose.position
        distance = np.linalg.norm(offset, axis=1)
        direction = (offset / distance[:, None]).astype(np.float32)
        ray = mi.Ray3f(mi.Point3f(0.0, 0.0, 0.0), mi.Vector3f(*(mi.Float(direction[:, k]) for k in range(3))))
        hit = np.asarray(traced.first_hits(ray)[0], dtype=float)
        seen[start:start + len(offset)] = (hit >= distance - SEEN_TOLERANCE_M) & _in_window(scan, offset)
    totals = np.bincount(np.searchsorted(np.unique(owner), owner), weights * seen)
    return {int(oid): float(total) for oid, total in zip(np.unique(owner), totals)}


def _in_window(scan, offset: np.ndarray) -> np.ndarray:
    """Which world-frame offsets from the scanner point into the scan's grid (to half a step)."""
    local = offset @ scan.pose.rotation
    theta0, psi0 = float(scan.theta[0, 0]), float(scan.psi[0, 0])
    theta = theta0 + np.mod(np.arctan2(local[:, 1], local[:, 0]) - theta0 + np.pi, 2 * np.pi) - np.pi
    psi = np.arccos(np.clip(local[:, 2] / np.linalg.norm(local, axis=1), -1.0, 1.0))
    d_theta, d_psi = grid_steps(scan)
    row, col = (psi - psi0) / d_psi, (theta - theta0) / d_theta
    return (row >= -0.5) & (row < scan.shape[0] - 0.5) & (col >= -0.5) & (col < scan.shape[1] - 0.5)


#: Share of a leaf's largest extent that another object must lie in front of the leaf's outline plane to hide it
#: (leaves are bent and rolled: their surface leaves the plane of their outline by a fraction of their length).
HIDING_DEPTH_FRACTION = 0.2


def visibility(scan, object_id: int, outline, distance_m: float) -> float:
    """Share of a leaf's silhouette that the scan sees: not hidden by another object, not outside the window.

    The silhouette is the leaf's outline polygon projected on the scan grid.
    A silhouette pulse is hidden when its central ray stops (``truth_range``)
    on another object in front of the leaf: nearer than where the ray meets
    the plane of the leaf's outline, by more than
    :data:`HIDING_DEPTH_FRACTION` of the leaf's largest extent (so a leaf
    a few centimetres in front of another hides it); silhouette pulses
    beyond the scan's window are hidden too (leaves cut by the window's
    border). Edge pulses that mix the leaf with its background are not
    hidden, so a leaf alone in the window scores 1 at any distance and
    incidence.

    Parameters
    ----------
    scan : tlssim.Scan
        The simulated scan (truth arrays).
    object_id : int
        The leaf's object id.
    outline : ndarray, (n, 3)
        The leaf's outline, world frame, m.
    distance_m : float
        The leaf's median range, m (used where its plane is seen edge-on).
    """
    outline = np.asarray(outline, dtype=float)
    local = (outline - scan.pose.position) @ scan.pose.rotation
    theta0, psi0 = float(scan.theta[0, 0]), float(scan.psi[0, 0])
    theta = theta0 + np.mod(np.arctan2(local[:, 1], local[:, 0]) - theta0 + np.pi, 2 * np.pi) - np.pi
    psi = np.arccos(local[:, 2] / np.linalg.norm(local, axis=1))
    d_theta, d_psi = grid_steps(scan)
    rows, cols = polygon((psi - psi0) / d_psi, (theta - theta0) / d_theta)
    if len(rows) == 0:
        return math.nan
    inside = (rows >= 0) & (rows < scan.shape[0]) & (cols >= 0) & (cols < scan.shape[1])
    rows, cols = rows[inside], cols[inside]
    centre = local.mean(axis=0)
    normal = np.linalg.svd(local - centre)[2][-1]
    t, p = scan.theta[rows, cols], scan.psi[rows, cols]
    ray = np.stack([np.sin(p) * np.cos(t), np.sin(p) * np.sin(t), np.cos(p)], axis=-1)
    facing = ray @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        plane = np.where(np.abs(facing) > 0.1, (centre @ normal) / facing, distance_m)
    depth = HIDING_DEPTH_FRACTION * np.ptp(outline, axis=0).max()
    hidden = (scan.truth_id[rows, cols] != object_id) & (scan.truth_range[rows, cols] < plane - depth)
    return float(1.0 - (hidden.sum() + (~inside).sum()) / len(inside))


class TruthSurfaces:
    """Distances to the true surfaces of a scene's objects; each object's mesh is prepared once."""

    def __init__(self, scene):
        self.scene = scene
        self._prepared: dict[int, metrics.SurfaceDistance] = {}

    def distance(self, points: np.ndarray, object_ids: np.ndarray) -> np.ndarray:
        """Signed distance of each point to the true surface of its object (``object_ids``), m.

        Parameters
        ----------
        points : ndarray
            Points, m, shape ``(n, 3)``.
        object_ids : ndarray of int
            Scene object index of each point, shape ``(n,)``.

        Returns
        -------
        ndarray
            Signed distances, m, shape ``(n,)``.
        """
        out = np.full(len(points), np.nan)
        for oid in np.unique(object_ids):
            oid = int(oid)
            if oid not in self._prepared:
                obj = self.scene.objects[oid]
                self._prepared[oid] = metrics.SurfaceDistance(obj.vertices, obj.faces)
            sel = object_ids == oid
            out[sel] = self._prepared[oid](points[sel], signed=True)
        return out


#: Object types scored when a case names no targets: leaves, and the analytic test surfaces.
TARGET_TYPES = ("leaf", "surface")


def target_ids(scene, targets: list[str] | None = None) -> list[int]:
    """Object ids to score: the named ``targets``, or every object of a type in :data:`TARGET_TYPES`.

    Parameters
    ----------
    scene : Scene
        The scene.
    targets : list of str or None
        Object names to score; ``None`` for every object of a target type.

    Returns
    -------
    list of int
        Scene object indices.

    Raises
    ------
    BenchError
        If a named target is not in the scene.
    """
    names = scene.object_names
    if targets is None:
        return [i for i, o in enumerate(scene.objects) if o.type in TARGET_TYPES]
    unknown = sorted(set(targets) - set(names))
    if unknown:
        raise BenchError(f"scene {scene.name!r} has no object(s) {unknown}; objects: {names}")
    return [names.index(t) for t in targets]


def prepare_leaves(scene, scan, targets: list[str] | None = None,
                   min_share: float = metrics.MIN_POWER_SHARE) -> list[LeafTruth]:
    """Truth of every target leaf of a simulated scan.

    Parameters
    ----------
    scene : Scene
        The scanned scene (rebuilt from the case description).
    scan : tlssim.Scan
        The simulated scan (with truth arrays).
    targets : list of str, optional
        Object names to score (default: every leaf and analytic surface).
    min_share : float
        Smallest power share from the leaf for a point to count on it.

    Returns
    -------
    list of LeafTruth
        One per target seen by the scan (targets without a return are skipped).
    """
    if not scan.has_truth:
        raise BenchError("scoring needs a simulated scan with truth arrays")
    leaves = []
    valid = scan.valid
    surfaces = TruthSurfaces(scene)
    boxes = object_boxes(scan)
    seen_areas = visible_areas(scene, scan, [oid for oid in target_ids(scene, targets) if oid in boxes])
    for oid in target_ids(scene, targets):
        if oid not in boxes:
            continue
        box = boxes[oid]
        own_grid = valid[box] & (scan.truth_id[box] == oid)
        if not own_grid.any():
            continue
        distance_m = float(np.median(scan.range[box][own_grid]))
        points = valid[box] & (metrics.leaf_power_share(
            scan.truth_id[box], scan.mixed_fraction[box], scan.layers["truth_second_id"][box],
            scan.layers["second_fraction"][box], oid) >= min_share)
        window = _window(points, crop_margin_px(scan, distance_m), (box[0].start, box[1].start), scan.shape)
        part = crop_scan(scan, *window)
        mask = np.zeros(part.shape, dtype=bool)
        rows, cols = np.nonzero(points)
        mask[rows + box[0].start - window[0].start, cols + box[1].start - window[1].start] = True
        attributed = part.truth_id[mask]
        distance = surfaces.distance(part.xyz[mask], attributed)
        own = attributed == oid
        pure = own & (part.mixed_fraction[mask] < PURE_MIXED_FRACTION)
        sigma = metrics.robust_sigma(distance[pure])
        obj = scene.objects[oid]
        area = obj.truth.get("area_m2")
        stats = {
            "range_m": distance_m,
            "incidence_deg": float(np.degrees(np.median(scan.incidence[box][own_grid]))),
            "sigma_range_m": sigma,
            "intensity_dn": float(np.median(part.intensity[mask][pure])) if pure.any() else math.nan,
            "n_own": int(own.sum()),
            "points_per_cm2": int(own.sum()) / (area * 1e4) if area else math.nan,
            "visibility": visibility(scan, oid, obj.truth["outline"], distance_m) if "outline" in obj.truth
            else math.nan,
            "visible_area_m2": seen_areas[oid],
            "visible_area_ratio": seen_areas[oid] / area if area else math.nan,
        }
        leaves.append(LeafTruth(oid, obj.name, obj.type, obj.truth, part, mask, own, attributed, distance,
                                {"auto": metrics.auto_tau(sigma), "1cm": metrics.TAU_TRUE_M}, stats, surfaces,
                                window))
    return leaves


#: Fewest returned points a woody object needs to be reconstructed.
MIN_WOOD_POINTS = 10


def prepare_wood(scene, scan) -> list[Target]:
    """Every woody object (truth with ``cylinders``) with at least :data:`MIN_WOOD_POINTS` returns.

    Its points are the pulses it dominates (the per-tree isolation from
    ground-truth labels of the woody spec, C.1), on the whole scan.

    Parameters
    ----------
    scene : Scene
        The simulated scene (woody objects carry ``cylinders`` truth).
    scan : Scan
        Its simulated scan, with truth.

    Returns
    -------
    list of Target
        One target per woody object with enough returns.
    """
    valid = scan.valid
    return [Target(oid, obj.name, obj.type, obj.truth, scan, valid & (scan.truth_id == oid))
            for oid, obj in enumerate(scene.objects)
            if "cylinders" in obj.truth and int((valid & (scan.truth_id == oid)).sum()) >= MIN_WOOD_POINTS]


def score_wood(wood: Target, output: VariantOutput) -> dict:
    """Scores of reconstructed cylinders against a woody object's truth (:func:`woody.score`).

    Parameters
    ----------
    wood : Target
        The woody object and its points.
    output : VariantOutput
        A method's output, with ``cylinders`` in its traits.

    Returns
    -------
    dict
        ``diameter_err_bias_m``, ``diameter_err_mae_m``, ``diameter_err_rmse_m``,
        ``wood_completeness``, ``wood_seen_completeness`` (of the truth length
        the object's points reach), ``wood_precision``, ``detection_rate``,
        ``volume_rel_err`` (signed), ``volume_true_m3``, ``volume_rec_m3``,
        ``dbh_true_m`` and ``dbh_err_m`` (the stem's diameter 1.3 m above its
        base and the reconstruction's signed error there; None where the stem
        is shorter or not reconstructed there), the method's stats.
    """
    import woody

    scores = woody.score(wood.truth, output.traits["cylinders"], points=wood.scan.xyz[wood.mask])
    diameter = scores["diameter_error_m"]
    dbh = scores["taper"]["dbh"] or {}
    return json_ready({"target": wood.name, "object_id": wood.object_id, "object_type": wood.object_type,
                       "n_points": int(wood.mask.sum()), "diameter_err_bias_m": diameter["bias"],
                       "diameter_err_mae_m": diameter["mae"], "diameter_err_rmse_m": diameter["rmse"],
                       "wood_completeness": scores["completeness"],
                       "wood_seen_completeness": scores["seen_completeness"], "wood_precision": scores["precision"],
                       "detection_rate": scores["detection_rate"], "volume_rel_err": scores["volume_error"],
                       "volume_true_m3": scores["volume_true_m3"], "volume_rec_m3": scores["volume_rec_m3"],
                       "dbh_true_m": dbh.get("diameter_true_m"), "dbh_err_m": dbh.get("diameter_error_m"),
                       **output.stats})


def output_distance(leaf: LeafTruth, output: VariantOutput):
    """A variant's output points on a leaf and their signed distance to the truth.

    Parameters
    ----------
    leaf : LeafTruth
        The leaf's pixels, truth surfaces and distances before the method, m.
    output : VariantOutput
        A method's output points (``xyz`` in m, NaN where dropped).

    Returns
    -------
    points : ndarray, (n, 3)
        Output point of each of the leaf's masked pixels (NaN where dropped).
    kept : ndarray of bool, (n,)
        Pixels the variant kept.
    distance : ndarray, (n,)
        Signed distance of each output point to the true surface of the
        object its pulse is attributed to, m (recomputed only for moved points).
    """
    points = np.asarray(output.xyz)[leaf.mask]
    kept = np.isfinite(points).all(axis=1)
    moved = kept & (np.abs(points - leaf.scan.xyz[leaf.mask]) > 1e-9).any(axis=1)
    distance = leaf.distance.copy()
    distance[moved] = leaf.surfaces.distance(points[moved], leaf.attributed[moved])
    return points, kept, distance


def score_leaf(leaf: LeafTruth, output: VariantOutput) -> dict:
    """Scores of one variant's output on one leaf.

    Parameters
    ----------
    leaf : LeafTruth
        The leaf's pixels, truth and distances before the method, m.
    output : VariantOutput
        A method's output points (m) and flags.

    Returns
    -------
    dict
        JSON-ready: the leaf's name, id and object type, its scan properties; ``tau_m``; per threshold the
        outlier scores of :func:`benchmarks.metrics.outlier_scores` (the
        ``auto`` threshold unsuffixed, τ = 1 cm with the suffix ``_1cm``);
        ``inlier_p90_m``, the 90th percentile of the distance after of the
        kept inliers; ``surface_rmse_m`` and ``completeness`` (share of the
        leaf's own pulses with an output point within τ); ``flag_precision``
        and ``flag_recall`` of the points the method flags as outliers
        against the true outliers (τ auto); leaf-trait errors where both the
        truth and the method give the trait; the method's own stats (for
        whole-scan variants, the match of :func:`leaf_outputs`).
    """
    _, kept, distance = output_distance(leaf, output)
    before, after = np.abs(leaf.distance), np.abs(distance)
    tau = leaf.taus["auto"]
    scores = {"target": leaf.name, "object_id": leaf.object_id, "object_type": leaf.object_type,
              **leaf.scan_stats, "tau_m": tau}
    for label, threshold in leaf.taus.items():
        suffix = "" if label == "auto" else f"_{label}"
        for key, value in metrics.outlier_scores(before > threshold, kept, after > threshold).items():
            scores[key + suffix] = value
    inliers = kept & (before <= tau)
    scores["inlier_p90_m"] = float(np.quantile(after[inliers], 0.9)) if inliers.any() else math.nan
    if output.flags is not None:
        flagged = np.asarray(output.flags)[leaf.mask]
        truly = before > tau
        scores["flag_precision"] = metrics.ratio(int((flagged & truly).sum()), int(flagged.sum()))
        scores["flag_recall"] = metrics.ratio(int((flagged & truly).sum()), int(truly.sum()))
    scores["surface_rmse_m"] = metrics.rms(distance[kept])
    own = max(int(leaf.own.sum()), 1)
    scores["completeness"] = int((leaf.own & kept & (after <= tau)).sum()) / own
    scores.update(trait_errors(leaf.truth, output.traits))
    if "area_m2" in scores and leaf.scan_stats["visible_area_m2"] > 0:
        scores["area_seen_rel_err"] = metrics.relative_error(scores["area_m2"], leaf.scan_stats["visible_area_m2"])
    scores.update(output.stats)
    return json_ready(scores)


def target_labels(shape: tuple[int, int], leaves: list[LeafTruth]) -> np.ndarray:
    """Label image of the targets' points (``k + 1`` for ``leaves[k]``, 0 elsewhere), for variants given the targets.

    A pulse in the masks of several leaves goes to the leaf that dominates it,
    or else to the first of them.

    Parameters
    ----------
    shape : tuple of int
        The whole scan's grid shape.
    leaves : list of LeafTruth
        The targets (:func:`prepare_leaves`).
    """
    labels = np.zeros(shape, dtype=np.int32)
    for k, leaf in enumerate(leaves):
        part = labels[leaf.window]
        part[leaf.mask & (part == 0)] = k + 1
    for k, leaf in enumerate(leaves):
        labels[leaf.own_pixels()] = k + 1
    return labels


#: A true leaf is found when one output region covers at least this share of its visible pulses (issue 16).
MIN_FOUND_COVERAGE = 0.5
#: rppp counts kept per region (rppp_0 .. rppp_N, and rppp_more beyond).
RPPP_MAX = 3


def region_stats(output: VariantOutput, scan) -> dict:
    """Per output region (by label): its pixels, its rppp ratios and the object that dominates most of its pulses.

    Parameters
    ----------
    output : VariantOutput
        A whole-scan output with ``labels``, ``regions`` and ``candidates``.
    scan : tlssim.Scan
        The whole scan (``truth_id``).

    Returns
    -------
    dict
        ``labels`` (the regions with traits, sorted), arrays indexed like it:
        ``pixels``, ``rppp_0`` .. ``rppp_{RPPP_MAX}``, ``rppp_more`` and
        ``object`` (the dominant ``truth_id``, -1 for none).
    """
    labels = np.asarray(output.labels)
    ids = np.array(sorted(output.regions or {}), dtype=np.int64)
    top = int(max(labels.max(initial=0), ids.max(initial=0))) + 1
    flat = labels.ravel()
    pixels = np.bincount(flat, minlength=top)[ids]
    stats = {"labels": ids, "pixels": pixels}
    counts = np.zeros(labels.shape, int) if output.candidates is None else np.asarray(output.candidates)
    total = np.maximum(pixels, 1)
    for n in range(RPPP_MAX + 1):
        stats[f"rppp_{n}"] = np.bincount(flat, weights=(counts == n).ravel(), minlength=top)[ids] / total
    stats["rppp_more"] = np.bincount(flat, weights=(counts > RPPP_MAX).ravel(), minlength=top)[ids] / total
    inside = flat > 0
    objects = int(scan.truth_id.max(initial=-1)) + 2
    keys, n_pairs = np.unique(flat[inside].astype(np.int64) * objects + scan.truth_id.ravel()[inside] + 1,
                              return_counts=True)
    label, obj = keys // objects, keys % objects - 1
    dominant = np.full(top, -1)
    order = np.lexsort((n_pairs, label))  # by label, then count: the last of each label is its dominant object
    last = order[np.r_[label[order][1:] != label[order][:-1], True]] if len(order) else order
    dominant[label[last]] = obj[last]
    stats["object"] = dominant[ids]
    return stats


def leaf_outputs(leaves: list[LeafTruth], output: VariantOutput, scene, scan) -> tuple[list[VariantOutput], dict]:
    """Match a whole-scan output's regions to the true leaves; each leaf's view of the output, and the case's counts.

    Each leaf is matched to the output region that holds most of its
    visible pulses (the pulses it dominates, ``truth_id``); it is scored on
    that region's traits (none, so area 0, when no region holds any of its
    pulses) and on the output points of its part of the scan. A region that
    is the match of no target leaf is a false leaf, unless another leaf or
    surface that is not a target dominates most of its pulses.

    Parameters
    ----------
    leaves : list of LeafTruth
        The targets (:func:`prepare_leaves` on ``scan``).
    output : VariantOutput
        A whole-scan output with ``labels`` and ``regions``.
    scene : Scene
        The scanned scene.
    scan : tlssim.Scan
        The whole scan (with truth).

    Returns
    -------
    outputs : list of VariantOutput
        Per leaf, the output on its part of the scan, with the matched
        region's traits and the stats ``found`` (1 when the match covers at
        least :data:`MIN_FOUND_COVERAGE` of its visible pulses),
        ``coverage`` (that share), ``purity`` (share of the region's pulses
        the leaf dominates), ``region_pixels``, ``merged`` (1 when the leaf
        is found and its region is another found leaf's match too) and the
        region's rppp ratios.
    counts : dict
        ``n_regions``, ``n_false`` (regions matching no leaf),
        ``n_false_on_leaves`` (of those, regions on a target leaf that
        matched another region: split leaves), ``n_false_off_leaves`` (on
        wood, walls and other objects), ``n_merged`` (found leaves whose
        region also holds at least half of another leaf: leaves merged
        into one region; a few pulses of a mostly hidden leaf inside a
        neighbour's region do not make a merge).
    """
    if output.labels is None or output.regions is None:
        raise BenchError("whole-scan scoring needs an output with region labels and their traits")
    regions = region_stats(output, scan)
    index = {int(label): k for k, label in enumerate(regions["labels"])}
    labels = np.asarray(output.labels)
    visible = [labels[leaf.own_pixels()] for leaf in leaves]
    matches = [int(np.bincount(own[own > 0]).argmax()) if (own > 0).any() else None for own in visible]
    coverages = [float(np.mean(own == label)) if label is not None else 0.0 for own, label in zip(visible, matches)]
    shared = Counter(label for label, coverage in zip(matches, coverages) if coverage >= MIN_FOUND_COVERAGE)
    outputs = []
    for leaf, own, label, coverage in zip(leaves, visible, matches, coverages):
        stats, traits = {"found": 0, "coverage": 0.0}, {"area_m2": 0.0}
        if label is not None:
            k = index[label]
            found = coverage >= MIN_FOUND_COVERAGE
            stats = {"found": int(found), "coverage": coverage,
                     "purity": int((own == label).sum()) / int(regions["pixels"][k]),
                     "region_pixels": int(regions["pixels"][k]), "merged": int(found and shared[label] > 1),
                     **{key: float(regions[key][k]) for key in regions if key.startswith("rppp_")}}
            traits = output.regions[label]
        flags = None if output.flags is None else np.asarray(output.flags)[leaf.window]
        outputs.append(VariantOutput(np.asarray(output.xyz)[leaf.window], traits, {**output.stats, **stats}, flags))
    matched = {label for label in matches if label is not None}
    merged = sum(count for count in shared.values() if count > 1)
    targets = {leaf.object_id for leaf in leaves}
    others = {i for i, obj in enumerate(scene.objects) if obj.type in TARGET_TYPES} - targets
    false = [k for k, label in enumerate(regions["labels"]) if int(label) not in matched
             and regions["object"][k] not in others]
    on_leaves = sum(1 for k in false if regions["object"][k] in targets)
    return outputs, {"n_regions": len(regions["labels"]), "n_false": len(false), "n_false_on_leaves": on_leaves,
                     "n_false_off_leaves": len(false) - on_leaves, "n_merged": merged}


def found_counts(scores: list[dict], min_visibility: float = metrics.MIN_VISIBILITY) -> dict:
    """Found and missed leaves among scored leaves, all and at least ``min_visibility`` visible.

    Parameters
    ----------
    scores : list of dict
        Per-leaf scores with ``found`` and ``visibility``.
    min_visibility : float
        Share of the silhouette a leaf must show to count as visible.

    Returns
    -------
    dict
        ``n_leaves``, ``n_found``, ``n_missed``, ``n_visible``,
        ``n_found_visible``, ``n_missed_visible``.
    """
    leaves = [s for s in scores if s.get("object_type") == "leaf" and s.get("found") is not None]
    visible = [s for s in leaves if (s.get("visibility") or 0.0) >= min_visibility]
    found, found_visible = sum(s["found"] for s in leaves), sum(s["found"] for s in visible)
    return {"n_leaves": len(leaves), "n_found": found, "n_missed": len(leaves) - found, "n_visible": len(visible),
            "n_found_visible": found_visible, "n_missed_visible": len(visible) - found_visible}


def score_scan(leaves: list[LeafTruth], output: VariantOutput, scene, scan) -> tuple[list[dict], dict]:
    """Scores of a whole-scan output on every target leaf (:func:`leaf_outputs`, :func:`score_leaf`) and the
    case's counts (:func:`leaf_outputs`, :func:`found_counts`).

    Parameters
    ----------
    leaves : list of LeafTruth
        The targets.
    output : VariantOutput
        The variant's output on the whole ``scan``.
    scene : Scene
        The scanned scene.
    scan : tlssim.Scan
        The whole scan.
    """
    outputs, counts = leaf_outputs(leaves, output, scene, scan)
    scores = [score_leaf(leaf, out) for leaf, out in zip(leaves, outputs)]
    return scores, {**found_counts(scores), **counts}


def trait_errors(truth: dict, traits: dict | None) -> dict:
    """Area, elevation and azimuth errors where both the truth and the estimate have them.

    The estimated angles are stored aligned with the truth
    (:func:`benchmarks.metrics.aligned_axis_angles`: the midrib's sense
    flipped towards the truth, the azimuth within 180 deg of it), next to
    the true ones, for the regressions of the validation table.

    Parameters
    ----------
    truth : dict
        True leaf traits (``area_m2`` in m^2, angles in degrees).
    traits : dict or None
        Estimated traits, same units; ``None`` or empty when the method gives none.

    Returns
    -------
    dict
        Estimates, truths and their errors (m^2, degrees), keys named with units.
    """
    if not traits:
        return {}
    errors = {}
    if truth.get("area_m2") and np.isfinite(traits.get("area_m2", math.nan)):
        errors.update({"area_m2": traits["area_m2"], "area_true_m2": truth["area_m2"],
                       "area_abs_err_m2": traits["area_m2"] - truth["area_m2"],
                       "area_rel_err": metrics.relative_error(traits["area_m2"], truth["area_m2"])})
    keys = ("elevation_deg", "azimuth_deg")
    if all(k in truth for k in keys) and all(np.isfinite(traits.get(k, math.nan)) for k in keys):
        el, az = metrics.aligned_axis_angles(traits["elevation_deg"], traits["azimuth_deg"],
                                             truth["elevation_deg"], truth["azimuth_deg"])
        errors.update({"elevation_deg": el, "elevation_true_deg": truth["elevation_deg"], "azimuth_deg": az,
                       "azimuth_true_deg": truth["azimuth_deg"], "elevation_err_deg": abs(el - truth["elevation_deg"]),
                       "azimuth_err_deg": abs(az - truth["azimuth_deg"])})
    return errors


def json_ready(scores: dict) -> dict:
    """Scores with plain Python numbers; NaN becomes None (JSON has no NaN)."""
    clean = {}
    for key, value in scores.items():
        if isinstance(value, (np.generic,)):
            value = value.item()
        if isinstance(value, float) and not math.isfinite(value):
            value = None
        clean[key] = value
    return clean

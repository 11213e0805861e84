"""How well the PROP-SFS variants do on simulated leaves (``leafsfs accuracy``): ROP, area, orientation, purity.

The set: one pear leaf (9 cm, the thesis ch.2 ROP set-up, like the built-in
``leaf-1.5m``) at distance ``d`` facing the scanner, tilted by the incidence
``a`` about its horizontal axis, a wall 1 m behind; several leaf seeds (shape)
per case, one simulation seed each. Optionally the built-in ``leaf-cluster``.

Scores (issue 7's definitions; the truth is used here only):

- a returned point is an **outlier** when its distance to the true surface
  of the object it is attributed to (``truth_id``, the object that returned
  most of its power) exceeds tau; tau = max(3 sigma_range, 2 mm), with
  sigma_range the robust spread of the pure leaf returns, and tau = 1 cm;
- **ROP** = outliers / points on the leaf (pulses with at least 10 % of
  their power from it); ROP after: the same on the output points (corrected
  ranges where the variant corrected them, measured ones elsewhere, none
  where it dropped them);
- **good points damaged**: inliers that are outliers after; **inlier p90**:
  the 90th percentile of their distance to the truth after;
- **area** relative error ``(estimate - truth) / truth``, and the
  **visible area ratio** (:func:`visible_area`: what a single scan can see
  at all); midrib **elevation** and **azimuth** errors as undirected axes;
- **purity** of the leaf's region (the share of its pixels that the leaf
  dominates) and **coverage** (the share of the leaf's own pulses in it).

These follow :mod:`benchmarks.metrics` (issue 7), which the benchmark
harness scores every variant with; this module keeps the leaf engine's own
measurement runnable on its own.
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree
from tqdm.auto import tqdm
from trimesh.triangles import closest_point

from leafsfs.errors import SfsError

#: Smallest footprint power share from the leaf for a point to count on it (issue 7).
MIN_POWER_SHARE = 0.1
#: Floor of the automatic outlier threshold and the threshold of "true" outliers, m (tls-physics §7.10).
TAU_FLOOR_M, TAU_TRUE_M = 0.002, 0.01
#: Pure returns (for the range noise) have less than this power share from other objects.
PURE_MIXED_FRACTION = 1e-3
#: Triangles whose centroids are nearest to a point, tested exactly for its distance to a mesh.
_NEAREST_TRIANGLES = 24

DISTANCES_M = (0.8, 1.5, 3.0, 5.0)
INCIDENCES_DEG = (0.0, 20.0, 40.0, 60.0, 80.0)
VARIANTS = ("buffer", "fused")


def leaf_scene(distance_m: float, incidence_deg: float, seed: int):
    """A 9 cm pear leaf ``distance_m`` away facing the scanner, tilted by ``incidence_deg``, wall 1 m behind."""
    from scenes.builtin import window_around
    from scenes.scenefile import scene_from_spec

    spec = {"name": f"leaf-{distance_m:g}m-{incidence_deg:g}deg-s{seed}",
            "scanner": {"preset": "faro-ls880", "position": [0, 0, 0]},
            "objects": [
                {"name": "leaf", "type": "leaf", "preset": "pear", "seed": int(seed), "length": 0.09,
                 "material": "pear-leaf", "pose": {"center": [distance_m, 0, 0], "facing": "scanner",
                                                   "incidence_deg": incidence_deg, "rotation_axis": "horizontal"}},
                {"name": "wall", "type": "plane", "size": [1.0, 1.0], "material": "wall",
                 "pose": {"center": [distance_m + 1.0, 0, 0], "facing": "scanner"}}]}
    scene = scene_from_spec(spec, source=f"accuracy scene {spec['name']!r}")
    return scene.with_scanner(window=window_around(scene.objects[0].vertices, [0, 0, 0], 0.4))


class TruthDistance:
    """Distance from points to the true surfaces of a scene's objects (meshes indexed once per object).

    The closest point is searched exactly on the triangles whose centroids
    are nearest to the point; with meshes much finer than the distances that
    matter (leaves are faceted at a quarter of the footprint), that is the
    mesh distance.
    """

    def __init__(self, scene):
        self.scene = scene
        self._index: dict[int, tuple] = {}

    def __call__(self, points: np.ndarray, object_ids: np.ndarray) -> np.ndarray:
        """Signed distance of every point ``(n, 3)`` to the surface of its object ``(n,)``, m (NaN for id -1).

        The sign is that of the side of the closest triangle its normal points to.
        """
        out = np.full(len(points), np.nan)
        for oid in np.unique(object_ids[object_ids >= 0]):
            if oid not in self._index:
                obj = self.scene.objects[int(oid)]
                triangles = np.asarray(obj.vertices, float)[np.asarray(obj.faces)]
                self._index[oid] = (triangles, cKDTree(triangles.mean(axis=1)))
            triangles, tree = self._index[oid]
            sel = np.nonzero(object_ids == oid)[0]
            k = min(_NEAREST_TRIANGLES, len(triangles))
            _, nearest = tree.query(points[sel], k=k)
            nearest = nearest.reshape(len(sel), k)
            repeated = np.repeat(points[sel], k, axis=0)
            candidates = closest_point(triangles[nearest.ravel()], repeated)
            gaps = np.linalg.norm(candidates - repeated, axis=1).reshape(len(sel), k)
            best = np.argmin(gaps, axis=1)
            pick = np.arange(len(sel)) * k + best
            corners = triangles[nearest.ravel()[pick]]
            normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
            side = np.sign(np.einsum("ij,ij->i", repeated[pick] - candidates[pick], normal))
            out[sel] = np.where(side < 0, -1.0, 1.0) * gaps[np.arange(len(sel)), best]
        return out


def leaf_share(scan, object_id: int, reach_px: int) -> np.ndarray:
    """Share of each pulse's power from one object (exact where two objects share a footprint).

    ``1 - mixed_fraction`` where the object dominates; ``mixed_fraction``
    where another object dominates within ``reach_px`` of the object's pulses.
    """
    own = scan.truth_id == object_id
    mixed = np.nan_to_num(scan.mixed_fraction, nan=0.0)
    near = ndimage.maximum_filter(own, size=2 * reach_px + 1) & ~own & (scan.truth_id >= 0)
    return np.where(own, 1.0 - mixed, np.where(near, mixed, 0.0))


def visible_area(scan, object_id: int) -> float:
    """Leaf area the scan sees: the area elements ``r^2 dOmega / cos(incidence)`` of the pulses it dominates, m^2.

    The part of a leaf hidden by itself or by other objects is missing: no
    reconstruction from this scan can find it.
    """
    own = scan.valid & (scan.truth_id == object_id)
    d_theta = np.abs(np.gradient(scan.theta, axis=1))
    d_psi = np.abs(np.gradient(scan.psi, axis=0))
    element = scan.truth_range**2 * d_theta * d_psi * np.sin(scan.psi) / np.cos(scan.incidence)
    return float(np.sum(element[own]))


def footprint_reach_px(scan, distance_m: float) -> int:
    """Pixels reached by the footprint at ``distance_m``: its 1/e^2 diameter over the angular step, plus one."""
    model = scan.scanner_model
    radius = model["beam_waist_radius_m"] + distance_m * math.tan(math.radians(model["divergence_deg"]))
    step = abs(float(scan.theta[0, 1] - scan.theta[0, 0]))
    return int(math.ceil(2 * radius / (distance_m * step))) + 1


def axis_errors_deg(elevation_deg, azimuth_deg, true_elevation_deg, true_azimuth_deg) -> tuple[float, float]:
    """Elevation and azimuth errors of an axis of unknown sense, degrees (azimuth error in [0, 180])."""
    def unit(el, az):
        el, az = math.radians(el), math.radians(az)
        return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])

    estimate, truth = unit(elevation_deg, azimuth_deg), unit(true_elevation_deg, true_azimuth_deg)
    if estimate @ truth < 0:
        estimate = -estimate
    el = math.degrees(math.asin(float(np.clip(estimate[2], -1, 1))))
    az = math.degrees(math.atan2(estimate[1], estimate[0]))
    return abs(el - true_elevation_deg), abs((az - true_azimuth_deg + 180.0) % 360.0 - 180.0)


def score_leaf(scene, scan, result, object_id: int, distance: TruthDistance | None = None) -> dict:
    """Scores of a :class:`leafsfs.SfsResult` on one leaf of a simulated scan (see the module docstring)."""
    distance = distance or TruthDistance(scene)
    own = scan.valid & (scan.truth_id == object_id)
    d0 = float(np.median(scan.range[own]))
    on_leaf = scan.valid & (leaf_share(scan, object_id, footprint_reach_px(scan, d0)) >= MIN_POWER_SHARE)
    attributed = scan.truth_id[on_leaf]
    signed = distance(scan.xyz[on_leaf], attributed)
    before = np.abs(signed)
    output = (result.corrected_scan() if result is not None else scan).xyz[on_leaf]
    kept = np.isfinite(output).all(axis=1)
    after = before.copy()
    moved = kept & np.any(np.abs(output - scan.xyz[on_leaf]) > 1e-9, axis=1)
    after[moved] = np.abs(distance(output[moved], attributed[moved]))
    pure = (attributed == object_id) & (scan.mixed_fraction[on_leaf] < PURE_MIXED_FRACTION)
    sigma = 1.4826 * float(np.median(np.abs(signed[pure] - np.median(signed[pure])))) if pure.any() else math.nan
    tau = max(3 * sigma, TAU_FLOOR_M) if np.isfinite(sigma) else TAU_FLOOR_M
    inlier = before <= tau
    scores = {"range_m": d0, "n_points": int(on_leaf.sum()), "sigma_range_m": sigma, "tau_m": tau,
              "good_points_lost": float(np.mean(~kept[inlier])),
              "good_points_damaged": float(np.mean(kept[inlier] & (after[inlier] > tau))),
              "inlier_p90_m": float(np.quantile(after[inlier & kept], 0.9)) if (inlier & kept).any() else math.nan,
              "visible_area_ratio": visible_area(scan, object_id) / scene.objects[object_id].truth["area_m2"]}
    for label, threshold in (("", tau), ("_1cm", TAU_TRUE_M)):
        out_before, out_after = before > threshold, kept & (after > threshold)
        rop_before = float(out_before.mean())
        rop_after = float(out_after.sum() / max(kept.sum(), 1))
        scores[f"rop_before{label}"] = rop_before
        scores[f"rop_after{label}"] = rop_after
        scores[f"rop_reduction{label}"] = 1 - rop_after / rop_before if rop_before > 0 else math.nan
    truth = scene.objects[object_id].truth
    region = _region_of(result, own) if result is not None else np.zeros(own.shape, bool)
    scores["purity"] = float(np.mean(scan.truth_id[region] == object_id)) if region.any() else math.nan
    scores["coverage"] = float(np.mean(region[own]))
    traits = _traits_of(result, region)
    if traits is None:
        scores.update(area_rel_err=math.nan, elevation_err_deg=math.nan, azimuth_err_deg=math.nan)
        return scores
    scores["area_rel_err"] = (traits["area_m2"] - truth["area_m2"]) / truth["area_m2"]
    if np.isfinite(traits["elevation_deg"]):
        el, az = axis_errors_deg(traits["elevation_deg"], traits["azimuth_deg"], truth["elevation_deg"],
                                 truth["azimuth_deg"])
    else:
        el = az = math.nan
    scores.update(elevation_err_deg=el, azimuth_err_deg=az)
    return scores


def _region_of(result, own: np.ndarray) -> np.ndarray:
    """The reconstruction's region holding most of the leaf's own pulses (empty if none)."""
    labels = result.labels[own]
    labels = labels[labels > 0]
    if not len(labels):
        return np.zeros(own.shape, bool)
    return result.labels == np.bincount(labels).argmax()


def _traits_of(result, region: np.ndarray) -> dict | None:
    if not region.any():
        return None
    label = int(result.labels[region][0])
    for leaf in result.leaves:
        if leaf.label == label:
            return leaf.traits
    return None


def simulate_case(distance_m: float, incidence_deg: float, seed: int):
    """Scene and simulated scan of one case of the set."""
    import tlssim

    scene = leaf_scene(distance_m, incidence_deg, seed)
    return scene, tlssim.simulate(scene, tlssim.setup_from_section(scene.scanner), seed=seed, progress=False)


def run_accuracy(distances=DISTANCES_M, incidences=INCIDENCES_DEG, seeds=(0, 1, 2), variants=VARIANTS,
                 params=None, cluster: bool = True, progress: bool = True) -> list[dict]:
    """Score the variants on every case; one row per case, variant and leaf.

    Rows hold ``case`` (``distance_m``, ``incidence_deg``, ``seed`` or the
    scene name), ``variant``, ``leaf`` and the scores of :func:`score_leaf`.
    """
    from leafsfs.preprocess import resolve_calibration
    from leafsfs.reconstruct import reconstruct

    cases = [(d, a, s) for d in distances for a in incidences for s in seeds]
    rows = []
    calibration = None
    for d, a, s in tqdm(cases, desc="accuracy", disable=not progress):
        scene, scan = simulate_case(d, a, s)
        calibration = calibration or resolve_calibration("model", scan)
        truth = TruthDistance(scene)
        for variant in variants:
            case = {"distance_m": d, "incidence_deg": a, "seed": s, "variant": variant, "leaf": "leaf"}
            start = time.perf_counter()
            try:
                result = reconstruct(scan, variant=variant, params=params, calibration=calibration)
            except SfsError as exc:  # nothing reconstructed: the measured points stay
                result = None
                case["failure"] = str(exc)
            rows.append({**case, **score_leaf(scene, scan, result, 0, truth),
                         "runtime_s": time.perf_counter() - start})
    if cluster:
        rows += cluster_accuracy(variants, params, calibration)
    return rows


def cluster_accuracy(variants=VARIANTS, params=None, calibration=None) -> list[dict]:
    """Rows of :func:`run_accuracy` for the leaves of the built-in ``leaf-cluster`` (seen by >= 1000 pulses)."""
    import scenes
    import tlssim

    from leafsfs.preprocess import resolve_calibration
    from leafsfs.reconstruct import reconstruct

    scene = scenes.build("leaf-cluster")
    scan = tlssim.simulate(scene, tlssim.setup_from_section(scene.scanner), seed=0, progress=False)
    calibration = calibration or resolve_calibration("model", scan)
    truth = TruthDistance(scene)
    leaves = [i for i, o in enumerate(scene.objects)
              if o.type == "leaf" and np.sum(scan.valid & (scan.truth_id == i)) >= 1000]
    rows = []
    for variant in variants:
        result = reconstruct(scan, variant=variant, params=params, calibration=calibration)
        rows += [{"distance_m": "cluster", "incidence_deg": "", "seed": 0, "variant": variant,
                  "leaf": scene.objects[i].name, **score_leaf(scene, scan, result, i, truth)} for i in leaves]
    return rows


#: Printed columns: score key, header, scale.
COLUMNS = (("rop_before", "ROP0%", 100), ("rop_after", "ROP1%", 100), ("rop_reduction", "red", 1),
           ("rop_before_1cm", "R0cm%", 100), ("rop_after_1cm", "R1cm%", 100), ("good_points_damaged", "dmg%", 100),
           ("inlier_p90_m", "in90mm", 1000), ("area_rel_err", "area%", 100), ("area_abs_err", "|ar|%", 100),
           ("visible_area_ratio", "vis%", 100), ("elevation_err_deg", "el", 1), ("azimuth_err_deg", "az", 1),
           ("purity", "pur", 1))


def summarize(rows: list[dict]) -> list[dict]:
    """Medians per distance x incidence x variant, then over all cases per variant.

    ``area_abs_err`` is the median of ``|area_rel_err|``; the overall
    ``rop_reduction`` is that of the pooled ROPs (mean ROP after over mean ROP before).
    """
    groups: dict = {}
    for row in rows:
        groups.setdefault((str(row["distance_m"]), str(row["incidence_deg"]), row["variant"]), []).append(row)
    for variant in sorted({r["variant"] for r in rows}):
        groups[("all", "", variant)] = [r for r in rows if r["variant"] == variant]
    out = []
    for (d, a, v), members in groups.items():
        entry = {"distance_m": d, "incidence_deg": a, "variant": v, "n": len(members)}
        for key, _, _ in COLUMNS:
            values = np.array([abs(m.get("area_rel_err", math.nan)) if key == "area_abs_err" else
                               m.get(key, math.nan) for m in members], float)
            entry[key] = float(np.nanmedian(values)) if np.isfinite(values).any() else math.nan
        if d == "all":
            entry["rop_reduction"] = 1 - (np.nanmean([m["rop_after"] for m in members])
                                          / np.nanmean([m["rop_before"] for m in members]))
        out.append(entry)
    return out


def print_summary(summary: list[dict]) -> str:
    """The medians as a text table (ROP and area errors in %, inlier error p90 in mm, angles in degrees)."""
    lines = [f"{'dist':>7s} {'inc':>4s} {'variant':7s} {'n':>3s} " + " ".join(f"{h:>6s}" for _, h, _ in COLUMNS)]
    for e in summary:
        lines.append(f"{e['distance_m']:>7s} {e['incidence_deg']:>4s} {e['variant']:7s} {e['n']:3d} "
                     + " ".join(f"{e[key] * scale:6.2f}" if scale == 1 and key in ("rop_reduction", "purity")
                                else f"{e[key] * scale:6.1f}" for key, _, scale in COLUMNS))
    return "\n".join(lines)

"""Scores of a woody reconstruction against the scene truth (the benchmark harness uses these).

Both the truth (``docs/contracts.md``: a woody object's ``truth`` has
``cylinders`` and ``volume_m3``) and the reconstruction are cylinder lists
(:mod:`woody.geometry`). Definitions follow the woody spec, Part C.2:

- the truth centrelines are sampled every ``step_m``; samples buried inside
  another truth cylinder (the base of a child inside its parent) cannot be
  seen and are left out;
- a truth sample is *matched* by the nearest reconstructed axis within
  ``max(r_true, min_tolerance_m)`` whose direction is within
  ``max_angle_deg``; the reconstructed radius there (frusta interpolate) gives
  the radius error ``r_rec - r_true`` (and twice it, the diameter error);
- completeness is the matched share of the visible truth length; a truth
  branch is detected when at least half of it is matched; given the scan's
  points, ``seen_completeness`` is the matched share of the visible length
  with a point within ``r_true + min_tolerance_m`` of its axis (a branch the
  scan did not see — hidden behind another, or seen end-on along the line
  of sight — is not the method's miss);
- reconstructed centrelines are sampled and matched back the same way
  (tolerance from the truth radius; samples inside another reconstructed
  cylinder are left out as above); unmatched reconstructed length is false
  positive;
- length error of a detected branch: ``|L_rec - L_true| / L_true`` with
  ``L_rec`` the reconstructed length matched to it;
- volume error: ``(V_rec - V_true) / V_true`` with frustum volumes; the
  volume budget splits it by truth diameter class (truth volume, the part
  of it missed, the reconstructed volume matched to the class) and gives
  the false-positive volume, to tell over-wide cylinders from missed or
  spurious branches;
- taper: diameter error of the stem (the branch of the root cylinder) in
  height bins above its base; ``taper_ok_height_m`` is the height up to which
  every bin stays within ``taper_tolerance_m``; ``dbh`` is the same at breast
  height (:data:`woody.dbh.BREAST_HEIGHT_M` above the stem's base, one bin
  wide): the true stem diameter there and the mean diameter error of its
  matched samples (None where the stem does not reach that height or no
  sample there is matched);
- topology, when the reconstruction has parents and orders: each
  reconstructed branch is assigned the truth branch it mostly matches;
  parent-child edges are compared after that mapping, orders relative to the
  root's order.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from woody.dbh import BREAST_HEIGHT_M
from woody.errors import WoodyError
from woody.geometry import cylinder_arrays, cylinders_volume

#: Diameter classes (m) for the per-class summaries: [0, 2 cm), [2, 5 cm), ...
DIAMETER_CLASSES_M = (0.02, 0.05, 0.10, 0.20, 0.50)


def _cylinders_of(value, name: str) -> list[dict]:
    cylinders = value.get("cylinders") if isinstance(value, dict) else value
    if not isinstance(cylinders, list):
        raise WoodyError(f"{name} must be a cylinder list or a dict with 'cylinders'")
    for i, c in enumerate(cylinders):
        missing = {"start", "end", "radius_m"} - set(c)
        if missing:
            raise WoodyError(f"{name} cylinder {i} lacks {sorted(missing)}")
    return cylinders


def sample_centrelines(arr: dict, step_m: float) -> dict:
    """Centreline samples of a cylinder list: midpoints of pieces of at most ``step_m``.

    Parameters
    ----------
    arr : dict of ndarray
        Cylinder columns (:func:`woody.geometry.cylinder_arrays`: ``start``,
        ``end`` in m, radii ``r0``, ``r1`` in m).
    step_m : float
        Longest piece, m (> 0).

    Returns
    -------
    dict of ndarray
        ``xyz`` (m), ``radius`` (m), ``direction`` (unit), ``length`` (of the
        piece, m), ``row`` (cylinder row) and ``hidden`` (inside another cylinder).
    """
    xyz, radius, direction, length, row = [], [], [], [], []
    for i, (a, b, r0, r1) in enumerate(zip(arr["start"], arr["end"], arr["r0"], arr["r1"])):
        axis = b - a
        h = np.linalg.norm(axis)
        if h == 0:
            continue
        count = max(int(np.ceil(h / step_m)), 1)
        t = (np.arange(count) + 0.5) / count
        xyz.append(a + t[:, None] * axis)
        radius.append(r0 + (r1 - r0) * t)
        direction.append(np.repeat((axis / h)[None], count, axis=0))
        length.append(np.full(count, h / count))
        row.append(np.full(count, i))
    if not xyz:
        return {"xyz": np.empty((0, 3)), "radius": np.empty(0), "direction": np.empty((0, 3)),
                "length": np.empty(0), "row": np.empty(0, np.int64), "hidden": np.empty(0, bool)}
    out = {"xyz": np.concatenate(xyz), "radius": np.concatenate(radius), "direction": np.concatenate(direction),
           "length": np.concatenate(length), "row": np.concatenate(row)}
    out["hidden"] = _inside_other(out["xyz"], out["row"], arr)
    return out


def _segment_query(xyz: np.ndarray, arr: dict, rows: np.ndarray | None = None, chunk: int = 2048):
    """Distance from each point to every cylinder axis (chunked): distance (m, c) and axial fraction (m, c)."""
    a, b = arr["start"], arr["end"]
    axis = b - a
    length2 = np.maximum(np.einsum("ij,ij->i", axis, axis), 1e-300)
    for s in range(0, len(xyz), chunk):
        p = xyz[s:s + chunk]
        rel = p[:, None, :] - a[None]
        t = np.clip(np.einsum("mci,ci->mc", rel, axis) / length2, 0.0, 1.0)
        closest = a[None] + t[..., None] * axis[None]
        yield s, np.linalg.norm(p[:, None, :] - closest, axis=2), t


def _inside_other(xyz: np.ndarray, row: np.ndarray, arr: dict) -> np.ndarray:
    hidden = np.zeros(len(xyz), bool)
    for s, dist, t in _segment_query(xyz, arr):
        radius = arr["r0"][None] + (arr["r1"] - arr["r0"])[None] * t
        inside = (dist < radius - 1e-9) & (t > 0) & (t < 1)
        inside[np.arange(len(dist)), row[s:s + len(dist)]] = False
        hidden[s:s + len(dist)] = inside.any(axis=1)
    return hidden


def match_samples(samples: dict, target: dict, min_tolerance_m: float, max_angle_deg: float,
                  tolerance_from: str = "sample") -> dict:
    """Match centreline samples to the nearest admissible axis of ``target`` cylinders.

    Parameters
    ----------
    samples : dict of ndarray
        Centreline samples (:func:`sample_centrelines`).
    target : dict of ndarray
        Cylinder columns to match against (:func:`woody.geometry.cylinder_arrays`).
    min_tolerance_m : float
        Smallest distance tolerance, m.
    max_angle_deg : float
        Largest angle between a sample's direction and a matched axis, degrees.
    tolerance_from : {"sample", "target"}
        ``"sample"``: tolerance ``max(sample radius, min_tolerance_m)``;
        ``"target"``: ``max(target radius there, min_tolerance_m)``.

    Returns
    -------
    dict of ndarray
        ``row`` (matched target row or -1), ``radius`` (target radius at the
        match, m), ``angle_deg`` and ``distance`` (m); NaN where unmatched.
    """
    count = len(samples["xyz"])
    out = {"row": np.full(count, -1), "radius": np.full(count, np.nan), "angle_deg": np.full(count, np.nan),
           "distance": np.full(count, np.nan)}
    if count == 0 or len(target["start"]) == 0:
        return out
    axis = target["end"] - target["start"]
    axis = axis / np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-300)
    cos_max = np.cos(np.radians(max_angle_deg))
    for s, dist, t in _segment_query(samples["xyz"], target):
        stop = s + len(dist)
        cos = np.abs(samples["direction"][s:stop] @ axis.T)
        radius = target["r0"][None] + (target["r1"] - target["r0"])[None] * t
        reach = radius if tolerance_from == "target" else samples["radius"][s:stop, None]
        ok = (dist <= np.maximum(reach, min_tolerance_m)) & (cos >= cos_max)
        dist = np.where(ok, dist, np.inf)
        best = np.argmin(dist, axis=1)
        found = np.isfinite(dist[np.arange(len(best)), best])
        rows = np.arange(len(best))
        out["row"][s:stop] = np.where(found, best, -1)
        out["radius"][s:stop] = np.where(found, radius[rows, best], np.nan)
        out["angle_deg"][s:stop] = np.where(found, np.degrees(np.arccos(np.clip(cos[rows, best], 0, 1))), np.nan)
        out["distance"][s:stop] = np.where(found, dist[rows, best], np.nan)
    return out


def error_summary(errors: np.ndarray) -> dict:
    """Signed bias, MAE, SD, largest absolute error and RMSE of an error array (NaN when empty)."""
    errors = np.asarray(errors, float)
    if len(errors) == 0:
        return {"count": 0, "bias": float("nan"), "mae": float("nan"), "sd": float("nan"), "max": float("nan"),
                "rmse": float("nan")}
    return {"count": int(len(errors)), "bias": float(errors.mean()), "mae": float(np.abs(errors).mean()),
            "sd": float(errors.std()), "max": float(np.abs(errors).max()), "rmse": float(np.sqrt((errors ** 2).mean()))}


def score(truth, reconstruction, *, step_m: float = 0.01, min_tolerance_m: float = 0.02,
          max_angle_deg: float = 30.0, height_bin_m: float = 0.10, taper_tolerance_m: float = 0.01,
          diameter_classes_m=DIAMETER_CLASSES_M, points=None) -> dict:
    """Score a reconstructed cylinder list against the truth.

    Parameters
    ----------
    truth : dict or list of dict
        A woody object's truth (``cylinders`` and optional ``volume_m3``) or its cylinder list.
    reconstruction : dict or list of dict
        The reconstruction as a cylinder list (or a dict with ``cylinders``).
    step_m : float
        Centreline sampling step, m.
    min_tolerance_m : float
        Smallest matching distance, m (the spec's ``2 Delta_xyz``).
    max_angle_deg : float
        Largest axis angle of a match, degrees.
    height_bin_m, taper_tolerance_m : float
        Taper bins and the diameter tolerance of ``taper_ok_height_m``, m.
    diameter_classes_m : sequence of float
        Upper bounds of the diameter classes, m.
    points : array_like, (n, 3), optional
        The scanned points the reconstruction came from, m: adds ``seen_length_m`` (visible truth length with
        a point within its radius + ``min_tolerance_m``) and ``seen_completeness`` (its matched share).

    Returns
    -------
    dict
        JSON-ready scores (see the module docstring); lengths in m, volumes
        in m^3, radius and diameter errors in m, angles in degrees.
    """
    if not (step_m > 0 and min_tolerance_m >= 0 and 0 < max_angle_deg <= 90 and height_bin_m > 0):
        raise WoodyError("scoring needs step_m > 0, min_tolerance_m >= 0, 0 < max_angle_deg <= 90, height_bin_m > 0")
    true_cyl = _cylinders_of(truth, "truth")
    rec_cyl = _cylinders_of(reconstruction, "reconstruction")
    if not true_cyl:
        raise WoodyError("truth has no cylinders to score against")
    T = cylinder_arrays(true_cyl)
    R = cylinder_arrays(rec_cyl) if rec_cyl else {k: np.empty((0, 3)) if k in ("start", "end") else np.empty(0)
                                                  for k in ("start", "end", "r0", "r1")}
    gt = sample_centrelines(T, step_m)
    visible = ~gt["hidden"]
    match = match_samples(gt, R, min_tolerance_m, max_angle_deg)
    hit = visible & (match["row"] >= 0)
    errors = match["radius"][hit] - gt["radius"][hit]

    out: dict = {"radius_error_m": error_summary(errors), "diameter_error_m": error_summary(2 * errors)}
    out["direction_error_deg"] = {"mean": float(np.mean(match["angle_deg"][hit])) if hit.any() else float("nan"),
                                  "sd": float(np.std(match["angle_deg"][hit])) if hit.any() else float("nan")}
    per_cylinder = []
    for i in range(len(true_cyl)):
        rows = hit & (gt["row"] == i)
        per_cylinder.append(float(np.mean(match["radius"][rows] - gt["radius"][rows])) if rows.any() else None)
    out["per_cylinder_radius_error_m"] = per_cylinder

    visible_length = float(gt["length"][visible].sum())
    out["truth_length_m"] = visible_length
    out["completeness"] = float(gt["length"][hit].sum() / visible_length) if visible_length else float("nan")
    if points is not None:
        near = cKDTree(np.asarray(points, float).reshape(-1, 3)).query(gt["xyz"])[0]
        seen = visible & (near <= gt["radius"] + min_tolerance_m)
        out["seen_length_m"] = float(gt["length"][seen].sum())
        out["seen_completeness"] = (float(gt["length"][seen & hit].sum() / out["seen_length_m"])
                                    if out["seen_length_m"] else float("nan"))
    diameter = 2 * gt["radius"]
    bounds = [0.0, *diameter_classes_m, np.inf]
    classes = []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        cls = visible & (diameter >= lo) & (diameter < hi)
        if cls.any():
            cls_hit = cls & hit
            classes.append({"diameter_from_m": lo, "diameter_to_m": None if np.isinf(hi) else hi,
                            "length_m": float(gt["length"][cls].sum()),
                            "completeness": float(gt["length"][cls_hit].sum() / gt["length"][cls].sum()),
                            "radius_error_m": error_summary(match["radius"][cls_hit] - gt["radius"][cls_hit])})
    out["by_diameter_class"] = classes

    # Reverse matching: reconstructed length matched to some truth cylinder.
    rec = sample_centrelines(R, step_m)
    back = match_samples(rec, T, min_tolerance_m, max_angle_deg, tolerance_from="target")
    shown = ~rec["hidden"]
    rec_length = float(rec["length"][shown].sum())
    matched_rec = shown & (back["row"] >= 0)
    out["reconstructed_length_m"] = rec_length
    out["false_positive_length_m"] = float(rec["length"][shown & ~matched_rec].sum())
    out["precision"] = float(rec["length"][matched_rec].sum() / rec_length) if rec_length else float("nan")

    # Branch-level detection and length error.
    true_branch_of_sample = T["branch"][gt["row"]]
    branches = np.unique(T["branch"])
    rec_branch_len = np.zeros(len(branches))
    if matched_rec.any():
        idx = np.searchsorted(branches, T["branch"][back["row"][matched_rec]])
        np.add.at(rec_branch_len, idx, rec["length"][matched_rec])
    detected, length_errors = [], []
    for k, b in enumerate(branches):
        mine = visible & (true_branch_of_sample == b)
        total = gt["length"][mine].sum()
        if total == 0:
            continue
        if gt["length"][mine & hit].sum() >= 0.5 * total:
            detected.append(int(b))
            length_errors.append(abs(rec_branch_len[k] - total) / total)
    out["branches_true"] = int(len(branches))
    out["branches_detected"] = len(detected)
    out["detection_rate"] = len(detected) / len(branches)
    out["length_error"] = {"mean": float(np.mean(length_errors)) if length_errors else float("nan"),
                           "max": float(np.max(length_errors)) if length_errors else float("nan")}

    v_true = float(truth["volume_m3"]) if isinstance(truth, dict) and "volume_m3" in truth else cylinders_volume(true_cyl)
    v_rec = cylinders_volume(rec_cyl)
    out["volume_true_m3"], out["volume_rec_m3"] = v_true, v_rec
    out["volume_error"] = (v_rec - v_true) / v_true if v_true > 0 else float("nan")

    out["volume_budget"] = _volume_budget(T, gt, hit, rec, back, bounds)
    out["taper"] = _taper(T, gt, match, hit, height_bin_m, taper_tolerance_m)
    out["topology"] = _topology(T, R, rec_cyl, rec, back, detected) if rec_cyl else None
    return out


def _volume_budget(T: dict, gt: dict, hit: np.ndarray, rec: dict, back: dict, bounds: list) -> dict:
    """Where a volume error comes from: per truth diameter class, the truth volume, the part of it on unmatched
    centreline (missed), and the reconstructed volume matched to the class; and the false-positive volume.

    Volumes are summed over the centreline samples (``pi r^2`` times the piece length, m^3), hidden samples included
    on both sides, so that the totals approach the cylinders' volumes as the step shrinks.
    """
    true_volume = np.pi * gt["radius"] ** 2 * gt["length"]
    rec_volume = np.pi * rec["radius"] ** 2 * rec["length"]
    matched = back["row"] >= 0
    true_diameter = 2 * gt["radius"]
    rec_class_diameter = np.where(matched, T["r0"][back["row"]] + T["r1"][back["row"]], np.nan)
    classes = []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        cls = (true_diameter >= lo) & (true_diameter < hi)
        rec_cls = matched & (rec_class_diameter >= lo) & (rec_class_diameter < hi)
        if cls.any() or rec_cls.any():
            classes.append({"diameter_from_m": lo, "diameter_to_m": None if np.isinf(hi) else hi,
                            "true_m3": float(true_volume[cls].sum()),
                            "missed_m3": float(true_volume[cls & ~hit & ~gt["hidden"]].sum()),
                            "reconstructed_m3": float(rec_volume[rec_cls].sum())})
    return {"by_diameter_class": classes, "false_positive_m3": float(rec_volume[~matched].sum())}


def _taper(T: dict, gt: dict, match: dict, hit: np.ndarray, bin_m: float, tolerance_m: float) -> dict:
    """Diameter error of the stem against height above the stem base."""
    roots = np.flatnonzero(T["parent"] < 0)
    stem = T["branch"][roots[0]] if len(roots) else T["branch"][0]
    on_stem = (T["branch"][gt["row"]] == stem) & ~gt["hidden"]
    base = gt["xyz"][on_stem, 2].min() - 0.5 * gt["length"][on_stem].max() if on_stem.any() else 0.0
    height = gt["xyz"][:, 2] - base
    top = height[on_stem].max() if on_stem.any() else 0.0
    bins = []
    ok_height = 0.0
    failed = False
    for lo in np.arange(0.0, top + 1e-12, bin_m):
        sel = on_stem & (height >= lo) & (height < lo + bin_m)
        if not sel.any():
            continue
        sel_hit = sel & hit
        error = float(2 * np.mean(match["radius"][sel_hit] - gt["radius"][sel_hit])) if sel_hit.any() else None
        bins.append({"height_m": float(lo + 0.5 * bin_m), "diameter_true_m": float(2 * gt["radius"][sel].mean()),
                     "diameter_error_m": error})
        if not failed and error is not None and abs(error) <= tolerance_m:
            ok_height = float(lo + bin_m)
        else:
            failed = True
    breast = on_stem & (np.abs(height - BREAST_HEIGHT_M) <= 0.5 * bin_m)
    dbh = None
    if breast.any():
        matched = breast & hit
        dbh = {"diameter_true_m": float(2 * gt["radius"][breast].mean()),
               "diameter_error_m": (float(2 * np.mean(match["radius"][matched] - gt["radius"][matched]))
                                    if matched.any() else None)}
    return {"stem_branch": int(stem), "bins": bins, "taper_ok_height_m": ok_height, "dbh": dbh}


def _topology(T: dict, R: dict, rec_cyl: list[dict], rec: dict, back: dict, detected: list[int]) -> dict | None:
    """Branch counts, orders and parent-child edges after mapping reconstructed to truth branches."""
    if any(c.get("order") is None for c in rec_cyl):
        return None
    # Truth branch of each reconstructed branch: the one most of its matched length goes to.
    rec_branch_of_sample = R["branch"][rec["row"]]
    mapping: dict[int, int] = {}
    for b in np.unique(R["branch"]):
        sel = (rec_branch_of_sample == b) & (back["row"] >= 0)
        if sel.any():
            targets, weights = T["branch"][back["row"][sel]], rec["length"][sel]
            uniq = np.unique(targets)
            mapping[int(b)] = int(uniq[np.argmax([weights[targets == u].sum() for u in uniq])])

    def edges(arr) -> set[tuple[int, int]]:
        row_of = {int(i): k for k, i in enumerate(arr["id"])}
        out = set()
        for k in range(len(arr["id"])):
            p = int(arr["parent"][k])
            if p in row_of and arr["branch"][row_of[p]] != arr["branch"][k]:
                out.add((int(arr["branch"][row_of[p]]), int(arr["branch"][k])))
        return out

    true_edges = edges(T)
    rec_edges = {(mapping[p], mapping[c]) for p, c in edges(R) if p in mapping and c in mapping}
    rec_edges = {e for e in rec_edges if e[0] != e[1]}
    true_order = {int(b): int(o) for b, o in zip(T["branch"], T["order"])}
    rec_order = {int(b): int(o) for b, o in zip(R["branch"], R["order"])}
    t0, r0 = min(true_order.values()), min(rec_order.values())
    same_order = [rec_order[b] - r0 == true_order[m] - t0 for b, m in mapping.items()]
    n_rec = len(np.unique(R["branch"]))
    return {"branches_true": len(true_order), "branches_rec": n_rec,
            "max_order_true": max(true_order.values()) - t0 + 1, "max_order_rec": max(rec_order.values()) - r0 + 1,
            "edge_precision": len(rec_edges & true_edges) / len(rec_edges) if rec_edges else float("nan"),
            "edge_recall": len(rec_edges & true_edges) / len(true_edges) if true_edges else float("nan"),
            "order_accuracy": float(np.mean(same_order)) if same_order else float("nan"),
            "fragmentation": n_rec / len(detected) if detected else float("nan")}

"""Outlier budget of one variant on one case: where the outliers it leaves come from (``tlsbench budget``).

Every scored leaf pulse (each target leaf's mask, counted as :func:`benchmarks.scoring.score_leaf` counts it, so
a pulse in two leaves' masks counts twice) falls in one group by

- its **mixture**, from the truth: the types of the objects in its footprint, ``leaf alone`` for a pure pulse
  (mixed fraction under :data:`benchmarks.scoring.PURE_MIXED_FRACTION`), else the dominant and the second
  object's types sorted and joined (``leaf+leaf``, ``branch+leaf``, ``leaf+wall``...);
- its **action**: what the variant did with it: ``kept`` at its measured point, ``moved``, or ``removed``;
- its **place**, for whole-scan variants only: in the output region matched to its leaf (the region holding most
  of the leaf's visible pulses, as :func:`benchmarks.scoring.leaf_outputs` matches), in ``another region``, or in
  ``no region``.

Each group counts its pulses, its outliers before and after (at the case's threshold: ``auto`` = 3 σ of the leaf's
range noise, or ``1cm``), the good points the variant damaged (an inlier moved off the surface) and the good points
it lost (an inlier removed), and its share of the case's ROP as the benchmark computes it: the mean over the
leaves of each leaf's ROP, so a group's ``rop_before`` and ``rop_after`` are its outliers divided by its leaf's
pulses (kept pulses after) and by the number of leaves, and they sum to the case's mean ROPs. A leaf with few pulses
weighs as much as a large one: the pooled counts and the ROP shares can rank the groups differently.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np

from benchmarks import scoring
from benchmarks.errors import BenchError
from benchmarks.runner import TILED_SCAN_BYTES, case_variant, scan_setup
from benchmarks.suite import Case

#: What a variant can do with a pulse.
ACTIONS = ("kept", "moved", "removed")
#: Where a whole-scan variant's output puts a pulse.
PLACES = ("its leaf's region", "another region", "no region")
#: Counts of a group, in output order.
COUNTS = ("pulses", "outliers_before", "outliers_after", "good_damaged", "good_lost")
#: Shares of the case's mean per-leaf ROP before and after.
SHARES = ("rop_before", "rop_after")


def mixtures(leaf: scoring.LeafTruth, object_types: list[str]) -> np.ndarray:
    """The mixture of each of a leaf's scored pulses (see the module docstring).

    Parameters
    ----------
    leaf : LeafTruth
        The leaf (its part of the scan carries the truth layers).
    object_types : list of str
        Type of every scene object, by id.

    Returns
    -------
    ndarray of str, (n,)
        One label per masked pulse.
    """
    types = np.array([*object_types, "nothing"])  # id -1 (no object) reads the last entry
    part = leaf.scan
    dominant = types[part.truth_id[leaf.mask]]
    second = types[part.layers["truth_second_id"][leaf.mask]]
    pair = np.where(dominant <= second, np.char.add(np.char.add(dominant, "+"), second),
                    np.char.add(np.char.add(second, "+"), dominant))
    return np.where(part.mixed_fraction[leaf.mask] < scoring.PURE_MIXED_FRACTION,
                    np.char.add(dominant, " alone"), pair)


def tally(leaves: list[scoring.LeafTruth], xyz: list[np.ndarray], object_types: list[str],
          threshold: str = "auto", places: list[np.ndarray] | None = None) -> list[dict]:
    """Count the scored pulses of every leaf by mixture, action and place.

    Parameters
    ----------
    leaves : list of LeafTruth
        The targets (:func:`benchmarks.scoring.prepare_leaves`).
    xyz : list of ndarray
        Per leaf, the variant's output points on the leaf's part of the scan, (rows, cols, 3), m; NaN where removed.
    object_types : list of str
        Type of every scene object, by id.
    threshold : {"auto", "1cm"}
        Outlier threshold (the leaves' ``taus``).
    places : list of ndarray of int, optional
        Per leaf, the index in :data:`PLACES` of each masked pulse (whole-scan variants).

    Returns
    -------
    list of dict
        One per non-empty group: ``mixture``, ``action``, ``place`` (None without ``places``), the
        :data:`COUNTS` and the :data:`SHARES`, sorted by share of the ROP after, largest first.
    """
    groups = defaultdict(lambda: np.zeros(len(COUNTS) + len(SHARES)))
    for k, (leaf, points) in enumerate(zip(leaves, xyz)):
        if threshold not in leaf.taus:
            raise BenchError(f"unknown outlier threshold {threshold!r}; allowed: {sorted(leaf.taus)}")
        tau = leaf.taus[threshold]
        _, kept, distance = scoring.output_distance(leaf, scoring.VariantOutput(points))
        moved = kept & (np.abs(np.asarray(points)[leaf.mask] - leaf.scan.xyz[leaf.mask]) > 1e-9).any(axis=1)
        before, after = np.abs(leaf.distance) > tau, kept & (np.abs(distance) > tau)
        action = np.where(~kept, 2, np.where(moved, 1, 0))
        place = places[k] if places is not None else np.full(len(action), -1)
        weights = len(leaves) * np.array([len(before), max(int(kept.sum()), 1)], dtype=float)
        counts = np.stack([np.ones_like(before), before, after, ~before & after, ~before & ~kept,
                           before / weights[0], after / weights[1]], axis=1)
        for key, values in zip(zip(mixtures(leaf, object_types), action, place), counts.astype(float)):
            groups[key] += values
    rows = [{"mixture": str(mix), "action": ACTIONS[a], "place": PLACES[p] if p >= 0 else None,
             **dict(zip(COUNTS, map(int, values[:len(COUNTS)]))), **dict(zip(SHARES, values[len(COUNTS):]))}
            for (mix, a, p), values in groups.items()]
    return sorted(rows, key=lambda row: (-row["rop_after"], -row["outliers_after"], -row["outliers_before"],
                                         row["mixture"], row["action"], row["place"] or ""))


def _places(leaf: scoring.LeafTruth, labels: np.ndarray) -> np.ndarray:
    """Index in :data:`PLACES` of each of a leaf's masked pulses, from a whole-scan output's region labels."""
    own = labels[leaf.own_pixels()]
    match = int(np.bincount(own[own > 0]).argmax()) if (own > 0).any() else -1
    region = labels[leaf.window][leaf.mask]
    return np.where(region == 0, 2, np.where(region == match, 0, 1))


def case_budget(case: Case, variant_name: str, threshold: str = "auto") -> dict:
    """Simulate a case, run one leaf variant on it as ``tlsbench run`` does, and tally its scored pulses.

    Parameters
    ----------
    case : Case
        A suite case whose scan fits in memory in one piece (tiled cases are refused).
    variant_name : str
        A registered leaf variant (``tlsbench list``); the case's own parameters for it apply.
    threshold : {"auto", "1cm"}
        Outlier threshold.

    Returns
    -------
    dict
        ``case``, ``variant``, ``threshold``, ``scope``, ``n_leaves``, ``groups`` (:func:`tally`) and ``totals``
        (the :data:`COUNTS` and :data:`SHARES` summed, ``rop_reduction`` from the shares, as the benchmark's, and
        ``pooled_rop_reduction`` from the counts).

    Raises
    ------
    BenchError
        For a wood variant, a height-field or tiled case, or a case with no target leaf in its scan.
    """
    from benchmarks.generators import build_scene
    from benchmarks.heightfields import is_heightfield
    from tlssim.simulate import BYTES_PER_PULSE, simulate

    variant = case_variant(case, {"name": variant_name, "params": {}})
    if variant.target != "leaf":
        raise BenchError(f"variant {variant_name!r} reconstructs wood; the budget counts leaf pulses: "
                         f"give a leaf variant (tlsbench list)")
    if is_heightfield(case.scene):
        raise BenchError(f"case {case.name!r} is a height field: it has no scan to budget")
    scene = build_scene(case.scene)
    setup = scan_setup(case, scene)
    if setup.window.shape[0] * setup.window.shape[1] * BYTES_PER_PULSE > TILED_SCAN_BYTES:
        raise BenchError(f"case {case.name!r} is scanned in tiles ({setup.window.shape[0]} x "
                         f"{setup.window.shape[1]} pulses); the budget needs a scan that fits in one piece")
    scan = simulate(scene, setup, seed=case.seed, progress=False)
    leaves = scoring.prepare_leaves(scene, scan, None if case.targets is None else list(case.targets))
    if not leaves:
        raise BenchError(f"case {case.name!r}: no target leaf returned a pulse")
    if variant.prepare is not None:
        variant.prepare(scan)
    places = None
    if variant.scope == "scan":
        output = variant(scan, scoring.target_labels(scan.shape, leaves))
        xyz = [np.asarray(output.xyz)[leaf.window] for leaf in leaves]
        places = [_places(leaf, np.asarray(output.labels)) for leaf in leaves]
    else:
        xyz = [np.asarray(variant(leaf.scan, leaf.mask).xyz) for leaf in leaves]
    groups = tally(leaves, xyz, [obj.type for obj in scene.objects], threshold, places)
    totals = {key: sum(row[key] for row in groups) for key in COUNTS + SHARES}
    kept = totals["pulses"] - sum(row["pulses"] for row in groups if row["action"] == "removed")
    pooled_before = totals["outliers_before"] / totals["pulses"]
    pooled_after = totals["outliers_after"] / kept if kept else 0.0
    totals["rop_reduction"] = _reduction(totals["rop_before"], totals["rop_after"])
    totals["pooled_rop_reduction"] = _reduction(pooled_before, pooled_after)
    return {"case": case.name, "variant": variant_name, "threshold": threshold, "scope": variant.scope,
            "n_leaves": len(leaves), "groups": groups, "totals": totals}


def _reduction(before: float, after: float) -> float:
    """1 - after / before, NaN without outliers before."""
    return 1.0 - after / before if before > 0 else float("nan")


def format_budget(budget: dict, top: int = 12) -> str:
    """The budget as text: a table by mixture (its outliers before and after, its share of the ROP after; of the
    outliers left, how many the variant kept at their measured point and how many it moved; the outliers it
    removed; the good points it damaged and lost), then the groups with the largest shares of the ROP after.

    Parameters
    ----------
    budget : dict
        :func:`case_budget`'s result.
    top : int
        Groups listed in the second table.
    """
    groups, totals = budget["groups"], budget["totals"]
    rop_after = totals["rop_after"] or 1.0
    lines = [f"case {budget['case']}, variant {budget['variant']} ({budget['scope']} scope), "
             f"{budget['n_leaves']} leaves, threshold {budget['threshold']}: ROP {totals['rop_before']:.4f} -> "
             f"{totals['rop_after']:.4f} (mean over the leaves; reduction {totals['rop_reduction']:.3f}); "
             f"{totals['pulses']:,} scored pulses, outliers {totals['outliers_before']:,} -> "
             f"{totals['outliers_after']:,} (pooled reduction {totals['pooled_rop_reduction']:.3f}); good points "
             f"damaged {totals['good_damaged']:,}, lost {totals['good_lost']:,}", "",
             f"{'mixture':24s} {'pulses':>9s} {'before':>8s} {'after':>8s} {'% of ROP':>9s} {'left kept':>10s} "
             f"{'left moved':>10s} {'removed':>8s} {'damaged':>8s} {'lost':>7s}"]
    by_mixture = defaultdict(lambda: defaultdict(float))
    for row in groups:
        acc = by_mixture[row["mixture"]]
        for key in COUNTS + SHARES:
            acc[key] += row[key]
        acc[row["action"]] += row["outliers_after"] if row["action"] != "removed" else row["outliers_before"]
    for mixture, acc in sorted(by_mixture.items(), key=lambda item: (-item[1]["rop_after"], item[0])):
        acc = {key: value if key in SHARES else int(value) for key, value in acc.items()}
        lines.append(f"{mixture:24s} {acc['pulses']:9,d} {acc['outliers_before']:8,d} {acc['outliers_after']:8,d} "
                     f"{100 * acc['rop_after'] / rop_after:8.1f}% {acc.get('kept', 0):10,d} "
                     f"{acc.get('moved', 0):10,d} {acc.get('removed', 0):8,d} {acc['good_damaged']:8,d} "
                     f"{acc['good_lost']:7,d}")
    lines += ["", "largest shares of the ROP after (share, outliers left, group):"]
    for row in [row for row in groups if row["outliers_after"] > 0][:top]:
        where = f", {row['place']}" if row["place"] else ""
        lines.append(f"  {100 * row['rop_after'] / rop_after:5.1f}% {row['outliers_after']:8,d}  "
                     f"{row['mixture']}, {row['action']}{where}")
    return "\n".join(lines)

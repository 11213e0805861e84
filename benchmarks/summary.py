"""Aggregating stored results: one summary row per suite × variant, and the headline table.

Per-leaf scores (see :func:`benchmarks.scoring.score_leaf`) are first
aggregated within each case, then over the cases, so that every case weighs
the same whatever its number of leaves (a tree with 300 leaves does not
drown 60 single-leaf cases):

- ``rop_before``, ``rop_after``: mean over cases of the mean per-leaf ROP;
  ``rop_reduction`` = 1 − rop_after / rop_before (the same with ``_1cm``);
- ``good_points_lost``, ``outliers_restored``, ``good_points_damaged``,
  ``completeness``, ``flag_precision``, ``flag_recall`` and ``rppp_1`` (the
  share of pixels with exactly one PROP-SFS candidate): mean over cases of
  the mean over leaves;
- ``good_points_lost_pooled``: mean over cases of the good points lost
  pooled over each case's leaves (good pulses removed / good pulses). In a
  canopy the per-leaf mean above is carried by leaves with a handful of good
  pulses (a grazing sliver before a wall: 1 of 27), where one removed pulse
  is 4-100 %; the pooled share says what part of the good points a user
  loses;
- height-field cases (:mod:`benchmarks.heightfields`): ``abs_eps_mean``
  (the thesis' mean |relative height error|), ``within_5pct`` and
  ``completeness``, means over cases;
- ``area_rel_err_median``: median over cases of the median over the fully
  visible leaves (``visibility`` >= :data:`benchmarks.metrics.MIN_VISIBILITY`, like the
  thesis' 58 fully visible field leaves: no method recovers a hidden part)
  of |relative area error| (``area_rel_err_bias``: the same with the
  signed error; ``area_seen_rel_err_median``: the same against the true
  area in the scanner's line of sight, ``visible_area_m2``, which leaves
  out what a leaf hides behind its own curl); ``elevation_err_median_deg``,
  ``azimuth_err_median_deg``: the same with the absolute angle errors (on ``n_leaves_traits`` leaves);
  ``surface_rmse_m``: median over cases of the median over leaves;
- ``runtime_s``: median wall time of the variant on one case (all its
  targets), over the cases where it had targets; ``runtime_total_s``: sum over cases; ``peak_mem_mb``: largest
  peak over cases; ``pulses_per_s``: median over cases of the pulses the
  variant was given (the whole scan for variants that run on it, the
  parts around the leaves otherwise) per second;
- variants that segment the whole scan into leaves: ``n_found``,
  ``n_missed`` and ``n_false`` (leaves found, missed, and regions matching
  no leaf; see :func:`benchmarks.scoring.leaf_outputs`), sums over cases,
  and ``found_visible``, the share of the leaves at least
  :data:`benchmarks.metrics.MIN_VISIBILITY` visible that were found;
- woody objects (scored with :func:`woody.score`): ``diameter_err_median_m``,
  median over cases of the median over woody objects of the mean absolute
  diameter error; ``volume_rel_err``, the same with |relative volume error|;
  ``dbh_err_median_m``, the same with |DBH error| (the stem's diameter
  1.3 m above its base).

A metric that does not apply (no leaf with that truth, or a variant that
does not estimate it) is ``None``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from benchmarks import metrics

#: The goal of the project (issue 7): a PROP-SFS variant with this ROP reduction and median |area error|.
GOAL_ROP_REDUCTION = 0.90
GOAL_AREA_REL_ERR = 0.05


#: Keys of a summary row, in display order.
SUMMARY_KEYS = ("suite", "variant", "family", "n_cases", "n_targets", "n_leaves_traits", "n_errors", "rop_before",
                "rop_after", "rop_reduction", "rop_before_1cm", "rop_after_1cm", "rop_reduction_1cm", "good_points_lost",
                "good_points_lost_pooled", "outliers_restored", "good_points_damaged", "completeness", "flag_precision",
                "flag_recall",
                "rppp_1", "abs_eps_mean", "within_5pct", "surface_rmse_m",
                "area_rel_err_median", "area_rel_err_bias", "area_seen_rel_err_median", "elevation_err_median_deg",
                "azimuth_err_median_deg", "n_found", "n_missed", "n_false", "found_visible",
                "diameter_err_median_m", "volume_rel_err", "dbh_err_median_m", "runtime_s", "runtime_total_s",
                "pulses_per_s", "peak_mem_mb")

#: The headline table: (column title, summary key, format).
HEADLINE = (("variant", "variant", "{}"), ("ROP after", "rop_after", "{:.3f}"),
            ("ROP red.", "rop_reduction", "{:.0%}"), ("good lost", "good_points_lost", "{:.1%}"),
            ("found", "found_visible", "{:.0%}"), ("false", "n_false", "{}"),
            ("|area err| med", "area_rel_err_median", "{:.1%}"), ("elev err", "elevation_err_median_deg", "{:.1f}°"),
            ("azim err", "azimuth_err_median_deg", "{:.1f}°"), ("runtime/case", "runtime_s", "{:.3f} s"),
            ("errors", "n_errors", "{}"))
#: The headline of suites without leaves (height fields: the thesis' relative height errors).
HEADLINE_HEIGHTS = (("variant", "variant", "{}"), ("mean |height err|", "abs_eps_mean", "{:.2%}"),
                    ("within 5 %", "within_5pct", "{:.1%}"), ("completeness", "completeness", "{:.1%}"),
                    ("runtime/case", "runtime_s", "{:.3f} s"), ("errors", "n_errors", "{}"))
#: Columns added for woody objects (STEP and cylinder following).
WOODY_COLUMNS = (("diam err med", "diameter_err_median_m", "{:.4f} m"), ("|vol err| med", "volume_rel_err", "{:.1%}"),
                 ("|DBH err| med", "dbh_err_median_m", "{:.4f} m"))


def target_scores(rows: list[dict]) -> list[dict]:
    """Every per-target score (leaf, surface, woody object) of result rows, with ``case`` and ``variant`` added."""
    return [{"case": r["case_name"], "variant": r["variant"], **target}
            for r in rows if not r["error"] for target in r["metrics"]["targets"]]


def _values(leaves: list[dict], key: str, absolute: bool = False) -> np.ndarray:
    values = np.array([leaf[key] for leaf in leaves if leaf.get(key) is not None], dtype=float)
    return np.abs(values) if absolute else values


def _over_cases(rows: list[dict], key: str, reduce=np.mean, absolute: bool = False, visible: bool = False):
    """``reduce`` of a per-leaf score within each case, then over the cases (None when no case has it)."""
    per_case = []
    for row in rows:
        leaves = row["metrics"]["targets"]
        if visible:
            leaves = [leaf for leaf in leaves if (leaf.get("visibility") or 0.0) >= metrics.MIN_VISIBILITY]
        values = _values(leaves, key, absolute)
        if len(values):
            per_case.append(reduce(values))
    return float(reduce(per_case)) if per_case else None


def _pooled_lost(rows: list[dict]):
    """Mean over cases of the good points lost pooled over the case's leaves (None when no case has good points)."""
    per_case = []
    for row in rows:
        leaves = [leaf for leaf in row["metrics"]["targets"]
                  if leaf.get("n_points") is not None and leaf.get("good_points_lost") is not None]
        good = np.array([leaf["n_points"] - leaf["n_outliers"] for leaf in leaves], dtype=float)
        lost = np.array([leaf["good_points_lost"] for leaf in leaves], dtype=float)
        scored = (good > 0) & np.isfinite(lost)
        if scored.any():
            per_case.append(float(np.sum(lost[scored] * good[scored]) / np.sum(good[scored])))
    return float(np.mean(per_case)) if per_case else None


def _reduction(before, after):
    return None if before is None or after is None or before <= 0 else 1.0 - after / before


def summarize(rows: list[dict], suite: str) -> list[dict]:
    """One summary row per variant of a run's result rows (variants in first-seen order).

    Parameters
    ----------
    rows : list of dict
        Result rows of a run.
    suite : str
        Suite name stored in every summary row.

    Returns
    -------
    list of dict
        Summary rows (metrics in the units of their names).
    """
    return [_summary_row([r for r in rows if r["variant"] == variant], {"suite": suite})
            for variant in dict.fromkeys(r["variant"] for r in rows)]


def scene_kind(case_spec: dict) -> str:
    """The kind of scene of a stored case: its generator, built-in scene, scene file name or height-field surface."""
    scene = case_spec["scene"]
    if "file" in scene:
        return f"file: {Path(scene['file']).name}"
    return scene.get("generator") or scene.get("builtin") or f"height field: {scene['heightfield']}"


def summarize_by_scene(rows: list[dict], suite: str) -> list[dict]:
    """One summary row per kind of scene (:func:`scene_kind`) and variant, with a ``scene`` key.

    Parameters
    ----------
    rows : list of dict
        Result rows of a run.
    suite : str
        Suite name stored in every summary row.

    Returns
    -------
    list of dict
        Summary rows (metrics in the units of their names).
    """
    kinds = list(dict.fromkeys(scene_kind(r["case_spec"]) for r in rows))
    return [_summary_row(mine, {"suite": suite, "scene": kind})
            for kind in kinds for variant in dict.fromkeys(r["variant"] for r in rows)
            if (mine := [r for r in rows if r["variant"] == variant and scene_kind(r["case_spec"]) == kind])]


def _summary_row(mine: list[dict], labels: dict) -> dict:
    """Aggregate the result rows of one variant (see the module docstring)."""
    ok = [r for r in mine if not r["error"]]
    leaves = target_scores(ok)
    row = {**labels, "variant": mine[0]["variant"], "family": mine[0]["family"], "n_cases": len(mine),
           "n_targets": len(leaves), "n_errors": len(mine) - len(ok)}
    for suffix in ("", "_1cm"):
        before, after = _over_cases(ok, "rop_before" + suffix), _over_cases(ok, "rop_after" + suffix)
        row.update({f"rop_before{suffix}": before, f"rop_after{suffix}": after,
                    f"rop_reduction{suffix}": _reduction(before, after)})
    for key in ("good_points_lost", "outliers_restored", "good_points_damaged", "completeness", "flag_precision",
                "flag_recall", "rppp_1", "abs_eps_mean", "within_5pct"):
        row[key] = _over_cases(ok, key)
    row["good_points_lost_pooled"] = _pooled_lost(ok)
    row["surface_rmse_m"] = _over_cases(ok, "surface_rmse_m", np.median)
    row["n_leaves_traits"] = sum(1 for leaf in leaves if (leaf.get("visibility") or 0.0) >= metrics.MIN_VISIBILITY)
    row["area_rel_err_median"] = _over_cases(ok, "area_rel_err", np.median, absolute=True, visible=True)
    row["area_rel_err_bias"] = _over_cases(ok, "area_rel_err", np.median, visible=True)
    row["area_seen_rel_err_median"] = _over_cases(ok, "area_seen_rel_err", np.median, absolute=True, visible=True)
    row["elevation_err_median_deg"] = _over_cases(ok, "elevation_err_deg", np.median, visible=True)
    row["azimuth_err_median_deg"] = _over_cases(ok, "azimuth_err_deg", np.median, visible=True)
    row["diameter_err_median_m"] = _over_cases(ok, "diameter_err_mae_m", np.median)
    row["volume_rel_err"] = _over_cases(ok, "volume_rel_err", np.median, absolute=True)
    row["dbh_err_median_m"] = _over_cases(ok, "dbh_err_m", np.median, absolute=True)
    # Runtime over the cases that gave the variant something to score (woody methods skip leaf cases).
    runtimes = [r["runtime_s"] for r in ok if r["runtime_s"] is not None and r["metrics"]["targets"]]
    peaks = [r["peak_mem_mb"] for r in ok if r["peak_mem_mb"] is not None]
    counts = [r["metrics"]["case"] for r in ok if "n_regions" in r["metrics"].get("case", {})]
    for key, total in (("n_found", "n_found"), ("n_missed", "n_missed"), ("n_false", "n_false")):
        row[key] = int(sum(c[total] for c in counts)) if counts else None
    visible = sum(c["n_visible"] for c in counts)
    row["found_visible"] = sum(c["n_found_visible"] for c in counts) / visible if visible else None
    rates = [rate for r in ok if r["metrics"]["targets"] and (rate := pulses_per_s(r)) is not None]
    row["pulses_per_s"] = float(np.median(rates)) if rates else None
    row["runtime_s"] = float(np.median(runtimes)) if runtimes else None
    row["runtime_total_s"] = float(np.sum(runtimes)) if runtimes else None
    row["peak_mem_mb"] = float(max(peaks)) if peaks else None
    return {key: row[key] for key in tuple(labels) + SUMMARY_KEYS[1:]}


def goal_status(summary: list[dict]) -> str:
    """One sentence on whether a PROP-SFS variant meets the project goal on these results."""
    goal = (f"goal: a PROP-SFS variant with ROP reduction >= {GOAL_ROP_REDUCTION:.0%} and median |area error| "
            f"<= {GOAL_AREA_REL_ERR:.0%}")
    candidates = [r for r in summary if r["family"] == "prop-sfs"]
    if candidates and all(r["rop_reduction"] is None for r in candidates):
        return f"{goal}: not measured by this suite (no leaf scored)"
    if not candidates:
        return f"{goal}: NOT MET - no PROP-SFS variant in this run"
    met = [r["variant"] for r in candidates
           if (r["rop_reduction"] or 0) >= GOAL_ROP_REDUCTION
           and r["area_rel_err_median"] is not None and r["area_rel_err_median"] <= GOAL_AREA_REL_ERR]
    if met:
        return f"{goal}: MET by {', '.join(met)}"
    best = max(candidates, key=lambda r: r["rop_reduction"] or -math.inf)
    return (f"{goal}: NOT MET - best PROP-SFS variant {best['variant']}: ROP reduction "
            f"{_fmt(best['rop_reduction'], '{:.0%}')}, median |area error| {_fmt(best['area_rel_err_median'], '{:.1%}')}")


def _fmt(value, fmt: str) -> str:
    return "n/a" if value is None else fmt.format(value)


def headline_columns(summary: list[dict]) -> tuple:
    """:data:`HEADLINE`, or :data:`HEADLINE_HEIGHTS` for results without any leaf score; with
    :data:`WOODY_COLUMNS` before the runtime where woody objects were scored (alone for woody-only results)."""
    leaves = any(row["rop_after"] is not None for row in summary)
    heights = any(row["abs_eps_mean"] is not None for row in summary)
    columns = HEADLINE_HEIGHTS if heights and not leaves else HEADLINE
    if not any(row["volume_rel_err"] is not None for row in summary):
        return columns
    if not (leaves or heights):
        columns = columns[:1] + columns[-2:]
    return columns[:-2] + WOODY_COLUMNS + columns[-2:]


def headline_table(summary: list[dict]) -> str:
    """The headline table as aligned plain text (one line per variant)."""
    columns = headline_columns(summary)
    cells = [[title for title, _, _ in columns]]
    cells += [[_fmt(row[key], fmt) for _, key, fmt in columns] for row in summary]
    widths = [max(len(line[i]) for line in cells) for i in range(len(columns))]
    return "\n".join("  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(line, widths)))
                     for line in cells)


#: Keys of a row of the thesis' validation table (:func:`validation_table`), in display order.
VALIDATION_KEYS = ("variant", "n_leaves", "n_success", "success", "area_slope", "area_intercept_cm2", "area_r2",
                   "area_bias_cm2", "area_rel_err_median", "area_seen_r2", "elevation_r2", "elevation_precision_deg", "azimuth_r2",
                   "azimuth_precision_deg", "n_found", "n_merged", "n_missed", "n_false")


def visible_leaves(leaves: list[dict]) -> list[dict]:
    """The scored leaves with a true area that show at least :data:`benchmarks.metrics.MIN_VISIBILITY` of their
    silhouette (those whose area and angles are scored)."""
    return [leaf for leaf in leaves if leaf.get("area_true_m2") and (leaf.get("visibility") or 0.0)
            >= metrics.MIN_VISIBILITY]


def succeeded(leaf: dict) -> bool:
    """Whether a variant reconstructed a leaf: an area estimate above zero, from a region that found it (for
    variants that segment the scan themselves)."""
    return (leaf.get("area_m2") or 0.0) > 0 and leaf.get("found", 1) == 1


def validation_table(rows: list[dict]) -> list[dict]:
    """The thesis' leaf validation table (ch.7) per variant, over every visible leaf of every case.

    Over the leaves at least :data:`benchmarks.metrics.MIN_VISIBILITY`
    visible (``n_leaves``), those the variant reconstructed
    (:func:`succeeded`; ``success`` = their share) give: the least-squares
    line of estimated against true area (``area_slope``,
    ``area_intercept_cm2``, ``area_r2``, :func:`benchmarks.metrics.linear_fit`),
    the area BIAS of eq 2.1 (:func:`benchmarks.metrics.area_bias`, cm²),
    the median |relative area error|, ``area_seen_r2`` (R² of the estimated
    against the true area in the scanner's line of sight,
    ``visible_area_m2``: what one scan can measure, without the parts a
    leaf hides behind its own curl), and the R² and precision (standard
    deviation of the error, :func:`benchmarks.metrics.precision`) of the
    midrib elevation and azimuth. ``n_found`` / ``n_missed``: visible
    leaves found or missed by variants that segment the scan themselves
    (None for the others), ``n_merged`` of the found ones in a region that
    is another found leaf's match too; ``n_false``: their regions that match no
    leaf, over all cases.

    Returns
    -------
    list of dict
        One row per variant, keys :data:`VALIDATION_KEYS` (None where a value does not apply).
    """
    table = []
    for variant in dict.fromkeys(r["variant"] for r in rows):
        mine = [r for r in rows if r["variant"] == variant and not r["error"]]
        leaves = visible_leaves(target_scores(mine))
        if not leaves:
            continue
        done = [leaf for leaf in leaves if succeeded(leaf)]
        true_area = np.array([leaf["area_true_m2"] for leaf in done]) * 1e4
        area = np.array([leaf["area_m2"] for leaf in done]) * 1e4
        fit = metrics.linear_fit(true_area, area)
        row = {"variant": variant, "n_leaves": len(leaves), "n_success": len(done), "success": len(done) / len(leaves),
               "area_slope": fit["slope"], "area_intercept_cm2": fit["intercept"], "area_r2": fit["r2"],
               "area_bias_cm2": metrics.area_bias(area, true_area),
               "area_rel_err_median": float(np.median(np.abs(area / true_area - 1))) if len(done) else None}
        seen = [leaf for leaf in done if leaf.get("visible_area_m2")]
        row["area_seen_r2"] = metrics.linear_fit([leaf["visible_area_m2"] * 1e4 for leaf in seen],
                                                 [leaf["area_m2"] * 1e4 for leaf in seen])["r2"]
        for angle in ("elevation", "azimuth"):
            pairs = [(leaf[f"{angle}_true_deg"], leaf[f"{angle}_deg"]) for leaf in done
                     if leaf.get(f"{angle}_deg") is not None]
            truth, estimate = (np.array(v) for v in zip(*pairs)) if pairs else (np.zeros(0), np.zeros(0))
            row[f"{angle}_r2"] = metrics.linear_fit(truth, estimate)["r2"]
            row[f"{angle}_precision_deg"] = metrics.precision(estimate, truth)
        segmented = any(leaf.get("found") is not None for leaf in leaves)
        row["n_found"] = sum(leaf["found"] for leaf in leaves) if segmented else None
        row["n_missed"] = len(leaves) - row["n_found"] if segmented else None
        row["n_merged"] = sum(leaf.get("merged", 0) for leaf in leaves if leaf.get("found")) if segmented else None
        counts = [r["metrics"]["case"] for r in mine if "n_false" in r["metrics"].get("case", {})]
        row["n_false"] = sum(c["n_false"] for c in counts) if counts else None
        table.append({key: _finite(row[key]) for key in VALIDATION_KEYS})
    return table


#: Leaf groups by the size of the leaf's region (its alpha-matrix), pixels: the thesis' groups A-D (<2k, 3k,
#: 4-5k, >6k px) with edges chosen here (project choice: the thesis does not give them).
RPPP_GROUPS = (("A", 0, 2000), ("B", 2000, 3500), ("C", 3500, 6000), ("D", 6000, math.inf))
#: Keys of a row of :func:`rppp_groups`.
RPPP_KEYS = ("variant", "group", "pixels", "n_leaves", "rppp_0", "rppp_1", "rppp_2", "rppp_3", "rppp_more")


def rppp_groups(rows: list[dict]) -> list[dict]:
    """Mean redundancy ratios rppp_n per variant and leaf group (:data:`RPPP_GROUPS`), over the leaves found.

    rppp_n is the share of a region's pixels that received exactly n
    reconstructed values (rppp_1 the thesis' quality indicator).
    """
    table = []
    leaves = [leaf for leaf in target_scores([r for r in rows if not r["error"]])
              if leaf.get("region_pixels") and leaf.get("rppp_1") is not None and leaf.get("found")]
    for variant in dict.fromkeys(leaf["variant"] for leaf in leaves):
        for group, low, high in RPPP_GROUPS:
            mine = [leaf for leaf in leaves if leaf["variant"] == variant and low <= leaf["region_pixels"] < high]
            if mine:
                table.append({"variant": variant, "group": group,
                              "pixels": f"{low}-{high}" if math.isfinite(high) else f">={low}", "n_leaves": len(mine),
                              **{k: float(np.mean([leaf[k] for leaf in mine])) for k in RPPP_KEYS[4:]}})
    return table


#: Keys of a row of :func:`case_table`.
CASE_KEYS = ("case", "variant", "n_pulses", "runtime_s", "cpu_s", "pulses_per_s", "peak_mem_mb", "n_leaves",
             "n_found", "n_missed", "n_false", "n_merged")


def pulses_per_s(row: dict) -> float | None:
    """Pulses a variant was given on a case (``n_pulses``) per second of its runtime (None when unknown)."""
    pulses = row["metrics"].get("case", {}).get("n_pulses")
    return pulses / row["runtime_s"] if pulses is not None and row["runtime_s"] else None


def case_table(rows: list[dict]) -> list[dict]:
    """Per case, the variants that reconstruct the whole scan: pulses, runtime (wall and, where recorded, the
    process's CPU seconds, which other jobs on the machine inflate less), throughput, peak memory,
    found / missed / false leaves and the leaves whose region is shared with another leaf (merged)."""
    return [{"case": r["case_name"], "variant": r["variant"], "runtime_s": r["runtime_s"],
             "pulses_per_s": pulses_per_s(r), "peak_mem_mb": r["peak_mem_mb"],
             **{k: r["metrics"]["case"].get(k) for k in CASE_KEYS
                if k not in ("case", "variant", "runtime_s", "pulses_per_s", "peak_mem_mb")}}
            for r in rows if not r["error"] and "n_regions" in r["metrics"].get("case", {})]


def _finite(value):
    return None if isinstance(value, float) and not math.isfinite(value) else value


def text_table(table: list[dict], keys, formats: dict | None = None) -> str:
    """Rows as aligned plain text.

    Parameters
    ----------
    table : list of dict
        The rows.
    keys : sequence of str
        The columns, in order.
    formats : dict, optional
        Format strings by key (default: 3 significant digits; counts as integers).
    """
    formats = formats or {}

    def cell(value, key):
        if value is None:
            return "n/a"
        if isinstance(value, (str, int)):
            return f"{value:,}" if isinstance(value, int) and key.startswith("n_") and value > 9999 else str(value)
        return formats.get(key, "{:.3g}").format(value)

    cells = [list(keys)] + [[cell(row.get(k), k) for k in keys] for row in table]
    widths = [max(len(line[i]) for line in cells) for i in range(len(keys))]
    return "\n".join("  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(line, widths)))
                     for line in cells)


def leaf_printout(rows: list[dict]) -> str:
    """The validation table, the rppp groups and the per-case throughput as text ('' when no leaf was scored)."""
    parts = []
    validation = validation_table(rows)
    if validation:
        parts.append(f"validation (thesis ch.7; leaves >= {metrics.MIN_VISIBILITY:.0%} visible; areas cm2, angles deg)")
        parts.append(text_table(validation, VALIDATION_KEYS, {"success": "{:.0%}", "area_rel_err_median": "{:.1%}"}))
    groups = rppp_groups(rows)
    if groups:
        parts.append("rppp by leaf group (region pixels)")
        parts.append(text_table(groups, RPPP_KEYS, {k: "{:.3f}" for k in RPPP_KEYS[4:]}))
    cases = case_table(rows)
    if cases:
        parts.append("whole-scan reconstruction per case")
        parts.append(text_table(cases, CASE_KEYS, {"runtime_s": "{:.2f}", "cpu_s": "{:.2f}",
                                                   "pulses_per_s": "{:,.0f}",
                                                   "peak_mem_mb": "{:,.0f}"}))
    return "\n".join(parts)

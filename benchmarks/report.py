"""Reports of a stored run: a JSON document and a self-contained HTML page.

:func:`report_document` gives the machine-readable report (``tlsbench report
RUN --json``): run information, the goals of the open issues with our numbers
(:func:`goal_banner`), one summary row per suite × variant
(:func:`benchmarks.summary.summarize`), plus the tables of the sweeps
attached to the run. :func:`write_html` writes the page a person reads, one
file with every figure embedded as a PNG: first the goal banner, ROP before
and after with the area errors of the found leaves per variant, and the
headline table (headers with units); then per-case pictures (before/after on
one leaf, re-simulated from its case, which is deterministic; before/after on
one tree, its best whole-scan variant run once on the coarsened picture scan;
a range and intensity image of each case); then the tables by kind of scene, the thesis'
validation table, ROP against distance per kind of scene, estimated against
true areas, the sweep plots and, where the store holds runs of the suite at
several commits, the goal's metrics across commits (:mod:`benchmarks.history`).
"""

from __future__ import annotations

import base64
import dataclasses
import html
import io
import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from benchmarks import heightfields, metrics, scoring, summary, sweeps
from benchmarks.history import history_figures
from benchmarks.generators import build_scene
from benchmarks.registry import get_variant, variant_names
from benchmarks.runner import case_variant, scan_setup, simulate_case
from benchmarks.store import Store
from benchmarks.suite import Case
from benchmarks.summary import GOAL_AREA_REL_ERR, GOAL_ROP_REDUCTION


#: Scenes of the canopy goal (issue 16): trees and orchard rows with leaves.
CANOPY_SCENES = ("leafy-tree", "orchard-row", "tree")
#: The canopy goal's checks (issue 16): (label, summary or validation key, "min"/"max", threshold, format).
CANOPY_CHECKS = (("ROP red.", "rop_reduction", "min", 0.90, "{:.0%}"),
                 ("ROP red. 1 cm", "rop_reduction_1cm", "min", 0.90, "{:.0%}"),
                 ("good lost", "good_points_lost", "max", 0.01, "{:.1%}"),
                 ("found", "found_visible", "min", 0.90, "{:.0%}"),
                 ("median |area err|", "area_rel_err_median", "max", GOAL_AREA_REL_ERR, "{:.1%}"),
                 ("area R²", "area_r2", "min", 0.95, "{:.2f}"),
                 ("elev. err", "elevation_err_median_deg", "max", 5.0, "{:.1f}°"),
                 ("azim. err", "azimuth_err_median_deg", "max", 10.0, "{:.1f}°"))


def _passes(value, side: str, threshold: float) -> bool:
    return value is not None and (value >= threshold if side == "min" else value <= threshold)


def _checked(row: dict, checks) -> tuple[int, str]:
    """How many of ``checks`` a row passes, and its numbers (``label value``, a check it misses marked ✗)."""
    passed, text = 0, []
    for label, key, side, threshold, fmt in checks:
        ok = _passes(row.get(key), side, threshold)
        passed += ok
        text.append(f"{label} {summary._fmt(row.get(key), fmt)}{'' if ok else ' ✗'}")
    return passed, ", ".join(text)


def _best(rows: list[dict], checks) -> dict:
    """Goal entry fields of the row passing most checks (ties: the best in the first check)."""
    _, key, side, _, _ = checks[0]

    def rank(row):
        value = row.get(key)
        return _checked(row, checks)[0], -math.inf if value is None else (value if side == "min" else -value)

    row = max(rows, key=rank)
    passed, text = _checked(row, checks)
    return {"status": "met" if passed == len(checks) else "not met", "measured": f"{row['variant']}: {text}"}


def goal_banner(rows: list[dict], table: list[dict]) -> list[dict]:
    """The goals of the open issues that a run measures, each with our number and whether it is met.

    Parameters
    ----------
    rows : list of dict
        Result rows of the run.
    table : list of dict
        Their summary rows (:func:`benchmarks.summary.summarize`).

    Returns
    -------
    list of dict
        One entry per goal: ``issue``, ``goal``, ``measured`` (the best variant's numbers, a missed check marked
        ✗) and ``status`` (``met``, ``not met`` or ``not measured``: the run has no case or variant for it).
    """
    def entry(issue, goal, candidates, checks, note=""):
        result = {"issue": issue, "goal": goal, "status": "not measured", "measured": f"not measured by this run{note}"}
        candidates = [r for r in candidates if any(r.get(key) is not None for _, key, *_ in checks)]
        if candidates:
            result.update(_best(candidates, checks))
            result["measured"] += note
        return result

    prop_sfs = [r for r in table if r["family"] == "prop-sfs"]
    goals = [entry("project (issue 7)", f"a PROP-SFS variant with ROP reduction ≥ {GOAL_ROP_REDUCTION:.0%} and "
                   f"median |area error| ≤ {GOAL_AREA_REL_ERR:.0%} over the suite", prop_sfs,
                   (("ROP red.", "rop_reduction", "min", GOAL_ROP_REDUCTION, "{:.0%}"),
                    ("median |area err|", "area_rel_err_median", "max", GOAL_AREA_REL_ERR, "{:.1%}")))]
    canopy = [r for r in rows if summary.scene_kind(r["case_spec"]) in CANOPY_SCENES]
    cases = sorted({r["case_name"] for r in canopy})
    validation = {v["variant"]: v for v in summary.validation_table(canopy)}
    canopy_rows = [{**row, "area_r2": validation.get(row["variant"], {}).get("area_r2")}
                   for row in summary.summarize(canopy, "canopy") if row["family"] == "prop-sfs"]
    goals.append(entry("canopy (issue 16)", "tree and orchard canopies (at 0.018 deg in the issue): ROP reduction "
                       "≥ 90 % (3σ and 1 cm), ≤ 1 % good points lost, ≥ 90 % of the visible leaves found, median "
                       "|area error| ≤ 5 %, area R² ≥ 0.95, elevation ≤ 5°, azimuth ≤ 10°", canopy_rows, CANOPY_CHECKS,
                       f" (cases: {', '.join(cases)})" if cases else ""))
    goals.append(entry("woody (issue 11)", "STEP median diameter error ≤ 1 cm",
                       [r for r in table if r["variant"] == "step"],
                       (("diameter err", "diameter_err_median_m", "max", 0.01, "{:.4f} m"),)))
    goals.append(entry("woody (issue 11)", "cylinder following median |volume error| ≤ 10 %",
                       [r for r in table if r["variant"].startswith("cylinders")],
                       (("|volume err|", "volume_rel_err", "max", 0.10, "{:.1%}"),)))
    return goals


def report_document(store: Store, run_id: str) -> dict:
    """The JSON report of a run: ``run``, ``goal``, ``goals`` (:func:`goal_banner`), ``rows`` (suite × variant), ``by_scene``, the thesis'
    ``validation`` table and ``rppp_groups``, ``cases`` (whole-scan reconstruction per case) and ``sweeps``.

    Parameters
    ----------
    store : Store
        The results store holding the run.
    run_id : str
        The run's id.

    Returns
    -------
    dict
        JSON-ready report (metrics in the units of their names).
    """
    info = store.run_info(run_id)
    rows = store.results(run_id)
    table = summary.summarize(rows, info["suite"])
    document = {
        "run": {k: info[k] for k in ("run_id", "created", "finished", "status", "git_commit", "machine", "suite")},
        "goal": summary.goal_status(table),
        "goals": goal_banner(rows, table),
        "rows": table,
        "by_scene": summary.summarize_by_scene(rows, info["suite"]),
        "validation": summary.validation_table(rows),
        "rppp_groups": summary.rppp_groups(rows),
        "cases": summary.case_table(rows),
        "errors": [{"case": r["case_name"], "variant": r["variant"], "error": r["error"]} for r in rows if r["error"]],
        "sweeps": [],
    }
    for sweep_id in info["notes"].get("sweeps", []):
        sweep = store.run_info(sweep_id)
        kind = sweeps.sweep_of(sweep["suite"])
        document["sweeps"].append({"run_id": sweep_id, "kind": kind,
                                   "table": sweeps.sweep_table(store.results(sweep_id), kind)})
    return document


def _png(figure: Figure) -> str:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=100)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


def plot_rop_vs_distance(leaves: list[dict], kinds: dict | None = None) -> Figure:
    """Mean ROP per distance (0.25 m bins of the leaf's range) for every variant, on objects of type leaf: one
    panel per kind of scene, so that a line never joins different scenes.

    Parameters
    ----------
    leaves : list of dict
        Per-target scores (:func:`benchmarks.summary.target_scores`).
    kinds : dict, optional
        Kind of scene of each case name (:func:`benchmarks.summary.scene_kind`); one panel for all without it.

    Returns
    -------
    Figure
        ROP after (%) against leaf distance (m).
    """
    leaves = [leaf for leaf in leaves if leaf.get("object_type") == "leaf" and leaf.get("rop_after") is not None]
    kind_of = (lambda leaf: kinds.get(leaf["case"], "")) if kinds else (lambda leaf: "")
    groups = list(dict.fromkeys(kind_of(leaf) for leaf in leaves)) or [""]
    figure = Figure(figsize=(min(4.5 * len(groups), 13), 3.8), layout="constrained")
    for index, group in enumerate(groups):
        axes = figure.add_subplot(1, len(groups), index + 1)
        mine = [leaf for leaf in leaves if kind_of(leaf) == group]
        for variant in dict.fromkeys(leaf["variant"] for leaf in mine):
            ours = [leaf for leaf in mine if leaf["variant"] == variant]
            bins = np.round(np.array([leaf["range_m"] for leaf in ours]) * 4) / 4
            x = np.unique(bins)
            y = [100 * np.mean([leaf["rop_after"] for leaf, b in zip(ours, bins) if b == v]) for v in x]
            axes.plot(x, y, "o-" if variant == "raw" else ".-", label=variant, lw=2.5 if variant == "raw" else 1.2)
        axes.set(xlabel="leaf distance (m)", ylabel="ROP after the variant (%)", title=group or None)
        if index == len(groups) - 1:
            axes.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1))
    figure.suptitle("ROP against distance (τ = max(3σ, 2 mm)), per kind of scene", fontsize=10)
    return figure


def _found_area_errors(leaves: list[dict], variant: str) -> tuple[list[float], int, int]:
    """Relative area errors (%) of the visible leaves a variant reconstructed, and the counts found / missed."""
    mine = [leaf for leaf in summary.visible_leaves(leaves) if leaf["variant"] == variant]
    found = [leaf for leaf in mine if summary.succeeded(leaf) and leaf.get("area_rel_err") is not None]
    return [100 * leaf["area_rel_err"] for leaf in found], len(found), len(mine) - len(found)


def plot_area_errors(leaves: list[dict]) -> Figure:
    """Relative leaf-area error (%) per variant over the visible leaves it reconstructed (a missed leaf has no
    area to compare: it is counted beside its box, not drawn at -100 %).

    Parameters
    ----------
    leaves : list of dict
        Per-target scores (:func:`benchmarks.summary.target_scores`).

    Returns
    -------
    Figure
        Horizontal box plots, one per variant, with found / missed counts.
    """
    figure = Figure(figsize=(7, 4), layout="constrained")
    _area_axes(figure.subplots(), leaves, list(dict.fromkeys(leaf["variant"] for leaf in leaves)))
    return figure


def _area_axes(axes, leaves: list[dict], variants: list[str]) -> None:
    """Horizontal box plots of the found leaves' area errors on ``axes`` (variants top to bottom)."""
    data = [_found_area_errors(leaves, v) for v in variants]
    positions = np.arange(len(variants))[::-1]
    shown = [(errors, pos) for (errors, _, _), pos in zip(data, positions) if errors]
    if shown:
        axes.boxplot([e for e, _ in shown], positions=[pos for _, pos in shown], orientation="horizontal", widths=0.6,
                     flierprops={"markersize": 2})
    values = np.concatenate([e for e, _ in shown]) if shown else np.zeros(1)
    limit = max(15.0, float(np.percentile(np.abs(values), 95)) * 1.2)
    axes.set_xlim(-limit, limit)
    axes.axvspan(-100 * GOAL_AREA_REL_ERR, 100 * GOAL_AREA_REL_ERR, color="green", alpha=0.12,
                 label=f"goal ±{GOAL_AREA_REL_ERR:.0%}")
    axes.axvline(0, color="black", lw=0.5)
    for (errors, found, missed), pos in zip(data, positions):
        if found or missed:
            axes.annotate(f"{found} found / {missed} missed", (1.01, pos), xycoords=("axes fraction", "data"),
                          va="center", fontsize=7)
    axes.set_yticks(positions, variants, fontsize=8)
    axes.set_ylim(-0.7, len(variants) - 0.3)
    axes.set(xlabel="area error of the found leaves ≥ 80 % visible, all cases pooled (%)")
    axes.legend(fontsize=7, loc="lower left")


def plot_goal_figure(table: list[dict], leaves: list[dict]) -> Figure:
    """The report's first figure: ROP before and after per variant, and the area error of the leaves each variant
    found with its found / missed counts.

    Parameters
    ----------
    table : list of dict
        Summary rows (:func:`benchmarks.summary.summarize`); variants without a ROP are left out.
    leaves : list of dict
        Per-target scores (:func:`benchmarks.summary.target_scores`).

    Returns
    -------
    Figure
        Two panels sharing the variants' rows (ROP in %, area error in %).
    """
    rows = [r for r in table if r["rop_after"] is not None]
    variants = [r["variant"] for r in rows]
    figure = Figure(figsize=(12, 1.4 + 0.32 * max(len(rows), 3)), layout="constrained")
    left, right = figure.subplots(1, 2, gridspec_kw={"width_ratios": [1, 1.15]})
    positions = np.arange(len(rows))[::-1]
    before = np.array([100 * (r["rop_before"] or 0) for r in rows])
    after = np.array([100 * r["rop_after"] for r in rows])
    left.barh(positions, before, height=0.8, color="lightgrey", label="ROP before (raw scan)")
    left.barh(positions, after, height=0.5, color="tab:red", label="ROP after")
    left.scatter(before * (1 - GOAL_ROP_REDUCTION), positions, marker="|", s=120, color="green", zorder=3,
                 label=f"goal: {GOAL_ROP_REDUCTION:.0%} reduction")
    for r, pos, top in zip(rows, positions, before):
        if r["rop_reduction"] is not None:
            left.annotate(f"{-r['rop_reduction']:+.0%}".replace("-", "−"), (top, pos), xytext=(3, 0), textcoords="offset points",
                          va="center", fontsize=7)
    left.set_yticks(positions, variants, fontsize=8)
    left.set_ylim(-0.7, len(rows) - 0.3)
    left.set_xlim(0, 1.18 * max(before.max(initial=0), 1e-3))
    left.set(xlabel="ROP: outliers / points (%)")
    left.legend(fontsize=7, loc="lower left", bbox_to_anchor=(0, 1.01), ncol=3, frameon=False)
    _area_axes(right, leaves, variants)
    right.scatter([100 * r["area_rel_err_bias"] for r in rows if r["area_rel_err_bias"] is not None],
                  [pos for r, pos in zip(rows, positions) if r["area_rel_err_bias"] is not None], marker="D", s=18,
                  color="tab:blue", zorder=3, label="median over cases (signed)")
    right.legend(fontsize=7, loc="lower left", bbox_to_anchor=(0, 1.01), ncol=3, frameon=False)
    right.set_yticks(positions, [""] * len(rows))
    return figure


def plot_area_scatter(leaves: list[dict]) -> Figure:
    """Estimated against true leaf area per variant, on the leaves whose area is scored (reconstructed leaves in
    colour, the others in grey at their estimate; estimates beyond twice the largest true area on the top edge),
    with the 1:1 line and the least-squares line of the reconstructed leaves."""
    leaves = summary.visible_leaves(leaves)
    variants = list(dict.fromkeys(leaf["variant"] for leaf in leaves))
    columns = min(4, max(len(variants), 1))
    figure = Figure(figsize=(3.2 * columns, 3.0 * math.ceil(len(variants) / columns)), layout="constrained")
    for index, variant in enumerate(variants):
        axes = figure.add_subplot(math.ceil(len(variants) / columns), columns, index + 1)
        mine = [leaf for leaf in leaves if leaf["variant"] == variant]
        done = [summary.succeeded(leaf) for leaf in mine]
        truth = np.array([leaf["area_true_m2"] for leaf in mine]) * 1e4
        estimate = np.array([leaf.get("area_m2") or 0.0 for leaf in mine]) * 1e4
        ok = np.array(done, dtype=bool)
        right = 1.1 * float(truth.max())
        top = 2 * right  # estimates beyond (merged regions) are drawn on the top edge
        above = estimate > top
        shown = np.minimum(estimate, top)
        axes.scatter(truth[~ok], shown[~ok], s=6, color="lightgrey", label="not reconstructed")
        axes.scatter(truth[ok & ~above], shown[ok & ~above], s=6, color="tab:blue", label="reconstructed")
        if above.any():
            axes.scatter(truth[above], shown[above], s=12, marker="^", color="tab:orange",
                         label=f"{int(above.sum())} above {top:.0f} cm²", clip_on=False)
        axes.plot([0, right], [0, right], color="black", lw=0.6)
        fit = metrics.linear_fit(truth[ok], estimate[ok])
        if math.isfinite(fit["slope"]):
            axes.plot([0, right], [fit["intercept"], fit["intercept"] + fit["slope"] * right], color="tab:red", lw=0.8,
                      label=f"y = {fit['slope']:.2f} x + {fit['intercept']:.1f}, R² {fit['r2']:.2f}")
        axes.set(xlim=(0, right), ylim=(0, top), xlabel="true area (cm²)", ylabel="estimated area (cm²)")
        axes.set_title(variant, fontsize=9)
        axes.legend(fontsize=6)
    return figure


def plot_height_errors(rows: list[dict]) -> Figure:
    """Mean |relative height error| (thesis eq 3.2) of every height-field case, per variant."""
    cases = list(dict.fromkeys(r["case_name"] for r in rows if heightfields.is_heightfield(r["case_spec"]["scene"])))
    figure = Figure(figsize=(max(7.0, 0.22 * len(cases)), 4.5), layout="constrained")
    axes = figure.subplots()
    for variant in dict.fromkeys(r["variant"] for r in rows):
        values = {r["case_name"]: r["metrics"]["targets"][0].get("abs_eps_mean") for r in rows
                  if r["variant"] == variant and not r["error"] and r["metrics"]["targets"]}
        axes.plot(range(len(cases)), [100 * values[c] if values.get(c) is not None else np.nan for c in cases],
                  ".-", label=variant)
    axes.set_xticks(range(len(cases)), cases, rotation=90, fontsize=6)
    axes.set(ylabel="mean |height error| (% of h_max - h_min)", title="height fields (thesis eq. 3.2)")
    axes.legend(fontsize=7)
    return figure


#: The before/after figure re-runs every variant of its case at full resolution: a case whose variants took longer
#: than this in the run (s, summed over its variants) is not shown, so that a suite of large canopy cases (the
#: orchard-row window alone: 30 min) does not take twice as long for one picture.
SHOWCASE_MAX_S = 120.0


def pick_showcase(rows: list[dict]) -> dict | None:
    """The case shown before/after, among those scored on leaves whose variants took at most
    :data:`SHOWCASE_MAX_S` in the run: preferably a single leaf with visible outliers (ROP >= 0.1) that every
    variant reconstructed, and among those the one whose variants ran fastest, since the figure re-runs them."""
    runtime: dict[str, float] = {}
    skipped: dict[str, bool] = {}
    cases: dict[str, dict] = {}
    for r in rows:
        targets = [] if r["error"] else r["metrics"]["targets"]
        leaf_scores = bool(targets) and all("rop_before" in t for t in targets)  # woody targets have none
        if not leaf_scores or heightfields.is_heightfield(r["case_spec"]["scene"]):
            continue
        name = r["case_name"]
        runtime[name] = runtime.get(name, 0.0) + (r["runtime_s"] or 0.0)
        skipped[name] = skipped.get(name, False) or any(leaf.get("skipped") for leaf in r["metrics"]["targets"])
        cases[name] = r
    cases = {name: row for name, row in cases.items() if runtime[name] <= SHOWCASE_MAX_S}
    if not cases:
        return None

    def preference(name):
        leaves = cases[name]["metrics"]["targets"]
        return (len(leaves) != 1 or leaves[0].get("object_type") != "leaf", (leaves[0]["rop_before"] or 0) < 0.1,
                skipped[name], runtime[name])

    return cases[min(cases, key=preference)]["case_spec"]


def plot_before_after(case_spec: dict, variants: list[dict]) -> Figure:
    """Top view (lateral y against depth x) of one leaf's points for every variant.

    The case is re-simulated; points are coloured by what the variant left:
    within τ of the truth (green), outliers (red), removed (grey).

    Parameters
    ----------
    case_spec : dict
        Stored specification of the case (re-simulated here).
    variants : list of dict
        Variant specifications (``name``, ``params``).

    Returns
    -------
    Figure
        One top-view panel per variant, coordinates in m.
    """
    case = Case.from_dict(case_spec)
    scene, scan = simulate_case(case)
    leaves = scoring.prepare_leaves(scene, scan, None if case.targets is None else list(case.targets))
    leaf = leaves[0]
    columns = min(4, len(variants))
    rows = math.ceil(len(variants) / columns)
    figure = Figure(figsize=(3.2 * columns, 3.0 * rows), layout="constrained")
    measured = leaf.scan.xyz[leaf.mask]
    depth = np.median(measured[leaf.own, 0])
    for index, spec in enumerate(variants):
        axes = figure.add_subplot(rows, columns, index + 1)
        variant = get_variant(spec["name"]).with_params(**spec["params"])
        if variant.scope == "scan":
            output = scoring.leaf_outputs(leaves, variant(scan, scoring.target_labels(scan.shape, leaves)), scene,
                                          scan)[0][0]
        else:
            output = variant(leaf.scan, leaf.mask)
        out, kept, distance = scoring.output_distance(leaf, output)
        good = kept & (np.abs(distance) <= leaf.taus["auto"])
        axes.scatter(measured[~kept, 1], measured[~kept, 0] - depth, s=1, color="lightgrey", label="removed")
        axes.scatter(out[good, 1], out[good, 0] - depth, s=1, color="tab:green", label="within τ")
        axes.scatter(out[kept & ~good, 1], out[kept & ~good, 0] - depth, s=1, color="tab:red", label="outlier")
        axes.set_title(spec["name"], fontsize=9)
        axes.set_xlabel("y (m)", fontsize=8)
        axes.set_ylabel("depth from leaf (m)", fontsize=8)
        axes.tick_params(labelsize=7)
        if index == 0:
            axes.legend(fontsize=6, markerscale=5)
    figure.suptitle(f"case {case.name}: {leaf.name} seen from above (scanner looks along +x)", fontsize=10)
    return figure


#: Pulses of a per-case picture at most (a larger case is re-simulated at a coarser step for its picture).
PREVIEW_PULSES = 60_000
#: Per-case pictures at most per kind of scene, and in all.
PREVIEWS_PER_KIND, PREVIEWS_MAX = 3, 18


def preview_case(case_spec: dict, max_pulses: int = PREVIEW_PULSES):
    """The case of a per-case picture, re-simulated: at a coarser step where its scan has more than ``max_pulses``
    pulses.

    Parameters
    ----------
    case_spec : dict
        Stored specification of the case (re-simulated, deterministic).
    max_pulses : int
        Largest number of pulses of the picture's scan.

    Returns
    -------
    case : Case
    scene : Scene
    scan : tlssim.Scan
    n_pulses : int
        Pulses of the case's own scan.
    """
    from tlssim.simulate import simulate

    case = Case.from_dict(case_spec)
    scene = build_scene(case.scene)
    setup = scan_setup(case, scene)
    rows, columns = setup.window.shape
    if rows * columns > max_pulses:
        step = max(setup.window.step_deg) * math.sqrt(rows * columns / max_pulses)
        setup = dataclasses.replace(setup, window=dataclasses.replace(setup.window, step_deg=step))
    return case, scene, simulate(scene, setup, seed=case.seed, progress=False), rows * columns


def plot_case_preview(case_spec: dict, max_pulses: int = PREVIEW_PULSES) -> Figure:
    """A small picture of one case's scan: range and intensity images (rows = zenith, columns = azimuth), the
    pulses farther than 1 cm from the true range of their main object (the outliers a method must fix) in red.

    Parameters
    ----------
    case_spec : dict
        Stored specification of the case (re-simulated here, deterministic).
    max_pulses : int
        Largest number of pulses of the picture's scan (:func:`preview_case`).

    Returns
    -------
    Figure
        Two image panels: range (m) and intensity (DN).
    """
    _, _, scan, n_pulses = preview_case(case_spec, max_pulses)
    figure = Figure(figsize=(6.6, 2.4), layout="constrained")
    extent = np.degrees([np.nanmin(scan.theta), np.nanmax(scan.theta), np.nanmax(scan.psi), np.nanmin(scan.psi)])
    panels = []
    for index, (values, label, cmap) in enumerate(((scan.range, "range (m)", "viridis"),
                                                    (scan.intensity, "intensity (DN)", "gray"))):
        axes = figure.add_subplot(1, 2, index + 1)
        image = axes.imshow(values, cmap=cmap, extent=extent, aspect="auto", interpolation="nearest")
        figure.colorbar(image, ax=axes, label=label, shrink=0.9)
        axes.set_xlabel("azimuth θ (deg)", fontsize=8)
        axes.set_ylabel("zenith ψ (deg)", fontsize=8)
        axes.tick_params(labelsize=7)
        panels.append(axes)
    if scan.truth_range is not None:
        outlier = np.abs(scan.range - scan.truth_range) > 0.01
        overlay = np.zeros(scan.shape + (4,))
        overlay[outlier] = (0.9, 0.1, 0.1, 1.0)
        panels[1].imshow(overlay, extent=extent, aspect="auto", interpolation="nearest")
        panels[1].set_title(f"red: {int(outlier.sum()):,} pulses > 1 cm from the true range", fontsize=8)
    step = np.degrees(np.nanmedian(np.abs(np.diff(scan.theta, axis=1)))) if scan.shape[1] > 1 else float("nan")
    coarse = scan.shape[0] * scan.shape[1] < n_pulses
    figure.suptitle(f"{case_spec['name']}: {scan.shape[0]} × {scan.shape[1]} pulses at {step:.3f} deg"
                    + (f" (coarsened for this picture from {n_pulses:,} pulses)" if coarse else ""), fontsize=9)
    return figure


def pick_tree_showcase(rows: list[dict]) -> tuple[dict, dict] | None:
    """The tree shown before/after and the variant shown on it: a case with several target leaves scored by a
    whole-scan variant (scope ``scan``), preferably a canopy scene (:data:`CANOPY_SCENES`), with its whole-scan
    variant of lowest mean ROP after; ``None`` when the run has none. One case only, since the figure re-runs the
    variant."""
    best: dict[str, tuple] = {}
    for r in rows:
        targets = [] if r["error"] else r["metrics"]["targets"]
        leaves = [t for t in targets if t.get("object_type") == "leaf" and t.get("rop_after") is not None]
        if len(leaves) < 2 or heightfields.is_heightfield(r["case_spec"]["scene"]) \
                or get_variant(r["variant"]).scope != "scan":
            continue
        rank = (summary.scene_kind(r["case_spec"]) not in CANOPY_SCENES,
                float(np.mean([t["rop_after"] for t in leaves])))
        if r["case_name"] not in best or rank < best[r["case_name"]][0]:
            best[r["case_name"]] = (rank, r)
    if not best:
        return None
    _, row = min(best.values(), key=lambda item: item[0][0])
    return row["case_spec"], {"name": row["variant"], "params": row["params"]}


def plot_tree_before_after(case_spec: dict, variant_spec: dict, max_pulses: int = PREVIEW_PULSES) -> Figure:
    """A tree's leaf points before and after a whole-scan variant, run once on the case's picture scan
    (:func:`preview_case`, coarsened, so cheap).

    Both panels show the intensity image; red: the target leaves' points farther than 1 cm from their true surface
    (before: as measured; after: as the variant left them), blue: points it removed; the leaf regions it found are
    outlined. The title gives the mean ROP at 1 cm over the leaves, before and after, on this picture's scan.

    Parameters
    ----------
    case_spec : dict
        Stored specification of the case (re-simulated here, deterministic).
    variant_spec : dict
        The variant (``name``, ``params``), of scope ``scan``.
    max_pulses : int
        Largest number of pulses of the picture's scan.

    Returns
    -------
    Figure
        Two image panels (rows = zenith, columns = azimuth, deg): before and after.
    """
    case, scene, scan, n_pulses = preview_case(case_spec, max_pulses)
    leaves = scoring.prepare_leaves(scene, scan, None if case.targets is None else list(case.targets))
    variant = case_variant(case, variant_spec)
    if variant.prepare is not None:
        variant.prepare(scan)
    output = variant(scan, scoring.target_labels(scan.shape, leaves))
    outputs, _ = scoring.leaf_outputs(leaves, output, scene, scan)
    scores = [scoring.score_leaf(leaf, out) for leaf, out in zip(leaves, outputs)]
    before, after, removed = (np.zeros(scan.shape, bool) for _ in range(3))
    for leaf, out in zip(leaves, outputs):
        rows, cols = np.nonzero(leaf.mask)
        rows, cols = rows + leaf.window[0].start, cols + leaf.window[1].start
        _, kept, distance = scoring.output_distance(leaf, out)
        tau = leaf.taus["1cm"]
        before[rows, cols] |= np.abs(leaf.distance) > tau
        after[rows, cols] |= kept & (np.abs(distance) > tau)
        removed[rows, cols] |= ~kept
    figure = Figure(figsize=(8.0, 3.4), layout="constrained")
    extent = np.degrees([np.nanmin(scan.theta), np.nanmax(scan.theta), np.nanmax(scan.psi), np.nanmin(scan.psi)])
    regions = np.asarray(output.labels) > 0 if output.labels is not None else None
    rop = {key: float(np.mean([s[key] for s in scores])) for key in ("rop_before_1cm", "rop_after_1cm")}
    found = scoring.found_counts(scores)
    panels = ((before, None, f"before: {int(before.sum()):,} leaf points > 1 cm (red)"),
              (after, removed, f"after {variant_spec['name']}: {int(after.sum()):,} > 1 cm (red), "
                               f"{int((removed & ~after).sum()):,} removed (blue)"))
    for index, (outlier, dropped, title) in enumerate(panels):
        axes = figure.add_subplot(1, 2, index + 1)
        axes.imshow(scan.intensity, cmap="gray", extent=extent, aspect="auto", interpolation="nearest")
        overlay = np.zeros(scan.shape + (4,))
        if dropped is not None:
            overlay[dropped] = (0.2, 0.4, 0.9, 1.0)
        overlay[outlier] = (0.9, 0.1, 0.1, 1.0)
        axes.imshow(overlay, extent=extent, aspect="auto", interpolation="nearest")
        if index == 1 and regions is not None and regions.any():
            axes.contour(regions, levels=[0.5], colors="gold", linewidths=0.5, extent=extent, origin="upper")
        axes.set_title(title, fontsize=8)
        axes.set_xlabel("azimuth θ (deg)", fontsize=8)
        axes.set_ylabel("zenith ψ (deg)", fontsize=8)
        axes.tick_params(labelsize=7)
    coarse = scan.shape[0] * scan.shape[1] < n_pulses
    figure.suptitle(f"{case.name}, {variant_spec['name']} run on {scan.shape[0]} × {scan.shape[1]} pulses"
                    + (f" (coarsened from {n_pulses:,})" if coarse else "")
                    + f"\nROP at 1 cm {rop['rop_before_1cm']:.1%} → {rop['rop_after_1cm']:.1%}, "
                    f"{found['n_found']} of {found['n_leaves']} leaves found (gold outlines)", fontsize=9)
    return figure


def preview_cases(rows: list[dict]) -> tuple[list[dict], int]:
    """The cases that get a picture: up to :data:`PREVIEWS_PER_KIND` per kind of scene, :data:`PREVIEWS_MAX` in
    all (height-field cases have no scene to scan: none of them); also the number of cases of the run.

    Parameters
    ----------
    rows : list of dict
        Result rows of a run.

    Returns
    -------
    chosen : list of dict
        Case specifications.
    n_cases : int
    """
    specs = {r["case_name"]: r["case_spec"] for r in rows}
    chosen, per_kind = [], {}
    for spec in specs.values():
        kind = summary.scene_kind(spec)
        if heightfields.is_heightfield(spec["scene"]):
            continue
        if per_kind.get(kind, 0) < PREVIEWS_PER_KIND and len(chosen) < PREVIEWS_MAX:
            per_kind[kind] = per_kind.get(kind, 0) + 1
            chosen.append(spec)
    return chosen, len(specs)


#: Column titles and units of the report's tables: key -> (title, unit). Fractions are shown in %, lengths in
#: mm (keys ending in ``_m``), counts as counts; keys not listed fall back on their suffix (:func:`column_label`).
COLUMNS = {
    "suite": ("suite", ""), "variant": ("variant", ""), "family": ("family", ""), "scene": ("scene", ""),
    "case": ("case", ""), "group": ("leaf group", ""), "pixels": ("region size", "pixels"),
    "n_cases": ("cases", "count"), "n_targets": ("scored objects", "count"),
    "n_leaves_traits": ("leaves ≥ 80 % visible", "count"), "n_errors": ("failed cases", "count"),
    "rop_before": ("ROP before", "%"), "rop_after": ("ROP after", "%"), "rop_reduction": ("ROP reduction", "%"),
    "rop_before_1cm": ("ROP before, 1 cm", "%"), "rop_after_1cm": ("ROP after, 1 cm", "%"),
    "rop_reduction_1cm": ("ROP reduction, 1 cm", "%"), "good_points_lost": ("good points lost", "%"),
    "good_points_lost_pooled": ("good points lost, pooled", "%"),
    "outliers_restored": ("outliers restored", "%"), "good_points_damaged": ("good points damaged", "%"),
    "completeness": ("completeness", "%"), "flag_precision": ("flag precision", "%"),
    "flag_recall": ("flag recall", "%"), "rppp_0": ("pixels with 0 values", "%"),
    "rppp_1": ("pixels with 1 value (rppp₁)", "%"), "rppp_2": ("pixels with 2 values", "%"),
    "rppp_3": ("pixels with 3 values", "%"), "rppp_more": ("pixels with > 3 values", "%"),
    "abs_eps_mean": ("mean |height error|", "%"), "within_5pct": ("heights within 5 %", "%"),
    "surface_rmse_m": ("surface RMSE", "mm"), "area_rel_err_median": ("median |area error|", "%"),
    "area_rel_err_bias": ("median area error (signed)", "%"),
    "area_seen_rel_err_median": ("median |area error| against the visible area", "%"),
    "elevation_err_median_deg": ("median elevation error", "deg"),
    "azimuth_err_median_deg": ("median azimuth error", "deg"), "n_found": ("leaves found", "count"),
    "n_missed": ("leaves missed", "count"), "n_false": ("false leaves", "count"),
    "n_merged": ("leaves merged", "count"), "found_visible": ("visible leaves found", "%"),
    "diameter_err_median_m": ("median diameter error", "mm"), "volume_rel_err": ("median |volume error|", "%"),
    "runtime_s": ("runtime per case (median)", "s"), "runtime_total_s": ("runtime, all cases", "s"),
    "pulses_per_s": ("throughput", "pulses/s"), "peak_mem_mb": ("peak memory", "MB"),
    "n_pulses": ("pulses", "count"), "n_leaves": ("leaves ≥ 80 % visible", "count"),
    "n_success": ("leaves reconstructed", "count"), "success": ("reconstructed", "%"),
    "area_slope": ("area slope (est. / true)", "ratio"), "area_intercept_cm2": ("area intercept", "cm²"),
    "area_r2": ("area R²", "ratio"), "area_seen_r2": ("area R² against the visible area", "ratio"),
    "area_bias_cm2": ("area BIAS (eq 2.1)", "cm²"),
    "elevation_r2": ("elevation R²", "ratio"), "elevation_precision_deg": ("elevation precision (s.d.)", "deg"),
    "azimuth_r2": ("azimuth R²", "ratio"), "azimuth_precision_deg": ("azimuth precision (s.d.)", "deg"),
    "value": ("swept value", ""), "footprint_mm": ("footprint diameter", "mm"),
    "sigma_range_m": ("range noise σ", "mm"), "intensity_dn": ("intensity", "DN"),
    "points_per_cm2": ("point density", "points/cm²"), "n_points": ("points", "count"),
}
_SUFFIX_UNITS = (("_deg", "deg"), ("_cm2", "cm²"), ("_m2", "cm²"), ("_mm", "mm"), ("_m", "mm"), ("_s", "s"),
                 ("_mb", "MB"), ("_dn", "DN"))
_PERCENT = {key for key, (_, unit) in COLUMNS.items() if unit == "%"}


def column_label(key: str) -> tuple[str, str]:
    """Title and unit of a table column (``rop_after:fused`` is the ROP after ``fused``; unknown keys are named by
    their words and unit suffix).

    Parameters
    ----------
    key : str
        Column key of a report table.

    Returns
    -------
    title : str
    unit : str
        ``""`` for text columns.
    """
    base, _, variant = key.partition(":")
    if base in COLUMNS:
        title, unit = COLUMNS[base]
    else:
        unit = next((u for suffix, u in _SUFFIX_UNITS if base.endswith(suffix)), "")
        title = base.removesuffix(next((s for s, u in _SUFFIX_UNITS if base.endswith(s)), "")).replace("_", " ")
    return (f"{title}, {variant}" if variant else title), unit


def _cell(value, key: str) -> str:
    if value is None:
        return "–"
    if isinstance(value, str):
        return html.escape(value)
    if isinstance(value, int):
        return f"{value:,}"
    base = key.partition(":")[0]
    unit = column_label(key)[1]
    if base in _PERCENT:
        return f"{100 * value:.1f}"
    if unit == "mm" and not base.endswith("_mm"):
        return f"{value * 1e3:.2f}"
    if base.endswith("_m2"):
        return f"{value * 1e4:.2f}"
    if unit in ("s", "MB") or unit.startswith(("pulses", "points")):
        return f"{value:,.3g}" if abs(value) < 1000 else f"{value:,.0f}"
    if unit == "deg":
        return f"{value:.2f}"
    return f"{value:.3f}"


def _header(key: str) -> str:
    title, unit = column_label(key)
    return html.escape(f"{title} ({unit})" if unit else title)


def _table(rows: list[dict], keys) -> str:
    head = "".join(f"<th title='{html.escape(k)}'>{_header(k)}</th>" for k in keys)
    body = "".join("<tr>" + "".join(f"<td>{_cell(r.get(k), k)}</td>" for k in keys) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


_STYLE = """body{font-family:sans-serif;margin:1.5em;max-width:90em;color:#222}table{border-collapse:collapse;
margin:0.8em 0;font-size:0.85em}td,th{border:1px solid #ccc;padding:0.25em 0.5em;text-align:right}
th{background:#eee;font-weight:600;max-width:9em;vertical-align:bottom}td:first-child,th:first-child{text-align:left}
tbody tr:nth-child(even){background:#fafafa}.goals td,.goals th{text-align:left;vertical-align:top}.goals td:first-child{
white-space:nowrap;font-weight:bold}.met td:first-child{color:#176c17}.notmet td:first-child{color:#b22}
.unmeasured td:first-child{color:#777}.meta{color:#555;font-size:0.9em}.pictures{display:flex;flex-wrap:wrap;
gap:0.6em}.pictures figure{margin:0}figcaption{font-size:0.8em;color:#555}img{max-width:100%}
pre{background:#f6f6f6;padding:0.7em;white-space:pre-wrap}.wide{overflow-x:auto}
.goal{padding:0.6em;border-left:4px solid #c33;background:#fdf3f3}"""
_STATUS = {"met": ("✔ met", "met"), "not met": ("✘ not met", "notmet"), "not measured": ("– not measured", "unmeasured")}


def _image(title: str, figure: Figure) -> str:
    return f"<img alt='{html.escape(title)}' src='data:image/png;base64,{_png(figure)}'>"


def _banner(goals: list[dict]) -> str:
    rows = "".join(f"<tr class='{_STATUS[g['status']][1]}'><td>{_STATUS[g['status']][0]}</td>"
                   f"<td>{html.escape(g['issue'])}</td><td>{html.escape(g['goal'])}</td>"
                   f"<td>{html.escape(g['measured'])}</td></tr>" for g in goals)
    return ("<table class='goals'><thead><tr><th>status</th><th>goal of</th><th>goal</th><th>this run (best variant; "
            f"✗ marks a check it misses)</th></tr></thead><tbody>{rows}</tbody></table>")


def _machine(machine) -> str:
    if isinstance(machine, dict):
        return ", ".join(f"{k} {v}" for k, v in machine.items())
    return str(machine)


def write_html(store: Store, run_id: str, path, before_after: bool = True) -> Path:
    """Write the HTML report of a run (one self-contained file, figures embedded as PNG); returns the path.

    The first screen holds the goal banner (:func:`goal_banner`), ROP before/after and the found leaves' area
    errors per variant (:func:`plot_goal_figure`) and the headline table; then the per-case pictures (before /
    after on the showcase leaf and on one tree (:func:`plot_tree_before_after`), a range and intensity image of each case), then the detailed tables and figures.
    Table headers carry their units.

    Parameters
    ----------
    store : Store
        The results store holding the run.
    run_id : str
        The run's id.
    path : str or Path
        Output HTML file.
    before_after : bool
        Include the pictures that re-simulate cases (before/after and per-case images: slower).

    Returns
    -------
    Path
        The written file.
    """
    document = report_document(store, run_id)
    rows = store.results(run_id)
    leaves = summary.target_scores(rows)
    run = document["run"]
    parts = [
        f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>tlsbench {html.escape(run_id)}</title>"
        f"<style>{_STYLE}</style></head><body>",
        f"<h1>Benchmark run {html.escape(run_id)}: suite {html.escape(run['suite'])}</h1>",
        f"<p class='meta'>commit {html.escape(run['git_commit'])} · started {html.escape(run['created'][:19])} · "
        f"status {html.escape(run['status'])} · {html.escape(_machine(run['machine']))}</p>",
        "<h2>Goals</h2>", _banner(document["goals"]),
    ]
    if document["errors"]:
        first = document["errors"][0]
        parts.append(f"<p class='goal'><b>{len(document['errors'])} failed result(s)</b>, first: "
                     f"{html.escape(first['case'])} / {html.escape(first['variant'])}: "
                     f"{html.escape(str(first['error']).strip().splitlines()[-1])} (all at the end)</p>")
    if any(r["rop_after"] is not None for r in document["rows"]):
        parts.append(_image("ROP before and after, area errors of the found leaves",
                            plot_goal_figure(document["rows"], leaves)))
    parts += ["<h2>Headline</h2>", "<div class='wide'>",
              _table(document["rows"], [key for _, key, _ in summary.headline_columns(document["rows"])]),
              "</div><p class='meta'>ROP: mean over leaves of outliers / points (points with ≥ 10 % of their footprint "
              "power from the leaf; outliers farther than τ = max(3σ, 2 mm) from the true surface of their object). "
              "Area and angle errors: medians over cases of the median absolute error over the leaves ≥ 80 % "
              "visible. Runtime: median per case.</p>"]
    pictures = []
    # The pictures re-run variants: rows of a variant no longer registered are left out of them.
    rerunnable = [r for r in rows if r["variant"] in set(variant_names())]
    showcase = pick_showcase(rerunnable) if before_after else None
    if showcase is not None:
        shown = [r for r in rerunnable if r["case_name"] == showcase["name"] and not r["error"]  # leaf methods only
                 and r["metrics"]["targets"] and all("rop_before" in t for t in r["metrics"]["targets"])]
        specs = list({r["variant"]: {"name": r["variant"], "params": r["params"]} for r in shown}.values())
        pictures.append(("Before / after on one leaf", plot_before_after(showcase, specs)))
    tree = pick_tree_showcase(rerunnable) if before_after else None
    if tree is not None:
        pictures.append(("Before / after on a tree", plot_tree_before_after(*tree)))
    if pictures or before_after:
        parts.append("<h2>Per-case pictures</h2>")
        parts += [f"<h3>{html.escape(title)}</h3>{_image(title, figure)}" for title, figure in pictures]
    if before_after:
        chosen, n_cases = preview_cases(rows)
        parts.append(f"<p class='meta'>Range and intensity of {len(chosen)} of the {n_cases} cases (up to "
                     f"{PREVIEWS_PER_KIND} per kind of scene); red: pulses more than 1 cm from the true range of their "
                     "main object.</p><div class='pictures'>")
        for spec in chosen:
            parts.append(f"<figure>{_image(spec['name'], plot_case_preview(spec))}"
                         f"<figcaption>{html.escape(spec['name'])} ({html.escape(summary.scene_kind(spec))})"
                         "</figcaption></figure>")
        parts.append("</div>")
    parts += ["<h2>By kind of scene</h2>", "<div class='wide'>",
              _table([r for r in document["by_scene"] if r["n_targets"] or r["n_errors"]], ["scene", "variant", "n_targets", "n_errors", "rop_before", "rop_after",
                                            "rop_reduction", "outliers_restored", "good_points_lost",
                                            "good_points_lost_pooled", "area_rel_err_median", "area_rel_err_bias",
                                            "runtime_s"]), "</div>"]
    if document["validation"]:
        parts += [f"<h2>Validation table (thesis ch.7)</h2><p class='meta'>Over the leaves at least "
                  f"{metrics.MIN_VISIBILITY:.0%} visible; regressions, BIAS (eq 2.1) and precisions (standard "
                  "deviation of the error) over the leaves the variant reconstructed (success).</p>",
                  "<div class='wide'>", _table(document["validation"], summary.VALIDATION_KEYS), "</div>"]
    if document["rppp_groups"]:
        parts += ["<h3>Redundancy rppp by leaf group (region pixels)</h3>",
                  _table(document["rppp_groups"], summary.RPPP_KEYS)]
    if document["cases"]:
        parts += ["<h3>Whole-scan reconstruction per case</h3>", "<div class='wide'>",
                  _table(document["cases"], summary.CASE_KEYS), "</div>"]
    figures = []
    if any(leaf.get("object_type") == "leaf" for leaf in leaves):
        kinds = {r["case_name"]: summary.scene_kind(r["case_spec"]) for r in rows}
        figures.append(("ROP against distance", plot_rop_vs_distance(leaves, kinds)))
    if summary.visible_leaves(leaves):
        figures.append(("Estimated against true leaf area", plot_area_scatter(leaves)))
    if any(heightfields.is_heightfield(r["case_spec"]["scene"]) for r in rows):
        figures.append(("Height-field errors", plot_height_errors(rows)))
    for sweep in document["sweeps"]:
        if sweep["table"]:
            figures.append((f"Sweep: {sweep['kind']} (run {sweep['run_id']})", sweeps.plot_sweep(sweep["table"], sweep["kind"])))
    figures += history_figures(store, run["suite"])
    parts += [f"<h2>{html.escape(title)}</h2>{_image(title, figure)}" for title, figure in figures]
    for sweep in document["sweeps"]:
        if sweep["table"]:
            parts.append(f"<h3>Sweep table: {html.escape(sweep['kind'])}</h3>" + _table(sweep["table"], list(sweep["table"][0])))
    parts += ["<h2>All metrics (variant × metric)</h2>", "<div class='wide'>",
              _table(document["rows"], summary.SUMMARY_KEYS), "</div>"]
    if document["errors"]:
        parts.append("<h2>Errors</h2><pre>" + html.escape("\n".join(
            f"{e['case']} / {e['variant']}: {e['error']}" for e in document["errors"])) + "</pre>")
    parts.append("</body></html>")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(parts), encoding="utf-8")
    return path

"""Reports of a stored run: a JSON document and a self-contained HTML page.

:func:`report_document` gives the machine-readable report (``tlsbench report
RUN --json``): run information, the goal status and one summary row per
suite × variant (:func:`benchmarks.summary.summarize`), plus the tables of
the sweeps attached to the run. :func:`write_html` writes the page a person
reads: the headline table, the full variant × metric table, ROP against
distance per variant, area-error distributions, before/after point clouds of
one leaf (re-simulated from its case, which is deterministic), the sweep
plots and, where the store holds runs of the suite at several commits, the
goal's metrics across commits (:mod:`benchmarks.history`), every figure
embedded as a PNG.
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from benchmarks import heightfields, metrics, scoring, summary, sweeps
from benchmarks.history import history_figures
from benchmarks.registry import get_variant
from benchmarks.runner import simulate_case
from benchmarks.store import Store
from benchmarks.suite import Case


def report_document(store: Store, run_id: str) -> dict:
    """The JSON report of a run: ``run``, ``goal``, ``rows`` (suite × variant), ``by_scene``, the thesis'
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


def plot_rop_vs_distance(leaves: list[dict]) -> Figure:
    """Mean ROP per distance (0.25 m bins of the leaf's range) for every variant, on objects of type leaf."""
    figure = Figure(figsize=(7, 4), layout="constrained")
    axes = figure.subplots()
    leaves = [leaf for leaf in leaves if leaf.get("object_type") == "leaf"]
    variants = list(dict.fromkeys(leaf["variant"] for leaf in leaves))
    for variant in variants:
        mine = [leaf for leaf in leaves if leaf["variant"] == variant and leaf.get("rop_after") is not None]
        bins = np.round(np.array([leaf["range_m"] for leaf in mine]) * 4) / 4
        x = np.unique(bins)
        y = [np.mean([leaf["rop_after"] for leaf, b in zip(mine, bins) if b == v]) for v in x]
        axes.plot(x, y, "o-" if variant == "raw" else ".-", label=variant, lw=2.5 if variant == "raw" else 1.2)
    axes.set(xlabel="leaf distance (m)", ylabel="ROP after the variant", title="ROP against distance (τ = max(3σ, 2 mm))")
    axes.legend(fontsize=8)
    return figure


def plot_area_errors(leaves: list[dict]) -> Figure:
    """Distribution of the relative leaf-area error per variant (box plots, %)."""
    figure = Figure(figsize=(7, 4), layout="constrained")
    axes = figure.subplots()
    variants = [v for v in dict.fromkeys(leaf["variant"] for leaf in leaves)
                if any(leaf.get("area_rel_err") is not None for leaf in leaves if leaf["variant"] == v)]
    data = [[100 * leaf["area_rel_err"] for leaf in leaves if leaf["variant"] == v and leaf.get("area_rel_err") is not None]
            for v in variants]
    if data:
        axes.boxplot(data, tick_labels=variants)
    axes.axhspan(-100 * summary.GOAL_AREA_REL_ERR, 100 * summary.GOAL_AREA_REL_ERR, color="green", alpha=0.1,
                 label=f"goal ±{summary.GOAL_AREA_REL_ERR:.0%}")
    axes.axhline(0, color="black", lw=0.5)
    axes.set(ylabel="relative area error (%)", title="leaf area error")
    axes.tick_params(axis="x", labelrotation=30)
    axes.legend(fontsize=8)
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


def pick_showcase(rows: list[dict]) -> dict | None:
    """The case shown before/after, among those scored on leaves: preferably a single leaf with visible
    outliers (ROP >= 0.1) that every variant reconstructed, and among those the one whose variants ran fastest, since the figure re-runs them."""
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


def _cell(value, key: str) -> str:
    if value is None:
        return "–"
    if isinstance(value, str):
        return html.escape(value)
    if isinstance(value, int):
        return str(value)
    if key.endswith("_deg"):
        return f"{value:.2f}"
    if key.endswith("_m"):
        return f"{value * 1e3:.2f} mm"
    if key.endswith(("_s", "_mb")):
        return f"{value:.3g}"
    return f"{value:.3f}"


def _table(rows: list[dict], keys) -> str:
    head = "".join(f"<th>{html.escape(k)}</th>" for k in keys)
    body = "".join("<tr>" + "".join(f"<td>{_cell(r.get(k), k)}</td>" for k in keys) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


_STYLE = """body{font-family:sans-serif;margin:2em;max-width:80em}table{border-collapse:collapse;margin:1em 0;
font-size:0.85em}td,th{border:1px solid #ccc;padding:0.25em 0.5em;text-align:right}th{background:#eee}
td:first-child{text-align:left}.goal{padding:0.7em;border-left:4px solid #c33;background:#fdf3f3}
.met{border-color:#3a3;background:#f2fbf2}pre{background:#f6f6f6;padding:0.7em}"""


def write_html(store: Store, run_id: str, path, before_after: bool = True) -> Path:
    """Write the HTML report of a run (figures embedded as PNG); returns the path.

    Parameters
    ----------
    store : Store
        The results store holding the run.
    run_id : str
        The run's id.
    path : str or Path
        Output HTML file.
    before_after : bool
        Include the before/after figures (re-simulates cases: slower).

    Returns
    -------
    Path
        The written file.
    """
    document = report_document(store, run_id)
    rows = store.results(run_id)
    leaves = summary.target_scores(rows)
    run = document["run"]
    met = ": MET" in document["goal"]
    parts = [
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>tlsbench {html.escape(run_id)}</title>"
        f"<style>{_STYLE}</style></head><body>",
        f"<h1>Benchmark run {html.escape(run_id)}</h1>",
        f"<p>suite <b>{html.escape(run['suite'])}</b> · commit {html.escape(run['git_commit'])} · "
        f"started {html.escape(run['created'])} · status {html.escape(run['status'])} · "
        f"machine {html.escape(str(run['machine']))}</p>",
        f"<p class='goal{' met' if met else ''}'>{html.escape(document['goal'])}</p>",
        "<h2>Headline</h2>",
        _table(document["rows"], [key for _, key, _ in summary.headline_columns(document["rows"])]),
        "<h2>All metrics (variant × metric)</h2>",
        _table(document["rows"], summary.SUMMARY_KEYS),
        "<h2>By kind of scene</h2>",
        _table(document["by_scene"], ["scene", "variant", "n_targets", "n_errors", "rop_before", "rop_after",
                                      "rop_reduction", "outliers_restored", "good_points_lost",
                                      "area_rel_err_median", "area_rel_err_bias", "runtime_s"]),
        "<p>ROP: mean over leaves of outliers / points (points with ≥ 10 % of their footprint power from the leaf; "
        "outliers farther than τ from the true surface of their object). Area and angle errors: medians of absolute "
        "errors over leaves. Runtime: median per case. Lengths in mm.</p>",
    ]
    if document["validation"]:
        parts += [f"<h2>Validation table (thesis ch.7)</h2><p>Over the leaves at least "
                  f"{metrics.MIN_VISIBILITY:.0%} visible; regressions, BIAS (eq 2.1) and precisions (standard "
                  "deviation of the error) over the leaves the variant reconstructed (success). Areas in cm², "
                  "angles in degrees.</p>", _table(document["validation"], summary.VALIDATION_KEYS)]
    if document["rppp_groups"]:
        parts += ["<h3>Redundancy rppp by leaf group (region pixels)</h3>",
                  _table(document["rppp_groups"], summary.RPPP_KEYS)]
    if document["cases"]:
        parts += ["<h3>Whole-scan reconstruction per case</h3>", _table(document["cases"], summary.CASE_KEYS)]
    figures = []
    if any(leaf.get("object_type") == "leaf" for leaf in leaves):
        figures.append(("ROP against distance", plot_rop_vs_distance(leaves)))
    if any(leaf.get("area_rel_err") is not None for leaf in leaves):
        figures.append(("Leaf area error", plot_area_errors(leaves)))
    if summary.visible_leaves(leaves):
        figures.append(("Estimated against true leaf area", plot_area_scatter(leaves)))
    if any(heightfields.is_heightfield(r["case_spec"]["scene"]) for r in rows):
        figures.append(("Height-field errors", plot_height_errors(rows)))
    showcase = pick_showcase(rows) if before_after else None
    if showcase is not None:
        shown = [r for r in rows if r["case_name"] == showcase["name"] and not r["error"]]
        specs = list({r["variant"]: {"name": r["variant"], "params": r["params"]} for r in shown}.values())
        figures.append(("Before / after on one leaf", plot_before_after(showcase, specs)))
    for sweep in document["sweeps"]:
        if sweep["table"]:
            figures.append((f"Sweep: {sweep['kind']} (run {sweep['run_id']})", sweeps.plot_sweep(sweep["table"], sweep["kind"])))
    figures += history_figures(store, run["suite"])
    for title, figure in figures:
        parts.append(f"<h2>{html.escape(title)}</h2><img alt='{html.escape(title)}' src='data:image/png;base64,{_png(figure)}'>")
    for sweep in document["sweeps"]:
        if sweep["table"]:
            parts.append(f"<h3>Sweep table: {html.escape(sweep['kind'])}</h3>" + _table(sweep["table"], list(sweep["table"][0])))
    if document["errors"]:
        parts.append("<h2>Errors</h2><pre>" + html.escape("\n".join(
            f"{e['case']} / {e['variant']}: {e['error']}" for e in document["errors"])) + "</pre>")
    parts.append("</body></html>")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(parts), encoding="utf-8")
    return path

"""Writing reproduction rows: text table, CSV, PNG and the results store.

Rows are stored as one run of the suite ``reproduce`` (``reproduce-quick``
for ``--quick``): one result per row, the experiment as the case and
``EXPERIMENT/ROW`` as the variant (so that :mod:`benchmarks.compare`, which
pairs cases per variant, judges every row on its own: one row leaving its
tolerance is a regression), with the per-row metrics ``within_tolerance``
(1 or 0) and ``tolerance_ratio`` (``|ours - published| / tolerance``).
"""

from __future__ import annotations

import base64
import csv
import hashlib
import io
import json
import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from benchmarks.reproduce.core import OUTSIDE, REPORTED, WITHIN, Experiment, Outcome, Row, count_within
from benchmarks.store import Store

#: CSV columns, in order.
COLUMNS = ("key", "quantity", "unit", "published", "ours", "tolerance", "verdict", "tolerance_note", "source",
           "claim", "x", "series", "note")


def format_number(value) -> str:
    """A value for a table cell: 4 significant digits, ``nan``, or empty for ``None``."""
    if value is None:
        return ""
    if isinstance(value, float) and not math.isfinite(value):
        return "nan"
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def format_rows(rows: list[Row]) -> str:
    """Published and ours side by side with the verdict, one line per row.

    Parameters
    ----------
    rows : list of Row
        Rows of one experiment.

    Returns
    -------
    str
        Aligned text (tolerance in the rows' units; claims shown for rows without a published number).
    """
    lines = [("row", "published", "ours", "tolerance", "unit", "verdict")]
    for r in rows:
        verdict = r.verdict if r.published is not None or r.holds is None else f"{r.verdict} (claim)"
        lines.append((r.key, format_number(r.published), format_number(r.ours), format_number(r.tolerance), r.unit,
                      verdict))
    widths = [max(len(line[i]) for line in lines) for i in range(6)]
    text = ["  ".join(c.ljust(w) if i in (0, 4, 5) else c.rjust(w) for i, (c, w) in enumerate(zip(line, widths)))
            for line in lines]
    claims = list(dict.fromkeys(f"  claim tested: {r.claim}" for r in rows if r.claim and r.holds is not None))
    tolerances = list(dict.fromkeys(f"  tolerance: {r.tolerance_note}" for r in rows if r.tolerance_note))
    return "\n".join(text + tolerances + claims)


def write_csv(rows: list[Row], path) -> Path:
    """Write the rows (every field and the verdict; numbers at full precision) as CSV; returns the path.

    Parameters
    ----------
    rows : list of Row
        Rows of one experiment.
    path : str or Path
        Output file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(COLUMNS)
        for row in rows:
            data = row.as_dict()
            writer.writerow([("" if data[c] is None else repr(float(data[c]))) if c in ("published", "ours",
                             "tolerance", "x") else data[c] for c in COLUMNS])
    return path


def read_csv(path) -> list[Row]:
    """Rows back from :func:`write_csv` (the verdict is recomputed).

    Parameters
    ----------
    path : str or Path
        A CSV file written by :func:`write_csv`.
    """
    rows = []
    with Path(path).open(newline="") as handle:
        for data in csv.DictReader(handle):
            numbers = {c: (float(data[c]) if data[c] else None) for c in ("published", "ours", "tolerance", "x")}
            holds = data["verdict"] == WITHIN if data["claim"] and data["verdict"] != REPORTED else None
            rows.append(Row(data["key"], data["quantity"], data["unit"], numbers["ours"], numbers["published"],
                            numbers["tolerance"], data["tolerance_note"], data["source"], data["claim"], holds,
                            numbers["x"], data["series"], data["note"]))
    return rows


def plot_rows(experiment: Experiment, rows: list[Row]) -> Figure:
    """Published against ours, plotted the same way: one panel per quantity.

    Ours is drawn as a line per series; the published values as open
    markers with the tolerance as error bars; rows outside are crossed in
    red. Rows without an abscissa are placed by their order; claim rows are
    left to the table unless they share a quantity with other rows or there
    is nothing else.

    Parameters
    ----------
    experiment : Experiment
        The experiment (its title heads the figure).
    rows : list of Row
        Its rows.

    Returns
    -------
    matplotlib.figure.Figure
    """
    # claims mix units: they stay in the table, unless they share a quantity (so a unit) with rows plotted
    quantities = {r.quantity for r in rows if r.claim == ""}
    rows = [r for r in rows if r.quantity in quantities] or rows
    quantities = list(dict.fromkeys(r.quantity for r in rows))
    columns = min(3, max(1, len(quantities)))
    lines = math.ceil(len(quantities) / columns) if quantities else 1
    figure = Figure(figsize=(4.6 * columns, 3.4 * lines), layout="constrained")
    figure.suptitle(experiment.title, fontsize=9)
    for k, quantity in enumerate(quantities):
        axes = figure.add_subplot(lines, columns, k + 1)
        chosen = [r for r in rows if r.quantity == quantity]
        for index, series in enumerate(dict.fromkeys(r.series for r in chosen)):
            part = [r for r in chosen if r.series == series]
            xs = [r.x if r.x is not None else i for i, r in enumerate(part)]
            color = f"C{index % 10}"
            order = np.argsort(xs, kind="stable") if all(r.x is not None for r in part) else np.arange(len(xs))
            axes.plot(np.asarray(xs, float)[order], np.asarray([r.ours for r in part], float)[order], "-o",
                      color=color, ms=4, label=f"ours {series}".strip())
            published = [(x, r) for x, r in zip(xs, part) if r.published is not None]
            if published:
                axes.errorbar([x for x, _ in published], [r.published for _, r in published],
                              yerr=[r.tolerance for _, r in published], fmt="s", mfc="none", color=color, capsize=3,
                              label=f"published {series}".strip())
            for x, r in zip(xs, part):
                if r.verdict == OUTSIDE:
                    axes.plot([x], [r.ours], "x", color="red", ms=8)
        axes.set_title(quantity, fontsize=8)
        axes.set_ylabel(chosen[0].unit, fontsize=8)
        axes.tick_params(labelsize=7)
        axes.legend(fontsize=6)
    return figure


def figure_png(figure: Figure) -> str:
    """A figure as base64-encoded PNG (90 dpi): what the experiments' extra figures travel as, also from Dask."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=90)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


def write_images(name: str, images: dict[str, str], directory) -> list[Path]:
    """Write an experiment's extra figures (base64 PNG by name) as ``NAME-<name>.png``; returns the paths.

    Parameters
    ----------
    name : str
        Experiment name.
    images : dict of str
        Base64 PNG by figure name (:func:`figure_png`).
    directory : str or Path
        Output directory.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for key, data in images.items():
        path = directory / f"{name}-{key}.png"
        path.write_bytes(base64.b64decode(data))
        paths.append(path)
    return paths


def write_png(experiment: Experiment, rows: list[Row], path) -> Path:
    """Write :func:`plot_rows` as PNG; returns the path.

    Parameters
    ----------
    experiment : Experiment
        The experiment.
    rows : list of Row
        Its rows.
    path : str or Path
        Output file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    plot_rows(experiment, rows).savefig(path, dpi=90)
    return path


def result_rows(outcome: Outcome) -> list[dict]:
    """Results-store rows of one experiment's outcome (see the module docstring)."""
    out = []
    name = outcome.experiment.name
    for row in outcome.rows:
        ratio = (abs(row.ours - row.published) / row.tolerance if row.published is not None and row.tolerance
                 and math.isfinite(row.ours) else None)
        target = {"within_tolerance": None if row.verdict == REPORTED else float(row.verdict == WITHIN),
                  "tolerance_ratio": ratio, "ours": row.ours if math.isfinite(row.ours) else None}
        out.append({"case_name": name, "variant": f"{name}/{row.key}", "family": "reproduce",
                    "params": {"experiment_seconds": outcome.seconds},
                    "case_spec": {k: v for k, v in row.as_dict().items() if k != "ours"},
                    "metrics": {"targets": [target]}, "runtime_s": None, "error": None})
    if outcome.error:
        out.append({"case_name": name, "variant": f"{name}/(error)", "family": "reproduce",
                    "params": {"experiment_seconds": outcome.seconds}, "case_spec": {}, "metrics": {"targets": []},
                    "runtime_s": None, "error": outcome.error})
    return out


def store_outcomes(store: Store, outcomes: list[Outcome], quick: bool, seed: int) -> str:
    """Store every outcome as one run of the ``reproduce`` suite; returns the run id.

    Parameters
    ----------
    store : Store
        The results store.
    outcomes : list of Outcome
        Experiments run.
    quick : bool
        Whether they ran in their quick form (suite ``reproduce-quick``).
    seed : int
        Seed they ran with.
    """
    config = {"experiments": [o.experiment.name for o in outcomes], "quick": quick, "seed": seed}
    digest = hashlib.sha256(json.dumps(config, sort_keys=True).encode()).hexdigest()[:16]
    suite = "reproduce-quick" if quick else "reproduce"
    run_id = store.create_run(suite, digest, config, digest)
    store.add_results(run_id, [row for outcome in outcomes for row in result_rows(outcome)])
    store.finish_run(run_id)
    return run_id


def summary_table(outcomes: list[Outcome], left_out: list[str] = ()) -> str:
    """Per-experiment count of rows within tolerance and run time, for the end of the command's output.

    Parameters
    ----------
    outcomes : list of Outcome
        The experiments run, in order.
    left_out : list of str
        Heavy experiments ``--quick`` did not run (listed, so that the total is read against them).

    Returns
    -------
    str
        Aligned lines: experiment, within / compared, rows outside, seconds (``failed`` for an error).
    """
    lines = [("experiment", "within", "outside", "seconds")]
    for o in outcomes:
        within, compared = count_within(o.rows)
        lines.append((o.experiment.name, "failed" if o.error else f"{within}/{compared}", str(compared - within),
                      f"{o.seconds:.1f}"))
    widths = [max(len(line[i]) for line in lines) for i in range(4)]
    text = ["  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(line, widths)))
            for line in lines]
    if left_out:
        text.append(f"left out by --quick (heavy; name one to run it): {', '.join(left_out)}")
    return "\n".join(text)


def summary_line(rows: list[Row]) -> str:
    """The command's last line: ``N/M rows within tolerance``."""
    within, compared = count_within(rows)
    return f"{within}/{compared} rows within tolerance"

"""A metric across the commits of a results store, the way asv draws a benchmark over commits.

Every complete run of a suite in the store was made at a commit (the store
records it). :func:`metric_history` keeps one run per commit (the latest),
puts the commits in the order of the repository's history (parents before
children, ``git rev-list --topo-order``; a run of uncommitted code,
``<sha>-dirty``, comes right after its commit; commits the repository does
not know come last, in the order of their runs) and gives the metric of the
suite's summary (:func:`benchmarks.summary.summarize`, or of one case) for
every variant at each. :func:`plot_history` draws it; the HTML report adds
:func:`history_figures` for the goal's metrics.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

from matplotlib.figure import Figure

from benchmarks import summary
from benchmarks.errors import BenchError
from benchmarks.store import Store

#: Summary keys that are not metrics.
_LABELS = ("suite", "variant", "family")
#: Metrics drawn in the HTML report's history section.
REPORT_METRICS = ("rop_reduction", "area_rel_err_median")


def history_metrics() -> tuple[str, ...]:
    """The metrics :func:`metric_history` accepts (the numeric keys of a summary row)."""
    return tuple(k for k in summary.SUMMARY_KEYS if k not in _LABELS)


def commit_order(repo=None) -> dict[str, int]:
    """Position of every commit of a repository in its history, parents first (``git rev-list --topo-order``).

    Parameters
    ----------
    repo : str or Path, optional
        A directory of the repository (default: the one holding this package). Outside git, an empty mapping.
    """
    where = str(repo or Path(__file__).resolve().parent)
    try:
        out = subprocess.run(["git", "-C", where, "rev-list", "--topo-order", "--reverse", "--all"],
                             capture_output=True, text=True, check=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError):
        return {}
    return {sha: index for index, sha in enumerate(out.split())}


def metric_history(store: Store, metric: str, suite: str = "quick", variant: str | None = None,
                   case: str | None = None, repo=None) -> list[dict]:
    """One point per commit: the metric of the latest complete run of the suite at that commit.

    Parameters
    ----------
    store : Store
        The results store.
    metric : str
        A key of :func:`history_metrics` (e.g. ``rop_reduction``).
    suite : str
        Suite name.
    variant : str, optional
        Only this variant (default: every variant).
    case : str, optional
        The metric on this case alone (default: over the suite).
    repo : str or Path, optional
        Repository that orders the commits (:func:`commit_order`).

    Returns
    -------
    list of dict
        In commit order, ``{"commit", "run_id", "created", "values": {variant: value or None}}``.

    Raises
    ------
    BenchError
        If the metric is unknown or no run (with that variant or case) is stored.
    """
    if metric not in history_metrics():
        raise BenchError(f"unknown metric {metric!r}; one of: {', '.join(history_metrics())}")
    latest = {run["git_commit"]: run for run in store.runs(suite)}  # runs come oldest first: the latest wins
    if not latest:
        raise BenchError(f"{store.path}: no complete run of suite {suite!r}")
    order = commit_order(repo)
    created = {commit: run["created"] for commit, run in latest.items()}

    def position(commit: str):
        sha, dirty = commit.removesuffix("-dirty"), commit.endswith("-dirty")
        return (0, order[sha], dirty) if sha in order else (1, created[commit], dirty)

    points = []
    for commit in sorted(latest, key=position):
        run = latest[commit]
        rows = [r for r in store.results(run["run_id"]) if case is None or r["case_name"] == case]
        values = {row["variant"]: row[metric] for row in summary.summarize(rows, suite)
                  if variant is None or row["variant"] == variant}
        if values:
            points.append({"commit": commit, "run_id": run["run_id"], "created": run["created"], "values": values})
    if not points:
        what = " and ".join(f"{k} {v!r}" for k, v in (("variant", variant), ("case", case)) if v)
        raise BenchError(f"{store.path}: no run of suite {suite!r} has {what}")
    return points


def _label(commit: str) -> str:
    return commit[:8] + ("+" if commit.endswith("-dirty") else "")


def format_history(points: list[dict], metric: str) -> str:
    """The history as aligned text: one line per commit, one column per variant.

    Parameters
    ----------
    points : list of dict
        :func:`metric_history`.
    metric : str
        Its metric (for the title).
    """
    variants = list(dict.fromkeys(v for p in points for v in p["values"]))
    cells = [["commit", "run", *variants]]
    for p in points:
        cells.append([_label(p["commit"]), p["run_id"],
                      *("n/a" if p["values"].get(v) is None else f"{p['values'][v]:.4g}" for v in variants)])
    widths = [max(len(line[i]) for line in cells) for i in range(len(cells[0]))]
    table = "\n".join("  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(line, widths)))
                      for line in cells)
    return f"{metric} across {len(points)} commit(s), oldest first ('+': uncommitted changes on that commit)\n{table}"


def plot_history(points: list[dict], metric: str, title: str | None = None) -> Figure:
    """The metric of every variant against the commits (x: commits in order, labelled by short hash).

    Parameters
    ----------
    points : list of dict
        :func:`metric_history`.
    metric : str
        Its metric (the y label).
    title : str, optional
        Figure title.
    """
    figure = Figure(figsize=(max(7.0, 0.35 * len(points) + 3), 4.5), layout="constrained")
    axes = figure.subplots()
    x = list(range(len(points)))
    for variant in dict.fromkeys(v for p in points for v in p["values"]):
        y = [p["values"].get(variant) for p in points]
        axes.plot(x, [float("nan") if v is None else v for v in y], "o-", ms=4, label=variant)
    axes.set_xticks(x, [_label(p["commit"]) for p in points], rotation=60, fontsize=7)
    axes.set(xlabel="commit (oldest first)", ylabel=metric, title=title or f"{metric} across commits")
    axes.grid(alpha=0.3)
    axes.legend(fontsize=7, ncol=2)
    return figure


def history_figures(store: Store, suite: str) -> list[tuple[str, Figure]]:
    """The report's history section: :data:`REPORT_METRICS` across commits, where the store holds several.

    Parameters
    ----------
    store : Store
        The results store.
    suite : str
        Suite name.
    """
    if len({run["git_commit"] for run in store.runs(suite)}) < 2:
        return []
    figures = []
    for metric in REPORT_METRICS:
        points = metric_history(store, metric, suite)
        if any(v is not None for p in points for v in p["values"].values()):
            figures.append((f"History across commits: {metric}", plot_history(points, metric)))
    return figures

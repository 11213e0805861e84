"""The committed baseline of a suite, and the check of a run against it.

``benchmarks/baseline/<suite>.json`` holds what the project last accepted:
the accuracy metrics of every case and variant (one
:func:`benchmarks.summary.summarize` row per case and variant, plus the
aggregate over the suite's cases under :data:`SUITE_CASE`), the commit and
run that wrote it, and, separately, the timings of that run.
``tlsbench baseline update`` rewrites it from a run, so that a change that
moves numbers shows in its diff which ones and by how much.

:func:`compare_to_baseline` compares a run with it. The accuracy metrics are
deterministic (same code, same seed, same bytes), so a difference beyond
:data:`TOLERANCES` (which only absorbs floating-point rounding between
machines) comes from the code: per case and variant, a change in the worse
direction of a metric (:data:`RULES`) is a regression, in the better
direction an improvement. Timings depend on the machine and its load: they
are compared as the ratio of a variant's runtime to the time the same run
took to trace the same cases' scans (the raw-trace rate measured in the same
run); a variant outside a noise band of :data:`TIMING_BAND` in that ratio and
in seconds alike gets a warning (slower) or a note (faster), never a failure.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from benchmarks import summary
from benchmarks.errors import BenchError
from benchmarks.store import Store

#: Where the committed baselines live (one file per suite name).
BASELINE_DIR = Path(__file__).resolve().parent / "baseline"
#: Version of the baseline file format.
FORMAT = 1
#: Case name of the aggregate over all the suite's cases (the headline numbers).
SUITE_CASE = "(suite)"
#: Significant digits kept in the file (far below the tolerances; keeps its diffs readable).
DIGITS = 6

#: Largest difference that is not a change, by unit: fractions (ROP, shares, relative errors), angles (deg),
#: lengths (m) and counts. Deterministic metrics differ between machines by rounding at most; a real change of
#: the code moves them by far more (a 1-point change of a fraction is ten times the tolerance). A tree's wood
#: volume error (``"volume"``) is the exception: cylinder following makes discrete choices (a circle kept or
#: refused, a branch followed or stopped), so the few pulses by which two machines' scans differ move it by
#: whole cylinders. Measured on the quick suite (round 34): scans differing in the sixth digit of ROP before
#: (0.237831 against 0.237827) gave `cylinders` 11.61 against 11.14 % and `cylinders-trunk` 1.28 against 1.85 %,
#: and moved the woody variants' median diameter errors by 0.04-0.08 mm: the volume takes 1 point, the diameters
#: (``"diameter"``, m) 0.3 mm.
TOLERANCES = {"fraction": 1e-3, "volume": 1e-2, "deg": 0.05, "m": 1e-4, "diameter": 3e-4, "count": 0.0}
#: What counts as one unit of change when regressions are ordered from the worst (1 point, 1 deg, 1 mm, 1).
SCALES = {"fraction": 0.01, "volume": 0.01, "deg": 1.0, "m": 1e-3, "diameter": 1e-3, "count": 1.0}


@dataclass(frozen=True)
class Rule:
    """How a metric is checked: which direction is better and its unit (:data:`TOLERANCES`).

    ``better`` is ``"higher"``, ``"lower"``, ``"zero"`` (a smaller magnitude; signed biases) or ``None`` (a
    property of the scene or the scan, not of the method: a change is reported, never a regression).
    """

    better: str | None
    unit: str


#: The accuracy metrics of :data:`benchmarks.summary.SUMMARY_KEYS` that are checked, and their rules.
RULES = {
    "n_targets": Rule(None, "count"),
    "n_leaves_traits": Rule(None, "count"),
    "n_errors": Rule("lower", "count"),
    "rop_before": Rule(None, "fraction"),
    "rop_after": Rule("lower", "fraction"),
    "rop_reduction": Rule("higher", "fraction"),
    "rop_before_1cm": Rule(None, "fraction"),
    "rop_after_1cm": Rule("lower", "fraction"),
    "rop_reduction_1cm": Rule("higher", "fraction"),
    "good_points_lost": Rule("lower", "fraction"),
    "good_points_lost_pooled": Rule("lower", "fraction"),
    "outliers_restored": Rule("higher", "fraction"),
    "good_points_damaged": Rule("lower", "fraction"),
    "completeness": Rule("higher", "fraction"),
    "flag_precision": Rule("higher", "fraction"),
    "flag_recall": Rule("higher", "fraction"),
    "rppp_1": Rule(None, "fraction"),
    "abs_eps_mean": Rule("lower", "fraction"),
    "within_5pct": Rule("higher", "fraction"),
    "surface_rmse_m": Rule("lower", "m"),
    "area_rel_err_median": Rule("lower", "fraction"),
    "area_rel_err_bias": Rule("zero", "fraction"),
    "area_seen_rel_err_median": Rule("lower", "fraction"),
    "elevation_err_median_deg": Rule("lower", "deg"),
    "azimuth_err_median_deg": Rule("lower", "deg"),
    "diameter_err_median_m": Rule("lower", "diameter"),
    "volume_rel_err": Rule("lower", "volume"),
    "dbh_err_median_m": Rule("lower", "diameter"),
}

#: A variant's runtime, per trace time and in seconds, may move by this factor either way before a warning. On
#: the 2 cores shared by six sessions, three checks of the quick suite against its baseline (same code of the
#: benchmarks) gave factors of 0.32-1.62 per trace time and 0.70-3.04 in seconds, both the same way at most 1.62:
#: the trace of a case is a snapshot of a few seconds, a variant may run for minutes while the load changes.
TIMING_BAND = 3.0


def baseline_path(suite: str, path=None) -> Path:
    """The baseline file of a suite: ``path`` if given, else ``benchmarks/baseline/<suite>.json``.

    Parameters
    ----------
    suite : str
        Suite name.
    path : str or Path, optional
        Explicit file.
    """
    return Path(path) if path else BASELINE_DIR / f"{suite}.json"


def _rounded(value):
    if value is None or isinstance(value, int):
        return value
    return float(f"{value:.{DIGITS}g}")


def accuracy_table(rows: list[dict], suite: str) -> dict[str, dict[str, dict]]:
    """The checked metrics (:data:`RULES`) of result rows per case and variant, with :data:`SUITE_CASE`.

    Parameters
    ----------
    rows : list of dict
        Stored result rows of one run.
    suite : str
        Suite name.

    Returns
    -------
    dict
        ``{case: {variant: {metric: value}}}``, cases sorted by name after :data:`SUITE_CASE`, variants in
        first-seen order; metrics that do not apply (``None``) are left out.
    """
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    groups = {SUITE_CASE: rows}
    for case in sorted({r["case_name"] for r in rows}):
        groups[case] = [r for r in rows if r["case_name"] == case]
    table = {}
    for case, mine in groups.items():
        by_variant = {row["variant"]: row for row in summary.summarize(mine, suite)}
        table[case] = {v: {k: _rounded(by_variant[v][k]) for k in RULES if by_variant[v][k] is not None}
                       for v in variants if v in by_variant}
    return table


def timing_table(rows: list[dict]) -> dict:
    """Timings of result rows: per variant its runtime and trace time summed over the cases where it ran.

    The trace time of a case is the time its run took to build the scene and trace the scan (``simulate_s``
    of its rows): the raw-trace rate of the machine at that moment. ``ratio`` (runtime / trace time) is what
    :func:`timing_warnings` compares between runs, since both slow down alike on a loaded machine.

    Returns
    -------
    dict
        ``{"trace_s": total trace time over the cases, s, "variants": {variant: {"runtime_s", "trace_s",
        "ratio"}}}``.
    """
    trace = {r["case_name"]: r["simulate_s"] for r in rows if r["simulate_s"] is not None}
    variants = {}
    for variant in dict.fromkeys(r["variant"] for r in rows):
        mine = [r for r in rows if r["variant"] == variant and not r["error"] and r["runtime_s"] is not None
                and r["case_name"] in trace]
        runtime = sum(r["runtime_s"] for r in mine)
        traced = sum(trace[r["case_name"]] for r in mine)
        if traced > 0:
            variants[variant] = {"runtime_s": _rounded(runtime), "trace_s": _rounded(traced),
                                 "ratio": _rounded(runtime / traced)}
    return {"trace_s": _rounded(sum(trace.values())), "variants": variants}


def run_document(store: Store, run_id: str) -> dict:
    """A stored run in the form of a baseline file (accuracy per case and variant, timings, provenance).

    Parameters
    ----------
    store : Store
        The results store.
    run_id : str
        The run.
    """
    info = store.run_info(run_id)
    rows = store.results(run_id)
    if not rows:
        raise BenchError(f"run {run_id} holds no result")
    return {"format": FORMAT, "suite": info["suite"], "suite_digest": info["suite_digest"],
            "commit": info["git_commit"], "run_id": run_id, "created": info["created"], "machine": info["machine"],
            "variants": [v["name"] for v in info["config"].get("variants", [])]
            or list(dict.fromkeys(r["variant"] for r in rows)),
            "tolerances": TOLERANCES, "accuracy": accuracy_table(rows, info["suite"]), "timings": timing_table(rows)}


def baseline_of_run(store: Store, run_id: str) -> dict:
    """:func:`run_document` of a run that may become a baseline: complete and without failed results.

    Parameters
    ----------
    store : Store
        The results store.
    run_id : str
        The run.

    Raises
    ------
    BenchError
        If the run is unfinished or has failed results (a baseline records what works).
    """
    info = store.run_info(run_id)
    if info["status"] != "complete":
        raise BenchError(f"run {run_id} is not complete: finish it (tlsbench run --resume {run_id}) first")
    failed = [r for r in store.results(run_id) if r["error"]]
    if failed:
        raise BenchError(f"run {run_id} has {len(failed)} failed result(s) (first: case {failed[0]['case_name']!r}, "
                         f"variant {failed[0]['variant']!r}: {failed[0]['error']}); a baseline records only what works")
    return run_document(store, run_id)


def write_baseline(document: dict, path) -> Path:
    """Write a baseline document (indented JSON, one metric a line, for readable diffs); returns the path.

    Parameters
    ----------
    document : dict
        :func:`baseline_of_run` of a run.
    path : str or Path
        The file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")
    return path


def load_baseline(path, suite: str) -> dict:
    """Read a baseline file.

    Parameters
    ----------
    path : str or Path
        The file.
    suite : str
        The suite it must belong to.

    Raises
    ------
    BenchError
        If the file is missing, is not a baseline of this format, or belongs to another suite.
    """
    path = Path(path)
    if not path.is_file():
        raise BenchError(f"{path}: no baseline for suite {suite!r}; write one with: tlsbench baseline update "
                         f"--suite {suite}")
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BenchError(f"{path}: not a baseline file ({exc})") from None
    if isinstance(document, dict) and isinstance(document.get("suite"), str) and document["suite"] != suite:
        raise BenchError(f"{path}: a baseline of suite {document['suite']!r}, not {suite!r}")
    if not _well_formed(document):
        raise BenchError(f"{path}: not a baseline file of format {FORMAT} (rewrite it with tlsbench baseline update)")
    return document


def _well_formed(document) -> bool:
    """Whether a decoded file has the shape of :func:`run_document` (what the check reads of it)."""
    def number(value):
        return isinstance(value, (int, float)) and not isinstance(value, bool)

    def mapping(value, check):
        return isinstance(value, dict) and all(isinstance(k, str) and check(v) for k, v in value.items())

    try:
        timings = document["timings"]
        return (document["format"] == FORMAT and all(isinstance(document[k], str) for k in
                                                     ("suite", "suite_digest", "commit", "run_id"))
                and isinstance(document["variants"], list) and all(isinstance(v, str) for v in document["variants"])
                and mapping(document["accuracy"], lambda case: mapping(case, lambda v: mapping(v, number)))
                and (timings["trace_s"] is None or number(timings["trace_s"]))
                and mapping(timings["variants"], lambda v: mapping(v, number)))
    except (KeyError, TypeError):
        return False


@dataclass(frozen=True)
class Change:
    """One difference between a run and its baseline.

    ``verdict`` is ``regression``, ``improvement`` or ``changed`` (a metric without a better direction);
    ``metric`` is ``None`` for a (case, variant) pair missing from the run; ``severity`` orders regressions
    (units of :data:`SCALES`; infinite for a missing pair).
    """

    case: str
    variant: str
    metric: str | None
    old: float | None
    new: float | None
    verdict: str
    severity: float

    def describe(self) -> str:
        """One line naming the case, the variant, the metric and both numbers."""
        where = f"case {self.case}, variant {self.variant}"
        if self.metric is None:
            return f"{where}: in the baseline, missing from this run"
        return f"{where}: {self.metric} {_number(self.old)} -> {_number(self.new)} (baseline -> now)"


def _number(value) -> str:
    return "n/a" if value is None else str(value) if isinstance(value, int) else f"{value:.4g}"


def _judge(rule: Rule, old, new) -> tuple[str, float] | None:
    """Verdict and severity of one metric, or ``None`` when it did not change beyond the tolerance."""
    if old is None and new is None:
        return None
    tolerance = TOLERANCES[rule.unit] * (1 + 1e-9)  # a change of exactly the tolerance is no change
    if rule.better is None:
        changed = old is None or new is None or abs(new - old) > tolerance
        return ("changed", 0.0) if changed else None
    if new is None:
        return "regression", math.inf
    if old is None:
        return "improvement", -math.inf
    delta = new - old
    worse = {"lower": delta, "higher": -delta, "zero": abs(new) - abs(old)}[rule.better]
    if worse > tolerance:
        return "regression", worse / SCALES[rule.unit]
    if worse < -tolerance:
        return "improvement", worse / SCALES[rule.unit]
    return None


def compare_to_baseline(baseline: dict, current: dict, variants=None) -> list[Change]:
    """Every change of a run against the baseline, worst regressions first, then changes, then improvements.

    Parameters
    ----------
    baseline, current : dict
        Documents of :func:`run_document` (the baseline file and the run to check).
    variants : iterable of str, optional
        Variants the check covers (default: those of the baseline): a baseline (case, variant) pair of these
        variants that the run lacks is a regression; pairs of other variants are not compared.

    Returns
    -------
    list of Change
    """
    covered = set(baseline["variants"] if variants is None else variants)
    changes = []
    for case, old_variants in baseline["accuracy"].items():
        for variant, old in old_variants.items():
            if variant not in covered:
                continue
            new = current["accuracy"].get(case, {}).get(variant)
            if new is None:
                changes.append(Change(case, variant, None, None, None, "regression", math.inf))
                continue
            for metric, rule in RULES.items():
                verdict = _judge(rule, old.get(metric), new.get(metric))
                if verdict is not None:
                    changes.append(Change(case, variant, metric, old.get(metric), new.get(metric), *verdict))
    order = {"regression": 0, "changed": 1, "improvement": 2}
    return sorted(changes, key=lambda c: (order[c.verdict], -c.severity if c.verdict == "regression" else c.severity))


def new_pairs(baseline: dict, current: dict) -> list[tuple[str, str]]:
    """(case, variant) pairs of the run that the baseline does not hold (not guarded until it is updated).

    Parameters
    ----------
    baseline, current : dict
        Documents of :func:`run_document` (the baseline file and the run to check).
    """
    return [(case, variant) for case, by_variant in current["accuracy"].items() for variant in by_variant
            if variant not in baseline["accuracy"].get(case, {})]


def valid_band(band: float) -> float:
    """``band`` if it is a usable noise band of timings (a finite factor above 1); else a :class:`BenchError`."""
    if not band > 1 or not math.isfinite(band):
        raise BenchError(f"the timing band must be a factor above 1, got {band}")
    return band


def timing_warnings(baseline: dict, current: dict, band: float = TIMING_BAND) -> list[str]:
    """Variants whose runtime moved by more than ``band``, both per trace time and in seconds, the same way.

    A change of the code moves both; a change of the machine's load moves mostly one (the trace, which
    Dr.Jit spreads over every core, slows down under load more than a single-threaded variant does). Slower
    is a warning, faster a note; neither fails the check.

    Parameters
    ----------
    baseline, current : dict
        Documents of :func:`run_document`.
    band : float
        Factor of the noise band (> 1).

    Returns
    -------
    list of str
        One line per variant outside the band (``timing warning: ...`` or ``timing note: ...``).

    Raises
    ------
    BenchError
        If ``band`` is not a number above 1.
    """
    valid_band(band)
    old, new = baseline["timings"]["variants"], current["timings"]["variants"]
    lines = []
    for variant in new:
        if variant not in old or not all(t[variant]["ratio"] and t[variant]["runtime_s"] for t in (old, new)):
            continue
        factor = new[variant]["ratio"] / old[variant]["ratio"]
        seconds = new[variant]["runtime_s"] / old[variant]["runtime_s"]
        if min(factor, seconds) > band or max(factor, seconds) < 1 / band:
            kind, word = ("timing warning", "slower") if factor > 1 else ("timing note", "faster")
            lines.append(f"{kind}: variant {variant}: {factor:.2f}x the baseline's runtime per trace time ({word}: "
                         f"{old[variant]['ratio']:.3g} -> {new[variant]['ratio']:.3g}; runtime "
                         f"{old[variant]['runtime_s']:.3g} s -> {new[variant]['runtime_s']:.3g} s)")
    return lines


def format_check(baseline: dict, current: dict, changes: list[Change], band: float = TIMING_BAND) -> tuple[str, bool]:
    """The check's report as text, and whether it passed (no regression).

    Parameters
    ----------
    baseline, current : dict
        Documents of :func:`run_document`.
    changes : list of Change
        :func:`compare_to_baseline` of the two.
    band : float
        Noise band of the timings (:func:`timing_warnings`).
    """
    regressions = [c for c in changes if c.verdict == "regression"]
    improvements = [c for c in changes if c.verdict == "improvement"]
    neutral = [c for c in changes if c.verdict == "changed"]
    tolerances = ", ".join(f"{unit} {value:g}" for unit, value in TOLERANCES.items())
    lines = [f"suite {current['suite']}: run {current['run_id']} (commit {current['commit']}) against the baseline "
             f"of commit {baseline['commit']} (run {baseline['run_id']})",
             f"tolerances: {tolerances} (deg for angles, m for lengths and woody diameters, volume for a tree's "
             "wood volume error)"]
    if current["suite_digest"] != baseline["suite_digest"]:
        lines.append("note: the suite changed since the baseline was written")
    for title, group in (("REGRESSION", regressions), ("changed", neutral), ("improved", improvements)):
        lines += [f"{title}: {c.describe()}" for c in group]
    added = new_pairs(baseline, current)
    if added:
        lines.append(f"not in the baseline (not guarded until it is updated): {len(added)} (case, variant) pair(s), "
                     f"e.g. case {added[0][0]}, variant {added[0][1]}")
    trace_old, trace_new = baseline["timings"]["trace_s"], current["timings"]["trace_s"]
    if trace_old and trace_new:
        lines.append(f"timings: trace time {trace_new:.3g} s (baseline {trace_old:.3g} s); runtimes compared per trace "
                     f"time and in seconds with a noise band of {band:g}x, warnings only")
    lines += timing_warnings(baseline, current, band)
    if regressions:
        worst = regressions[0]
        lines.append(f"FAILED: {len(regressions)} regression(s) beyond the tolerances; the worst: {worst.describe()}. "
                     "If the change is intended, update the baseline in the same commit: tlsbench baseline update "
                     f"--suite {current['suite']}")
    else:
        summary_line = f"passed: no regression; {len(improvements)} improvement(s)"
        if improvements:
            pairs = len({(c.case, c.variant) for c in improvements})
            summary_line += (f" over {pairs} (case, variant) pair(s), the largest: {improvements[0].describe()}; "
                             f"lock them in with: tlsbench baseline update --suite {current['suite']}")
        lines.append(summary_line)
    return "\n".join(lines), not regressions

"""Comparing two runs: which metrics of which variants got worse beyond noise.

The comparison is paired: for every variant and metric, the per-case values
(mean over the case's leaves) of the two runs are matched by case name and
the differences ``d`` (oriented so that positive is worse) are tested. A
change is flagged when the mean difference exceeds both ``z`` standard
errors of the paired differences (case-to-case scatter) and a minimal
effect that matters for the metric (:data:`METRICS`). Runtime is compared
as the log of the ratio, with a 25 % minimal effect, because timings on a
shared machine are noisy; the accuracy metrics are deterministic for a
fixed code and seed, so any change there comes from the code.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from benchmarks.errors import BenchError


@dataclass(frozen=True)
class MetricRule:
    """How a metric is compared: its direction and the smallest change that matters."""

    better: str  # "lower" or "higher"
    min_effect: float
    log: bool = False


#: Compared metrics (per-case values) and their rules.
METRICS = {
    "rop_after": MetricRule("lower", 0.005),
    "rop_after_1cm": MetricRule("lower", 0.005),
    "good_points_lost": MetricRule("lower", 0.005),
    "completeness": MetricRule("higher", 0.005),
    "abs_area_rel_err": MetricRule("lower", 0.005),
    "elevation_err_deg": MetricRule("lower", 0.5),
    "azimuth_err_deg": MetricRule("lower", 0.5),
    "abs_eps_mean": MetricRule("lower", 0.002),
    "within_5pct": MetricRule("higher", 0.005),
    "runtime_s": MetricRule("lower", math.log(1.25), log=True),
    # rows of ``tlsbench reproduce`` (benchmarks.reproduce.output): a row leaving its tolerance, or drifting
    # a quarter of its tolerance further from the published value
    "within_tolerance": MetricRule("higher", 0.0),
    "tolerance_ratio": MetricRule("lower", 0.25),
}


def case_values(rows: list[dict]) -> dict[tuple[str, str], dict[str, float]]:
    """Per (variant, case): the mean over leaves of every compared metric, and the runtime."""
    values = {}
    for row in rows:
        if row["error"]:
            continue
        leaves = row["metrics"]["targets"]
        entry = {}
        for key in METRICS:
            if key == "runtime_s":
                entry[key] = row["runtime_s"]
                continue
            source = "area_rel_err" if key == "abs_area_rel_err" else key
            numbers = [abs(leaf[source]) for leaf in leaves if leaf.get(source) is not None]
            entry[key] = float(np.mean(numbers)) if numbers else None
        values[(row["variant"], row["case_name"])] = entry
    return values


def compare_runs(rows_a: list[dict], rows_b: list[dict], z: float = 3.0) -> list[dict]:
    """Paired comparison of run B against run A.

    Parameters
    ----------
    rows_a, rows_b : list of dict
        Stored result rows of the two runs.
    z : float
        Standard errors a mean difference must exceed to count.

    Returns
    -------
    list of dict
        One entry per variant and metric with ``n`` paired cases, ``a`` and
        ``b`` (means), ``change`` (B − A, or B / A − 1 for runtime) and
        ``verdict``: ``regression``, ``improvement`` or ``same``.
    """
    a, b = case_values(rows_a), case_values(rows_b)
    common = sorted(set(a) & set(b))
    if not common:
        raise BenchError("the two runs share no (variant, case) pair to compare")
    out = []
    for variant in dict.fromkeys(v for v, _ in common):
        for key, rule in METRICS.items():
            pairs = [(a[p][key], b[p][key]) for p in common if p[0] == variant
                     and a[p][key] is not None and b[p][key] is not None]
            if rule.log:
                pairs = [(x, y) for x, y in pairs if x > 0 and y > 0]
            if not pairs:
                continue
            x, y = np.array(pairs, dtype=float).T
            diff = np.log(y / x) if rule.log else y - x
            worse = diff if rule.better == "lower" else -diff
            mean = float(worse.mean())
            se = float(worse.std(ddof=1) / math.sqrt(len(worse))) if len(worse) > 1 else 0.0
            threshold = max(z * se, rule.min_effect)
            verdict = "regression" if mean > threshold else "improvement" if mean < -threshold else "same"
            change = math.expm1(float(diff.mean())) if rule.log else float(diff.mean())
            out.append({"variant": variant, "metric": key, "n": len(worse), "a": float(x.mean()),
                        "b": float(y.mean()), "change": change, "verdict": verdict})
    return out


def format_comparison(entries: list[dict], only_changes: bool = False) -> str:
    """The comparison as aligned text.

    Parameters
    ----------
    entries : list of dict
        Comparison entries (``variant``, ``metric``, ``n``, ``a``, ``b``,
        ``change``, ``verdict``), the metrics in their own units.
    only_changes : bool
        Show only the entries whose verdict is not ``same``.

    Returns
    -------
    str
        One line per entry under a header; ``runtime_s`` changes as percentages.
    """
    shown = [e for e in entries if e["verdict"] != "same"] if only_changes else entries
    lines = [("variant", "metric", "n", "A", "B", "change", "verdict")]
    for e in shown:
        change = f"{e['change']:+.1%}" if e["metric"] == "runtime_s" else f"{e['change']:+.4g}"
        lines.append((e["variant"], e["metric"], str(e["n"]), f"{e['a']:.4g}", f"{e['b']:.4g}", change, e["verdict"]))
    widths = [max(len(line[i]) for line in lines) for i in range(7)]
    return "\n".join("  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(line, widths)))
                     for line in lines)

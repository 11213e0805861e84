"""The outlier budget (``tlsbench budget``): its totals are the scores' pooled counts, its groups partition them."""

import pytest
import yaml

from benchmarks import cli, registry, runner
from benchmarks.budget import ACTIONS, case_budget
from benchmarks.errors import BenchError
from benchmarks.suite import parse_suite

SUITE = {"name": "budget", "cases": [
    {"name": "plate", "scene": {"generator": "plate-leaf", "distance_m": 3.0}},
    {"name": "cluster", "scene": {"builtin": "leaf-cluster"}, "scanner": {"step_deg": 0.1}},
]}


@pytest.fixture(scope="module")
def cases():
    return {case.name: case for case in parse_suite(SUITE).cases}


def pooled_counts(case, variant: str, threshold: str) -> dict:
    """Pulses, outliers before and after summed over the case's targets, and their mean ROPs, from the benchmark's
    own rows."""
    (row,) = runner.case_rows(case.to_dict(), runner.variant_specs(registry.resolve([variant])))
    assert row["error"] is None
    suffix = "" if threshold == "auto" else "_" + threshold
    targets = row["metrics"]["targets"]
    totals = {"pulses": 0, "outliers_before": 0, "outliers_after": 0.0,
              "rop_before": sum(score["rop_before" + suffix] for score in targets) / len(targets),
              "rop_after": sum(score["rop_after" + suffix] for score in targets) / len(targets)}
    for score in targets:
        n, n_out = score["n_points"], score["n_outliers" + suffix]
        lost = score["good_points_lost" + suffix] * (n - n_out) if n > n_out else 0.0
        removed = score["outliers_removed" + suffix] * n_out if n_out else 0.0
        totals["pulses"] += n
        totals["outliers_before"] += n_out
        totals["outliers_after"] += score["rop_after" + suffix] * (n - lost - removed)
    return totals


@pytest.mark.parametrize("name, variant, threshold", [("plate", "raw", "auto"), ("cluster", "stray-point", "auto"),
                                                      ("plate", "fused", "1cm")])
def test_totals_are_the_scores_pooled_counts(cases, name, variant, threshold):
    budget = case_budget(cases[name], variant, threshold)
    expected = pooled_counts(cases[name], variant, threshold)
    totals = budget["totals"]
    assert totals["pulses"] == expected["pulses"]
    assert totals["outliers_before"] == expected["outliers_before"] > 0
    assert totals["outliers_after"] == pytest.approx(expected["outliers_after"], abs=1e-6)
    assert totals["rop_before"] == pytest.approx(expected["rop_before"], rel=1e-9)
    assert totals["rop_after"] == pytest.approx(expected["rop_after"], rel=1e-9, abs=1e-12)
    assert {row["action"] for row in budget["groups"]} <= set(ACTIONS)
    keys = [(row["mixture"], row["action"], row["place"]) for row in budget["groups"]]
    assert len(keys) == len(set(keys))  # groups partition the pulses


def test_raw_output_keeps_every_pulse_and_every_outlier(cases):
    budget = case_budget(cases["plate"], "raw")
    assert {row["action"] for row in budget["groups"]} == {"kept"}
    assert all(row["outliers_after"] == row["outliers_before"] for row in budget["groups"])
    assert budget["totals"]["rop_reduction"] == pytest.approx(0.0)
    # the plate in front of its background: pure leaf pulses and leaf pulses mixed with the background
    mixtures = {row["mixture"] for row in budget["groups"]}
    assert "leaf alone" in mixtures and any("+" in m and "leaf" in m for m in mixtures)


def test_whole_scan_variants_place_their_pulses(cases):
    budget = case_budget(cases["plate"], "fused")
    assert budget["scope"] == "scan"
    assert all(row["place"] is not None for row in budget["groups"])
    assert budget["totals"]["outliers_after"] < budget["totals"]["outliers_before"]


def test_refusals_name_what_is_allowed(cases, tmp_path, capsys):
    with pytest.raises(BenchError, match="wood"):
        case_budget(cases["plate"], "cylinders")
    path = tmp_path / "suite.yaml"
    path.write_text(yaml.safe_dump(SUITE))
    assert cli.main(["budget", "--suite", str(path)]) == 2
    assert "name one with --case: plate, cluster" in capsys.readouterr().err
    assert cli.main(["budget", "--suite", str(path), "--case", "nope"]) == 2
    assert "no case 'nope'" in capsys.readouterr().err

"""``tlsbench experiment NAME`` and ``tlsbench perf NAME``: the experiments and perf harnesses of the packages."""

import json

import numpy as np
import pytest

from benchmarks.cli import main


def test_unknown_experiment_subset_is_a_one_line_error(capsys):
    assert main(["experiment", "woody", "--only", "nonsense"]) == 2
    err = capsys.readouterr().err
    assert "nonsense" in err and err.count("\n") == 1


def test_experiments_write_tables_and_json(tmp_path, capsys):
    assert main(["experiment", "woody", "--quick", "--only", "directions", "-o", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "directions.json").read_text())
    assert {r["estimator"] for r in rows} == {"covariance", "iterative", "normals"}
    assert all(r["angle_mean_deg"] < 5 for r in rows)
    assert "angle_mean_deg" in capsys.readouterr().out


def test_bench_reports_time_memory_and_nlogn(capsys):
    assert main(["perf", "woody", "--sizes", "2000", "--methods", "cylinders", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    row = report["rows"][0]
    assert row["method"] == "cylinders" and abs(row["points"] - 2000) < 200
    assert row["time_s"] > 0 and row["peak_mb"] >= 0
    assert row["us_per_nlogn"] == 1e6 * row["time_s"] / (row["points"] * np.log2(row["points"]))


def test_bench_prints_each_row_when_its_run_is_done(capsys):
    """The table is printed row by row (a long --sizes list shows the sizes already done), each row handed over
    as soon as its run ends."""
    from benchmarks.experiments.woody_perf import run_perf

    seen = []
    report = run_perf([300, 600], ["cylinders"], on_row=lambda row: seen.append(row["points"]))
    assert seen == [row["points"] for row in report["rows"]] and len(seen) == 2 and seen[0] < seen[1]
    assert main(["perf", "woody", "--sizes", "300,600", "--methods", "cylinders"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("machine:") and lines[1].split()[:3] == ["method", "points", "time_s"]
    assert [line.split()[0] for line in lines[2:]] == ["cylinders", "cylinders"]


def test_goal_lines_judge_the_worst_case_within_the_goal_range():
    from benchmarks.experiments.woody_experiments import goal_lines

    rows = [{"arc_deg": arc, "normals": "pca", "circles": "refit", "diameter_mae_cm": mae}
            for arc, mae in ((10, 9.0), (40, 0.8), (90, 0.2))]
    (line,) = goal_lines("occlusion", rows)
    assert ": met; worst 0.80 cm at arc_deg = 40" in line  # the 10-deg arc is outside the goal's range
    rows[1]["diameter_mae_cm"] = 1.2
    assert "NOT met" in goal_lines("occlusion", rows)[0]
    trees = [{"tree": "apple-like", "sampling": "one side", "method": "cylinders (spec)", "volume_error_pct": -10.5},
             {"tree": "apple-like", "sampling": "one side", "method": "step (pca)", "volume_error_pct": 1.0}]
    assert goal_lines("trees", trees) == ["goal |volume error| <= 10 %, apple-like, one side, cylinders (spec): "
                                          "NOT met (-10.5 %)"]


def test_every_experiment_and_perf_command_is_registered(capsys):
    from benchmarks.cli import build_parser

    parser = build_parser()
    for argv in (["experiment", "woody"], ["experiment", "sfs-compare"], ["perf", "scenes"], ["perf", "simulator"],
                 ["perf", "sfs"], ["perf", "woody"]):
        assert callable(parser.parse_args(argv).func)
    assert main(["perf", "sfs", "--sizes", "5"]) == 2  # refused before anything runs
    assert "--sizes must be >= 10" in capsys.readouterr().err


def test_occlusion_viewpoints_face_every_visible_point():
    from benchmarks.experiments.woody_experiments import occlusion_viewpoints
    from woody.synthetic import sample_cylinders, straight_cylinder

    for arc, scanners in ((90.0, 1), (170.0, 1), (180.0, 4), (350.0, 4), (360.0, 4)):
        cloud = sample_cylinders(straight_cylinder(), 2e3, seed=1, arc_deg=arc)
        views = occlusion_viewpoints(cloud.points, cloud.normals)
        facing = np.einsum("ni,ni->n", views - cloud.points, cloud.normals)
        assert np.all(facing > 0), arc  # PCA normals oriented towards them point outwards
        assert len(np.unique(views, axis=0)) <= scanners, arc


def test_simulator_scan_memory_splits_into_start_output_and_growth():
    """One measured scan's peak resident memory is what was resident at its start, its output and what it grew
    beyond both; Dr.Jit's own peak is that of the scan's chunk buffers (the scan allocates on the tracer)."""
    import sys

    from benchmarks.experiments.simulator_perf import perf_setup, simulate_measured

    scene, setup = perf_setup(8)
    row = simulate_measured(scene, setup, 0, "llvm")
    assert row["output_mb"] == 8 * 8 * 92 / 2**20  # the scan's grids and truth: 92 bytes per pulse
    assert row["drjit_peak_mb"] > 0
    if sys.platform == "linux":
        assert row["peak_mb"] >= row["start_mb"] > 0
        assert abs(row["peak_mb"] - row["start_mb"] - row["output_mb"] - row["growth_mb"]) < 1e-9


def test_dbh_stems_gives_the_presets_footprint_and_the_grid_it_is_asked_for(tmp_path, capsys):
    import math

    from benchmarks.experiments.dbh_stems import preset_beam
    from tlssim.beam import footprint_axes_m
    from tlssim.scanner import get_preset

    exit_m, growth = preset_beam()
    model = get_preset("faro-ls880")
    for distance in (2.0, 10.0):  # the footprint across a beam at normal incidence
        assert exit_m + growth * distance == pytest.approx(footprint_axes_m(model, distance, 0.0)[1], rel=1e-6)
    assert math.isclose(exit_m, 0.003)
    out = tmp_path / "stems.csv"
    assert main(["experiment", "dbh-stems", "--beam", "--diameters", "0.1", "--distances", "3", "--steps", "0.066",
                 "--csv", str(out)]) == 0
    assert "1/1 within 3 %" in capsys.readouterr().out and len(out.read_text().splitlines()) == 2

"""The ``woody`` console script: reconstruct, experiments, bench, and one-line errors."""

import json

import numpy as np
import trimesh

from tlssim.scan import write_npz, write_ply_points
from woody.cli import main
from woody.synthetic import sample_cylinders, straight_cylinder


def test_reconstruct_cylinders_writes_cylinders_branches_labels_and_mesh(tmp_path):
    cloud = sample_cylinders(straight_cylinder(0.04, 0.6), 1e4, seed=1)
    path = write_npz(tmp_path / "c.npz", {"points": cloud.points})
    assert main(["reconstruct", str(path), "--method", "cylinders", "-o", str(tmp_path / "out")]) == 0
    summary = json.loads((tmp_path / "out" / "cylinders.json").read_text())
    assert summary["method"] == "cylinders"
    assert summary["volume_m3"] == np.pi * 0.04 ** 2 * 0.6 or abs(summary["volume_m3"] / (np.pi * 0.04 ** 2 * 0.6) - 1) < 0.05
    branches = json.loads((tmp_path / "out" / "branches.json").read_text())
    assert len(branches["branches"]) == len({c["branch"] for c in summary["cylinders"]})
    assert len(np.load(tmp_path / "out" / "point_labels.npy")) == len(cloud.points)
    assert trimesh.load(tmp_path / "out" / "mesh.ply").volume > 0


def test_reconstruct_step_from_a_ply_with_normals(tmp_path, capsys):
    cloud = sample_cylinders(straight_cylinder(0.15, 0.8), 1e4, seed=2)
    columns = [(a, "<f8", cloud.points[:, i]) for i, a in enumerate("xyz")]
    columns += [(a, "<f4", cloud.normals[:, i]) for i, a in enumerate(("nx", "ny", "nz"))]
    path = write_ply_points(tmp_path / "c.ply", columns)
    out = tmp_path / "step"
    assert main(["reconstruct", str(path), "--method", "step", "-o", str(out), "--r-min-m", "0.08",
                 "--r-max-m", "0.25"]) == 0
    tuboids = json.loads((out / "tuboids.json").read_text())
    assert len(tuboids) == 1 and abs(np.mean(tuboids[0]["radii"]) - 0.15) < 0.002
    assert "1 tuboids" in capsys.readouterr().out


def test_user_errors_are_one_line_messages_with_status_2(tmp_path, capsys):
    path = write_npz(tmp_path / "empty.npz", {"points": np.empty((0, 3))})
    assert main(["reconstruct", str(path), "--method", "cylinders", "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("woody: error:") and "empty" in err and err.count("\n") == 1
    assert main(["reconstruct", str(path), "--method", "step", "-o", str(tmp_path / "o"), "--cell-m", "0.01"]) == 2
    assert main(["experiments", "--only", "nonsense"]) == 2


def test_experiments_write_tables_and_json(tmp_path, capsys):
    assert main(["experiments", "--quick", "--only", "directions", "-o", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "directions.json").read_text())
    assert {r["estimator"] for r in rows} == {"covariance", "iterative", "normals"}
    assert all(r["angle_mean_deg"] < 5 for r in rows)
    assert "angle_mean_deg" in capsys.readouterr().out


def test_bench_reports_time_memory_and_nlogn(capsys):
    assert main(["bench", "--sizes", "2000", "--methods", "cylinders", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    row = report["rows"][0]
    assert row["method"] == "cylinders" and abs(row["points"] - 2000) < 200
    assert row["time_s"] > 0 and row["peak_mb"] >= 0
    assert row["us_per_nlogn"] == 1e6 * row["time_s"] / (row["points"] * np.log2(row["points"]))


def test_goal_lines_judge_the_worst_case_within_the_goal_range():
    from woody.experiments import goal_lines

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

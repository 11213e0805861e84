"""The ``woody`` console script: reconstruct and one-line errors."""

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


def test_separate_writes_the_wood_points_and_labels(tmp_path, capsys):
    from woody.cloud import read_cloud

    rng = np.random.default_rng(3)
    angle, z = rng.uniform(0, 2 * np.pi, 20000), rng.uniform(0, 1.0, 20000)
    stem = np.column_stack([0.03 * np.cos(angle), 0.03 * np.sin(angle), z])
    blob = np.array([0.6, 0.0, 0.5]) + rng.uniform(-0.03, 0.03, (500, 3))  # a stray clump beside it
    path = write_npz(tmp_path / "c.npz", {"points": np.vstack([stem, blob])})
    for suffix in (".npz", ".ply", ".laz"):
        out = tmp_path / f"wood{suffix}"
        assert main(["separate", str(path), "-o", str(out), "--labels", str(tmp_path / "labels.npy")]) == 0
        labels = np.load(tmp_path / "labels.npy")
        assert labels[len(stem):].sum() == 0 and labels[:len(stem)][stem[:, 2] < 0.8].all()
        assert len(read_cloud(out).points) == labels.sum()
    assert "points are wood" in capsys.readouterr().out

"""TreeQSM-style cylinder tables: conventions, volume, round trip, and the file written by ``woody reconstruct``."""

import csv

import numpy as np
import pytest

from tlssim.scan import write_npz
from woody.cli import main
from woody.errors import WoodyError
from woody.geometry import cylinders_volume
from woody.qsm import COLUMNS, qsm_table, read_qsm_csv, write_qsm_csv
from woody.synthetic import sample_cylinders, straight_cylinder

#: A trunk of two frusta (branch 7) with a side branch of two cylinders (branch 3) on its first piece.
TREE = [
    {"id": 10, "parent": -1, "branch": 7, "order": 0, "start": [0, 0, 0], "end": [0, 0, 1], "radius_m": 0.2,
     "radius_end_m": 0.15},
    {"id": 11, "parent": 10, "branch": 7, "order": 0, "start": [0, 0, 1], "end": [0, 0, 2], "radius_m": 0.15,
     "radius_end_m": 0.1},
    {"id": 12, "parent": 10, "branch": 3, "order": 1, "start": [0, 0, 0.8], "end": [0.6, 0, 1.6], "radius_m": 0.05},
    {"id": 13, "parent": 12, "branch": 3, "order": 1, "start": [0.6, 0, 1.6], "end": [0.6, 0, 1.6],
     "radius_m": 0.04},
    {"id": 14, "parent": 13, "branch": 3, "order": 1, "start": [0.6, 0, 1.6], "end": [0.9, 0, 2.0],
     "radius_m": 0.04},
]


def test_table_follows_treeqsm_conventions_and_keeps_the_volume():
    table = qsm_table(TREE)
    assert len(table["radius"]) == 4  # the zero-length cylinder is left out, its child re-attached
    assert table["parent"].tolist() == [0, 1, 1, 3]
    assert table["extension"].tolist() == [2, 0, 4, 0]
    assert table["branch"].tolist() == [2, 2, 1, 1] and table["order"].tolist() == [0, 0, 1, 1]
    assert table["position_in_branch"].tolist() == [1, 2, 1, 2]
    assert np.allclose(table["length"], [1, 1, 1, 0.5])
    assert np.allclose(table["axis_x"] ** 2 + table["axis_y"] ** 2 + table["axis_z"] ** 2, 1)
    volume = (np.pi * table["radius"] ** 2 * table["length"]).sum()
    assert volume == pytest.approx(cylinders_volume(TREE))


def test_csv_round_trip(tmp_path):
    path = write_qsm_csv(TREE, tmp_path / "q.csv")
    with open(path) as handle:
        assert tuple(next(csv.reader(handle))) == COLUMNS
    back = read_qsm_csv(path)
    assert cylinders_volume(back) == pytest.approx(cylinders_volume(TREE), rel=1e-12)
    assert [c["parent"] for c in back] == [-1, 1, 1, 3]
    assert np.allclose(back[3]["end"], TREE[4]["end"]) and np.allclose(back[2]["start"], TREE[2]["start"])
    (tmp_path / "bad.csv").write_text("radius,length\n1,2\n")
    with pytest.raises(WoodyError, match="TreeQSM"):
        read_qsm_csv(tmp_path / "bad.csv")


def test_reconstruct_writes_the_table_and_removes_the_other_methods_files(tmp_path):
    cloud = sample_cylinders(straight_cylinder(0.04, 0.6), 1e4, seed=1)
    path = write_npz(tmp_path / "c.npz", {"points": cloud.points})
    out = tmp_path / "out"
    out.mkdir()
    (out / "tuboids.json").write_text("[]")  # left by an earlier STEP run
    assert main(["reconstruct", str(path), "--method", "cylinders", "-o", str(out)]) == 0
    table = read_qsm_csv(out / "qsm_cylinders.csv")
    assert cylinders_volume(table) == pytest.approx(np.pi * 0.04 ** 2 * 0.6, rel=0.1)
    assert not (out / "tuboids.json").exists() and (out / "branches.json").exists()

"""Real tree clouds (tests/data/real): the reader round trip, the references, and the DBH of a cut-out tree."""

import laspy
import numpy as np
import pytest
import trimesh

from benchmarks.experiments.woody_real import CLOUDS, DATA, cloud_dbh_reference, treeqsm_reference
from tlssim.formats.points import read_points
from woody.cloud import read_cloud
from woody.dbh import measure_dbh


@pytest.mark.parametrize("name, cloud, ref", CLOUDS)
def test_real_clouds_read_without_viewpoint_or_normals_and_round_trip(tmp_path, name, cloud, ref):
    read = read_cloud(DATA / cloud)
    assert read.viewpoints is None and read.normals is None and len(read.points) > 10000
    local = read.points - read.points.min(axis=0)  # trimesh's PLY is float32: georeferenced x, y would round
    ply, xyz, las = (tmp_path / f"{name}.{suffix}" for suffix in ("ply", "xyz", "las"))
    trimesh.PointCloud(local).export(ply)
    np.savetxt(xyz, local, fmt="%.6f")
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [1e-5] * 3, [0.0] * 3
    out = laspy.LasData(header)
    out.x, out.y, out.z = local.T
    out.write(las)
    for path, tolerance in ((ply, 5e-5), (xyz, 1e-6), (las, 1e-5)):
        again = read_cloud(path)
        assert again.viewpoints is None and np.allclose(again.points, local, atol=tolerance, rtol=0)


def test_treeqsm_references_match_the_published_tree_data():
    # rTwig's QSM.mat holds TreeQSM's own tree data: the cylinders must give its TotalVolume (dm^3) and DBHqsm
    rtwig = treeqsm_reference(DATA / "rtwig_treeqsm.mat")
    assert rtwig["volume_m3"] == pytest.approx(21.5675e-3, rel=1e-4)
    assert rtwig["dbh_m"] == pytest.approx(0.073514, rel=1e-4)
    archi = treeqsm_reference(DATA / "archi_tree1_treeqsm.txt")
    assert archi["cylinders"] == 2271 and 0.45 < archi["dbh_m"] < 0.55
    # tReeTraits' table has a header and its own volume column; its stem's first cylinder spans 0-1.52 m, r 7 cm
    pine = treeqsm_reference(DATA / "treetraits_tree_0744_qsm.txt")
    published = np.genfromtxt(DATA / "treetraits_tree_0744_qsm.txt", names=True)["volume"]
    assert pine["cylinders"] == len(published) == 288
    assert pine["volume_m3"] == pytest.approx(published.sum(), rel=1e-9)
    assert pine["dbh_m"] == pytest.approx(0.14)


def test_dbh_of_the_rtwig_tree_is_within_5_percent_of_its_treeqsm_model():
    # a tree cut out of its scan: no ground points, no scanner position; it must stand on its stem base
    points = read_cloud(DATA / "rtwig_cloud.txt").points
    stem = measure_dbh(points)[0]
    assert stem.ground_z_m == pytest.approx(points[:, 2].min(), abs=0.05)
    assert stem.dbh_m == pytest.approx(treeqsm_reference(DATA / "rtwig_treeqsm.mat")["dbh_m"], rel=0.05)
    assert stem.flag == "ok"


def test_dbh_of_the_treetraits_pine_with_its_needles_is_within_5_percent_of_its_treeqsm_model():
    # not looked at before the DBH code was written: a pine scanned with its needles, its QSM made from the wood
    points = read_cloud(DATA / "treetraits_tree_0744.laz").points
    stem = measure_dbh(points)[0]
    assert stem.dbh_m == pytest.approx(treeqsm_reference(DATA / "treetraits_tree_0744_qsm.txt")["dbh_m"], rel=0.05)


def test_cloud_dbh_reference_fits_the_stem_and_trims_a_branch_beside_it():
    # a 30 cm vertical stem (one half seen, 2 mm noise) and a branch's points 5-10 cm outside it at breast height
    rng = np.random.default_rng(3)
    angle, z = rng.uniform(0, np.pi, 3000), rng.uniform(0.5, 2.0, 3000)
    radius = 0.15 + rng.normal(0, 0.002, 3000)
    stem = np.column_stack([2 + radius * np.cos(angle), 1 + radius * np.sin(angle), 0.3 + z])
    branch = np.column_stack([2.2 + rng.uniform(0, 0.05, 30), 1 + rng.uniform(-0.02, 0.02, 30),
                              1.6 + rng.uniform(-0.05, 0.05, 30)])
    ref = cloud_dbh_reference(np.vstack([stem, branch]), ground_z=0.3)
    assert ref["dbh_m"] == pytest.approx(0.30, abs=0.004) and ref["residual_m"] < 0.004
    assert ref["n_points"] <= ((np.abs(stem[:, 2] - 1.6) <= 0.05).sum())  # the branch is left out

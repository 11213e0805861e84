"""The trunk followed from the ground up by stacked circle fits, and cylinder following with it (follow_tree)."""

import numpy as np
import pytest

from woody import follow_cylinders
from woody.dbh import model_diameter_at
from woody.geometry import cylinders_volume
from woody.synthetic import polyline_cylinders, sample_cylinders
from woody.trunk import follow_trunk, follow_tree


def one_sided(cylinders, density, seed, noise=0.001, ground=True):
    rng = np.random.default_rng(seed)
    points = sample_cylinders(cylinders, density, seed=rng, view=(-1.0, 0.0, 0.0)).points
    points = points + rng.normal(0, noise, points.shape)
    if ground:
        xy = rng.uniform(-1.5, 1.5, (15000, 2))
        points = np.concatenate([points, np.column_stack([xy, rng.normal(0, 0.002, len(xy))])])
    return points


def stem(top, radius, radius_top=None):
    return [{"id": 0, "parent": -1, "order": 0, "branch": 0, "start": [0.0, 0.0, 0.0], "end": list(top),
             "radius_m": radius, "radius_end_m": radius if radius_top is None else radius_top}]


@pytest.mark.parametrize("lean_deg", [0.0, 15.0])
def test_a_one_sided_tapering_stem_is_followed_from_the_ground_to_its_top(lean_deg):
    lean = np.radians(lean_deg)
    top = [2.5 * np.sin(lean), 0.0, 2.5 * np.cos(lean)]
    trunk = follow_trunk(one_sided(stem(top, 0.15, 0.11), 2e4, seed=1))
    assert trunk.ground_z_m == pytest.approx(0.0, abs=0.01)
    assert trunk.centres[0, 2] == pytest.approx(0.0, abs=0.01) and trunk.centres[-1, 2] > 0.9 * top[2]
    t = trunk.centres[:, 2] / top[2]
    expected = 0.15 - 0.04 * t
    assert np.abs(trunk.radii[t < 1] - expected[t < 1]).max() < 0.006
    assert np.abs(trunk.centres[:, 0] - t * top[0]).max() < 0.03  # the leaning axis is followed


@pytest.mark.parametrize("stub_radius, rise", [(0.03, 0.05), (0.015, 0.3)])
def test_the_trunk_is_followed_through_a_whorl_of_branch_bases(stub_radius, rise):
    # a 6-5 cm stem 5 m tall with five branch stubs leaving it at 2.5 m (before: the trunk ended at the whorl)
    cylinders = stem([0, 0, 5.0], 0.06, 0.05) + [
        {"id": k + 1, "parent": 0, "order": 1, "branch": k + 1, "start": [0.0, 0.0, 2.5],
         "end": [0.3 * np.cos(a), 0.3 * np.sin(a), 2.5 + rise], "radius_m": stub_radius}
        for k, a in enumerate(np.linspace(0, 2 * np.pi, 5, endpoint=False))]
    rng = np.random.default_rng(1)
    points = sample_cylinders(cylinders, 2e4, seed=rng).points
    trunk = follow_trunk(points + rng.normal(0, 0.001, points.shape))
    assert trunk.centres[-1, 2] > 4.8
    expected = 0.06 - 0.002 * trunk.centres[:, 2]
    assert np.abs(trunk.radii - expected).max() < 0.006


def test_follow_tree_attaches_the_branches_to_the_trunk_and_keeps_the_volume():
    cylinders = stem([0, 0, 2.5], 0.12) + [
        {"id": 1, "parent": 0, "order": 1, "branch": 1, "start": [0.0, 0.0, 1.8], "end": [0.0, 0.9, 2.6],
         "radius_m": 0.04}]
    points = sample_cylinders(cylinders, 1e4, seed=2).points
    result = follow_tree(points)
    assert result.branches[0]["id"] == 0 and result.stats["trunk"]["circles"] >= 8
    children = [b for b in result.branches if b["parent"] == 0]
    assert children and all(b["order"] == 2 for b in children)
    assert model_diameter_at(result.cylinders(), 1.3) == pytest.approx(0.24, rel=0.02)
    assert result.volume == pytest.approx(cylinders_volume(cylinders), rel=0.1)
    assert (result.labels >= 0).mean() > 0.9


def test_follow_tree_without_a_stem_at_breast_height_is_plain_cylinder_following():
    twig = [{"id": 0, "parent": -1, "order": 0, "branch": 0, "start": [0, 0, 0], "end": [0.5, 0, 0.2],
             "radius_m": 0.03}]
    points = sample_cylinders(twig, 5e3, seed=3).points
    assert follow_tree(points).cylinders() == follow_cylinders(points).cylinders()


def test_degenerate_clouds_end_in_a_result_or_a_woody_error_at_once():
    from woody import WoodyError, step
    from woody.dbh import measure_dbh

    line = np.array([[1.0, 1, 1], [2, 2, 2], [3, 3, 3], [4, 4, 4]])  # as in a real 4-point LAS test file
    for follow in (follow_cylinders, follow_tree):
        assert len(follow(line).branches) == 1
    for cloud, message in ((line, "straight line"), (np.ones((50, 3)), "coincide")):
        with pytest.raises(WoodyError, match=message):
            step(cloud)
        with pytest.raises(WoodyError):
            measure_dbh(cloud)


def test_all_parts_follows_every_connected_part_of_a_cloud_without_stem():
    # Two lying branch pieces (r 1.5 cm) 30 cm apart, both below 0.5 m: no stem, two connected parts.
    first = polyline_cylinders(np.array([[0.0, 0, 0.0], [0.5, 0, 0.1]]), np.array([0.015, 0.015]), first_id=0,
                               parent=-1, order=1, branch=0)
    second = polyline_cylinders(np.array([[0.8, 0, 0.15], [1.3, 0, 0.25]]), np.array([0.015, 0.015]), first_id=1,
                                parent=-1, order=1, branch=1)
    cloud = sample_cylinders(first + second, 2e4, seed=4)
    lowest = follow_tree(cloud.points, bridge_m=0.0)
    bridged = follow_tree(cloud.points)
    both = follow_tree(cloud.points, all_parts=True)
    assert (lowest.labels >= 0).mean() < 0.6  # growth from the lowest point never reaches the second part
    # Bridged (the default): the second part grows as a child across the 30 cm gap, one tree.
    assert (bridged.labels >= 0).mean() > 0.95 and sum(b["parent"] == -1 for b in bridged.branches) == 1
    assert bridged.volume == pytest.approx(cloud.truth["volume_m3"], rel=0.2)
    assert (both.labels >= 0).mean() > 0.95 and both.stats["parts"] == 2
    assert both.volume == pytest.approx(cloud.truth["volume_m3"], rel=0.2)

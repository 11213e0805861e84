"""Cylinder following: a hand-made Y recovers topology and volume; fits, hierarchy, skeleton and errors."""

import numpy as np
import pytest

from woody import FollowParams, WoodyError, follow_cylinders, score
from woody.cylfit import fit_circle, fit_direction, median
from woody.geometry import axis_distance, segment_axis
from woody.synthetic import add_noise, sample_cylinders, straight_cylinder



@pytest.fixture(scope="module")
def y_result(y_tree):
    cloud = sample_cylinders(y_tree, 1e4, seed=2)
    return cloud, follow_cylinders(cloud.points)


def test_y_shaped_branches_recover_topology_and_volume(y_result):
    cloud, result = y_result
    s = score(cloud.truth, result.cylinders())
    assert s["branches_detected"] == 3
    assert s["topology"]["edge_recall"] == 1.0 and s["topology"]["edge_precision"] == 1.0
    assert abs(s["volume_error"]) < 0.10
    trunk = result.branches[0]
    assert trunk["parent"] == -1 and trunk["order"] == 1
    assert trunk["radius_m"] == pytest.approx(0.05, rel=0.05)
    assert {b["order"] for b in result.branches if b["parent"] == 0} == {2}
    assert result.stats["unassigned"] < 0.01 * len(cloud.points)


def test_hierarchy_skeleton_and_labels_are_consistent(y_result):
    cloud, result = y_result
    ids = {b["id"] for b in result.branches}
    for b in result.branches:
        assert b["parent"] == -1 or b["parent"] in ids
        assert all(c in ids for c in b["children"])
    assert np.bincount(result.labels[result.labels >= 0]).tolist() == [b["n_points"] for b in result.branches]
    nodes, edges = result.skeleton()
    assert len(edges) == 2 * len(result.branches) - 1  # one axis per branch, one link per child
    assert edges.max() < len(nodes)
    cylinders = result.cylinders()
    assert all(c["parent"] < c["id"] for c in cylinders)
    assert result.volume == pytest.approx(sum(np.pi * c["radius_m"] ** 2 * np.linalg.norm(
        np.subtract(c["end"], c["start"])) for c in cylinders))
    assert result.mesh().volume == pytest.approx(result.volume, rel=0.05)


def test_straight_cylinder_is_one_branch_with_its_radius():
    cloud = sample_cylinders(straight_cylinder(0.04, 0.8), 1e4, seed=3)
    result = follow_cylinders(cloud.points)
    assert len(result.branches) == 1
    assert result.branches[0]["radius_m"] == pytest.approx(0.04, rel=0.02)
    assert result.volume == pytest.approx(np.pi * 0.04 ** 2 * 0.8, rel=0.05)
    literal = follow_cylinders(cloud.points, radius="max", section_radii=0)
    assert literal.branches[0]["radius_m"] >= 0.04  # the paper's largest distance never under-estimates


@pytest.mark.parametrize("method", ["covariance", "iterative"])
def test_direction_estimators_recover_the_axis(method):
    rng = np.random.default_rng(7)
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    cloud = sample_cylinders([{"start": (-0.3 * d).tolist(), "end": (0.3 * d).tolist(), "radius_m": 0.05}],
                             3e4, seed=8)
    axis = fit_direction(add_noise(cloud.points, 0.001, seed=9, kind="gaussian"), method)
    assert np.degrees(np.arccos(min(abs(axis @ d), 1.0))) < 2.0


def test_circle_fit_is_exact_on_a_short_arc():
    angle = np.linspace(0.0, np.radians(60), 30)
    centre, radius = fit_circle(np.column_stack([0.3 + 0.2 * np.cos(angle), -0.1 + 0.2 * np.sin(angle)]))
    assert radius == pytest.approx(0.2, abs=1e-9) and np.allclose(centre, [0.3, -0.1], atol=1e-9)
    assert np.isnan(fit_circle(np.zeros((2, 2)))[1])


def test_fast_helpers_give_numpys_bits():
    """The growth loop's shortcuts (median, a reused segment) must not move a single bit of the results."""
    rng = np.random.default_rng(5)
    for n in [1, 2, 3, 4, 17, 64, 255]:
        values = rng.normal(size=n) * 0.01
        assert median(values) == np.median(values)
        values[n // 2] = np.nan
        assert np.isnan(median(values))
    points, ends = rng.normal(size=(50, 3)), rng.normal(size=(2, 3))
    for start, end in [ends, (ends[0], ends[0])]:
        axis = end - start  # the arithmetic of segment_distance before the split
        length2 = np.einsum("i,i->", axis, axis)
        t = np.clip(np.einsum("...i,...i->...", points - start, axis) / (length2 if length2 > 0 else 1.0), 0.0, 1.0)
        dist, t_got = axis_distance(points, *segment_axis(start, end))
        assert np.array_equal(dist, np.linalg.norm(points - (start + t[:, None] * axis), axis=1))
        assert np.array_equal(t_got, t)


def test_free_seed_table_reads_order_thresholds():
    params = FollowParams()
    assert [params.n_s(o) for o in (1, 2, 3, 4, 7, 8, 11)] == [80, 60, 60, 40, 40, 30, 20]


@pytest.mark.parametrize("overrides, message", [
    ({"k_r": (1.0, 1.1)}, "k_r"),
    ({"free_seed": ((3, 10), (1, 5))}, "free_seed"),
    ({"radius": "biggest"}, "radius"),
    ({"precision_m": -1.0}, "precision_m"),
    ({"no_such_setting": 1}, "unknown"),
    ({"footprint_m": None}, r"invalid .*footprint_m=None"),
    ({"bridge_m": "1 m"}, r"invalid .*bridge_m='1 m'"),
])
def test_absurd_parameters_are_refused(overrides, message):
    with pytest.raises(WoodyError, match=message):
        follow_cylinders(np.random.default_rng(0).normal(size=(50, 3)), **overrides)


def test_invalid_clouds_are_refused():
    with pytest.raises(WoodyError, match="empty"):
        follow_cylinders(np.empty((0, 3)))
    with pytest.raises(WoodyError, match="NaN"):
        follow_cylinders(np.array([[0.0, 0.0, 0.0], [np.inf, 0.0, 0.0], [1.0, 1.0, 1.0]]))
    with pytest.raises(WoodyError, match="at least 3"):
        follow_cylinders(np.zeros((2, 3)))


@pytest.fixture(scope="module")
def y_gap_cloud(y_tree):
    """The Y seen from one side (+x), with a 10 cm stretch of one arm hidden (as behind a leaf)."""
    cloud = sample_cylinders(y_tree, 1e4, seed=5, view=(1.0, 0.0, 0.0))
    arm = np.asarray(y_tree[1]["end"], float) - np.asarray(y_tree[1]["start"], float)
    t = (cloud.points - np.asarray(y_tree[1]["start"], float)) @ arm / (arm @ arm)
    hidden = (cloud.labels == 1) & (t > 0.3) & (t < 0.3 + 0.1 / np.linalg.norm(arm))
    return cloud, ~hidden


def test_a_one_sided_y_with_a_gap_comes_back_as_one_tree(y_gap_cloud):
    cloud, keep = y_gap_cloud
    result = follow_cylinders(cloud.points[keep])
    roots = [b for b in result.branches if b["parent"] == -1]
    assert len(roots) == 1
    assert result.stats["unassigned"] < 0.02 * keep.sum()
    s = score(cloud.truth, result.cylinders())
    assert abs(s["volume_error"]) < 0.10
    assert s["completeness"] > 0.8
    # Without bridging the growth stops at the gap: the far end of the arm is never reached.
    plain = follow_cylinders(cloud.points[keep], bridge_m=0.0)
    assert plain.stats["unassigned"] > 0.05 * keep.sum()


def test_the_start_does_not_hang_on_which_base_point_is_lowest(y_gap_cloud):
    cloud, keep = y_gap_cloud
    points = cloud.points[keep]
    lowest = np.argsort(points[:, 2])[:8]
    volumes, radii = [], []
    for index in lowest[[0, 3, 7]]:
        moved = points.copy()
        moved[index, 2] = points[lowest[0], 2] - 1e-3  # this base point becomes the lowest
        result = follow_cylinders(moved)
        volumes.append(result.volume)
        radii.append(result.branches[0]["radius_m"])
    assert np.ptp(volumes) < 0.05 * np.mean(volumes)
    assert np.ptp(radii) < 0.05 * np.mean(radii)


def test_a_few_side_twig_points_do_not_move_a_leaders_axis():
    """A one-sided 15 mm leader (the visible half circle, 2 mm range noise) with five points of a side twig 4-5 cm
    beside it: the circle that places the axis is fitted without the twig's points (all of them draw a 6 cm circle
    whose centre lies 5 cm off the leader's axis)."""
    from woody.branch import Branch

    rng = np.random.default_rng(3)
    angle, z = rng.uniform(-np.pi / 2, np.pi / 2, 80), rng.uniform(0, 0.12, 80)
    leader = np.column_stack([-0.015 * np.cos(angle) + rng.normal(0, 0.002, 80), 0.015 * np.sin(angle), z])
    twig = np.column_stack([np.zeros(5), np.linspace(0.04, 0.05, 5), rng.uniform(0, 0.12, 5)])
    points = np.vstack([leader, twig])
    branch = Branch(0, 0, None, 1, (points, None), FollowParams(direction="covariance"))
    branch.points = list(range(len(points)))
    branch.refit(np.array([0.0, 0.0, 1.0]))
    assert branch.fitted and np.linalg.norm(branch.axis_point[:2]) < 0.003


def test_parts_out_of_reach_of_growth_are_bridged_from_anchors():
    # two branch pieces 1.6 m apart, beyond the 1 m bridge of each other; a trunk's points (anchors) run past both
    def piece(start, end, radius, seed):
        record = {"id": 0, "parent": -1, "order": 0, "branch": 0, "start": start, "end": end, "radius_m": radius}
        return sample_cylinders([record], 2e4, seed=seed).points

    low = piece([0.1, 0, 0.2], [0.6, 0, 0.6], 0.02, 1)
    high = piece([0.1, 0, 2.2], [0.6, 0, 2.8], 0.025, 2)
    points = np.vstack([low, high])
    alone = follow_cylinders(points)
    assert (alone.labels[len(low):] < 0).all()  # growth starts at the lowest point and never reaches the high piece
    trunk_axis = np.column_stack([np.zeros(300), np.zeros(300), np.linspace(0.0, 3.0, 300)])
    anchored = follow_cylinders(points, anchors=trunk_axis)
    assert (anchored.labels[len(low):] >= 0).mean() > 0.95
    roots = [b for b in anchored.branches if b["parent"] == -1]
    assert sorted(round(b["radius_m"], 3) for b in roots) == pytest.approx([0.02, 0.025], abs=0.003)
    truth = np.pi * (0.02**2 * np.hypot(0.5, 0.4) + 0.025**2 * np.hypot(0.5, 0.6))
    assert anchored.volume == pytest.approx(truth, rel=0.05)


@pytest.mark.parametrize("normal, up", [((1, 0, 0), (1, 0, 0)), ((-2, 0, 0), (3, 0, 0)), ((0, 0, 1), (0, 0, 1)),
                                        ((0.3, -0.4, 0.5), (0, 0, 1))])
def test_frames_are_right_handed_and_orthonormal_whatever_up(normal, up):
    # the scene library's frame and reconstruction's copy of it (a normal and an up both along x gave NaN)
    from scenes.primitives import orthonormal_frame as scene_frame
    from woody.geometry import orthonormal_frame

    for frame in (orthonormal_frame, scene_frame):
        u, v, n = frame(normal, up)
        assert np.allclose(np.array([u, v, n]) @ np.array([u, v, n]).T, np.eye(3), atol=1e-12)
        assert np.allclose(np.cross(u, v), n) and np.allclose(n, np.asarray(normal) / np.linalg.norm(normal))

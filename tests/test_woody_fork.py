"""Cylinder following at a fork: a stem that splits into four leaders ends at the fork (strict mode); a plain
stem, a stem with a side branch and a stem with a branch running alongside it go on."""

import numpy as np

from woody import FollowParams, follow_cylinders
from woody.branch import Branch
from woody.fork import fill_to_fork, fork_position
from woody.synthetic import polyline_cylinders, sample_cylinders, straight_cylinder

FORK_Z = 0.5  # m: the stem (radius 5 cm) splits here into four leaders of 2.5 cm
DENSITY = 5e3  # points per m^2
SPACING = np.sqrt(1 / DENSITY)  # m


def _fork_tree():
    parts = straight_cylinder(0.05, FORK_Z)
    for k in range(4):
        angle = k * np.pi / 2 + 0.3
        tip = np.array([0.45 * np.cos(angle), 0.45 * np.sin(angle), FORK_Z + 0.8])
        parts += polyline_cylinders(np.array([[0, 0, FORK_Z], tip]), np.array([0.025, 0.025]), first_id=len(parts),
                                    parent=0, order=2, branch=k + 1)
    return parts


def _side_branch_tree():
    # a 5 cm stem 1.2 m tall with a 1.5 cm branch leaving it at 0.5 m at 45 deg
    branch = polyline_cylinders(np.array([[0.05, 0, 0.5], [0.5, 0, 0.95]]), np.array([0.015, 0.012]), first_id=1,
                                parent=0, order=2, branch=1)
    return straight_cylinder(0.05, 1.2) + branch


def _alongside_tree():
    # a 3 cm stem 1.2 m tall with a 1 cm branch that leaves it at 0.3 m and runs alongside it, 2 cm off its
    # surface, up to 0.8 m before it turns away
    centres = np.array([[0.03, 0, 0.3], [0.06, 0, 0.4], [0.06, 0, 0.8], [0.3, 0, 1.1]])
    branch = polyline_cylinders(centres, np.array([0.01, 0.01, 0.01, 0.008]), first_id=1, parent=0, order=2, branch=1)
    return straight_cylinder(0.03, 1.2) + branch


def _branch(points):
    branch = Branch(0, 0, None, 1, (points, None), FollowParams())
    branch.points = list(range(len(points)))
    branch.refit()
    return branch


def _stem_position(points):
    branch = _branch(points)
    cut = fork_position(branch, SPACING)
    return None if cut is None else (branch.axis_point + cut * branch.direction)[2]


def test_fork_found_where_the_points_split():
    cloud = sample_cylinders(_fork_tree(), DENSITY, seed=1)
    z = _stem_position(cloud.points[cloud.points[:, 2] < FORK_Z + 0.2])  # a stem grown 20 cm past the fork
    assert z is not None and FORK_Z <= z <= FORK_Z + 0.2  # within the part that holds the leaders' bases


def test_plain_stem_not_cut():
    assert _stem_position(sample_cylinders(straight_cylinder(0.05, 0.7), DENSITY, seed=1).points) is None


def test_stem_with_side_branch_not_cut():
    # the slices where the branch leaves split into two parts, but one of them is as wide as the stem
    cloud = sample_cylinders(_side_branch_tree(), DENSITY, seed=1)
    assert _stem_position(cloud.points[np.hypot(cloud.points[:, 0], cloud.points[:, 1]) < 0.2]) is None


def test_stem_ends_at_the_fork():
    # The leaders' bases lie within the stem's reach for a few radii past the fork: the stem gives them back
    # (without the cut it ended 12-15 cm past the fork on seeds 1-3).
    for seed in (1, 2):
        cloud = sample_cylinders(_fork_tree(), DENSITY, seed=seed)
        result = follow_cylinders(cloud.points, mode="strict")
        stem = result.branches[0]
        assert stem["end"][2] - FORK_Z < 2 * 0.05  # within the slice (two stem radii) where the limbs part
        leaders = [b for b in result.branches if b["n_points"] >= 100 and b["order"] == 2]
        assert len(leaders) >= 4
        assert abs(result.volume / cloud.truth["volume_m3"] - 1) < 0.05


def test_branch_alongside_does_not_take_the_stem():
    # A branch running alongside the stem is no fork: the stem goes on to its top at its own radius.
    for view in (None, (1.0, 0.0, 0.0)):
        cloud = sample_cylinders(_alongside_tree(), DENSITY, seed=1, view=view)
        result = follow_cylinders(cloud.points, mode="strict")
        stem = result.branches[0]
        assert stem["end"][2] > 1.15
        assert abs(stem["radius_m"] / 0.03 - 1) < 0.1
        assert abs(result.volume / cloud.truth["volume_m3"] - 1) < 0.1


def _leader_records(offset: float, radius: float, across: bool = False) -> tuple[list[dict], np.ndarray]:
    """A stem record (radius 4.5 cm, z 0-1 m) and a leader record resolved from 1.3 m up, leaning 20 deg, whose
    line back passes ``offset`` m beside the stem's top (the leader bends: its hidden base runs straight to the
    top); its sections of 4 radii over 0.48 m of ``radius`` m; a few points on its hidden base, every 5 cm; with
    ``across``, a resolved 3 cm piece of another limb across the base's middle."""
    lean = np.radians(20.0)
    direction = np.array([np.sin(lean), 0.0, np.cos(lean)])
    side = np.array([np.cos(lean), 0.0, -np.sin(lean)])  # across the line, in its plane
    back = 0.3 / np.cos(lean)  # the line's point level with the stem's top is this far back along it
    origin = np.array([0.0, 0.0, 1.0]) + back * direction + offset * side
    edges = np.arange(0.0, 0.4801, 4 * radius)
    sections = [((origin + a * direction).tolist(), (origin + b * direction).tolist(), radius)
                for a, b in zip(edges[:-1], edges[1:])]
    records = [{"id": 0, "parent": -1, "children": [1], "start": [0, 0, 0],
                "sections": [([0, 0, 0], [0, 0, 1], 0.045)], "reliable": [True]},
               {"id": 1, "parent": 0, "children": [], "start": sections[0][0], "sections": sections,
                "reliable": [True] * len(sections)}]
    path = np.array([0.0, 0.0, 1.0]) - origin
    t = np.arange(0.1, 0.9, 0.15)[:, None]
    seen = origin + t * path + radius * np.array([0.0, 1.0, 0.0])
    if across:
        middle = origin + 0.5 * path
        records[0]["children"].append(2)
        records.append({"id": 2, "parent": 0, "children": [], "start": (middle - [0, 0.1, 0]).tolist(),
                        "sections": [((middle - [0, 0.1, 0]).tolist(), (middle + [0, 0.1, 0]).tolist(), 0.03)],
                        "reliable": [True]})
    return records, seen


def test_a_leader_resolved_above_a_hidden_fork_is_filled_to_the_stems_top():
    # Its line passes the stem's top 5 cm off (1.1 stem radii): filled along the straight path from its first
    # resolved section to the stem's surface near the top, at the pipe model's radii from its own, under the stem's.
    records, seen = _leader_records(0.05, 0.02)
    resolved = list(records[1]["sections"])
    assert fill_to_fork(records, seen, 1.0, 4.0) == 1
    sections = records[1]["sections"]
    filled = sections[:-len(resolved)]
    assert sections[-len(resolved):] == resolved and all(records[1]["reliable"])
    assert np.allclose(filled[-1][1], resolved[0][0])
    start = np.asarray(filled[0][0])  # where the path meets the stem (its top; the ray is sampled every r0 / 2)
    reach = np.hypot(np.hypot(start[0], start[1]), max(start[2] - 1.0, 0.0))
    assert 0.045 - 0.01 <= reach <= 0.045 and start[2] > 0.95
    radii = [r for _, _, r in filled]
    assert all(0.02 <= r <= 0.045 for r in radii) and radii == sorted(radii, reverse=True)


def test_no_fill_to_the_stems_top_off_the_line_for_no_leader_without_points_or_across_other_wood():
    # A line passing 3 stem radii off; a limb as wide as 0.8 of the stem (it continues the stem: no leader); no
    # point on the path; another resolved limb across it.
    for offset, radius, empty, across in ((0.135, 0.02, False, False), (0.05, 0.036, False, False),
                                          (0.05, 0.02, True, False), (0.05, 0.02, False, True)):
        records, seen = _leader_records(offset, radius, across)
        sections = list(records[1]["sections"])
        assert fill_to_fork(records, seen[:0] if empty else seen, 1.0, 4.0) == 0
        assert records[1]["sections"] == sections

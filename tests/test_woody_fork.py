"""Cylinder following at a fork: a stem that splits into four leaders ends at the fork (strict mode); a plain
stem, a stem with a side branch and a stem with a branch running alongside it go on."""

import numpy as np

from woody import FollowParams, follow_cylinders
from woody.branch import Branch
from woody.fork import fork_position
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

"""leafsfs.symmetry: completing the far half a leaf hides behind its own roll from the near half."""

import math

import numpy as np
import pytest
from scipy import ndimage

from leafsfs.symmetry import FOLD_MIN_INCIDENCE_DEG, occluded_area, symmetric_area

STEP = 0.001  # m between the synthetic pulses
HALF_LENGTH, HALF_WIDTH = 0.05, 0.025  # m, an elliptic leaf in the xy plane, midrib along x, normal +z
NORMAL, AXIS = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])


def _view(towards_y: float, along_x: float = 0.0) -> np.ndarray:
    """A beam onto the leaf (against its normal) whose component in the leaf's plane is (along_x, towards_y)."""
    return np.array([along_x, towards_y, -0.3])


def _leaf(keep, incidence_deg):
    """Points of the part ``keep(s, t)`` of the elliptic leaf, their area, the cosine of an incidence
    ``incidence_deg(s, t)`` and the outline of the part."""
    s, t = np.meshgrid(np.arange(-HALF_LENGTH, HALF_LENGTH + STEP / 2, STEP),
                       np.arange(-HALF_WIDTH, HALF_WIDTH + STEP / 2, STEP), indexing="ij")
    inside = ((s / HALF_LENGTH) ** 2 + (t / HALF_WIDTH) ** 2 <= 1) & keep(s, t)
    outline = inside & ~ndimage.binary_erosion(inside, np.ones((3, 3), bool))
    points = np.stack([s[inside], t[inside], np.zeros(inside.sum())], axis=1)
    cos = np.cos(np.radians(incidence_deg(s[inside], t[inside])))
    return points, np.full(inside.sum(), STEP ** 2), cos, outline[inside]


def _lower_third_seen_at_a_fold():
    """The upper half and a third of the lower half (t < 0), whose outline is turned edge-on (85 deg)."""
    return _leaf(lambda s, t: t > -HALF_WIDTH / 3, lambda s, t: np.where(t < 0, 85.0, 20.0))


def test_a_whole_leaf_is_left_as_measured():
    # the whole ellipse, one half turning edge-on: both halves hold the same area, nothing is completed
    leaf = _leaf(lambda s, t: np.ones_like(s, bool), lambda s, t: np.where(t > 0, 80.0, 30.0))
    area, side = symmetric_area(*leaf, NORMAL, AXIS, _view(1.0))
    assert side == 0
    assert area == pytest.approx(leaf[1].sum())


def test_the_far_half_turned_edge_on_is_completed_from_the_near_half():
    # the beam crosses the midrib towards -y: the lower half is the far one; its seen third ends at a fold, so the
    # leaf is about twice its upper half (the pulses on the midrib and the ends' slices count once)
    leaf = _lower_third_seen_at_a_fold()
    area, side = symmetric_area(*leaf, NORMAL, AXIS, _view(-1.0))
    whole, seen = math.pi * HALF_LENGTH * HALF_WIDTH, leaf[1].sum()
    assert side == -1
    assert seen + 0.8 * (whole - seen) < area < 1.02 * whole


def test_the_same_leaf_mirrored_completes_the_other_half():
    points, area, cos, outline = _lower_third_seen_at_a_fold()
    completed, side = symmetric_area(points * [1, -1, 1], area, cos, outline, NORMAL, AXIS, _view(1.0))
    assert side == 1
    assert completed == pytest.approx(symmetric_area(points, area, cos, outline, NORMAL, AXIS, _view(-1.0))[0])


def test_a_near_half_is_not_completed():
    # the same part seen with the beam towards +y: the short half is the near one, which the far half cannot hide
    leaf = _lower_third_seen_at_a_fold()
    area, side = symmetric_area(*leaf, NORMAL, AXIS, _view(1.0))
    assert (area, side) == (pytest.approx(leaf[1].sum()), 0)


def test_a_leaf_seen_along_its_midrib_is_not_completed():
    # a beam along the midrib hides the far end behind the bend, not a half behind the roll
    leaf = _lower_third_seen_at_a_fold()
    area, side = symmetric_area(*leaf, NORMAL, AXIS, _view(-0.3, along_x=1.0))
    assert (area, side) == (pytest.approx(leaf[1].sum()), 0)


def test_a_cut_half_with_a_true_edge_is_not_completed():
    # the same part, but its cut outline sees the leaf at its own incidence (a cut or eaten leaf, not a fold)
    leaf = _leaf(lambda s, t: t > -HALF_WIDTH / 3, lambda s, t: np.full_like(s, 40.0))
    area, side = symmetric_area(*leaf, NORMAL, AXIS, _view(-1.0))
    assert (area, side) == (pytest.approx(leaf[1].sum()), 0)


def test_a_fold_below_the_threshold_is_not_completed():
    leaf = _leaf(lambda s, t: t > -HALF_WIDTH / 3,
                 lambda s, t: np.where(t < 0, FOLD_MIN_INCIDENCE_DEG - 5.0, 20.0))
    assert symmetric_area(*leaf, NORMAL, AXIS, _view(-1.0))[1] == 0


def test_too_few_pulses_are_left_as_measured():
    points = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.01, 0.0]])
    area, side = symmetric_area(points, np.ones(3), np.zeros(3), np.ones(3, bool), NORMAL, AXIS, _view(-1.0))
    assert (area, side) == (3.0, 0)


def test_only_the_slices_whose_cut_is_a_fold_are_completed():
    # the lower (far) half is cut along the whole leaf, but only towards the base (s < 2 cm, seven of the ten
    # slices) at a fold; towards the tip the cut is a true edge (eaten): only the base's slices count twice their
    # upper side
    fold_until = 0.02
    leaf = _leaf(lambda s, t: t > -HALF_WIDTH / 3,
                 lambda s, t: np.where((t < 0) & (s < fold_until), 85.0, np.where(t < 0, 30.0, 20.0)))
    area, side = symmetric_area(*leaf, NORMAL, AXIS, _view(-1.0))
    points, pulse_area = leaf[0], leaf[1]
    upper_base = pulse_area[(points[:, 0] < fold_until) & (points[:, 1] > 0)].sum()
    expected = 2 * upper_base + pulse_area[points[:, 0] >= fold_until].sum()
    assert side == -1
    # (the cut reaches the leaf's ends, whose points put the midrib a little towards the upper side)
    assert area == pytest.approx(expected, rel=0.06)
    assert area < 2 * pulse_area[points[:, 1] > 0].sum() * 0.97


def _occluded(keep, beside):
    """The part ``keep`` of the elliptic leaf, with the outline pulses where ``beside(s, t)`` flagged as beside an
    occluder."""
    points, area, _, outline = _leaf(keep, lambda s, t: np.zeros_like(s))
    return points, area, outline, outline & beside(points[:, 0], points[:, 1])


def test_a_half_cut_short_by_an_occluder_is_completed_from_the_other_half():
    # an occluder hides the lower half (t < 0) beyond -0.4 of its width for -2 cm < s < 2 cm: the slices it cuts
    # short count twice their upper half, which restores the hidden area to the pulses' resolution
    hidden = lambda s, t: (t < -0.4 * HALF_WIDTH) & (np.abs(s) < 0.02)
    points, area, outline, occluded = _occluded(lambda s, t: ~hidden(s, t),
                                                lambda s, t: (t < 0) & (np.abs(s) < 0.02))
    whole = _leaf(lambda s, t: np.ones_like(s, bool), lambda s, t: np.zeros_like(s))[1].sum()
    added, slices = occluded_area(points, area, outline, occluded, NORMAL, AXIS)
    assert slices >= 3
    assert area.sum() + added == pytest.approx(whole, rel=0.02)


def test_an_occluder_that_touches_the_outline_adds_nothing():
    # a whole leaf whose lower outline meets an occluder's silhouette: the occluded side is not short of the other
    points, area, outline, occluded = _occluded(lambda s, t: np.ones_like(s, bool),
                                                lambda s, t: (t < 0) & (np.abs(s) < 0.02))
    assert occluded_area(points, area, outline, occluded, NORMAL, AXIS) == (0.0, 0)


def test_a_tip_hidden_on_both_sides_of_the_midrib_is_not_completed():
    # an occluder across the tip (s > 3 cm) borders both halves: no half tells what the other holds
    points, area, outline, occluded = _occluded(lambda s, t: s < 0.03, lambda s, t: s > 0.028)
    assert occluded_area(points, area, outline, occluded, NORMAL, AXIS) == (0.0, 0)


def test_a_half_is_completed_only_where_its_mirror_image_is_hidden():
    # the half cut short as above, its cut outline beside pulses in front: where the scan shows the part the mirror
    # image would fill as hidden, it is completed; where it shows that part empty (a bite beside a twig that only
    # touches its edge), nothing is added
    hidden = lambda s, t: (t < -0.4 * HALF_WIDTH) & (np.abs(s) < 0.02)
    points, area, outline, occluded = _occluded(lambda s, t: ~hidden(s, t),
                                                lambda s, t: (t < 0) & (np.abs(s) < 0.02))
    seen = lambda p: ((p[:, 0] / HALF_LENGTH) ** 2 + (p[:, 1] / HALF_WIDTH) ** 2 <= 1) & ~hidden(p[:, 0], p[:, 1])
    behind_occluder = lambda p: (hidden(p[:, 0], p[:, 1]), seen(p))
    behind_nothing = lambda p: (np.zeros(len(p), bool), seen(p))
    assert occluded_area(points, area, outline, occluded, NORMAL, AXIS, behind_occluder) == (
        occluded_area(points, area, outline, occluded, NORMAL, AXIS))
    assert occluded_area(points, area, outline, occluded, NORMAL, AXIS, behind_nothing) == (0.0, 0)

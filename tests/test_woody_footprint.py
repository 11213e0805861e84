"""The radius bound from the points' spread across the line of sight less the beam footprint."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from woody.cylfit import fit_circle
from woody.footprint import MIN_POINTS, SLICE_SPACINGS, facing_radius, lateral_radii, lateral_radius, silhouette_radius

VIEW = np.array([0.0, 0.0, 0.5])  # the scanner, 4 m from a vertical axis at x = 4


def _one_sided(radius, footprint, noise, count=4000, seed=0):
    """A vertical branch of ``radius`` at x = 4 m seen along x: each pulse's lateral offset evenly over the
    branch's width widened by the footprint, its point on the central ray at the surface's range (the widened
    edges at the silhouette's range) plus range noise along x."""
    rng = np.random.default_rng(seed)
    y = rng.uniform(-(radius + footprint / 2), radius + footprint / 2, count)
    depth = np.sqrt(np.clip(radius**2 - y**2, 0.0, None))
    x = 4.0 - depth + rng.normal(0.0, noise, count)
    return np.c_[x, y, rng.uniform(0.0, 1.0, count)]


@pytest.mark.parametrize("radius", [0.0003, 0.002, 0.01, 0.05])
def test_the_bound_recovers_the_radius_of_a_widened_branch(radius):
    points = _one_sided(radius, 0.005, 0.0)
    assert lateral_radius(points, [4, 0, 0], [4, 0, 1], VIEW, 0.005) == pytest.approx(radius, abs=3e-4, rel=0.02)


def test_range_noise_along_the_line_of_sight_does_not_widen_the_bound():
    clean = lateral_radius(_one_sided(0.001, 0.005, 0.0), [4, 0, 0], [4, 0, 1], VIEW, 0.005)
    noisy = lateral_radius(_one_sided(0.001, 0.005, 0.004), [4, 0, 0], [4, 0, 1], VIEW, 0.005)
    assert noisy == pytest.approx(clean, abs=1e-9)


def test_a_spread_under_the_footprint_gives_zero_and_too_few_points_or_an_end_on_axis_no_bound():
    points = _one_sided(0.0, 0.005, 0.003)
    assert lateral_radius(points, [4, 0, 0], [4, 0, 1], VIEW, 0.008) == 0.0
    assert lateral_radius(points[:MIN_POINTS - 1], [4, 0, 0], [4, 0, 1], VIEW, 0.005) == np.inf
    assert lateral_radius(points, [3, 0, 0.5], [5, 0, 0.5], VIEW, 0.005) == np.inf  # axis along the view


def test_sections_take_every_point_near_their_axis_whichever_branch_holds_it():
    points = _one_sided(0.02, 0.005, 0.001)
    tree = cKDTree(points)
    sections = [([4.0, 0.0, 0.1], [4.0, 0.0, 0.5], 0.02), ([4.0, 0.0, 0.5], [4.0, 0.0, 0.9], 0.02),
                ([4.0, 1.0, 0.1], [4.0, 1.0, 0.5], 0.02)]  # the last one where there are no points
    out = lateral_radii(sections, points, tree, VIEW, 0.005)
    assert out[0] == pytest.approx(0.02, rel=0.03) and out[1] == pytest.approx(0.02, rel=0.03)
    assert out[2] == np.inf


def test_follow_cylinders_is_unchanged_without_a_footprint_and_never_wider_with_one(y_tree):
    from woody import follow_cylinders
    from woody.synthetic import sample_cylinders

    points = sample_cylinders(y_tree, 1e4, seed=2).points
    plain = follow_cylinders(points)
    same = follow_cylinders(points, viewpoint=(0.0, 0.0, 0.0))  # no footprint: the bound is off
    bounded = follow_cylinders(points, viewpoint=(-4.0, 0.0, 1.0), footprint_m=0.005)
    assert [b["sections"] for b in same.branches] == [b["sections"] for b in plain.branches]
    for b, p in zip(bounded.branches, plain.branches):
        assert all(s[2] <= q[2] + 1e-12 for s, q in zip(b["sections"], p["sections"]))
    assert bounded.volume <= plain.volume


def test_invalid_scanner_settings_are_refused():
    from woody import FollowParams, WoodyError

    with pytest.raises(WoodyError, match="footprint_m"):
        FollowParams(footprint_m=-0.001)
    with pytest.raises(WoodyError, match="viewpoint"):
        FollowParams(viewpoint=(0.0, 1.0))


def test_only_the_sections_the_points_do_not_resolve_take_the_bound():
    from woody.cylinders import bound_by_footprint

    records = [{"sections": [([0, 0, 0], [0, 0, 1], 0.05), ([0, 0, 1], [0, 0, 2], 0.04)], "reliable": [True, False]},
               {"sections": [([0, 0, 2], [0, 0, 2.1], 0.003)]}]  # no verdict: resolved
    bound_by_footprint(records, [[0.01, 0.01], [0.001]])
    assert [s[2] for s in records[0]["sections"]] == [0.05, 0.01]
    assert records[1]["sections"][0][2] == 0.003
    bound_by_footprint(records, [[np.inf, np.inf], [np.inf]])  # no bound: radii kept
    assert [s[2] for s in records[0]["sections"]] == [0.05, 0.01]


@pytest.mark.parametrize("radius", [0.01, 0.02, 0.05])
def test_the_facing_refit_removes_the_silhouettes_widening(radius):
    points = _one_sided(radius, 0.005, 0.001, count=2000)
    _, everything = fit_circle(points[:, :2] - [4.0, 0.0])
    assert everything > radius + 2e-4  # the points beyond the silhouette pull a circle of all of them out
    refit = facing_radius(points, [4, 0, 0], [4, 0, 1], everything, VIEW, 0.005)
    assert abs(refit - radius) < 0.5 * abs(everything - radius)
    assert refit == pytest.approx(radius, abs=3e-4)


def test_the_facing_refit_leaves_short_arcs_hidden_sides_and_end_on_axes_alone():
    points = _one_sided(0.02, 0.005, 0.001, count=2000)
    assert facing_radius(points, [4, 0, 0], [4, 0, 1], 0.008, VIEW, 0.005) == np.inf  # arc under +-45 deg
    assert facing_radius(points[points[:, 1] > -0.01], [4, 0, 0], [4, 0, 1], 0.021, VIEW, 0.005) == np.inf
    assert facing_radius(points[:MIN_POINTS - 1], [4, 0, 0], [4, 0, 1], 0.021, VIEW, 0.005) == np.inf
    assert facing_radius(points, [3, 0, 0.5], [5, 0, 0.5], 0.021, VIEW, 0.005) == np.inf


def test_the_facing_refit_only_shrinks_resolved_sections():
    from woody.cylinders import refit_facing

    stem = _one_sided(0.02, 0.005, 0.001, count=2000)
    twig = _one_sided(0.02, 0.005, 0.001, count=2000, seed=1) + [0.0, 0.5, 0.0]
    points = np.r_[stem, twig]
    labels = np.r_[np.zeros(len(stem), int), np.ones(len(twig), int)]
    records = [{"id": 0, "sections": [([4, 0, 0], [4, 0, 1], 0.022)], "reliable": [True]},
               {"id": 1, "sections": [([4, 0.5, 0], [4, 0.5, 1], 0.022)], "reliable": [False]}]
    refit_facing(records, points, labels, VIEW, 0.005)
    assert records[0]["sections"][0][2] == pytest.approx(0.02, abs=3e-4)
    assert records[1]["sections"][0][2] == 0.022  # judged unresolved: the pipe model's radius stands
    records[0]["sections"] = [([4, 0, 0], [4, 0, 1], 0.015)]
    refit_facing(records, points, labels, VIEW, 0.005)
    assert records[0]["sections"][0][2] == 0.015  # never wider


def _grid(radius, footprint, spacing, centre_y=0.0, length=1.0, seed=0):
    """Pulses on an even grid (``spacing`` across and along a vertical branch at x = 4 m, random phase) wherever the
    beam touches the branch: lateral offsets over ``2 radius + footprint``, each point at the surface's range."""
    rng = np.random.default_rng(seed)
    half = radius + footprint / 2
    y = np.arange(-half + rng.uniform(0, spacing), half, spacing)
    z = np.arange(rng.uniform(0, spacing), length, spacing)
    yy, zz = np.meshgrid(y, z)
    depth = np.sqrt(np.clip(radius**2 - yy.ravel()**2, 0.0, None))
    return np.c_[4.0 - depth, centre_y + yy.ravel(), zz.ravel()]


@pytest.mark.parametrize("radius", [0.0005, 0.002, 0.008, 0.02])
def test_the_point_count_recovers_the_radius_of_a_widened_branch(radius):
    points = _grid(radius, 0.005, 0.002)
    bound = silhouette_radius(points[:, 2], 1.0, 0.002, 0.005)
    assert bound == pytest.approx(radius, abs=0.002 / 2 + 1e-9)  # within half a spacing: one point per row more or less


def test_the_count_of_twigs_side_by_side_adds_their_widths_not_the_gap_between_them():
    twigs = np.r_[_grid(0.002, 0.005, 0.002, centre_y=-0.02), _grid(0.002, 0.005, 0.002, centre_y=0.02, seed=1)]
    spread = lateral_radius(twigs, [4, 0, 0], [4, 0, 1], VIEW, 0.005)
    count = silhouette_radius(twigs[:, 2], 1.0, 0.002, 0.005)
    assert spread > 0.02  # the spread spans the 4 cm between the twigs
    assert count == pytest.approx(0.002 + 0.002 + 0.005 / 2, abs=0.002)  # ((2 r + D) + (2 r + D) - D) / 2


@pytest.mark.parametrize("radius", [0.0005, 0.004])
def test_a_branch_hidden_whole_over_less_than_half_its_length_stays_bounded_over_more_gets_no_bound(radius):
    points = _grid(radius, 0.005, 0.002)
    whole = silhouette_radius(points[:, 2], 1.0, 0.002, 0.005)
    seen = points[(points[:, 2] % 0.1) < 0.06]  # 4 cm of every 10 cm hidden
    assert silhouette_radius(seen[:, 2], 1.0, 0.002, 0.005) == pytest.approx(whole, abs=0.001)
    seen = points[(points[:, 2] % 0.1) < 0.04]  # 6 cm of every 10 cm hidden
    assert silhouette_radius(seen[:, 2], 1.0, 0.002, 0.005) == np.inf


def test_a_stem_seen_in_slivers_over_less_than_half_its_length_keeps_its_radius():
    # A 12 mm stem behind a plate that leaves 4 cm of every 10 cm open, and there only its silhouette's outer
    # 9 mm (the plate's edge): the slivers undercount the silhouette.
    points = _grid(0.012, 0.005, 0.002)
    slivers = points[((points[:, 2] % 0.1) < 0.04) & (points[:, 1] > 0.006)]
    assert silhouette_radius(slivers[:, 2], 1.0, 0.002, 0.005) == np.inf
    # Counted over its seen stretches alone, the bound would cut the stem.
    first = slivers[slivers[:, 2] < 0.04, 2]
    assert silhouette_radius(first, 0.04, 0.002, 0.005) < 0.012 - 0.002


def test_short_sections_and_sections_without_points_give_no_bound():
    points = _grid(0.004, 0.005, 0.002)
    assert silhouette_radius(points[:, 2] * 0.001, SLICE_SPACINGS * 0.002 * 0.9, 0.002, 0.005) == np.inf
    assert silhouette_radius([], 1.0, 0.002, 0.005) == np.inf


def test_sections_with_a_spacing_take_the_lower_of_the_two_bounds():
    twigs = np.r_[_grid(0.002, 0.005, 0.002, centre_y=-0.01), _grid(0.002, 0.005, 0.002, centre_y=0.01, seed=1)]
    tree = cKDTree(twigs)
    sections = [([4.0, 0.0, 0.1], [4.0, 0.0, 0.9], 0.02)]
    spread = lateral_radii(sections, twigs, tree, VIEW, 0.005)
    both = lateral_radii(sections, twigs, tree, VIEW, 0.005, spacing_m=0.002)
    assert both[0] < spread[0]
    assert both[0] == pytest.approx(silhouette_radius(twigs[(twigs[:, 2] > 0.1) & (twigs[:, 2] < 0.9), 2] - 0.1, 0.8,
                                                      0.002, 0.005))

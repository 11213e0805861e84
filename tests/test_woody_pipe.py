"""The pipe model of unresolved radii: growth lengths and the shrinking of unresolved cylinders only."""

import numpy as np

from woody.pipe import growth_length, pipe_radii

# A stem of two cylinders (1 m, 0.5 m); the second carries two twigs of 0.25 m, one of which carries a 0.1 m tip.
PARENTS = np.array([-1, 0, 1, 1, 3])
LENGTHS = np.array([1.0, 0.5, 0.25, 0.25, 0.1])


def test_growth_length_sums_everything_a_cylinder_carries():
    assert growth_length(LENGTHS, PARENTS).tolist() == [2.1, 1.1, 0.25, 0.35, 0.1]


def test_only_unresolved_radii_shrink_by_the_square_root_of_their_share():
    fitted = np.array([0.04, 0.03, 0.02, 0.02, 0.02])
    reliable = np.array([True, True, False, False, False])
    out = pipe_radii(fitted, LENGTHS, PARENTS, reliable)
    assert out[:2].tolist() == fitted[:2].tolist()
    assert np.isclose(out[2], 0.03 * np.sqrt(0.25 / 1.1))
    assert np.isclose(out[3], 0.03 * np.sqrt(0.35 / 1.1))
    assert np.isclose(out[4], 0.03 * np.sqrt(0.1 / 1.1))  # its anchor is the resolved stem, not its parent
    # Cross-sections are conserved where the fitted twigs were too wide: the twigs carry the stem's area.
    assert np.isclose(out[2] ** 2 + out[3] ** 2, 0.03**2 * 0.6 / 1.1)


def test_the_fitted_radius_stays_an_upper_bound():
    fitted = np.array([0.04, 0.03, 0.001, 0.02, 0.02])
    out = pipe_radii(fitted, LENGTHS, PARENTS, [True, True, False, False, False])
    assert np.all(out <= fitted)
    assert out[2] == 0.001


def test_without_a_resolved_ancestor_radii_are_kept():
    fitted = np.array([0.04, 0.03, 0.02, 0.02, 0.02])
    assert pipe_radii(fitted, LENGTHS, PARENTS, [False] * 5).tolist() == fitted.tolist()
    # A resolved twig below an unresolved stem anchors its own tip only.
    out = pipe_radii(fitted, LENGTHS, PARENTS, [False, False, False, True, False])
    assert out[:4].tolist() == fitted[:4].tolist()
    assert np.isclose(out[4], 0.02 * np.sqrt(0.1 / 0.35))


def test_a_resolved_tree_keeps_its_radii(y_tree):
    from woody import follow_cylinders
    from woody.synthetic import sample_cylinders

    points = sample_cylinders(y_tree, 1e4, seed=2).points
    plain, piped = follow_cylinders(points), follow_cylinders(points, pipe_model=True)
    radii = [[s[2] for s in b["sections"]] for b in plain.branches]
    assert [[s[2] for s in b["sections"]] for b in piped.branches if b["n_points"] >= 100] == \
        [r for r, b in zip(radii, plain.branches) if b["n_points"] >= 100]
    assert piped.volume <= plain.volume
    assert all(piped.branches[0]["reliable"])
    assert all(plain.branches[0]["reliable"])  # strict mode marks clamped sections only: none here


def test_a_clamped_circle_drawn_across_twigs_is_told_from_a_limb_under_a_thin_parent():
    from woody.cylinders import _cap_radii, _covered

    spacing = 0.005
    # A limb's visible half (r 2 cm, 0.2 m long) sampled at the spacing; three twigs (lines of points 1 cm apart)
    # whose points a 6 cm circle was fitted across.
    phi, z = np.meshgrid(np.arange(-np.pi / 2, np.pi / 2, spacing / 0.02), np.arange(0.0, 0.2, spacing))
    limb = np.c_[0.02 * np.cos(phi.ravel()), 0.02 * np.sin(phi.ravel()), z.ravel()]
    twigs = np.concatenate([np.c_[np.full(40, x), np.zeros(40), np.arange(40) * spacing] for x in (0.0, 0.01, 0.02)])
    assert _covered([([0, 0, 0], [0, 0, 0.2], 0.02)], limb, spacing) == [True]
    assert _covered([([0, 0, 0], [0, 0, 0.2], 0.06)], twigs, spacing) == [False]
    parent = {"sections": [([0, 0, -1.0], [0, 0, 0.0], 0.01)], "radius_m": 0.01}
    child = {"start": [0, 0, 0], "radius_m": 0.06,
             "sections": [([0, 0, 0], [0, 0, 0.1], 0.0105), ([0, 0, 0.1], [0, 0, 0.2], 0.06)]}
    assert _cap_radii(child, parent, 1.1) == [False, True]  # within k_r of the parent: not a misfit
    assert [s[2] for s in child["sections"]] == [0.01, 0.01] and child["radius_m"] == 0.01


def test_a_circle_on_a_few_stray_points_is_cut_to_the_radius_they_cover():
    from woody import follow_cylinders
    from woody.cylinders import COVERED_FRACTION, covered_radii
    from woody.synthetic import sample_cylinders, straight_cylinder

    spacing, rng = 0.005, np.random.default_rng(3)
    # Twenty stray returns on a 2 cm circle along 0.12 m: they cover a 2 mm cylinder's visible half, not a 2 cm one.
    phi, z = rng.uniform(-np.pi / 2, np.pi / 2, 20), rng.uniform(0.0, 0.12, 20)
    stray = np.c_[0.02 * np.cos(phi), 0.02 * np.sin(phi), z]
    limit = covered_radii([([0, 0, 0], [0, 0, 0.12], 0.02)], stray, spacing)[0]
    assert np.isclose(limit, 20 * spacing**2 / (COVERED_FRACTION * np.pi * 0.12))
    assert covered_radii([([0, 0, 0], [0, 0, 0.0], 0.02)], stray, spacing) == [np.inf]
    # The streak centred 10 cm off the axis of a 3 cm stem (1 m, ~1 cm spacing) grows as a branch whose 2 cm circle
    # passes as resolved (such circles held 0.30 dm3 of false volume on a simulated leafless apple-like tree).
    stem = sample_cylinders(straight_cylinder(0.03, 1.0), 1e4, seed=2).points
    cloud = np.r_[stem, stray + [0.1, 0.0, 0.5]]
    result = follow_cylinders(cloud)
    twig = [b for b in result.branches if b["parent"] >= 0]
    assert len(twig) == 1 and twig[0]["n_points"] == 20
    assert max(s[2] for s in twig[0]["sections"]) < 0.5 * 0.02
    for branch in result.branches:  # no resolved section wider than what its branch's points cover
        limits = covered_radii(branch["sections"], cloud[result.labels == branch["id"]], result.stats["spacing_m"])
        assert all(s[2] <= lim + 1e-12 for s, lim, ok in zip(branch["sections"], limits, branch["reliable"]) if ok)


def test_a_restored_section_releases_its_branchs_other_clamps_to_the_pipe_model():
    from woody.cylinders import released_clamps

    # A leader under a thin parent: sections 0 and 2 keep their own circles, 1 and 3 were left at the clamp.
    assert released_clamps([True, True, True, True, False], [True, False, True, False, False]) == \
        [False, True, False, True, False]
    # No own circle stands (a circle drawn across twigs): every clamp holds.
    assert released_clamps([True, True, False], [False, False, False]) == [False, False, False]
    # Released, a section between resolved ones of its branch takes the pipe model's radius from the one before
    # it, not the parent's: the chain stem (4 mm) -> 16 mm -> released (fitted 20 mm) -> 15 mm.
    out = pipe_radii([0.004, 0.016, 0.020, 0.015], [0.3, 0.06, 0.06, 0.06], [-1, 0, 1, 2],
                     [True, True, False, True])
    assert np.isclose(out[2], 0.016 * np.sqrt(0.12 / 0.18))
    assert 0.004 < out[2] <= 0.016

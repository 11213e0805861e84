"""Leaf segmentation in a canopy: edge pulses, necks, wood shapes, and small simulated canopies with known answers."""

import functools
import math

import numpy as np
import pytest
from scipy import ndimage

import scenes
import tlssim
from leafsfs import SfsError, reconstruct
from leafsfs.canopy import (crease_pulses, dark_surfaces, edge_pulses, grow_outline, join_occluded, narrow_surfaces,
                            plane_fits, rim_mixed, rim_shares, shifted, split_creases, split_necks, visibility,
                            wood_surfaces)
from leafsfs.leaves import range_noise
from leafsfs.leaves import _near_background, segment_scan
from leafsfs.preprocess import scan_alpha
from tlssim.pattern import beam_frame
from benchmarks.experiments.calibration import simulated_calibration

STEP = math.radians(0.036)
NOISE_M = 0.002  # range noise of a FARO-class scanner on a leaf at a few metres, m (assumption)


def _grid(rows, cols):
    theta, psi = np.meshgrid(STEP * (np.arange(cols) - cols / 2), np.pi / 2 + STEP * (np.arange(rows) - rows / 2))
    return theta, psi


def test_plane_fits_recover_slope_and_noise():
    rng = np.random.default_rng(0)
    rows, cols = np.mgrid[0:60, 0:60]
    range_m = 2.0 + 0.003 * rows - 0.004 * cols + 0.001 * rng.standard_normal(rows.shape)
    rms, slope, slope_noise, deviation = plane_fits(range_m, 3.0)
    inner = (slice(5, -5), slice(5, -5))
    assert abs(np.median(rms[inner]) - 0.001) < 0.0001
    assert abs(np.median(slope[inner]) - 0.005) < 0.0003
    # a 29-pixel disc: the slope's standard deviation is sigma / sqrt(sum of squared row offsets) = sigma / sqrt(68)
    assert np.isclose(slope_noise[30, 30], 1 / math.sqrt(68))
    # a pulse's own deviation has the range noise's spread; one pulse 1 cm off its plane shows at about 1 cm
    assert abs(1.4826 * np.median(np.abs(deviation[inner])) - 0.001) < 0.0001
    spiked = range_m.copy()
    spiked[30, 30] += 0.01
    assert abs(plane_fits(spiked, 3.0)[3][30, 30] - 0.01) < 0.004
    with pytest.raises(SfsError):
        plane_fits(range_m, 0.5)


def test_a_step_between_two_surfaces_is_an_edge_a_steep_plane_is_not():
    rng = np.random.default_rng(1)
    rows, cols = np.mgrid[0:40, 0:80]
    spacing = 2.0 * STEP
    # left: a leaf 2 m away facing the beam, 3 cm in front of another one; the footprint mixes them over 3 pulses
    share = np.clip((40 - cols) / 3.0, 0, 1)
    range_m = share * 2.0 + (1 - share) * 2.03 + 0.0015 * rng.standard_normal(rows.shape)
    max_slope = np.full(range_m.shape, math.tan(math.radians(35)))  # the intensity says: nearly facing the beam
    edges = edge_pulses(range_m, 2.5, 0.0015, 2.5, max_slope=max_slope, spacing_m=spacing)
    assert edges[:, 38:40].mean() > 0.9  # every row flags the step's mixed pulses
    # and no pure pulse, not even those next to the step (a half disc of their own side is one plane)
    assert edges[3:-3, 3:38].mean() < 0.01 and edges[3:-3, 40:77].mean() < 0.01
    # a plane at 75 deg incidence: steep, but the intensity says so
    steep = 2.0 + math.tan(math.radians(75)) * spacing * cols + 0.0015 * rng.standard_normal(rows.shape)
    flags = edge_pulses(steep, 2.5, 0.0015, 2.5, max_slope=math.tan(math.radians(85)), spacing_m=spacing)
    assert flags[3:-3, 3:-3].mean() < 0.01


def test_behind_gap_judges_a_narrow_leaf_before_a_wall_as_before_the_sky():
    rng = np.random.default_rng(4)
    rows, cols = np.mgrid[0:40, 0:60]
    spacing = 2.0 * STEP
    # a leaf strip 2 m away, 2 pure pulses wide (narrower than a half disc), 1 m in front of a wall; the footprint
    # mixes them over 4 pulses on either side (the wall's share 0.2 .. 0.8: 20-80 cm behind the leaf)
    depth = np.minimum(cols - 25, 26 - cols)  # 0 in the pure core, negative outside
    share = np.clip((depth + 5) / 5.0, 0, 1)
    range_m = share * 2.0 + (1 - share) * 3.0 + 0.0015 * rng.standard_normal(rows.shape)
    max_slope = np.full(range_m.shape, math.tan(math.radians(35)))
    core, band = (slice(3, -3), slice(25, 27)), (slice(3, -3), np.r_[21:25, 27:31])
    before = edge_pulses(range_m, 2.5, 0.0015, 2.5, max_slope=max_slope, spacing_m=spacing)
    after = edge_pulses(range_m, 2.5, 0.0015, 2.5, max_slope=max_slope, spacing_m=spacing, behind_gap=True)
    # every half disc of the core's outer pulses reaches the wall's mixed band: they were edge pulses
    assert before[core].mean() > 0.9
    # without the pulses behind them they lie on the leaf's plane; the mixed ones still lie off it
    assert after[core].mean() < 0.01 and after[band].mean() > 0.95
    # the same strip before the open sky: the core is no edge either way
    sky = np.where(share == 1, range_m, np.nan)
    assert edge_pulses(sky, 2.5, 0.0015, 2.5, max_slope=max_slope, spacing_m=spacing)[core].mean() < 0.01


def test_behind_gap_applies_before_a_background_only_not_before_a_leaf_5_cm_behind():
    rng = np.random.default_rng(5)
    rows, cols = np.mgrid[0:40, 0:60]
    theta, psi = _grid(40, 60)
    spacing = 2.0 * STEP
    # a leaf strip 2 pure pulses wide, 24 long, mixed over 4 pulses on either side
    depth = np.minimum(cols - 25, 26 - cols)
    share = np.clip((depth + 5) / 5.0, 0, 1)
    max_slope = np.full(rows.shape, math.tan(math.radians(35)))
    core = (slice(11, 29), slice(25, 27))

    def scene(gap_m, behind):
        range_m = share * 2.0 + (1 - share) * (2.0 + gap_m) + 0.0015 * rng.standard_normal(rows.shape)
        range_m = np.where(behind | ((share == 1) & (rows >= 8) & (rows < 32)), range_m, np.nan)
        near = _near_background(range_m, theta, psi, None, 2.5, 80.0, 25.0, 0.0015, 9)
        gated = edge_pulses(range_m, 2.5, 0.0015, 2.5, max_slope=max_slope, spacing_m=spacing, behind_gap=near)
        return near, gated, edge_pulses(range_m, 2.5, 0.0015, 2.5, max_slope=max_slope, spacing_m=spacing)

    # another leaf 5 cm behind, inside the window (sky around): no background, the plain edge test
    other = (rows >= 5) & (rows < 35) & (cols >= 12) & (cols < 40)
    near, gated, plain = scene(0.05, other)
    assert not near.any() and np.array_equal(gated, plain)
    # a wall 1 m behind filling the window: the strip and its mixed band are near it, the core is no edge pulse
    near, gated, plain = scene(1.0, np.ones(rows.shape, dtype=bool))
    assert near[core].all() and plain[core].mean() > 0.9 and gated[core].mean() < 0.05


def test_a_small_leaf_1_m_in_front_of_a_wall_is_found():
    # a 3.5 cm leaf 4.5 m away at 60 deg, 0.018 deg: about 130 pulses, a third of them mixed with the wall; before
    # the edge test judged its pulses without the wall's mixed band behind them, none was left to link (no region)
    half = 0.6
    spec = {"name": "small-before-wall", "scanner": {"preset": "faro-ls880", "position": [0, 0, 0], "window": {
                "theta_deg": [-half, half], "psi_deg": [90 - half, 90 + half], "step_deg": 0.018}},
            "objects": [{**LEAF, "name": "front", "length": 0.035,
                         "pose": {"center": [4.5, 0, 0], "facing": "scanner", "incidence_deg": 60}},
                        {"name": "wall", "type": "plane", "size": [1.5, 1.0], "material": "wall",
                         "pose": {"center": [5.5, 0, 0], "facing": "scanner"}}]}
    scene = scenes.scene_from_spec(spec)
    scan = tlssim.simulate(scene, tlssim.setup_from_section(scene.scanner), seed=0, progress=False)
    alpha, _ = scan_alpha(scan.intensity, scan.range, simulated_calibration(scan.scanner.model))
    labels = segment_scan(scan.range, scan.theta, scan.psi, alpha, intensity=scan.intensity).leaves
    pixels = scan.valid & (scan.truth_id == 0)
    assert (pixels & (scan.mixed_fraction > 0.05)).sum() > 0.2 * pixels.sum()
    region, cover = _best_region(labels, pixels)
    assert region > 0 and cover >= 0.75
    # and the region holds the leaf's pulses only, none of the wall's
    assert (scan.truth_id[labels == region] == 0).mean() > 0.95


def test_rim_mixed_flags_outline_pulses_off_their_surface_not_pure_ones():
    rng = np.random.default_rng(3)
    rows, cols = np.mgrid[0:60, 0:60]
    # a round leaf 2 m away, tilted; its outermost ring of pulses mixes 30 % of a branch 3 cm behind (9 mm off)
    range_m = 2.0 + 0.002 * rows + 0.001 * cols + 0.0015 * rng.standard_normal(rows.shape)
    inside = (rows - 30) ** 2 + (cols - 30) ** 2 <= 20 ** 2
    depth = ndimage.distance_transform_edt(inside)
    ring = inside & (depth <= 1)
    mixed = range_m + 0.3 * 0.03 * ring
    surfaces = inside.astype(int)  # the linking took the ring in (its steps are within the noise)
    flagged = rim_mixed(mixed, surfaces, 0.0015, 2.0)
    assert flagged[ring].mean() > 0.9
    assert flagged[inside & ~ring].mean() < 0.01  # pure pulses, at the outline or deeper, stay in
    # a curved leaf (a bowl 4 mm deep over its radius) with no mixing: its outline is no mixed pulse
    bowl = 2.0 + 1e-5 * ((rows - 30) ** 2 + (cols - 30) ** 2) + 0.0015 * rng.standard_normal(rows.shape)
    assert rim_mixed(bowl, surfaces, 0.0015, 2.0)[inside].mean() < 0.01
    assert not rim_mixed(mixed, np.zeros_like(surfaces), 0.0015, 2.0).any()


def test_grow_outline_takes_unpaired_outline_pulses_on_the_region_plane_only():
    rng = np.random.default_rng(5)
    rows, cols = np.mgrid[0:60, 0:60]
    noise = 0.0015
    # a tilted round leaf 2 m away (region 1) and, beside it, a second one 5 cm behind (region 2)
    range_m = 2.0 + 0.002 * rows + 0.001 * cols + noise * rng.standard_normal(rows.shape)
    inside = (rows - 30) ** 2 + (cols - 20) ** 2 <= 12 ** 2
    other = (rows - 30) ** 2 + (cols - 48) ** 2 <= 8 ** 2
    range_m = np.where(other, range_m + 0.05, range_m)
    labels = np.where(inside, 1, np.where(other, 2, 0))
    depth_out = ndimage.distance_transform_edt(labels == 0)
    ring = (labels == 0) & (depth_out <= 2) & ~(ndimage.distance_transform_edt(~other) <= 2)
    ring &= ndimage.distance_transform_edt(~inside) <= 2
    far = (labels == 0) & (ndimage.distance_transform_edt(~inside) > 3)
    off = ring & (cols < 20)  # half the ring lies 10 sigma behind the leaf's plane (a mixed pulse)
    measured = np.where(off, range_m + 10 * noise, range_m)
    candidates = labels == 0
    grown = grow_outline(labels, measured, candidates, labels > 0, noise, 2.0)
    assert (grown[ring & ~off] == 1).mean() > 0.95  # on the plane within the noise: joined
    assert not grown[off].any()  # off the plane: left out
    assert not grown[far].any()  # beyond a footprint radius: left out
    assert (grown[labels > 0] == labels[labels > 0]).all()  # the regions keep their pulses
    assert (grown[~candidates & (labels == 0)] == 0).all()
    # pulses only a candidate may join; none when no pulse is a candidate
    assert (grow_outline(labels, measured, np.zeros_like(candidates), labels > 0, noise, 2.0) == labels).all()
    # region 2's outline pulses join it where they lie on its plane (5 cm behind region 1's), not on region 1's
    ring2 = (labels == 0) & (ndimage.distance_transform_edt(~other) <= 1.5)
    behind = np.where(ring2, range_m + 0.05, measured)
    grown = grow_outline(labels, behind, candidates, labels > 0, noise, 2.0)
    assert (grown[ring2] == 2).mean() > 0.95
    assert not (grow_outline(labels, measured, candidates, labels > 0, noise, 2.0)[ring2] == 2).any()


def _roof_and_cup(noise_m=0.0015, seed=2):
    """Ranges of two planes meeting at column 60 with normals 70 deg apart (two leaves touching at the same
    distance), and of a leaf curved with a 5 cm radius (normals turn 17 deg over 12 pulses), 2 m away."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:60, 0:120]
    spacing = 2.0 * STEP
    x = (cols - 60) * spacing
    roof = 2.0 + math.tan(math.radians(35)) * np.abs(x)
    cup = 2.0 + x ** 2 / (2 * 0.05)
    return [r + noise_m * rng.standard_normal(r.shape) for r in (roof, cup)], spacing, cols


def test_crease_pulses_mark_where_two_planes_meet_not_a_curved_leaf():
    (roof, cup), spacing, cols = _roof_and_cup()
    known = np.ones(roof.shape, dtype=bool)
    crease = crease_pulses(roof, known, spacing, 0.0015)
    inner = slice(8, -8)
    assert crease[inner, 56:65].sum(axis=1).min() >= 3  # every row is cut at the ridge
    assert not crease[inner][:, np.abs(cols[0] - 60) > 8].any()  # and nowhere far from it
    assert not crease_pulses(cup, known, spacing, 0.0015).any()
    with pytest.raises(SfsError):
        crease_pulses(roof, known, spacing, 0.0015, max_angle_deg=0)
    # a surface narrower than the planes' offset has no crease (and no error)
    assert not crease_pulses(roof[:4, :5], known[:4, :5], spacing, 0.0015).any()
    image = np.arange(12.0).reshape(3, 4)
    assert np.array_equal(shifted(image, 1, -1, -1.0), [[-1, 4, 5, 6], [-1, 8, 9, 10], [-1, -1, -1, -1]])
    assert (shifted(image, 0, 4, -1.0) == -1).all() and (shifted(image, -3, 0, -1.0) == -1).all()


def test_split_creases_cuts_two_touching_leaves_apart_and_keeps_a_curved_one_whole():
    (roof, cup), spacing, cols = _roof_and_cup()
    one = np.ones(roof.shape, dtype=int)
    labels, cut = split_creases(one, roof, np.array([False, True]), np.full(roof.shape, spacing), 0.0015, 40.0, 30)
    assert cut and labels.max() == 2 and (labels > 0).all()
    assert len(np.unique(labels[:, :58])) == 1 and len(np.unique(labels[:, 63:])) == 1
    assert labels[0, 0] != labels[0, -1]
    # not a candidate (wood, say): not cut; a curved leaf: not cut
    assert not split_creases(one, roof, np.array([False, False]), np.full(roof.shape, spacing), 0.0015, 40.0, 30)[1]
    same, cut = split_creases(one, cup, np.array([False, True]), np.full(roof.shape, spacing), 0.0015, 40.0, 30)
    assert not cut and np.array_equal(same, one)


def test_split_necks_cuts_an_appendage_off_a_blade_and_keeps_a_leaf_whole():
    rows, cols = np.mgrid[0:80, 0:120]
    blade = ((rows - 40) / 20.0) ** 2 + ((cols - 40) / 30.0) ** 2 <= 1
    twig = (np.abs(rows - 40) <= 2) & (cols >= 60)
    labels = split_necks((blade | twig).astype(int), 0.3, 30)
    assert labels.max() == 2
    assert len(np.unique(labels[blade & (cols < 60)])) == 1 and len(np.unique(labels[twig & (cols > 75)])) == 1
    assert labels[40, 40] != labels[40, 100]
    # an ellipse alone (its tips narrower than the disc) stays one surface; labels are renumbered from 1
    alone = split_necks(np.where(blade, 7, 0), 0.3, 30)
    assert np.array_equal(alone, blade.astype(int))


def test_a_leaf_whose_petiole_joins_a_twig_across_the_window_is_cut_from_it_at_the_neck():
    # the twig reaches the window's border (in a tree: through the branches, the trunk and the ground), the petiole
    # is wider than a thin part (9 mm at 2 m) and continuous in range with the blade: one surface until the neck cut
    rows, cols = 160, 200
    theta, psi = _grid(rows, cols)
    i, j = np.mgrid[:rows, :cols]
    blade = np.hypot((i - 95) / 35, (j - 100) / 25) <= 1
    petiole = (np.abs(j - 100) <= 3) & (i >= 20) & (i <= 62)
    twig = (i >= 12) & (i <= 24)
    range_m = np.where(twig | petiole, 2.0, np.nan)
    range_m[blade] = 2.0 + 0.0006 * (i[blade] - 60)
    range_m += np.random.default_rng(0).normal(0, 0.0005, range_m.shape)
    labels = segment_scan(range_m, theta, psi, noise_m=0.0005).leaves
    region, cover = _best_region(labels, blade)
    assert region > 0 and cover > 0.95
    assert not (labels[twig] > 0).any() and labels.max() == 1


def test_wood_surfaces_are_elongated_or_sparse_whatever_their_scale():
    for distance in (1.0, 4.0):
        rows, cols = np.mgrid[0:150, 0:150]
        theta, psi = _grid(150, 150)
        range_m = np.full(rows.shape, distance)
        labels = np.zeros(rows.shape, int)
        labels[((rows - 30) / 20.0) ** 2 + ((cols - 35) / 30.0) ** 2 <= 1] = 1  # a leaf, 1.5 : 1
        labels[(np.abs(rows - 75) <= 3) & (cols > 10) & (cols < 140)] = 2  # a branch, 18 : 1
        fork = (np.abs(cols - 110 - (rows - 100)) <= 2) | (np.abs(cols - 110 + (rows - 100)) <= 2)
        labels[fork & (rows > 95) & (rows < 145)] = 3  # a fork of two twigs: not elongated, but sparse
        wood = wood_surfaces(labels, range_m, theta, psi, STEP)
        assert wood.tolist() == [False, False, True, True]
    with pytest.raises(SfsError):
        wood_surfaces(labels, range_m, theta, psi, STEP, max_aspect=0.5)


def _tilted_plane(distance, incidence_deg, rows=200, cols=200):
    """Ranges of a plane ``distance`` m ahead turned ``incidence_deg`` about the vertical, and its points' in-plane
    coordinates (across the turn, vertical), m."""
    theta, psi = _grid(rows, cols)
    u = beam_frame(theta, psi)[0]
    axis = u[rows // 2, cols // 2]
    turn = math.radians(incidence_deg)
    up = np.array([0.0, 0.0, 1.0])
    side = np.cross(up, axis)
    normal = math.cos(turn) * axis + math.sin(turn) * side
    range_m = distance * (axis @ normal) / (u @ normal)
    point = u * range_m[..., None] - distance * axis
    return theta, psi, range_m, point @ (math.cos(turn) * side - math.sin(turn) * axis), point @ up


def test_narrow_surfaces_measure_the_width_in_3d_not_in_the_image():
    rng = np.random.default_rng(3)
    for distance, incidence in ((2.0, 0.0), (2.0, 80.0), (5.0, 75.0)):
        theta, psi, range_m, across, up = _tilted_plane(distance, incidence)
        labels = np.zeros(range_m.shape, int)
        # a 3 x 6 cm leaf (seen at 80 deg only 5 mm wide in the image) and a 1 cm wide strip of a leaf or a twig
        labels[(across / 0.015) ** 2 + ((up - 0.035) / 0.03) ** 2 <= 1] = 1
        labels[(np.abs(across) <= 0.005) & (np.abs(up + 0.03) <= 0.03)] = 2
        noisy = range_m + rng.normal(0, NOISE_M, range_m.shape)
        assert narrow_surfaces(labels, noisy, theta, psi, 0.016).tolist() == [False, False, True]
        assert not narrow_surfaces(labels, noisy, theta, psi, 0.0).any()
    with pytest.raises(SfsError):
        narrow_surfaces(labels, range_m, theta, psi, -0.01)


def test_a_flat_leaf_seen_at_83_deg_fills_its_ellipse_and_is_no_wood():
    # the sparse test counts each pulse's area up to MAX_AREA_INCIDENCE_DEG (at a cap of 75 deg: fill 0.47, wood)
    theta, psi, range_m, across, up = _tilted_plane(1.0, 83.0, 300, 300)
    labels = ((across / 0.015) ** 2 + (up / 0.03) ** 2 <= 1).astype(int)
    alpha = np.full(range_m.shape, math.radians(83.0))
    assert labels.sum() > 30 and wood_surfaces(labels, range_m, theta, psi, STEP, alpha).tolist() == [False, False]


def test_dark_surfaces_a_bark_cylinder_is_darker_than_its_plane_a_leaf_is_not():
    rng = np.random.default_rng(1)
    theta, psi = _grid(80, 120)
    rows, cols = np.mgrid[0:80, 0:120]
    for distance in (1.5, 5.0):
        spacing = distance * STEP
        labels = np.zeros(rows.shape, int)
        range_m = np.full(rows.shape, np.nan)
        alpha = np.full(rows.shape, np.nan)
        # a leaf tilted 50 deg along the rows, its intensity giving its own incidence (alpha noise 5 deg)
        leaf = (rows < 40) & (cols < 50)
        labels[leaf], range_m[leaf] = 1, distance + spacing * math.tan(math.radians(50)) * rows[leaf]
        alpha[leaf] = math.radians(50) + math.radians(5) * rng.standard_normal(leaf.sum())
        # a vertical cylinder 30 pixels across, its front (the pulses within 0.8 of its radius from the axis:
        # the rest are edge pulses); bark reflecting 0.73 of a leaf: cos(alpha) = 0.73 cos(incidence)
        radius = 15 * spacing
        x = (cols - 85) * spacing
        bark = (np.abs(x) < 0.8 * radius) & (rows > 10)
        incidence = np.arcsin(np.abs(x[bark]) / radius)
        labels[bark], range_m[bark] = 2, distance - np.sqrt(radius ** 2 - x[bark] ** 2)
        alpha[bark] = np.arccos(0.73 * np.cos(incidence))
        # the same cylinder with a leaf's reflectance: its curvature alone is within the tolerance
        leaf_like = alpha.copy()
        leaf_like[bark] = incidence
        same = dark_surfaces(labels, range_m, leaf_like, STEP, math.radians(25), NOISE_M)
        assert dark_surfaces(labels, range_m, alpha, STEP, math.radians(25), NOISE_M).tolist() == [False, False, True]
        assert same.tolist() == [False, False, False]
    with pytest.raises(SfsError):
        dark_surfaces(labels, range_m, alpha, STEP, -1.0, NOISE_M)


def test_dark_surfaces_spare_a_dome_whose_curvature_the_ranges_resolve():
    # The thesis' hemisphere, 8 cm across at 1.5 m, of a leaf's reflectance: its intensity gives the incidence of
    # each pulse (45 deg median) while its least-squares plane faces the beam; its ranges leave that plane by
    # far more than the noise, so the plane is no measure of what its pulses see.
    theta, psi = _grid(120, 120)
    rows, cols = np.mgrid[0:120, 0:120]
    spacing = 1.5 * STEP
    radius = 0.04
    rho = np.hypot(rows - 60, cols - 60) * spacing
    dome = rho < 0.95 * radius
    labels = np.where(dome, 1, 0)
    range_m = np.where(dome, 1.5 - np.sqrt(np.clip(radius ** 2 - rho ** 2, 0, None)), np.nan)
    alpha = np.where(dome, np.arcsin(np.clip(rho / radius, 0, 1)), np.nan)
    assert dark_surfaces(labels, range_m, alpha, STEP, math.radians(25), NOISE_M).tolist() == [False, False]
    # were the same ranges within the noise of a plane, the intensity would make it dark
    assert dark_surfaces(labels, range_m, alpha, STEP, math.radians(25), 0.01).tolist() == [False, True]


def test_join_occluded_joins_the_parts_of_a_leaf_behind_a_twig_only():
    rows, cols = np.mgrid[0:40, 0:60]
    plane = 3.0 + 0.0005 * rows + 0.001 * cols
    labels = np.zeros(rows.shape, int)
    labels[5:35, 5:27], labels[5:35, 31:55] = 1, 2  # two parts 4 pixels apart
    labels[:3, :3] = 3  # a third surface, far away
    gap = (cols >= 27) & (cols < 31)
    candidates = np.array([False, True, True, True])
    for between, behind, joined in ((plane - 0.03, 0.0, True),  # a twig in front: one leaf
                                    (np.nan, 0.0, False),  # nothing returns between them: two leaves
                                    (plane + 0.05, 0.0, False),  # what lies behind shows between them
                                    (plane - 0.03, 0.02, False)):  # a twig in front, the parts 2 cm apart in range
        range_m = np.where(gap, between, plane + np.where(labels == 2, behind, 0.0))
        out = join_occluded(labels, range_m, candidates, 6.0, 0.005)
        assert (out[labels == 2] == 1).all() == joined
        assert (out[labels == 1] == 1).all() and (out[labels == 3] == 3).all()
    assert (join_occluded(labels, range_m, candidates, 3.0, 0.005) == labels).all()  # the gap wider than an occluder
    with pytest.raises(SfsError):
        join_occluded(labels, range_m, candidates, 0.0, 0.005)


def test_join_occluded_reaches_across_the_edge_bands_beside_a_twig():
    rows, cols = np.mgrid[0:40, 0:80]
    plane = 3.0 + 0.0005 * rows + 0.001 * cols
    labels = np.zeros(rows.shape, int)
    labels[5:35, 5:30], labels[5:35, 42:70] = 1, 2  # two parts 12 pixels apart: a 4-pixel twig, 4-pixel bands
    twig = (cols >= 34) & (cols < 38)
    band = ((cols >= 30) & (cols < 34)) | ((cols >= 38) & (cols < 42))  # mixed pulses between twig and leaf
    candidates = np.array([False, True, True])
    for between, joined in ((plane - 0.03, True), (np.nan, False), (plane + 0.05, False)):
        range_m = np.where(twig, between, np.where(band, plane - 0.015 if joined else between, plane))
        assert (join_occluded(labels, range_m, candidates, 6.0, 0.005)[labels == 2] == 2).all()  # no bands: too far
        assert (join_occluded(labels, range_m, candidates, 6.0, 0.005, bands_px=8.0)[labels == 2] == 1).all() == joined
    # far beyond the occluder and its bands, a part is another leaf
    range_m = np.where(twig | band, plane - 0.03, plane)
    assert (join_occluded(labels, range_m, candidates, 3.0, 0.005, bands_px=6.0)[labels == 2] == 2).all()


def test_join_occluded_gives_a_fragment_cut_off_by_a_twig_back_to_its_leaf_only():
    rows, cols = np.mgrid[0:40, 0:60]
    plane = 3.0 + 0.0005 * rows + 0.001 * cols
    labels = np.zeros(rows.shape, int)
    labels[5:35, 5:40], labels[15:25, 44:52] = 1, 2  # a leaf and its tip (no leaf on its own) beyond a 4-pixel twig
    labels[15:25, 56:60] = 3  # a second leaf beyond the tip, as far from it
    gap = ((cols >= 40) & (cols < 44)) | ((cols >= 52) & (cols < 56))
    leaf, tip = np.array([False, True, False, True]), np.array([False, False, True, False])
    for between, behind, joined in ((plane - 0.03, 0.0, True),  # a twig in front: the tip is the leaf's
                                    (np.nan, 0.0, False),  # nothing returns between them
                                    (plane + 0.05, 0.0, False),  # what lies behind shows between them
                                    (plane - 0.03, 0.03, False)):  # the tip 3 cm behind the leaf: another surface
        range_m = np.where(gap, between, plane + np.where(labels == 2, behind, 0.0))
        out = join_occluded(labels, range_m, leaf, 6.0, 0.005, 9.0, tip)
        assert (out[labels == 2] == 1).all() == joined
        assert (out[labels == 1] == 1).all() and (out[labels == 3] == 3).all()  # the two leaves stay two
        assert (join_occluded(labels, range_m, leaf, 6.0, 0.005, 9.0)[labels == 2] == 2).all()  # without fragments
    # a surface that is no leaf and larger than the leaf part it meets behind a twig (the branch the leaf lies on)
    range_m = np.where(gap, plane - 0.03, plane)
    big = labels.copy()
    big[5:35, 44:52] = 2
    big[labels == 1] = np.where(cols[labels == 1] >= 32, 1, 0)
    assert (join_occluded(big, range_m, leaf, 6.0, 0.005, 9.0, tip)[big == 2] == 2).all()


def test_join_occluded_joins_a_curved_leaf_behind_a_twig_on_the_planes_near_the_cut():
    rows, cols = np.mgrid[0:40, 0:60]
    curved = 3.0 + 0.001 * rows + 4e-5 * cols ** 2  # a leaf curving away: 14 cm deeper over 60 pixels
    labels = np.zeros(rows.shape, int)
    labels[5:35, 5:27], labels[5:35, 31:55] = 1, 2  # two parts 4 pixels apart
    gap = (cols >= 27) & (cols < 31)
    candidates = np.array([False, True, True])
    for between, joined in ((curved - 0.03, True),  # a twig in front: one leaf
                            (np.nan, False),  # nothing returns between them: two leaves
                            (curved + 0.05, False)):  # what lies behind shows between them
        range_m = np.where(gap, between, curved)
        # the whole parts' planes miss each other by centimetres: joined only on the planes within 9 pixels of the cut
        assert (join_occluded(labels, range_m, candidates, 6.0, 0.005)[labels == 2] == 2).all()
        assert (join_occluded(labels, range_m, candidates, 6.0, 0.005, 9.0)[labels == 2] == 1).all() == joined
    folded = 3.0 + 0.001 * rows + 1e-3 * np.abs(cols - 29)  # a fold at the cut: the planes near it disagree too
    range_m = np.where(gap, folded - 0.03, folded)
    assert (join_occluded(labels, range_m, candidates, 6.0, 0.005, 9.0)[labels == 2] == 2).all()



def test_join_occluded_gives_a_lobe_cut_at_a_neck_back_to_its_leaf_when_it_continues_the_leaf_plane():
    rows, cols = np.mgrid[0:40, 0:60]
    plane = 3.0 + 0.0005 * rows + 0.001 * cols + np.random.default_rng(0).normal(0.0, 0.001, rows.shape)
    labels = np.zeros(rows.shape, int)
    labels[5:35, 5:40] = 1  # the blade: 1,050 pulses
    labels[18:24, 40:48] = 2  # a lobe touching it, no leaf on its own: 48 pulses (4.6 %)
    leaf, lobe = np.array([False, True, False]), np.array([False, False, True])
    range_m = np.where(labels > 0, plane, np.nan)  # nothing returns around them: the gap test cannot join them
    out = join_occluded(labels, range_m, leaf, 6.0, 0.003, 9.0, lobe, 0.15)
    assert (out[labels == 2] == 1).all() and (out[labels == 1] == 1).all()
    assert (join_occluded(labels, range_m, leaf, 6.0, 0.003, 9.0, lobe)[labels == 2] == 2).all()  # lobe_ratio 0
    # a piece of twig at the blade's base: its round front bulges 8 mm out of the blade's plane
    bulge = 0.008 * np.sqrt(np.clip(1 - ((rows - 20.5) / 3.5) ** 2, 0, 1))
    twig = np.where(labels == 2, range_m - bulge, range_m)
    assert (join_occluded(labels, twig, leaf, 6.0, 0.003, 9.0, lobe, 0.15)[labels == 2] == 2).all()
    # a piece on the plane but holding 34 % of the blade's pulses (a branch the leaf lies against)
    big = labels.copy()
    big[5:35, 40:52] = 2
    range_m = np.where(big > 0, plane, np.nan)
    assert (join_occluded(big, range_m, leaf, 6.0, 0.003, 9.0, lobe, 0.15)[big == 2] == 2).all()
    # a lobe on the plane that does not touch the blade (background between them) is left to the gap test
    apart = labels.copy()
    apart[18:24, 40:42] = 0
    range_m = np.where(apart > 0, plane, np.nan)
    assert (join_occluded(apart, range_m, leaf, 6.0, 0.003, 9.0, lobe, 0.15)[apart == 2] == 2).all()


def _leaf_and_branch(twig_cols, leaf=True):
    """Ranges at 2 m of a leaf (7 x 9.6 cm) and a branch 2.1 cm across on its plane beside it, cut by 7.5 mm twigs
    3 cm in front (starting at ``twig_cols``), and the leaf's and branch's pixels."""
    rows, cols = np.mgrid[0:120, 0:330]
    plane = 2.0 + 0.0002 * rows + 0.0003 * cols
    blade = (((rows - 60) / 28.0) ** 2 + ((cols - 50) / 38.0) ** 2 <= 1) & leaf
    branch = (np.abs(rows - 60) <= 8) & (cols >= 95) & (cols < 320)
    twig = np.zeros(rows.shape, bool)
    for start in twig_cols:
        twig |= (cols >= start) & (cols < start + 6) & (np.abs(rows - 60) <= 40)
    noise = np.random.default_rng(1).normal(0, 0.0007, rows.shape)
    range_m = np.where(twig, plane - 0.03, np.where(blade | branch, plane, np.nan)) + noise
    return range_m, blade & ~twig, branch & ~twig


def test_a_leaf_joined_to_the_branch_piece_behind_its_twig_is_parted_again_and_branch_pieces_are_no_leaf():
    theta, psi = _grid(120, 330)
    # a twig between the leaf and a 15 cm piece of the branch (elongated: no leaf, smaller than the leaf): the
    # occluder join takes it into the leaf, whose group is then as elongated as wood; the leaf comes out alone
    range_m, blade, branch = _leaf_and_branch((89, 215))
    labels = segment_scan(range_m, theta, psi).leaves
    region, cover = _best_region(labels, blade)
    assert region > 0 and cover > 0.99 and not (labels[branch] > 0).any()
    # the branch alone, cut by four twigs into pieces 7 cm long (3 : 1, each leaf-shaped): joined they are
    # 13 : 1, pieces of one branch, none a leaf
    range_m, _, branch = _leaf_and_branch((89, 150, 211, 272), leaf=False)
    assert not (segment_scan(range_m, theta, psi).leaves[branch] > 0).any()


# --- small simulated canopies (0.036 deg, 2 m: a 9 cm leaf spans about 70 pulses) ------------------------------

LEAF = {"type": "leaf", "preset": "pear", "seed": 7, "length": 0.09, "material": "pear-leaf"}
WOOD = {"type": "cylinder", "length": 0.3, "material": {"reflectance": 0.4}}
CANOPIES = {
    # a second leaf 3 cm behind the first, half hidden by it
    "two-leaves": [{**LEAF, "name": "behind", "seed": 8,
                    "pose": {"center": [2.03, 0.035, 0.01], "facing": "scanner", "incidence_deg": 10}}],
    # a vertical branch (2.4 cm across) 5 cm behind the leaf
    "branch": [{**WOOD, "name": "branch", "radius": 0.012, "pose": {"translate": [2.05, 0.02, 0.0]}}],
    # a twig (6 mm across) 3 cm in front of the leaf, crossing it at 30 deg from vertical
    "twig": [{**WOOD, "name": "twig", "radius": 0.003,
              "pose": {"translate": [1.97, 0.01, 0.0], "rotate": {"axis": [1, 0, 0], "angle_deg": 60}}}],
    # a short piece of branch (4 cm long, 1.6 cm across: 2.5 : 1, as wide as a leaf) beside the leaf
    "stub": [{**WOOD, "name": "stub", "radius": 0.008, "length": 0.04, "pose": {"translate": [2.0, 0.07, 0.0]}}],
}
# the twig 4 cm in front of a curled leaf (bent and rolled 40 deg, at 30 deg): its two parts are on no common plane
_TWIG = CANOPIES["twig"][0]
CANOPIES["curled-twig"] = [{**_TWIG, "pose": {**_TWIG["pose"], "translate": [1.96, 0.01, 0.0]}}]
CURLED = {"curled-twig": ({"bend_deg": 40, "roll_deg": 40}, 30)}


@functools.lru_cache(maxsize=None)
def _canopy_scan(kind):
    shape, incidence = CURLED.get(kind, ({}, 10))
    objects = [{**LEAF, **shape, "name": "front",
                "pose": {"center": [2.0, 0, 0], "facing": "scanner", "incidence_deg": incidence}},
               *CANOPIES[kind]]
    spec = {"name": kind, "scanner": {"preset": "faro-ls880", "position": [0, 0, 0],
                                      "window": {"theta_deg": [-3.5, 3.5], "psi_deg": [87, 93], "step_deg": 0.036}},
            "objects": objects}
    scene = scenes.scene_from_spec(spec)
    scan = tlssim.simulate(scene, tlssim.setup_from_section(scene.scanner), seed=0, progress=False)
    alpha, _ = scan_alpha(scan.intensity, scan.range, simulated_calibration(scan.scanner.model))
    return scan, segment_scan(scan.range, scan.theta, scan.psi, alpha, intensity=scan.intensity).leaves


def _best_region(labels, pixels):
    values, counts = np.unique(labels[pixels], return_counts=True)
    counts = np.where(values > 0, counts, 0)
    return int(values[np.argmax(counts)]), counts.max() / pixels.sum()


@pytest.mark.parametrize("kind", sorted(CANOPIES))
def test_each_leaf_is_its_own_region_and_wood_is_none(kind):
    scan, labels = _canopy_scan(kind)
    regions = []
    for index, obj in enumerate(scan.object_names):
        pixels = scan.valid & (scan.truth_id == index)
        if obj in ("front", "behind"):
            region, cover = _best_region(labels, pixels)
            # found: one region covers at least half of its visible pulses (the front one nearly all of them)
            # (the twig cuts the front leaf in two: its parts are joined, on the planes near the cut when curled)
            assert region > 0 and cover >= (0.9 if obj == "front" else 0.5)
            # and that region is that leaf's: at most 5 % of it from other objects
            assert np.mean(scan.truth_id[labels == region] == index) > 0.95
            regions.append(region)
        else:  # wood keeps its measured points: (almost) none of them in a leaf region
            assert np.mean(labels[pixels] > 0) < 0.02
    assert len(set(regions)) == len(regions)


def test_a_leaf_behind_another_is_cut_the_front_one_is_whole():
    scan, labels = _canopy_scan("two-leaves")
    seen = visibility(labels, scan.range, 3 * range_noise(scan.range))
    front, _ = _best_region(labels, scan.valid & (scan.truth_id == scan.object_names.index("front")))
    behind, _ = _best_region(labels, scan.valid & (scan.truth_id == scan.object_names.index("behind")))
    assert not seen[front]["cut"] and seen[front]["occluded_fraction"] < 0.01
    assert seen[behind]["cut"] and not seen[behind]["border"] and seen[behind]["occluded_fraction"] > 0.1
    # a region touching the window's border is cut
    edge = np.zeros_like(labels)
    edge[:10, :10] = 1
    assert visibility(edge, scan.range, 0.005)[1] == {"occluded_fraction": 0.0, "border": True, "cut": True}


def test_a_pulse_straddling_two_leaves_is_shared_by_both_with_its_power_shares():
    scan, labels = _canopy_scan("two-leaves")
    alpha, _ = scan_alpha(scan.intensity, scan.range, simulated_calibration(scan.scanner.model))
    segmentation = segment_scan(scan.range, scan.theta, scan.psi, alpha, intensity=scan.intensity)
    front, behind = (scan.object_names.index(name) for name in ("front", "behind"))
    # the surfaces of each leaf (the one behind is cut into pieces by the one in front)
    pure = segmentation.mixed.surfaces
    surfaces = {obj: [k for k in np.unique(pure[scan.truth_id == obj]) if k > 0
                      and np.mean(scan.truth_id[pure == k] == obj) > 0.5] for obj in (front, behind)}
    second, fraction = scan.layers["truth_second_id"], scan.layers["second_fraction"]
    # the truth: pulses with 20-80 % of their power from each leaf
    truth_front = np.where(scan.truth_id == front, 1 - scan.mixed_fraction, np.where(second == front, fraction, 0))
    both = scan.valid & np.isin(scan.truth_id, [front, behind]) & np.isin(second, [front, behind]) \
        & (truth_front > 0.2) & (truth_front < 0.8) & (scan.mixed_fraction - fraction < 0.02)
    assert both.sum() > 30
    share_front, share_behind = (sum(segmentation.mixed.share_of(k) for k in surfaces[obj])[both]
                                 for obj in (front, behind))
    pair = segmentation.mixed.pair[both]
    paired = np.isin(pair, surfaces[front]).any(axis=1) & np.isin(pair, surfaces[behind]).any(axis=1)
    assert paired.mean() > 0.85  # attributed to both leaves, not deleted nor given whole to one (0.90)
    # those paired in the band around the leaves carry both power shares (0.59 of them, median error 0.035; the
    # rest were paired only by the thin-part pass, which gives them to neither leaf: a shortfall)
    shared = paired & ~segmentation.mixed.thin[both]
    assert shared.mean() > 0.5 and np.allclose((share_front + share_behind)[shared], 1.0)
    assert np.median(np.abs(share_front - truth_front[both])[shared]) < 0.1


def test_a_leaf_3_cm_in_front_of_a_branch_its_straddling_pulses_are_flagged_mixed_and_corrected():
    # 4 m, 0.018 deg (the FARO protocol's step): the footprint spans about 4 pulses, and the mixed ranges across the
    # leaf's outline ramp in steps within the noise; some are linked into the leaf or the branch as if pure
    objects = [{**LEAF, "name": "front", "pose": {"center": [4.0, 0, 0], "facing": "scanner", "incidence_deg": 10}},
               {**WOOD, "name": "branch", "radius": 0.012, "pose": {"translate": [4.042, 0.03, 0.0]}}]
    half = math.degrees(0.1 / 4.0)
    spec = {"name": "leaf-branch", "scanner": {"preset": "faro-ls880", "position": [0, 0, 0], "window": {
        "theta_deg": [-half, half], "psi_deg": [90 - half, 90 + half], "step_deg": 0.018}}, "objects": objects}
    scene = scenes.scene_from_spec(spec)
    scan = tlssim.simulate(scene, tlssim.setup_from_section(scene.scanner), seed=1, progress=False)
    front, branch = (scan.object_names.index(name) for name in ("front", "branch"))
    second, fraction = scan.layers["truth_second_id"], scan.layers["second_fraction"]
    share = np.where(scan.truth_id == front, 1 - scan.mixed_fraction, np.where(second == front, fraction, 0))
    # the truth: pulses with 10-90 % of their power from each, whose range is off the dominant one by over 6 mm
    straddling = scan.valid & np.isin(scan.truth_id, [front, branch]) & np.isin(second, [front, branch]) \
        & (share > 0.1) & (share < 0.9) & (np.abs(scan.range - scan.truth_range) > 0.006)
    assert straddling.sum() > 80
    result = reconstruct(scan, variant="fused", calibration=simulated_calibration(scan.scanner.model))
    # flagged mixed (outliers) and moved onto the surface that returned most of their power: 0.92, median 3.1 mm
    # off (12.0 mm measured); the edge test before the linking alone flags 0.87 of them, left 3.6 mm off
    assert result.outlier[straddling].mean() > 0.9
    assert np.nanmedian(np.abs(result.range - scan.truth_range)[straddling]) < 0.0034


def test_a_scan_without_leaves_is_reconstructed_and_its_wood_edges_corrected():
    # a branch 15 cm in front of a wall, no leaf: no leaf region, but the pulses straddling the branch's outline
    # go to the surface that dominates them as in a canopy (wall-dominated pulses off the wall by over 1 cm: 368
    # -> 0; before round 16 the scan was refused, and a tiled scan's leafless windows were left as measured)
    objects = [{**WOOD, "name": "branch", "radius": 0.02, "length": 0.4, "pose": {"translate": [2.0, 0, 0]}},
               {"name": "wall", "type": "plane", "size": [1.5, 1.0], "material": "wall",
                "pose": {"center": [2.15, 0, 0], "facing": "scanner"}}]
    spec = {"name": "branch-wall", "scanner": {"preset": "faro-ls880", "position": [0, 0, 0], "window": {
        "theta_deg": [-3, 3], "psi_deg": [87, 93], "step_deg": 0.036}}, "objects": objects}
    scene = scenes.scene_from_spec(spec)
    scan = tlssim.simulate(scene, tlssim.setup_from_section(scene.scanner), seed=0, progress=False)
    result = reconstruct(scan, variant="fused", calibration=simulated_calibration(scan.scanner.model))
    assert not result.leaves and not result.labels.any()
    wall = scan.truth_id == scan.object_names.index("wall")
    plane = 2.15 * scan.range / scan.xyz[..., 0]  # the wall's distance along each pulse's beam
    off = {name: int((wall & (np.abs(ranges - plane) > 0.01)).sum())
           for name, ranges in (("measured", scan.range), ("corrected", result.range))}
    assert off["measured"] > 200 and off["corrected"] < 0.05 * off["measured"]
    with pytest.raises(SfsError, match="mask selects none"):
        reconstruct(scan, mask=np.zeros(scan.shape, bool), calibration=simulated_calibration(scan.scanner.model))


def test_traits_carry_the_visible_area_and_whether_the_leaf_is_cut():
    scan, _ = _canopy_scan("two-leaves")
    result = reconstruct(scan, variant="buffer", calibration=simulated_calibration(scan.scanner.model))
    names = {}
    for leaf in result.leaves:
        owner = np.bincount(scan.truth_id[(result.labels == leaf.label) & scan.valid]).argmax()
        names.setdefault(scan.object_names[owner], []).append(leaf.traits)
    (front,) = names["front"]
    assert not front["cut"] and front["visible_area_m2"] == front["area_m2"]
    truth = {o.name: o.truth["area_m2"] for o in scenes.scene_from_spec(
        {"name": "x", "objects": [{**LEAF, "name": "front"}, *CANOPIES["two-leaves"]]}).objects}
    assert abs(front["area_m2"] / truth["front"] - 1) < 0.1
    # the leaf in front cuts the leaf behind in pieces: joined into one region (one plane, something nearer between
    # them), cut by the leaf in front, its visible area about half of the leaf's
    (behind,) = names["behind"]
    assert 0.3 < behind["visible_area_m2"] / truth["behind"] < 0.8
    assert behind["cut"] and behind["occluded_fraction"] > 0.2 and not behind["cut_by_border"]


def test_rim_shares_read_the_footprint_share_from_the_intensity_deficit():
    gain = 263.0
    region = np.zeros((30, 30), dtype=bool)
    region[5:25, 5:25] = True
    intensity = np.full(region.shape, 1400.0)
    outline = region & ~np.pad(region[1:-1, 1:-1] & region[:-2, 1:-1] & region[2:, 1:-1] & region[1:-1, :-2]
                               & region[1:-1, 2:], 1)
    intensity[outline] = 1400.0 + gain * math.log(0.4)  # 40 % of those footprints on the region
    share = rim_shares(region, intensity, gain, 2.5)
    assert np.allclose(share[outline], 0.4) and np.all(share[region & ~outline] == 1) and np.all(share[~region] == 0)
    # a brighter rim pulse (noise) counts once, not more; a region with no pulse deeper than the rim keeps 1
    intensity[5, 10] = 1500.0
    assert rim_shares(region, intensity, gain, 2.5)[5, 10] == 1.0
    assert np.all(rim_shares(region, intensity, gain, 30.0)[region] == 1.0)
    with pytest.raises(SfsError):
        rim_shares(region, intensity, 0.0, 2.5)


def test_a_leaf_with_nothing_behind_it_is_not_dilated_by_its_footprint():
    # the front leaf alone, no return around it: its outline pulses return its range with part of the power
    spec = {"name": "alone", "scanner": {"preset": "faro-ls880", "position": [0, 0, 0],
                                         "window": {"theta_deg": [-3.5, 3.5], "psi_deg": [87, 93], "step_deg": 0.036}},
            "objects": [{**LEAF, "name": "front", "pose": {"center": [2.0, 0, 0], "facing": "scanner",
                                                         "incidence_deg": 10}}]}
    scene = scenes.scene_from_spec(spec)
    scan = tlssim.simulate(scene, tlssim.setup_from_section(scene.scanner), seed=0, progress=False)
    result = reconstruct(scan, variant="fused", calibration=simulated_calibration(scan.scanner.model))
    (leaf,) = result.leaves
    # +0.2 %; counted whole, the outline pulses add about the perimeter times a footprint radius (+15 %)
    assert abs(leaf.traits["area_m2"] / scene.objects[0].truth["area_m2"] - 1) < 0.05


@pytest.mark.parametrize("incidence_deg, seed", [(40, 1), (50, 0)])
def test_a_leaf_of_thirty_pulses_at_a_coarse_step_is_one_region(incidence_deg, seed):
    # a 4 cm leaf 4 m away at 0.08 deg (7 mm between pulses, a footprint under one pulse): about 30 pulses, 4 to 6
    # across; its outline pulses, darkened by the part of their footprint off the leaf, made a 5 x 5 edge test's
    # surface darker than its plane (no leaf) in these draws; a 3 x 3 one sets them apart as edge pulses
    half = math.degrees(0.03)
    spec = {"name": "coarse", "scanner": {"preset": "faro-ls880", "position": [0, 0, 0], "window": {
                "theta_deg": [-half, half], "psi_deg": [90 - half, 90 + half], "step_deg": 0.08}},
            "objects": [{**LEAF, "name": "front", "length": 0.04,
                         "pose": {"center": [4.0, 0, 0], "facing": "scanner", "incidence_deg": incidence_deg}}]}
    scene = scenes.scene_from_spec(spec)
    scan = tlssim.simulate(scene, tlssim.setup_from_section(scene.scanner), seed=seed, progress=False)
    alpha, _ = scan_alpha(scan.intensity, scan.range, simulated_calibration(scan.scanner.model))
    labels = segment_scan(scan.range, scan.theta, scan.psi, alpha, intensity=scan.intensity).leaves
    pixels = scan.valid & (scan.truth_id == 0)
    assert 25 <= pixels.sum() <= 40
    region, cover = _best_region(labels, pixels)
    assert region > 0 and cover >= 0.75


def test_join_occluded_joins_two_touching_leaf_surfaces_on_one_plane_and_not_two_leaves_at_an_angle():
    rows, cols = np.mgrid[0:40, 0:70]
    noise = np.random.default_rng(1).normal(0.0, 0.001, rows.shape)
    labels = np.zeros(rows.shape, int)
    labels[5:35, 5:40] = 1  # the blade: 1,050 pulses
    labels[8:32, 40:55] = 2  # a piece of it split off (a neck or crease cut): 360 pulses, 34 %
    leaf = np.array([False, True, True])
    plane = 3.0 + 0.0005 * rows + 0.001 * cols + noise
    range_m = np.where(labels > 0, plane, np.nan)  # nothing returns around them: the gap test cannot join them
    out = join_occluded(labels, range_m, leaf, 6.0, 0.003, 9.0, piece_ratio=0.5)
    assert (out[labels > 0] == 1).all()
    assert (join_occluded(labels, range_m, leaf, 6.0, 0.003, 9.0)[labels == 2] == 2).all()  # piece_ratio 0
    assert (join_occluded(labels, range_m, leaf, 6.0, 0.003, 9.0, piece_ratio=0.3)[labels == 2] == 2).all()
    # a second leaf meeting the first at the cut but turned 30 deg from it (range steepening away from the cut)
    turned = np.where(labels == 2, plane + np.tan(np.radians(30.0)) * 0.0009 * (cols - 39), plane)
    out = join_occluded(labels, np.where(labels > 0, turned, np.nan), leaf, 6.0, 0.003, 9.0, piece_ratio=0.5)
    assert (out[labels == 2] == 2).all()

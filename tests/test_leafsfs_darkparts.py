"""Tests of leafsfs.darkparts: bark joined to a leaf surface is cut off, a leaf that is merely dark stays whole."""
import math

import numpy as np

from leafsfs.darkparts import bark_surfaces, cylinder_fit, dark_parts, is_bark

STEP = math.radians(0.036)
NOISE_M = 0.0015  # range noise of a FARO-class scanner on a leaf at a few metres, m (assumption)
ROWS, COLS = 110, 160
RANGE_M = 2.0
PIXEL_M = RANGE_M * STEP
EXCESS = math.radians(20.0)


def _grid():
    theta, psi = np.meshgrid(STEP * (np.arange(COLS) - COLS / 2), np.pi / 2 + STEP * (np.arange(ROWS) - ROWS / 2))
    return theta, psi


def _dark(cos_incidence, share):
    """Incidence a leaf calibration reads from a Lambertian surface returning ``share`` of a leaf's power, rad."""
    return np.arccos(np.clip(share * cos_incidence, 0, 1))


def _leaf_and_branch(seed=0):
    """A leaf lying on a horizontal branch of 1.5 cm radius 2 m away, tangent to it 35 deg above its front (one
    range surface to the linking): the leaf, a plane inclined by 35 deg, hides the branch above that line, the
    branch shows below it down to 76 deg. The leaf reads its true incidence (with 4 deg of noise), the bark half a
    leaf's power (a darker reflectance). Returns ranges, alpha and the masks of the leaf and the branch."""
    rng = np.random.default_rng(seed)
    i, j = np.mgrid[:ROWS, :COLS]
    radius_px = 0.015 / PIXEL_M
    contact = math.radians(-35.0)
    axis_row = 75
    contact_row = axis_row + radius_px * math.sin(contact)
    sin_phi = (i - axis_row) / radius_px
    leaf = (np.hypot((i - 40) / 30, (j - 80) / 40) <= 1) & (i < contact_row)
    leaf |= (i >= 40) & (i < contact_row) & (np.abs(j - 80) <= 40)  # the blade down to the branch
    branch = (i >= contact_row) & (sin_phi < 0.97) & (j >= 10) & (j < 150)
    cos_phi = np.sqrt(np.clip(1 - sin_phi ** 2, 0, 1))
    contact_range = RANGE_M + 0.015 * (1 - math.cos(contact))
    range_m = np.full((ROWS, COLS), np.nan)
    range_m[leaf] = contact_range + (i[leaf] - contact_row) * PIXEL_M * math.tan(contact)
    range_m[branch] = RANGE_M + 0.015 * (1 - cos_phi[branch])
    range_m += NOISE_M * rng.standard_normal(range_m.shape)
    alpha = np.full((ROWS, COLS), np.nan)
    alpha[leaf] = np.abs(-contact + math.radians(4.0) * rng.standard_normal(leaf.sum()))
    alpha[branch] = _dark(cos_phi[branch], 0.5)
    return range_m, alpha, leaf, branch


def _cut(range_m, alpha):
    theta, psi = _grid()
    surfaces = np.isfinite(range_m).astype(int)
    return dark_parts(surfaces, np.array([False, True]), range_m, theta, psi, alpha, STEP, NOISE_M, EXCESS, 30)


def test_a_branch_sharing_a_leafs_range_surface_is_cut_off():
    range_m, alpha, leaf, branch = _leaf_and_branch()
    out, parents = _cut(range_m, alpha)
    assert len(parents) >= 1 and set(parents) == {1}
    cut = out >= 2
    assert cut[branch].mean() >= 0.8  # the bark, less its outline strip the opening keeps
    assert cut[leaf].mean() <= 0.01


def test_a_flat_leaf_dark_all_over_stays_whole():
    # a leaf seen through another leaf returns half its power everywhere: dark_surfaces' business, not cut
    range_m, alpha, leaf, _ = _leaf_and_branch()
    range_m = np.where(leaf, range_m, np.nan)
    alpha = np.where(leaf, _dark(np.ones(alpha.shape), 0.5), np.nan)
    out, parents = _cut(range_m, alpha)
    assert len(parents) == 0 and np.array_equal(out, np.isfinite(range_m).astype(int))


def test_a_flat_leaf_with_a_round_dark_patch_stays_whole():
    # a patch behind another leaf's edge: dark, but a plane and as broad as long (no wood shape)
    range_m, alpha, leaf, _ = _leaf_and_branch()
    range_m = np.where(leaf, range_m, np.nan)
    i, j = np.mgrid[:ROWS, :COLS]
    patch = leaf & (np.hypot(i - 40, j - 95) <= 15)
    alpha = np.where(patch, _dark(np.ones(alpha.shape), 0.5), np.where(leaf, alpha, np.nan))
    out, parents = _cut(range_m, alpha)
    assert len(parents) == 0 and np.array_equal(out, np.isfinite(range_m).astype(int))


def _branch_points(radius, rng, count=600, arc=1.2, length=0.1):
    """Points of a branch of ``radius`` seen from the side 4 m away (+-``arc`` rad about its front), m."""
    phi, along = rng.uniform(-arc, arc, count), rng.uniform(0, length, count)
    return np.stack([radius * np.sin(phi), 4 - radius * np.cos(phi) + NOISE_M * rng.standard_normal(count), along], 1)


def test_cylinder_fit_gives_a_branchs_radius_and_a_plane_no_evidence():
    rng = np.random.default_rng(1)
    evidence, radius, along, width = cylinder_fit(_branch_points(0.01, rng), NOISE_M)
    assert evidence > 100 and 0.7 * 0.01 < radius < 1.3 * 0.01 and along > 10 * radius
    assert 1.5 * 0.01 < width < 2.5 * 0.01
    plane = np.stack([rng.uniform(-0.02, 0.02, 600), 4 + NOISE_M * rng.standard_normal(600), rng.uniform(0, 0.1, 600)],
                     1)
    evidence, *_ = cylinder_fit(plane, NOISE_M)
    assert evidence < 25


def test_a_branch_is_bark_and_a_rolled_or_domed_leaf_is_not():
    rng = np.random.default_rng(2)
    assert is_bark(_branch_points(0.012, rng), NOISE_M)
    # a leaf 5 cm wide rolled by 0.5 rad at each margin: radius 5 cm, a width of 2 x 5 cm x sin(0.5)
    assert not is_bark(_branch_points(0.05, rng, arc=0.5, length=0.08), NOISE_M)
    # a dome of 2 cm radius (curved along as across): no straight branch
    u, v = rng.uniform(-0.012, 0.012, (2, 600))
    dome = np.stack([v, 4 + (u ** 2 + v ** 2) / 0.04 + NOISE_M * rng.standard_normal(600), u], 1)
    assert not is_bark(dome, NOISE_M)


def test_bark_surfaces_tests_only_the_candidates():
    range_m, alpha, leaf, branch = _leaf_and_branch()
    theta, psi = _grid()
    surfaces = np.where(leaf, 1, np.where(branch, 2, 0))
    assert list(bark_surfaces(surfaces, np.array([False, True, True]), range_m, theta, psi, NOISE_M)) == \
        [False, False, True]
    assert not bark_surfaces(surfaces, np.array([False, True, False]), range_m, theta, psi, NOISE_M).any()

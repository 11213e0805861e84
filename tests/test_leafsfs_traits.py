"""Leaf area at grazing incidence (leafsfs.traits): flat plates whose area is known."""

import math

import numpy as np
import pytest
from scipy import ndimage

from leafsfs.canopy import nearer_ring
from leafsfs.frame import local_frame
from leafsfs.traits import (_edge_secants, _grazing_differences, _quadratic_slope, background_spread, leaf_traits,
                             mixed_band)
from tlssim.pattern import beam_frame

STEP = math.radians(0.018)


def _tilted_plate(incidence_deg, distance_m=3.5, rows=90, cols=60):
    """Ranges of a plane through (distance, 0, 0) whose normal is tilted by the incidence about the horizontal."""
    theta, psi = np.meshgrid(STEP * (np.arange(cols) - cols / 2), np.pi / 2 + STEP * (np.arange(rows) - rows / 2))
    axis = beam_frame(theta, psi)[0]
    a = math.radians(incidence_deg)
    normal = np.array([-math.cos(a), 0.0, math.sin(a)])
    range_m = (normal @ [distance_m, 0.0, 0.0]) / (axis @ normal)
    return theta, psi, range_m, axis


def _traits_with_flattened_rim(theta, psi, range_m, region, rings):
    """Traits of ``region`` whose outer ``rings`` of pulses are mixed (share 0.5) with heights flattened towards the
    middle, as a biased correction of edge pulses leaves them; also the pulses' weights."""
    frame = local_frame(theta, psi, range_m, region)
    height = np.where(region, frame.height(range_m), np.nan)
    rim = region & ~ndimage.binary_erosion(region, iterations=rings)
    centre = np.nanmedian(height[region])
    height[rim] = centre + 0.3 * (height[rim] - centre)
    weight = np.where(rim, 0.5, region.astype(float))
    return leaf_traits(frame, height[frame.box], weight[frame.box], 0.005), weight


def test_area_of_a_flat_plate_at_80_deg_incidence_ignores_flattened_rim_heights():
    # A 14 x 50 pulse rectangle of a plate at 80 deg, 3.5 m away (a 7 cm leaf seen foreshortened): its area is
    # N r^2 dOmega / cos(80 deg). Its outermost 3 rings of pulses (mixed, share 0.5) got heights flattened towards
    # the middle, as a biased correction of edge pulses does: the slope from the pure pulses holds.
    theta, psi, range_m, axis = _tilted_plate(80.0)
    region = np.zeros(theta.shape, bool)
    region[38:52, 5:55] = True
    traits, weight = _traits_with_flattened_rim(theta, psi, range_m, region, rings=3)
    expected = np.sum(weight * range_m**2 * STEP**2 / np.abs(np.sum(axis * [-math.cos(math.radians(80)), 0,
                                                                             math.sin(math.radians(80))], -1)))
    assert traits["area_m2"] == pytest.approx(expected, rel=0.03)


@pytest.mark.parametrize("incidence_deg", [0.0, 60.0, 75.0, 80.0])
def test_area_of_a_noisy_flat_plate_is_that_of_its_pulses_whatever_the_incidence(incidence_deg):
    rng = np.random.default_rng(3)
    theta, psi, range_m, axis = _tilted_plate(incidence_deg)
    region = np.zeros(theta.shape, bool)
    region[10:80, 10:50] = True
    exact = np.sum(range_m[region] ** 2 * STEP**2 / math.cos(math.radians(incidence_deg)))
    noisy = range_m + 0.001 * rng.standard_normal(range_m.shape)
    frame = local_frame(theta, psi, noisy, region)
    height = np.where(region, frame.height(noisy), np.nan)
    traits = leaf_traits(frame, height[frame.box], region[frame.box].astype(float), 0.005)
    assert traits["area_m2"] == pytest.approx(exact, rel=0.05)


def _rolled_leaf(incidence_deg, curvature, distance_m=3.5, rows=120, cols=60):
    """Ranges and cosines of incidence of a plate tilted about the horizontal and rolled about the steep direction.

    The surface ``n.(p - p0) = curvature (p.y)^2`` (a parabolic trough, radius ``1 / (2 curvature)`` m) through
    ``p0 = (distance, 0, 0)``, its normal ``n`` at ``incidence_deg`` to the beam in the middle.
    """
    theta, psi = np.meshgrid(STEP * (np.arange(cols) - cols / 2), np.pi / 2 + STEP * (np.arange(rows) - rows / 2))
    u = beam_frame(theta, psi)[0]
    a = math.radians(incidence_deg)
    n = np.array([-math.cos(a), 0.0, math.sin(a)])
    # curvature (r u_y)^2 - r (u.n) + p0.n = 0: its positive root, in the form that holds where u_y = 0
    quad, lin, const = curvature * u[..., 1] ** 2, -(u @ n), n @ [distance_m, 0.0, 0.0]
    range_m = 2 * const / (-lin - np.sqrt(lin**2 - 4 * quad * const))
    grad = n - 2 * curvature * range_m[..., None] * u[..., 1:2] * np.array([0.0, 1.0, 0.0])
    return theta, psi, range_m, np.abs(np.sum(u * grad, -1)) / np.linalg.norm(grad, axis=-1)


@pytest.mark.parametrize("incidence_deg", [0.0, 75.0])
def test_area_of_a_rolled_leaf_takes_its_steeper_margins_from_the_curvature_of_its_pure_part(incidence_deg):
    # A leaf rolled to a 3.3 cm radius about the steep direction, its outer 10 rings of pulses mixed (share 0.5)
    # with heights flattened towards the middle: the margins' slopes come from the quadratic fitted to the pure
    # pulses (the nearest local plane's slope, flatter, lost 3 % at either incidence).
    theta, psi, range_m, cos_incidence = _rolled_leaf(incidence_deg, 15.0)
    region = np.zeros(theta.shape, bool)
    region[25:95, 5:55] = True
    traits, weight = _traits_with_flattened_rim(theta, psi, range_m, region, rings=10)
    assert traits["area_m2"] == pytest.approx(np.sum(weight * range_m**2 * STEP**2 / cos_incidence), rel=0.01)


def test_quadratic_slope_is_the_gradient_of_a_quadratic_height_field():
    rows, cols = np.indices((30, 40)).astype(float)
    height = 0.01 + 2e-3 * rows - 1e-3 * cols + 3e-5 * rows**2 - 2e-5 * rows * cols + 4e-5 * cols**2
    known = np.zeros(height.shape, bool)
    known[5:20, 8:30] = True
    slope = _quadratic_slope(np.where(known, height, np.nan), known)
    assert slope[..., 0] == pytest.approx(2e-3 + 6e-5 * rows - 2e-5 * cols, abs=1e-12)
    assert slope[..., 1] == pytest.approx(-1e-3 - 2e-5 * rows + 8e-5 * cols, abs=1e-12)


class _CosineCalibration:
    """Amplitude ``exp((I - I0) / k)`` proportional to the cosine of the incidence (a Lambertian leaf, fixed range)."""

    def __init__(self, i0, gain):
        self.i0, self.gain = i0, gain

    def alpha(self, intensity_dn, range_m):
        return np.arccos(np.clip(np.exp((np.asarray(intensity_dn) - self.i0) / self.gain), 0.0, 1.0))


@pytest.mark.parametrize("incidence_deg", [40.0, 75.0, 85.0])
def test_mixed_band_recovers_the_share_and_incidence_of_a_leaf_edge_over_a_wall(incidence_deg):
    # A footprint 0.1-0.9 on a leaf at the incidence (amplitude per unit beam cos), the rest on a wall facing the
    # scanner (amplitude 1.2, as bright as a leaf of 20 % more reflectance at normal incidence): the range gives the
    # leaf's power share, the intensity the total; share and secant come back exactly.
    gain, i0 = 100.0, 1500.0
    share = np.array([0.1, 0.3, 0.5, 0.7, 0.9])
    leaf, wall = math.cos(math.radians(incidence_deg)), 1.2
    total = share * leaf + (1 - share) * wall
    band = mixed_band(share * leaf / total, i0 + gain * np.log(total), np.full(5, i0 + gain * math.log(wall)),
                      np.full(5, 3.0), gain, _CosineCalibration(i0, gain))
    assert band[:, 0] == pytest.approx(share, rel=1e-9)
    assert band[:, 1] == pytest.approx(1.0 / leaf, rel=1e-6)


def test_mixed_band_is_unknown_without_the_other_surface_or_with_an_impossible_share():
    band = mixed_band(np.array([0.5, 0.5]), np.array([1500.0, 1600.0]), np.array([np.nan, 1500.0]), np.full(2, 3.0),
                      100.0, _CosineCalibration(1500.0, 100.0))
    assert np.isnan(band).all()  # no wall intensity; more total than the wall's half share explains: f < 0


def _plate_rim(incidence_deg: float, rows: slice, cols: slice, rings: int):
    """A tilted plate's region, frame and heights, its outer ``rings`` as mixed pulses of share 0.5."""
    theta, psi, range_m, axis = _tilted_plate(incidence_deg)
    region = np.zeros(theta.shape, bool)
    region[rows, cols] = True
    frame = local_frame(theta, psi, range_m, region)
    height = np.where(region, frame.height(range_m), np.nan)
    rim = region & ~ndimage.binary_erosion(region, iterations=rings)
    weight = np.where(rim, 0.5, region.astype(float))
    return theta, range_m, axis, frame, height, rim, weight


def _grazing_plate_rim():
    theta, range_m, axis, frame, height, rim, weight = _plate_rim(80.0, slice(38, 52), slice(5, 55), 3)
    cos_plate = np.abs(np.sum(axis * [-math.cos(math.radians(80)), 0, math.sin(math.radians(80))], -1))
    return theta, frame, height, rim, weight, cos_plate, range_m**2 * STEP**2


def test_a_grazing_plates_mixed_pulses_count_for_their_decomposed_share_at_the_larger_secant():
    # The 80 deg plate's outer 3 rings (share 0.5, flattened heights): given a decomposed share of 0.55 at 82 deg
    # (steeper than the plate), they count 0.55 / cos(82 deg) footprints; given 0.55 at 60 deg, the planes' secant.
    theta, frame, height, rim, weight, cos_plate, footprint = _grazing_plate_rim()
    for band_deg, secant in ((82.0, np.full(theta.shape, 1 / math.cos(math.radians(82)))), (60.0, 1 / cos_plate)):
        band = np.where(rim[..., None], [0.55, 1 / math.cos(math.radians(band_deg))], np.nan)
        traits = leaf_traits(frame, height[frame.box], weight[frame.box], 0.005, band[frame.box])
        expected = np.sum(np.where(rim, 0.55 * secant, weight / cos_plate) * footprint)
        assert traits["area_m2"] == pytest.approx(expected, rel=0.03)


def test_a_grazing_plates_mixed_pulses_count_at_most_twice_the_planes_area():
    # Share 0.9 at 87 deg would count the rings 0.9 / cos(87 deg) / (0.5 / cos(80 deg)) = 6 times what the planes
    # give them (a wrong background intensity): they count BAND_LEAF_CAP (2) times, the pure pulses as before.
    theta, frame, height, rim, weight, cos_plate, footprint = _grazing_plate_rim()
    band = np.where(rim[..., None], [0.9, 1 / math.cos(math.radians(87))], np.nan)
    with_band = leaf_traits(frame, height[frame.box], weight[frame.box], 0.005, band[frame.box])["area_m2"]
    planes = leaf_traits(frame, height[frame.box], weight[frame.box], 0.005)["area_m2"]
    pure = np.sum(np.where(rim, 0.0, weight / cos_plate) * footprint)
    assert with_band - planes == pytest.approx(planes - pure, rel=0.03)  # the rings' area doubled, nothing more


@pytest.mark.parametrize("incidence_deg", [40.0, 65.0])
def test_mixed_pulses_of_a_plate_below_70_deg_keep_the_planes_area(incidence_deg):
    # Below 70 deg the planes' area is right; a noisy intensity secant (here 85 deg) must not raise it.
    _, _, _, frame, height, rim, weight = _plate_rim(incidence_deg, slice(20, 70), slice(10, 50), 2)
    band = np.where(rim[..., None], [0.7, 1 / math.cos(math.radians(85))], np.nan)
    with_band = leaf_traits(frame, height[frame.box], weight[frame.box], 0.005, band[frame.box])
    assert with_band["area_m2"] == pytest.approx(leaf_traits(frame, height[frame.box], weight[frame.box],
                                                             0.005)["area_m2"], rel=1e-12)


def test_background_spread_is_the_other_surfaces_intensity_spread_in_the_band():
    # Surface 2 (right half) alternates 1000 / 1040 DN column by column (standard deviation 20 DN), surface 3 (the
    # bottom right corner) is flat at 900 DN; each pulse asks for one of them within 1 pixel, on the grid's border
    # too, and a surface with no pulse near is unknown (infinite).
    surfaces = np.zeros((6, 8), int)
    surfaces[:, 4:] = 2
    surfaces[4:, 6:] = 3
    intensity = np.where(np.arange(8) % 2 == 0, 1000.0, 1040.0) * np.ones((6, 1))
    intensity[surfaces == 3] = 900.0
    intensity[0, 5] = np.nan  # no return: no part of the spread
    other = np.full((6, 8), 2)
    other[5, 7] = 3
    other[0, 0] = 3
    spread = background_spread(surfaces, intensity, other, (slice(None), slice(None)), 1)
    assert spread[2, 4] == pytest.approx(20.0)  # columns 4 (1000) and 5 (1040), three rows each
    assert spread[2, 3] == pytest.approx(0.0)  # column 4 alone
    assert spread[5, 7] == pytest.approx(0.0)
    assert np.isinf(spread[0, 0]) and np.isinf(spread[2, 1])
    window = background_spread(surfaces, intensity, other[1:4, 3:6], (slice(1, 4), slice(3, 6)), 1)
    assert window == pytest.approx(spread[1:4, 3:6])


def _pleated_plate(incidence_deg, amplitude_m, wavelength_px, fine=5, distance_m=3.5, rows=90, cols=60):
    """A plate tilted about the horizontal, its range rippled across the columns (pleats along the steep direction).

    Returns the angles and ranges of the scan's pulses and the exact area of the pulses ``[10:80, 10:50]``: the sum
    of the surface's area elements on a grid ``fine`` times finer (their solid angles together are the pulses').
    """
    r_idx = (np.arange(rows * fine) - rows * fine / 2) / fine
    c_idx = (np.arange(cols * fine) - cols * fine / 2) / fine
    theta, psi = np.meshgrid(STEP * c_idx, np.pi / 2 + STEP * r_idx)
    u = beam_frame(theta, psi)[0]
    a = math.radians(incidence_deg)
    normal = np.array([-math.cos(a), 0.0, math.sin(a)])
    range_m = (normal @ [distance_m, 0.0, 0.0]) / (u @ normal) + amplitude_m * np.sin(2 * np.pi * c_idx / wavelength_px)
    d_row, d_col = np.gradient(u * range_m[..., None], axis=(0, 1))
    element = np.linalg.norm(np.cross(d_row, d_col), axis=-1)
    half = fine // 2
    exact = element[10 * fine - half:80 * fine - half, 10 * fine - half:50 * fine - half].sum()
    return theta[::fine, ::fine], psi[::fine, ::fine], range_m[::fine, ::fine], exact


def _pleated_traits(incidence_deg, amplitude_m):
    rng = np.random.default_rng(3)
    theta, psi, range_m, exact = _pleated_plate(incidence_deg, amplitude_m, 6)
    region = np.zeros(theta.shape, bool)
    region[10:80, 10:50] = True
    noisy = range_m + 0.001 * rng.standard_normal(range_m.shape)
    frame = local_frame(theta, psi, noisy, region)
    height = np.where(region, frame.height(noisy), np.nan)
    return frame, height[frame.box], region[frame.box].astype(float), exact


def test_a_grazing_pleated_leaf_counts_its_pleats_from_the_differences_of_its_heights():
    # Pleats of 2 mm amplitude every 6 pulses on a plate at 80 deg, 3.5 m away, 1 mm range noise: the local planes
    # (2 pulses' smoothing) flatten the pleats and lost 2.4 % of the area; the differences between neighbours keep
    # them (and the noise inflates them by under 1 %).
    frame, height, weight, exact = _pleated_traits(80.0, 0.002)
    assert leaf_traits(frame, height, weight, 0.005)["area_m2"] == pytest.approx(exact, rel=0.01)


@pytest.mark.parametrize("incidence_deg", [0.0, 60.0])
def test_a_leaf_below_78_deg_keeps_the_planes_area(incidence_deg, monkeypatch):
    # Below 78 deg the noise of the differences would inflate the area: the planes' elements stand, pleats or not.
    frame, height, weight, _ = _pleated_traits(incidence_deg, 0.002)
    area = leaf_traits(frame, height, weight, 0.005)["area_m2"]
    monkeypatch.setattr("leafsfs.traits._grazing_differences",
                        lambda elements, height, pure, planes, noise_m, min_secant=None:
                        (planes, np.zeros(planes.shape[:-1])))
    assert area == leaf_traits(frame, height, weight, 0.005)["area_m2"]


def test_grazing_differences_are_the_gradient_of_a_linear_height_field_up_to_its_gaps():
    # h = 3 i - 2 j with holes: central differences inside, one-sided beside a hole or the border; a pulse with no
    # pure neighbour along an axis, or below the threshold secant, keeps the planes' element.
    rows, cols = np.indices((7, 9)).astype(float)
    height = 3.0 * rows - 2.0 * cols
    pure = np.ones(height.shape, bool)
    pure[3, 4] = pure[0, 1] = pure[1, 1] = False  # pulse (1, 0) has no pure neighbour along the columns
    pure[5, :] = False  # row 6's pulses and pulse (4, 4) have none along the rows
    elements = lambda slope: np.concatenate([slope, np.ones(slope.shape[:-1] + (1,))], axis=-1)
    planes = np.full(height.shape + (3,), 10.0)
    planes[0, 0] = [0.0, 0.0, 1.0]  # a facing pulse
    out, deviation = _grazing_differences(elements, height, pure, planes, 0.0)
    steep = pure & (np.arange(7)[:, None] != 6)
    steep[0, 0] = steep[1, 0] = steep[4, 4] = False
    assert out[steep] == pytest.approx(np.broadcast_to([3.0, -2.0, 1.0], (steep.sum(), 3)))
    assert out[~steep] == pytest.approx(planes[~steep])
    assert np.all(deviation == 0)


def test_grazing_differences_deviation_is_the_rise_of_the_norm_one_noise_deviation_steeper():
    # h = 3 i - 2 j, noise 0.1 per height: a pulse with central differences along both axes has slope noise 0.1 /
    # sqrt(2) in any direction, so its norm sqrt(1 + |g|^2) rises to sqrt(1 + (|g| + 0.1 / sqrt(2))^2); one at the
    # border has a one-sided difference (noise 0.1 sqrt(2)) along the rows, and its deviation is larger.
    rows, cols = np.indices((7, 9)).astype(float)
    height = 3.0 * rows - 2.0 * cols
    elements = lambda slope: np.concatenate([slope, np.ones(slope.shape[:-1] + (1,))], axis=-1)
    planes = np.full(height.shape + (3,), 10.0)
    out, deviation = _grazing_differences(elements, height, np.ones(height.shape, bool), planes, 0.1)
    gradient = math.sqrt(13.0)
    assert deviation[3, 4] == pytest.approx(math.sqrt(1 + (gradient + 0.1 / math.sqrt(2)) ** 2) - math.sqrt(14.0))
    assert deviation[0, 4] > deviation[3, 4]


def test_edge_secants_are_the_steepest_pure_secant_beside_the_nearest_pure_pulse():
    # Pure pulses in rows 1-3, columns 1-4 with secants 2 + column / 10, one steeper (9) at (1, 4): a pulse outside
    # takes the largest secant of the 3 x 3 around the pure pulse nearest to it.
    secant = 2.0 + 0.1 * np.indices((6, 7))[1]
    secant[1, 4] = 9.0
    pure = np.zeros(secant.shape, bool)
    pure[1:4, 1:5] = True
    edge = _edge_secants(np.where(pure, secant, np.nan), pure, np.zeros(secant.shape))
    assert edge[5, 1] == pytest.approx(2.2)  # nearest pure (3, 1): columns 0-2 of rows 2-3 hold 2.1 and 2.2
    assert edge[0, 5] == pytest.approx(9.0)  # nearest pure (1, 4), itself the steepest
    assert edge[4, 4] == pytest.approx(2.4)  # nearest pure (3, 4): rows 2-3 of columns 3-4 (9 is two rows up)
    zeros = np.zeros(secant.shape)
    assert np.all(_edge_secants(secant, np.zeros(secant.shape, bool), zeros) == 0)


def test_edge_secants_give_up_the_expected_largest_of_their_noisy_neighbours():
    # Four pure pulses of equal secant 5 and noise 0.5: the largest of four noisy secants exceeds 5 by 1.029 noise
    # deviations on average (the expected largest of four standard normal deviates), which the edge gives up; a
    # single pure pulse, the largest of one, keeps its secant.
    pure = np.zeros((6, 6), bool)
    pure[2:4, 2:4] = True
    edge = _edge_secants(np.full(pure.shape, 5.0), pure, np.where(pure, 0.5, 0.0))
    assert edge[0, 0] == pytest.approx(5.0 - 1.029 * 0.5, abs=0.015)
    alone = np.zeros((5, 5), bool)
    alone[2, 2] = True
    assert _edge_secants(np.full(alone.shape, 5.0), alone, np.full(alone.shape, 0.5))[0, 0] == pytest.approx(5.0)


def test_a_flat_grazing_plates_band_of_known_share_counts_for_that_share_of_its_pulses():
    # A plate at 82 deg, 3.5 m away, its outer 3 rings mixed (share 0.5) at the plate's own heights: a flat leaf's
    # edge is as steep as its middle, and the band counts half of its pulses' footprints, no more.
    theta, range_m, axis, frame, height, rim, weight = _plate_rim(82.0, slice(30, 60), slice(5, 55), 3)
    cos_plate = np.abs(np.sum(axis * [-math.cos(math.radians(82)), 0, math.sin(math.radians(82))], -1))
    exact = np.sum(weight * range_m**2 * STEP**2 / cos_plate)
    assert leaf_traits(frame, height[frame.box], weight[frame.box], 0.005)["area_m2"] == pytest.approx(exact, rel=0.01)


def _kinked_plate(incidence_deg, margin_deg, kink_row, distance_m=3.5, rows=90, cols=60):
    """A plate at ``incidence_deg`` that turns, from row ``kink_row`` on, about a horizontal line to
    ``margin_deg`` (a margin curled edge-on); its ranges and cosines of incidence."""
    theta, psi = np.meshgrid(STEP * (np.arange(cols) - cols / 2), np.pi / 2 + STEP * (np.arange(rows) - rows / 2))
    u = beam_frame(theta, psi)[0]
    normals = [np.array([-math.cos(math.radians(a)), 0.0, math.sin(math.radians(a))])
               for a in (incidence_deg, margin_deg)]
    plate = (normals[0] @ [distance_m, 0.0, 0.0]) / (u @ normals[0])
    kink = u[kink_row, cols // 2] * plate[kink_row, cols // 2]  # the margin's plane holds the kink line
    margin = np.arange(rows)[:, None] >= kink_row
    range_m = np.where(margin, (normals[1] @ kink) / (u @ normals[1]), plate)
    return theta, psi, range_m, np.abs(np.where(margin, u @ normals[1], u @ normals[0]))


def test_a_grazing_leaf_curled_edge_on_at_its_margin_counts_its_band_at_the_margins_secant():
    # A plate at 80 deg whose margin (the last 4 pure rows and the 3 mixed rings beyond) is turned to 86 deg, the
    # mixed rings (share 0.5) at heights flattened towards the middle: the planes of the pure pulses give the band
    # about 80 deg and lost 2.9 % of the area; the margin's pure pulses' differences give it 86 deg.
    theta, psi, range_m, cos_incidence = _kinked_plate(80.0, 86.0, 54)
    region = np.zeros(theta.shape, bool)
    region[30:61, 5:55] = True
    traits, weight = _traits_with_flattened_rim(theta, psi, range_m, region, rings=3)
    assert traits["area_m2"] == pytest.approx(np.sum(weight * range_m**2 * STEP**2 / cos_incidence), rel=0.02)


@pytest.mark.parametrize("noise_spacings", [1.0, 2.0])
def test_a_noisy_flat_grazing_plates_band_rises_at_most_by_the_positive_part_of_its_noise(noise_spacings):
    # The 82 deg plate at 3.5 m, its outer 3 rings mixed (share 0.5), range noise of 1 and 2 pulse spacings: a flat
    # leaf's edge is as steep as its middle, so an unbiased edge secant, taken where it exceeds the planes', raises the
    # band by the mean positive part of its noise, at most 0.4 times the secant noise of a one-sided difference
    # (sqrt(2) noise over the height step of tan(82 deg) spacings); the plain largest of nine noisy secants rose by
    # 19 and 40 % of the band's area.
    theta, psi, range_m, axis = _tilted_plate(82.0)
    region = np.zeros(theta.shape, bool)
    region[30:60, 5:55] = True
    rim = region & ~ndimage.binary_erosion(region, iterations=3)
    weight = np.where(rim, 0.5, region.astype(float))
    cos_plate = np.abs(np.sum(axis * [-math.cos(math.radians(82)), 0, math.sin(math.radians(82))], -1))
    exact = np.sum(np.where(rim, weight, 0.0) * range_m**2 * STEP**2 / cos_plate)
    noisy = range_m + noise_spacings * 3.5 * STEP * np.random.default_rng(0).standard_normal(range_m.shape)
    frame = local_frame(theta, psi, noisy, region)
    height, w = np.where(region, frame.height(noisy), np.nan)[frame.box], weight[frame.box]
    # the band's count: the area less that with the band's shares (almost) nil, the pure pulses' area alike
    band = (leaf_traits(frame, height, w, 0.005)["visible_area_m2"]
            - leaf_traits(frame, height, np.where(w < 1, 1e-9 * w, w), 0.005)["visible_area_m2"])
    assert 1.0 <= band / exact <= 1.0 + 0.4 * math.sqrt(2.0) * noise_spacings / math.tan(math.radians(82.0))


def _bitten_leaf(cover_offset_m):
    """An elliptic leaf (8 x 3.5 cm) on a plate at 30 deg and 3.5 m, the part of its left half between two rows
    replaced by a second leaf ``cover_offset_m`` nearer (< 0) or farther (> 0); a wall 0.5 m behind. Returns the
    traits of the region left, the area the whole leaf has by :func:`leaf_traits` and the region's share of it."""
    theta, psi, range_m, _ = _tilted_plate(30.0, rows=90, cols=50)
    rows, cols = np.mgrid[:90, :50]
    leaf = ((rows - 45) / 36.0) ** 2 + ((cols - 25) / 16.0) ** 2 <= 1
    cover = (cols < 21) & (rows >= 30) & (rows < 58)
    measured = np.where(leaf & ~cover, range_m, range_m + 0.5)
    measured = np.where(cover, range_m + cover_offset_m, measured)
    region = leaf & ~cover

    def traits(region, nearer):
        frame = local_frame(theta, psi, measured, region)
        height = np.where(region, frame.height(measured), np.nan)
        return leaf_traits(frame, height[frame.box], region[frame.box].astype(float), 0.005,
                           nearer=None if nearer is None else nearer[frame.box])

    whole_range = np.where(leaf, range_m, measured)
    whole_frame = local_frame(theta, psi, whole_range, leaf)
    whole = leaf_traits(whole_frame, np.where(leaf, whole_frame.height(whole_range), np.nan)[whole_frame.box],
                        leaf[whole_frame.box].astype(float), 0.005)["area_m2"]
    return traits(region, nearer_ring(region, measured, 0.003, None)), whole


def test_a_leaf_half_hidden_behind_a_nearer_leaf_is_completed_from_its_other_half():
    # a second leaf 4 cm in front hides a quarter of the left half: the slices it cuts short count twice their right
    # side, and the leaf's area is the whole leaf's to a few per cent (its visible area is 17 % short)
    traits, whole = _bitten_leaf(-0.04)
    assert traits["visible_area_m2"] < 0.9 * whole
    assert traits["occluded_slices"] > 0
    assert traits["area_m2"] == pytest.approx(whole, rel=0.03)


def test_a_bite_with_a_leaf_behind_it_is_not_completed():
    # the same outline, but the second leaf lies behind the gap: the cut is the leaf's own edge (eaten), nothing added
    traits, whole = _bitten_leaf(0.04)
    assert traits["occluded_slices"] == 0
    assert traits["area_m2"] == pytest.approx(traits["visible_area_m2"])
    assert traits["area_m2"] < 0.9 * whole


@pytest.mark.parametrize("margin_deg", [72.0, 80.0])
def test_a_leaf_at_72_deg_curled_edge_on_in_its_last_pure_rows_counts_its_band_at_the_margins_secant(margin_deg):
    # A plate at 72 deg, 3.5 m away, whose last 3 pure rows and the 3 mixed rows beyond (share 0.5, heights flattened
    # towards the middle) turn to 80 deg: the local planes at the band mix both slopes and lie below 78 deg, which
    # counted the band 22 % short; from 70 deg (EDGE_MIN_SECANT) the band takes the steepest of its edge's
    # differences. Unturned (72 deg throughout), the band keeps the plate's own secant.
    theta, psi, range_m, cos_incidence = _kinked_plate(72.0, margin_deg, 55)
    region = np.zeros(theta.shape, bool)
    region[20:61, 5:55] = True
    band = region & (np.arange(theta.shape[0])[:, None] >= 58)
    weight = np.where(band, 0.5, region.astype(float))
    frame = local_frame(theta, psi, range_m, region)
    height = np.where(region, frame.height(range_m), np.nan)
    centre = np.nanmedian(height[region])
    height[band] = centre + 0.3 * (height[band] - centre)
    h, w = height[frame.box], weight[frame.box]
    counted = (leaf_traits(frame, h, w, 0.005)["visible_area_m2"]
               - leaf_traits(frame, h, np.where(w < 1, 1e-9 * w, w), 0.005)["visible_area_m2"])
    exact = np.sum(np.where(band, weight, 0.0) * range_m**2 * STEP**2 / cos_incidence)
    assert counted == pytest.approx(exact, rel=0.06)

"""Leaf area at grazing incidence (leafsfs.traits): flat plates whose area is known."""

import math

import numpy as np
import pytest
from scipy import ndimage

from leafsfs.frame import local_frame
from leafsfs.traits import _quadratic_slope, leaf_traits
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


@pytest.mark.parametrize("incidence_deg", [0.0, 60.0, 80.0])
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

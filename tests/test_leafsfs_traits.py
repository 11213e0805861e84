"""Leaf area at grazing incidence (leafsfs.traits): flat plates whose area is known."""

import math

import numpy as np
import pytest
from scipy import ndimage

from leafsfs.frame import local_frame
from leafsfs.traits import leaf_traits
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


def test_area_of_a_flat_plate_at_80_deg_incidence_ignores_flattened_rim_heights():
    # A 14 x 50 pulse rectangle of a plate at 80 deg, 3.5 m away (a 7 cm leaf seen foreshortened): its area is
    # N r^2 dOmega / cos(80 deg). Its outermost 3 rings of pulses (mixed, share 0.5) got heights flattened towards
    # the middle, as a biased correction of edge pulses does: the slope from the pure pulses holds.
    theta, psi, range_m, axis = _tilted_plate(80.0)
    region = np.zeros(theta.shape, bool)
    region[38:52, 5:55] = True
    frame = local_frame(theta, psi, range_m, region)
    height = np.where(region, frame.height(range_m), np.nan)
    rim = region & ~ndimage.binary_erosion(region, iterations=3)
    centre = np.nanmedian(height[region])
    height[rim] = centre + 0.3 * (height[rim] - centre)
    weight = np.where(rim, 0.5, region.astype(float))
    traits = leaf_traits(frame, height[frame.box], weight[frame.box], 0.005)
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

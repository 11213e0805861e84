"""Beam sampling: power weights, footprint size and the published footprint formula."""

import math

import numpy as np
import pytest

from tlssim.beam import footprint_axes_m, ring_counts, sample_beam
from tlssim.errors import ScanError
from tlssim.scanner import get_preset


@pytest.mark.parametrize("n", [1, 7, 19, 20, 37, 91, 200])
@pytest.mark.parametrize("profile", ["gaussian", "tophat"])
def test_weights_are_equal_power_cells_summing_to_one(n, profile):
    beam = sample_beam(n, profile)
    assert beam.count == n == sum(ring_counts(n))
    assert beam.weight.sum() == pytest.approx(1.0)
    assert np.allclose(beam.weight, 1.0 / n)
    assert beam.u[0] == beam.v[0] == 0.0  # the central sub-ray is on the axis


@pytest.mark.parametrize("profile", ["gaussian", "tophat"])
def test_second_moment_of_the_beam_is_kept(profile):
    # Gaussian exp(-2 r²) and a uniform unit disc both have E[r²] = 1/2 in
    # units of the 1/e² radius; only the central disc's share is dropped.
    for n in (19, 37, 91):
        beam = sample_beam(n, profile)
        second = float(np.sum(beam.weight * (beam.u**2 + beam.v**2)))
        assert second == pytest.approx(0.5, abs=1.5 / n**2)
        # isotropic: equal moments along both axes
        assert float(np.sum(beam.weight * beam.u**2)) == pytest.approx(second / 2, rel=1e-9, abs=1e-12)


def test_gaussian_cells_hold_their_power():
    # The radius of each ring must lie inside the ring's power bounds.
    n = 91
    beam = sample_beam(n)
    cumulative = np.cumsum([0] + ring_counts(n)) / n
    for k in range(1, beam.ring.max() + 1):
        r = np.hypot(beam.u, beam.v)[beam.ring == k][0]
        inside = 1 - math.exp(-2 * r**2)
        assert cumulative[k] < inside < cumulative[k + 1]


def test_published_footprint_values():
    # Sensors 2011 / thesis ch.6: 0.004 m at 0 deg and 0.046 m at 85 deg, 2.16 m;
    # digest table A.1 gives 4.1, 46.5 and 90.5 mm (10 m, 85 deg).
    model = get_preset("faro-ls880")
    assert footprint_axes_m(model, 2.16, 0.0)[0] == pytest.approx(4.06e-3, abs=0.05e-3)
    assert footprint_axes_m(model, 2.16, math.radians(85))[0] == pytest.approx(46.5e-3, abs=0.1e-3)
    assert footprint_axes_m(model, 10.0, math.radians(85))[0] == pytest.approx(90.5e-3, abs=0.1e-3)
    major, minor = footprint_axes_m(model, 1.0, 0.0)
    assert major == pytest.approx(minor) == pytest.approx(2 * 1.5e-3 + 2 * math.sin(math.radians(0.014)))
    with pytest.raises(ScanError, match="incidence"):
        footprint_axes_m(model, 2.0, math.radians(90))

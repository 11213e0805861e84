"""AM-CW ranging: phasor sums and hierarchical unwrapping."""

import math

import numpy as np
import pytest

from tlssim.ranging import phase_to_distance, unwrap_distance
from tlssim.scanner import SPEED_OF_LIGHT_M_S, get_preset


def _phasor(amplitudes, distances, freq):
    phase = 4 * math.pi * freq * np.asarray(distances) / SPEED_OF_LIGHT_M_S
    total = np.sum(np.asarray(amplitudes) * np.exp(1j * phase))
    return np.array([total.real]), np.array([total.imag])


@pytest.mark.parametrize(
    "freq, amplitudes, distances, expected",
    [  # two-return worked example of the prior-art digest (section 2.1)
        (1e6, (1, 1), (5.0, 10.0), 7.500),
        (10e6, (1, 0.3), (5.0, 10.0), 5.707),
        (10e6, (0.3, 1), (5.0, 10.0), 9.293),
    ],
)
def test_two_return_mixture(freq, amplitudes, distances, expected):
    assert phase_to_distance(*_phasor(amplitudes, distances, freq), freq)[0] == pytest.approx(expected, abs=1e-3)


def test_default_frequency_is_unambiguous_over_the_range():
    model = get_preset("faro-ls880")
    assert model.unambiguous_range_m >= model.max_range_m
    distances = np.linspace(0.6, 75.9, 50)
    for d in distances:
        assert phase_to_distance(*_phasor([1.0], [d], model.mod_freqs_hz[0]), model.mod_freqs_hz[0])[0] \
            == pytest.approx(d, abs=1e-9)


def test_hierarchical_unwrapping_recovers_pure_returns():
    freqs = (1.9e6, 15e6, 120e6)  # fine frequencies wrap every 10 m and 1.25 m
    for d in (0.61, 3.3, 12.7, 49.99, 75.0):
        phasors = [_phasor([1.0], [d], f) for f in freqs]
        assert unwrap_distance(phasors, freqs)[0] == pytest.approx(d, abs=1e-9)


def test_fine_frequencies_can_push_mixed_ranges_outside_the_two_surfaces():
    # Documented reason why the default model uses one coarse frequency.
    freqs = (1.9e6, 120e6)
    d = unwrap_distance([_phasor([1, 1], [2.0, 2.7], f) for f in freqs], freqs)[0]
    coarse = phase_to_distance(*_phasor([1, 1], [2.0, 2.7], freqs[0]), freqs[0])[0]
    assert 2.0 < coarse < 2.7
    assert not 2.0 <= d <= 2.7  # 2.97 m: the fine phases differ by more than pi

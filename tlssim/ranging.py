"""AM-CW ranging: distance from the phase of the summed return phasor.

For every modulation frequency ``f`` a pulse's return is the phasor sum over
its sub-rays ``S_f = sum_k P_k·exp(i·4·pi·f·d_k / c)``. The phase gives the
distance modulo ``c / (2 f)``; the lowest frequency is unambiguous over the
scanner's range and each finer one is unwrapped against the previous
estimate (hierarchical unwrapping). A footprint split between two surfaces
therefore yields an intermediate distance, as a phase-shift scanner does.
"""

from __future__ import annotations

import numpy as np

from tlssim.scanner import SPEED_OF_LIGHT_M_S


def phase_to_distance(real: np.ndarray, imag: np.ndarray, freq_hz: float) -> np.ndarray:
    """Distance modulo the ambiguity interval ``c / (2 f)`` from a phasor.

    Parameters
    ----------
    real, imag : ndarray
        Real and imaginary parts of the summed phasor (any common shape and scale).
    freq_hz : float
        Modulation frequency ``f``, Hz.

    Returns
    -------
    ndarray
        Distance in ``[0, c / (2 f))``, m, shape of ``real``.
    """
    phase = np.mod(np.arctan2(imag, real), 2.0 * np.pi)
    return phase * SPEED_OF_LIGHT_M_S / (4.0 * np.pi * freq_hz)


def unwrap_distance(phasors: list[tuple[np.ndarray, np.ndarray]], freqs_hz: tuple[float, ...]) -> np.ndarray:
    """Distance from multi-frequency phasors by hierarchical unwrapping.

    Parameters
    ----------
    phasors : list of (real, imag)
        Summed phasor of every pulse at each frequency, in the order of
        ``freqs_hz``.
    freqs_hz : tuple of float
        Modulation frequencies in increasing order, Hz; the first one must
        be unambiguous over the range of interest.

    Returns
    -------
    ndarray
        Distance, m, from the finest frequency.
    """
    distance = phase_to_distance(*phasors[0], freqs_hz[0])
    for (real, imag), freq in zip(phasors[1:], freqs_hz[1:]):
        interval = SPEED_OF_LIGHT_M_S / (2.0 * freq)
        wrapped = phase_to_distance(real, imag, freq)
        distance = wrapped + interval * np.round((distance - wrapped) / interval)
    return distance

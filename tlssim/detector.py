"""Detector chain: from the summed return of a pulse to range and intensity.

This is the pluggable stage between the physics (phasor sums) and the digital
output. :func:`log_amplifier_dn` is the logarithmic amplifier of the FARO
LS880 class (thesis ch.6 eq. 1.2): ``I = I_ref + k·ln(P / P_ref)``, clipped to
``[0, intensity_max_dn]`` and quantised to integers, where ``P_ref`` is the
power returned by the model's reference target.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlssim.radiometry import reference_power
from tlssim.scanner import ScannerModel


@dataclass
class PulseReturns:
    """Summed returns of a set of pulses, before the detector.

    Attributes
    ----------
    distance_m : ndarray
        Distance from the phasor phase (unwrapped), m.
    amplitude : ndarray
        Magnitude of the summed phasor at the lowest frequency (received
        power, in the units of :func:`tlssim.radiometry.reference_power`).
    """

    distance_m: np.ndarray
    amplitude: np.ndarray


def log_amplifier_dn(model: ScannerModel, power: np.ndarray) -> np.ndarray:
    """Intensity in digital numbers of a received power (NaN where the power is not positive)."""
    power = np.asarray(power, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        dn = model.intensity_ref_dn + model.log_gain_dn * np.log(power / reference_power(model))
    dn = np.clip(np.round(dn), 0, model.intensity_max_dn)
    return np.where(power > 0, dn, np.nan).astype(np.float32)


def detect(model: ScannerModel, returns: PulseReturns, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Turn summed returns into measured range and intensity.

    Parameters
    ----------
    model : ScannerModel
        Scanner model (range limits, amplifier).
    returns : PulseReturns
        Summed returns of the pulses.
    rng : numpy.random.Generator
        Random stream for detector noise (unused by this noise-free chain).

    Returns
    -------
    range_m : ndarray, float64
        Measured distance, NaN where there is no return (no power, or a
        distance outside ``[min_range_m, max_range_m]``).
    intensity_dn : ndarray, float32
        Intensity, NaN where there is no return.
    """
    distance = returns.distance_m
    valid = (returns.amplitude > 0) & (distance >= model.min_range_m) & (distance <= model.max_range_m)
    range_m = np.where(valid, distance, np.nan)
    intensity = np.where(valid, log_amplifier_dn(model, returns.amplitude), np.nan).astype(np.float32)
    return range_m, intensity

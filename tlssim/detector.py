"""Detector chain: from the summed return of a pulse to range and intensity.

This is the pluggable stage between the physics (phasor sums) and the digital
output, and it runs per pulse in numpy on the whole (psi, theta) grid:

1. **Signal.** The amplifier sees the amplitude of the summed phasor at the
   lowest modulation frequency (``intensity_signal = "phasor"``: a mixed
   footprint keeps the log of its *total* amplitude) or the summed optical
   power (``"power"``).
2. **Amplitude noise and dropouts.** Gaussian noise on that signal
   (:func:`tlssim.noise.amplitude_noise_std`); a pulse whose noisy signal
   lies below the detection threshold (``min_signal_dn`` on the amplifier's
   scale) has no return, so dark, far and grazing targets lose points first.
3. **Log amplifier** (thesis ch.6 eq. 1.2): ``I = I_ref + k·ln(P / P_ref)``
   clipped to ``[0, intensity_max_dn]`` and rounded, where ``P_ref`` is the
   power of the model's reference target seen through the near-range
   attenuator.
4. **Range noise** (:func:`tlssim.noise.range_noise_std`, from the
   noise-free phasor amplitude), the range limits, and the optional on-board
   range filter: the mean of ``range_filter_length`` consecutive returns
   along the zenith axis (the instrument's "filtered" precision).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlssim.noise import amplitude_noise_std, range_noise_std
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
    power : ndarray
        Summed received power of the sub-rays (same units).
    """

    distance_m: np.ndarray
    amplitude: np.ndarray
    power: np.ndarray


def log_amplifier_dn(model: ScannerModel, power: np.ndarray) -> np.ndarray:
    """Intensity in digital numbers of a received power: ``I = I_ref + k·ln(P / P_ref)``.

    Clipped to ``[0, intensity_max_dn]`` and rounded.

    Parameters
    ----------
    model : ScannerModel
        Scanner model (``intensity_ref_dn``, ``log_gain_dn`` ``k``, ``intensity_max_dn``, reference target).
    power : array_like
        Received power (or phasor amplitude) ``P``, units of :func:`~tlssim.radiometry.reference_power`.

    Returns
    -------
    ndarray, float32
        Intensity, DN, shape of ``power`` (NaN where the power is not positive).
    """
    power = np.asarray(power, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        dn = model.intensity_ref_dn + model.log_gain_dn * np.log(power / reference_power(model))
    dn = np.clip(np.round(dn), 0, model.intensity_max_dn)
    return np.where(power > 0, dn, np.nan).astype(np.float32)


def detection_threshold(model: ScannerModel) -> float:
    """Smallest detectable signal: the power the amplifier maps to ``min_signal_dn``."""
    return reference_power(model) * float(np.exp((model.min_signal_dn - model.intensity_ref_dn) / model.log_gain_dn))


def detect(model: ScannerModel, returns: PulseReturns, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Turn summed returns into measured range and intensity.

    Parameters
    ----------
    model : ScannerModel
        Scanner model (amplifier, noise, threshold, range limits, filter).
    returns : PulseReturns
        Summed returns of the pulses on the (psi, theta) grid (rows = psi).
    rng : numpy.random.Generator
        Random stream of the detector noise; two standard-normal draws per
        pulse (amplitude, then range), so the same stream gives the same bytes.

    Returns
    -------
    range_m : ndarray, float64
        Measured distance, NaN where there is no return (signal below the
        threshold, or a distance outside ``[min_range_m, max_range_m]``).
    intensity_dn : ndarray, float32
        Intensity, NaN where there is no return.
    """
    shape = np.shape(returns.amplitude)
    amplitude_noise = rng.standard_normal(shape, dtype=np.float32)
    return detect_with_noise(model, returns, amplitude_noise, rng.standard_normal(shape, dtype=np.float32))


def detect_with_noise(model: ScannerModel, returns: PulseReturns, amplitude_noise: np.ndarray,
                      range_noise: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`detect` with the standard-normal noise draws given.

    Parameters
    ----------
    model : ScannerModel
        Scanner model (amplifier, noise, threshold, range limits, filter).
    returns : PulseReturns
        Summed returns of the pulses on the (psi, theta) grid (rows = psi).
    amplitude_noise, range_noise : ndarray
        Standard-normal draws, one per pulse (shape of the grid), scaled by
        the amplitude and range noise of each pulse.

    Returns
    -------
    range_m : ndarray, float64
        Measured distance, m, NaN where there is no return.
    intensity_dn : ndarray, float32
        Intensity, DN, NaN where there is no return.
    """
    signal = returns.amplitude if model.intensity_signal == "phasor" else returns.power
    noisy = signal + amplitude_noise_std(model, signal) * amplitude_noise
    with np.errstate(invalid="ignore"):
        range_m = returns.distance_m + range_noise_std(model, returns.amplitude) * range_noise
        valid = (signal > 0) & (noisy >= detection_threshold(model))
        valid &= (range_m >= model.min_range_m) & (range_m <= model.max_range_m)
    range_m = average_along_psi(np.where(valid, range_m, np.nan), model.range_filter_length)
    intensity = np.where(valid, log_amplifier_dn(model, np.where(valid, noisy, 0.0)), np.nan).astype(np.float32)
    return range_m, intensity


def average_along_psi(range_m: np.ndarray, length: int) -> np.ndarray:
    """Centred moving average of returned ranges along the zenith axis (rows).

    Each returned sample becomes the mean of the returned samples among the
    ``length`` consecutive rows centred on it (fewer at the window's ends);
    samples without a return stay NaN and do not count.

    Parameters
    ----------
    range_m : ndarray, shape (rows, cols)
        Ranges, NaN where there is no return.
    length : int
        Filter length, samples (1 returns the input).

    Returns
    -------
    ndarray, shape (rows, cols)
        Filtered ranges, m, NaN where there is no return.
    """
    if length == 1:
        return range_m
    valid = np.isfinite(range_m)
    rows = range_m.shape[0]
    sums = np.zeros((rows + 1,) + range_m.shape[1:])
    counts = np.zeros((rows + 1,) + range_m.shape[1:])
    np.cumsum(np.where(valid, range_m, 0.0), axis=0, out=sums[1:])
    np.cumsum(valid, axis=0, out=counts[1:])
    index = np.arange(rows)
    lo = np.maximum(index - (length - 1) // 2, 0)
    hi = np.minimum(index + length // 2 + 1, rows)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (sums[hi] - sums[lo]) / (counts[hi] - counts[lo])
    return np.where(valid, mean, np.nan)

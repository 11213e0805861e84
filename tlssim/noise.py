"""Measurement noise of the detector chain, as functions of the received signal.

Both noise models depend on the pulse's received amplitude ``A`` relative to
the amplitude ``A_ref`` of the model's reference target
(:func:`tlssim.radiometry.reference_power`), so that everything that lowers
the signal (low reflectance, distance, incidence, the near-range attenuator,
a footprint only partly on a surface) raises the noise:

- **range** (digest 7.11): ``sigma_d = sqrt((s0·(A/A_ref)**-gamma)**2 + floor**2)``.
  ``s0`` and ``gamma`` are fitted to the four raw datasheet precisions
  (:data:`tlssim.scanner.FARO_LS880_RAW_PRECISION`) by
  :func:`fit_range_noise`; the form generalises the digest's
  ``sigma0·(rho·cos(alpha)/d²)**-gamma`` from panels to any return.
- **amplitude** (digest 7.4): Gaussian noise on the received amplitude with
  ``sigma_A = (sigma_I0 / k)·A_ref·(A/A_ref)**(1 - e)``; with ``e = 0.5`` this
  is shot noise (``sigma_A ~ sqrt(A)``). Behind the log amplifier of gain ``k``
  it becomes ``sigma_I ~ sigma_I0·(A/A_ref)**-e`` DN while the signal is well
  above the noise, and it decides the dropouts near the detection threshold.
"""

from __future__ import annotations

import numpy as np

from tlssim.radiometry import reference_power, subray_power
from tlssim.scanner import ScannerModel


def range_noise_std(model: ScannerModel, amplitude: np.ndarray) -> np.ndarray:
    """Standard deviation of the range noise of pulses with received ``amplitude``.

    ``sigma_d = sqrt((s0·(A/A_ref)**-gamma)**2 + floor**2)`` (module docstring).

    Parameters
    ----------
    model : ScannerModel
        Scanner model (``range_noise_m``, ``range_noise_exponent``, ``range_noise_floor_m``, reference target).
    amplitude : array_like
        Received amplitude ``A``, units of :func:`~tlssim.radiometry.reference_power`.

    Returns
    -------
    ndarray, float64
        ``sigma_d``, m, shape of ``amplitude`` (inf where the amplitude is 0).
    """
    with np.errstate(divide="ignore"):
        scale = np.power(np.asarray(amplitude, dtype=np.float64) / reference_power(model), -model.range_noise_exponent)
    sigma = model.range_noise_m * scale
    return np.hypot(sigma, model.range_noise_floor_m) if model.range_noise_floor_m else sigma


def amplitude_noise_std(model: ScannerModel, amplitude: np.ndarray) -> np.ndarray:
    """Standard deviation of the noise on the received amplitude.

    ``sigma_A = (sigma_I0 / k)·A_ref·(A/A_ref)**(1 - e)`` (module docstring).

    Parameters
    ----------
    model : ScannerModel
        Scanner model (``intensity_noise_dn``, ``log_gain_dn``, ``intensity_noise_exponent``, reference target).
    amplitude : array_like
        Received amplitude ``A``, units of :func:`~tlssim.radiometry.reference_power`.

    Returns
    -------
    ndarray, float64
        ``sigma_A``, units of :func:`~tlssim.radiometry.reference_power`, shape of ``amplitude``.
    """
    ref = reference_power(model)
    ratio = np.asarray(amplitude, dtype=np.float64) / ref
    return (model.intensity_noise_dn / model.log_gain_dn) * ref * np.power(ratio, 1.0 - model.intensity_noise_exponent)


def panel_amplitude(model: ScannerModel, reflectance, distance_m, cos_incidence=1.0):
    """Received amplitude of a Lambertian target filling the whole beam.

    Parameters
    ----------
    model : ScannerModel
        Scanner model (radiometry: near-range attenuator).
    reflectance : float or array_like
        Lambertian reflectance of the target, in [0, 1].
    distance_m : float or array_like
        Distance from the scanner, m.
    cos_incidence : float or array_like
        Cosine of the incidence angle (1: perpendicular).

    Returns
    -------
    float or ndarray
        Amplitude, units of :func:`~tlssim.radiometry.reference_power` (broadcast shape of the inputs).
    """
    return subray_power(model, 1.0, reflectance, cos_incidence, np.asarray(distance_m, dtype=np.float64))


def fit_range_noise(model: ScannerModel, precision) -> tuple[float, float]:
    """Fit ``sigma = s0·(A/A_ref)**-gamma`` to precision figures of perpendicular panels.

    Parameters
    ----------
    model : ScannerModel
        Supplies the radiometry (attenuator, reference target).
    precision : sequence of (reflectance, distance_m, sigma_m)
        Published precision figures, e.g.
        :data:`tlssim.scanner.FARO_LS880_RAW_PRECISION`.

    Returns
    -------
    s0 : float
        Range noise at the reference signal, m.
    gamma : float
        Exponent (least squares of ``ln sigma`` against ``ln A``).
    """
    rho, distance, sigma = (np.array(column, dtype=float) for column in zip(*precision))
    log_ratio = np.log(panel_amplitude(model, rho, distance) / reference_power(model))
    slope, intercept = np.polyfit(log_ratio, np.log(sigma), 1)
    return float(np.exp(intercept)), float(-slope)

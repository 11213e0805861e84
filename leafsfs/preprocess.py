"""From scan intensities to the alpha image: distance correction and the intensity-incidence relation.

The calibration (thesis ch.6; :mod:`leafsfs.calibration`) corrects the
intensity for distance against the 99 % reference curve and inverts the
fitted intensity-incidence relation: ``alpha = calibration.alpha(intensity,
range)``, with ``calibration.reliable(...)`` false beyond its validity limit
(about 60 deg, tls-physics §7 item 13). Any object with those two methods can
serve; a path is read with :meth:`leafsfs.calibration.Calibration.load`.
Reconstruction never simulates: a calibration of a simulated scanner comes
from ``tlsbench experiment calibration`` (or
:func:`benchmarks.experiments.calibration.simulated_calibration`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from leafsfs.calibration import Calibration
from leafsfs.errors import SfsError


def resolve_calibration(calibration):
    """A calibration object from an object with ``alpha`` and ``reliable`` methods, or the path of its JSON file.

    Raises
    ------
    SfsError
        If no calibration is given, or it cannot be read.
    """
    if calibration is None or str(calibration) == "model":
        raise SfsError("PROP-SFS needs an intensity calibration: pass a leafsfs Calibration or the path of its JSON "
                       "file (measure one with 'tlssim calibrate' and 'leafsfs calibrate', or simulate one for a "
                       "scanner model with 'tlsbench experiment calibration')")
    if hasattr(calibration, "alpha") and hasattr(calibration, "reliable"):
        return calibration
    if not isinstance(calibration, (str, Path)):
        raise SfsError(f"calibration must be a Calibration or a JSON path, got {type(calibration).__name__}")
    return Calibration.load(calibration)


def scan_alpha(intensity: np.ndarray, range_m: np.ndarray, calibration) -> tuple[np.ndarray, np.ndarray]:
    """Incidence angle (rad, NaN where there is no return) and its reliability flag for every pixel.

    Parameters
    ----------
    intensity : ndarray
        Measured intensity per pixel, DN (NaN without return).
    range_m : ndarray
        Measured range per pixel, m (NaN without return).
    calibration : Calibration
        Inverse model with ``alpha(intensity, range)`` and ``reliable(intensity, range)``.

    Returns
    -------
    alpha : ndarray
        Incidence angle, rad, clipped to 0..pi/2; NaN without return.
    reliable : ndarray of bool
        Whether the angle is reliable (False without return).
    """
    valid = np.isfinite(intensity) & np.isfinite(range_m)
    alpha = np.full(np.shape(range_m), np.nan)
    reliable = np.zeros(np.shape(range_m), dtype=bool)
    alpha[valid] = np.clip(calibration.alpha(intensity[valid], range_m[valid]), 0.0, np.pi / 2)
    reliable[valid] = calibration.reliable(intensity[valid], range_m[valid])
    return alpha, reliable

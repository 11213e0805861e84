"""From scan intensities to the alpha image: distance correction and the intensity-incidence relation.

The calibration (thesis ch.6; :mod:`tlssim.calibration`) corrects the
intensity for distance against the 99 % reference curve and inverts the
fitted intensity-incidence relation: ``alpha = calibration.alpha(intensity,
range)``, with ``calibration.reliable(...)`` false beyond its validity limit
(about 60 deg, tls-physics §7 item 13). Any object with those two methods can
serve; a path is read with :meth:`tlssim.calibration.Calibration.load`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from leafsfs.errors import SfsError


def resolve_calibration(calibration, scan=None):
    """A calibration object from an object, a JSON path, or ``"model"`` (simulate the scan's scanner model).

    Raises
    ------
    SfsError
        If no calibration is given, or it cannot be read or built.
    """
    if calibration is None:
        raise SfsError("PROP-SFS needs an intensity calibration: pass a tlssim Calibration, the path of its JSON "
                       "file, or 'model' to calibrate the scan's own scanner model by simulation")
    if hasattr(calibration, "alpha") and hasattr(calibration, "reliable"):
        return calibration
    if not isinstance(calibration, (str, Path)):
        raise SfsError(f"calibration must be a Calibration, a JSON path or 'model', got {type(calibration).__name__}")
    from tlssim.calibration import Calibration, calibrate_model

    if str(calibration) == "model":
        if scan is None or not scan.scanner_model:
            raise SfsError("calibration 'model' needs a scan that records its scanner model")
        from tlssim.scanner import ScannerModel

        try:
            model = ScannerModel(**scan.scanner_model)
        except (TypeError, ValueError) as exc:
            raise SfsError(f"the scan's scanner model cannot be rebuilt for calibration ({exc})") from None
        return calibrate_model(model)
    try:
        return Calibration.load(calibration)
    except ValueError as exc:
        raise SfsError(str(exc)) from None


def scan_alpha(intensity: np.ndarray, range_m: np.ndarray, calibration) -> tuple[np.ndarray, np.ndarray]:
    """Incidence angle (rad, NaN where there is no return) and its reliability flag for every pixel."""
    valid = np.isfinite(intensity) & np.isfinite(range_m)
    alpha = np.full(np.shape(range_m), np.nan)
    reliable = np.zeros(np.shape(range_m), dtype=bool)
    alpha[valid] = np.clip(calibration.alpha(intensity[valid], range_m[valid]), 0.0, np.pi / 2)
    reliable[valid] = calibration.reliable(intensity[valid], range_m[valid])
    return alpha, reliable

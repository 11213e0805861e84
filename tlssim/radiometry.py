"""Received power of a sub-ray (first radiometry: Lambertian targets).

A sub-ray of power share ``w`` that hits a Lambertian surface of reflectance
``rho`` at incidence ``alpha`` and distance ``d`` returns the power (relative to
the emitted power, up to the constant receiver factor ``eta·A_R/pi``)::

    P = w · rho · cos(alpha) · g(d),    g(d) = 1 / d²

(the radar equation of the sources, thesis ch.1 eq. 1.3). The functions here
use arithmetic operators only, so they accept numpy arrays and Dr.Jit arrays
alike (the tracing kernel calls them on Dr.Jit arrays).
"""

from __future__ import annotations

from tlssim.scanner import ScannerModel


def range_gain(model: ScannerModel, distance_m):
    """Distance factor ``g(d)`` of the received power (``1/d²``), for ``d`` in metres."""
    return 1.0 / (distance_m * distance_m)


def subray_power(model: ScannerModel, weight, reflectance, cos_incidence, distance_m):
    """Received power of sub-rays (same units as :func:`reference_power`)."""
    return weight * reflectance * cos_incidence * range_gain(model, distance_m)


def reference_power(model: ScannerModel) -> float:
    """Received power of the model's intensity reference target (full beam, normal incidence)."""
    return float(subray_power(model, 1.0, model.intensity_ref_reflectance, 1.0, model.intensity_ref_range_m))

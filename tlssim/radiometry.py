"""Received power of a sub-ray: Lambertian (or BSDF) targets behind a near-range attenuator.

A sub-ray of power share ``w`` that hits a Lambertian surface of reflectance
``rho`` at incidence ``alpha`` and distance ``d`` returns the power (relative to
the emitted power, up to the constant receiver factor ``eta·A_R/pi``)::

    P = w · rho · cos(alpha) · g(d),    g(d) = A(d) / d²

(the radar equation of the sources, thesis ch.1 eq. 1.3, with the device
distance function of ch.6 eq. 1.2). ``A(d)`` is the transmission of the
near-range optical attenuator that keeps close targets from overexposing the
photodiode: ``A(d) = 1 / (1 + (d_f / d)**m)`` (``near_filter_range_m``,
``near_filter_exponent``) or a user table. It tends to 1 far away, so that
``g`` becomes ``1/d²`` beyond a few metres, and falls as ``(d / d_f)**m`` close
in, so that intensity is neither ``1/d²`` nor linear at short range.

The functions here use arithmetic operators and ``abs`` only, so they accept
numpy arrays and Dr.Jit arrays alike (the tracing kernel calls them on
Dr.Jit arrays, once per sub-ray).
"""

from __future__ import annotations

from tlssim.scanner import ScannerModel


def near_filter(model: ScannerModel, distance_m):
    """Transmission ``A(d)`` of the near-range attenuator, in (0, 1].

    Parameters
    ----------
    model : ScannerModel
        Scanner model (``near_filter_table``, or ``near_filter_range_m`` and ``near_filter_exponent``).
    distance_m : float or array
        Distance ``d``, m (numpy or Dr.Jit array).

    Returns
    -------
    float or array
        ``A(d)`` (dimensionless), same type and shape as ``distance_m``.
    """
    if model.near_filter_table:
        return _interpolate(model.near_filter_table, distance_m)
    ratio = model.near_filter_range_m / distance_m
    return 1.0 / (1.0 + ratio ** model.near_filter_exponent)


def range_gain(model: ScannerModel, distance_m):
    """Distance factor ``g(d) = A(d) / d²`` of the received power.

    Parameters
    ----------
    model : ScannerModel
        Scanner model (near-range attenuator).
    distance_m : float or array
        Distance ``d``, m (numpy or Dr.Jit array).

    Returns
    -------
    float or array
        ``g(d)``, m⁻², same type and shape as ``distance_m``.
    """
    return near_filter(model, distance_m) / (distance_m * distance_m)


def subray_power(model: ScannerModel, weight, reflectance, cos_incidence, distance_m):
    """Received power of sub-rays, ``P = w · rho · cos(alpha) · g(d)``.

    All array arguments broadcast against each other (numpy or Dr.Jit arrays).

    Parameters
    ----------
    model : ScannerModel
        Scanner model (near-range attenuator).
    weight : float or array
        Power share ``w`` of each sub-ray in its pulse (the shares of a pulse sum to 1).
    reflectance : float or array
        Reflectance ``rho`` (Lambertian, in [0, 1]) or the effective reflectance ``pi·f_r`` of a BSDF
        (:mod:`tlssim.bsdf`).
    cos_incidence : float or array
        Cosine of the incidence angle ``alpha``.
    distance_m : float or array
        Distance ``d``, m.

    Returns
    -------
    float or array
        ``P``, relative to the emitted power up to the receiver factor, m⁻² (the units of
        :func:`reference_power`).
    """
    return weight * reflectance * cos_incidence * range_gain(model, distance_m)


def reference_power(model: ScannerModel) -> float:
    """Received power of the model's intensity reference target (full beam, normal incidence, attenuator included)."""
    return float(subray_power(model, 1.0, model.intensity_ref_reflectance, 1.0, model.intensity_ref_range_m))


def _interpolate(table, x):
    """Piecewise-linear interpolation of ``((x_i, y_i), ...)``, constant beyond the ends.

    Written as a sum of clamped ramps, ``y_0 + sum_i s_i·(clamp(x, x_i, x_i+1) - x_i)``
    with ``clamp(x, a, b) - a = relu(x - a) - relu(x - b)``, so that it needs
    no comparisons or gathers and runs unchanged on Dr.Jit arrays.
    """
    result = table[0][1] + 0.0 * x
    for (x0, y0), (x1, y1) in zip(table, table[1:]):
        slope = (y1 - y0) / (x1 - x0)
        result = result + slope * (_relu(x - x0) - _relu(x - x1))
    return result


def _relu(x):
    return 0.5 * (x + abs(x))

"""The 3-D state of an iso-alpha curve, its initialisation on the seed boundary, and toggle points.

Thesis ch.5 §2 and ch.7 §1.5: the heights of the seed's outer curve come
from the range image (bilinear samples at the Euclidean points), low-pass
filtered along the closed curve (ideal FFT filter on the arc-length
resampled signal keeping harmonics ``k <= round(f_c L)``, with ``f_c =
peaks / l`` and ``l = 2 sqrt(pi a_seed)``: eq 3.4 and digest A12). The 3-D
tangents follow from the spectral derivative of the filtered heights (A31).
The greatest-slope signs come from local least-squares planes of radius 5 px
on the range image; where they change along the curve, the point whose
greatest slope is closest to the curve tangent becomes a toggle point (sign
0), after sign runs shorter than the toggle window are discarded as noise
(digest A10-A11).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leafsfs.curves import Curve
from leafsfs.grid import PixelGrid, bilinear, local_planes
from leafsfs.slope import cross2


@dataclass
class CurveState:
    """A 3-D iso-alpha curve: the inner curve of the next annulus.

    Attributes
    ----------
    points, points_px : ndarray, (n, 2)
        Positions in continuous and pixel coordinates, counter-clockwise.
    pixels : ndarray of int, (n, 2)
        Contour pixel of each point (crossing inspection).
    tangents : ndarray, (n, 2)
        Unit horizontal tangents.
    height : ndarray, (n,)
        Heights.
    gamma : ndarray, (n,)
        Elevation of the 3-D tangent, rad.
    sign : ndarray of int, (n,)
        Greatest-slope side: +1 left, -1 right, 0 toggle point.
    gradient : ndarray, (n, 2)
        Height gradient of the surface at the point (tangent plane).
    variance : ndarray, (n,)
        Height variance (fused variant), continuous units squared.
    vertex : ndarray of int, (n,)
        Mesh vertex index of each point.
    """

    points: np.ndarray
    points_px: np.ndarray
    pixels: np.ndarray
    tangents: np.ndarray
    height: np.ndarray
    gamma: np.ndarray
    sign: np.ndarray
    gradient: np.ndarray
    variance: np.ndarray
    vertex: np.ndarray

    def __len__(self) -> int:
        return len(self.points)


def lowpass_closed(values: np.ndarray, arc: np.ndarray, length: float, harmonics: int | None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Ideal low-pass of a signal along a closed curve and its arc-length derivative.

    Parameters
    ----------
    values : ndarray, (n,)
        Samples at the arc parameters ``arc`` (e.g. heights, m).
    arc : ndarray, (n,)
        Arc parameters of the samples, increasing in ``[0, length)``, continuous units.
    length : float
        Length of the closed curve, same units.
    harmonics : int or None
        Highest harmonic kept (``k`` cycles per curve length); None keeps all.

    Returns
    -------
    filtered, derivative : ndarray, (n,)
        The filtered signal and ``d/ds`` of it at ``arc`` (signal units per continuous unit).
    """
    n = len(values)
    uniform = np.arange(n) * length / n
    resampled = np.interp(uniform, arc, values, period=length)
    spectrum = np.fft.rfft(resampled)
    k = np.arange(len(spectrum))
    if harmonics is not None:
        spectrum[k > harmonics] = 0.0
    if n % 2 == 0:
        spectrum_d = spectrum.copy()
        spectrum_d[-1] = 0.0  # the Nyquist term has no well-defined derivative
    else:
        spectrum_d = spectrum
    filtered = np.fft.irfft(spectrum, n)
    derivative = np.fft.irfft(spectrum_d * (2j * np.pi * k / length), n)
    return np.interp(arc, uniform, filtered, period=length), np.interp(arc, uniform, derivative, period=length)


def mark_toggles(sines: np.ndarray, window: int) -> np.ndarray:
    """Greatest-slope signs along a closed curve with toggle points (0) where they change.

    Parameters
    ----------
    sines : ndarray, (n,)
        ``sin`` of the angle from the curve tangent to the descending
        direction (positive: descending direction on the left).
    window : int
        Sign runs shorter than ``window`` points are noise and take the sign
        of their neighbours; each remaining change gets one toggle, at the
        point within ``window`` points of it with the smallest ``|sines|``.

    Returns
    -------
    ndarray of int, (n,)
        +1 (descending direction on the left), -1 (on the right) or 0 (toggle point).
    """
    sign = np.where(sines >= 0, 1, -1)
    n = len(sign)
    for _ in range(n):
        changes = np.nonzero(sign != np.roll(sign, -1))[0]  # change between k and k+1
        if len(changes) < 2:
            break
        runs = np.diff(np.append(changes, changes[0] + n))  # run after each change
        short = np.nonzero(runs < max(window, 1))[0]
        if not len(short):
            break
        k = short[np.argmin(runs[short])]
        idx = np.arange(changes[k] + 1, changes[k] + 1 + runs[k]) % n
        sign[idx] = -sign[idx]
    changes = np.nonzero(sign != np.roll(sign, -1))[0]
    result = sign.copy()
    for c in changes:
        idx = np.arange(c - max(window, 1) + 1, c + max(window, 1) + 1) % n
        result[idx[np.argmin(np.abs(sines[idx]))]] = 0
    return result


def seed_harmonics(curve: Curve, seed_area_px: int, cutoff, peaks: int) -> int | None:
    """Highest harmonic kept on the seed curve: ``round(f_c L_px)`` (None: no filtering).

    Parameters
    ----------
    curve : Curve
        The seed's boundary curve (its length is measured in pixels, ``L_px``).
    seed_area_px : int
        Area of the seed region ``a_seed``, pixels.
    cutoff : "auto", float or None
        Cutoff ``f_c`` in cycles per pixel of arc; ``"auto"`` = ``peaks / l``
        with ``l = 2 sqrt(pi a_seed)`` (thesis eq 3.4); None: no filtering.
    peaks : int
        Number of peaks of the seed curve in the ``"auto"`` cutoff.

    Returns
    -------
    int or None
        Highest harmonic kept (cycles per curve length).
    """
    if cutoff is None:
        return None
    length_px = float(np.sum(np.linalg.norm(np.roll(curve.points_px, -1, axis=0) - curve.points_px, axis=1)))
    f_c = peaks / (2.0 * np.sqrt(np.pi * max(seed_area_px, 1))) if cutoff == "auto" else float(cutoff)
    return int(round(f_c * length_px))


def initial_state(curve: Curve, height: np.ndarray, valid: np.ndarray, grid: PixelGrid, harmonics: int | None,
                  lsr_radius_px: float, toggle_window: int) -> CurveState | None:
    """3-D state of the seed's outer curve from the range (height) image; None without valid heights.

    Parameters
    ----------
    curve : Curve
        The seed's boundary curve.
    height : ndarray, 2-D
        Measured heights (the range image in the local frame, m; NaN = none).
    valid : ndarray of bool, 2-D
        Pixels whose heights may be used.
    grid : PixelGrid
        Pixel-to-continuous map of ``height``.
    harmonics : int or None
        Highest harmonic kept by the low-pass along the curve (:func:`seed_harmonics`).
    lsr_radius_px : float
        Radius of the local least-squares planes that set the greatest-slope signs, pixels.
    toggle_window : int
        Sign runs shorter than this (points) are noise (:func:`mark_toggles`).

    Returns
    -------
    CurveState or None
        The seed curve's 3-D state, or None if fewer than 3 of its points have a height.
    """
    sampled = bilinear(height, valid, curve.points_px)
    good = np.isfinite(sampled)
    if good.sum() < 3:
        return None
    if not good.all():
        sampled = np.interp(curve.arc, curve.arc[good], sampled[good], period=curve.length)
    heights, slope = lowpass_closed(sampled, curve.arc, curve.length, harmonics)
    gamma = np.arctan(slope)
    planes = local_planes(height, valid, grid, curve.pixels, lsr_radius_px)
    gradient = np.where(np.isfinite(planes.gradient), planes.gradient, 0.0)
    norm = np.linalg.norm(gradient, axis=1)
    descending = -gradient / np.maximum(norm, 1e-300)[:, None]
    sines = np.where(norm > 0, cross2(curve.tangents, descending), 0.0)
    sign = mark_toggles(sines, toggle_window)
    n = len(curve)
    return CurveState(curve.points, curve.points_px, curve.pixels, curve.tangents, heights, gamma, sign, gradient,
                      np.zeros(n), np.full(n, -1))

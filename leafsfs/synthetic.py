"""PROP-SFS inputs from the analytic test surfaces of :mod:`scenes.surfaces` (thesis ch.5 experiments).

An analytic height field seen from +z with a Lambertian, hot-spot set-up
gives the alpha image (the angle between the normal and +z) and the height
image directly. Noise follows the digest's A14: i.i.d. uniform in ``[-A, A]``
per pixel from a seeded generator; a bias is added to alpha.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leafsfs.grid import PixelGrid


@dataclass
class SyntheticInput:
    """A sampled surface ready for :func:`leafsfs.engine.reconstruct_heights`.

    Attributes
    ----------
    alpha : ndarray, 2-D
        Incidence angle with noise and bias, rad (NaN off the support).
    height : ndarray, 2-D
        Height image with noise (the "range image" of the thesis' tests).
    truth : ndarray, 2-D
        Exact heights.
    mask : ndarray of bool, 2-D
        Pixels on the surface.
    grid : PixelGrid
        Pixel-to-surface coordinates: rows are the surface's y, columns its x.
    """

    alpha: np.ndarray
    height: np.ndarray
    truth: np.ndarray
    mask: np.ndarray
    grid: PixelGrid

    @property
    def height_range(self) -> float:
        """``h_max - h_min`` of the exact surface (the thesis' ``h_tot``, eq 3.1)."""
        values = self.truth[self.mask]
        return float(values.max() - values.min())


def sample_surface(surface, side: int, *, alpha_noise_deg: float = 0.0, alpha_bias_deg: float = 0.0,
                   height_noise: float = 0.0, seed: int = 0) -> SyntheticInput:
    """Sample a :class:`scenes.surfaces.HeightField` on a ``side x side`` grid of its domain.

    Parameters
    ----------
    surface : scenes.surfaces.HeightField
        The surface.
    side : int
        Pixels along each axis.
    alpha_noise_deg : float
        Amplitude ``A`` of the uniform alpha noise, degrees.
    alpha_bias_deg : float
        Bias added to alpha, degrees.
    height_noise : float
        Amplitude of the uniform height noise, as a fraction of ``h_max - h_min``.
    seed : int
        Seed of the noise generator.

    Returns
    -------
    SyntheticInput
    """
    x, y, h, mask = surface.sample(side, side)
    alpha = np.where(mask, surface.alpha(x, y), np.nan)
    truth = np.where(mask, h, np.nan)
    rng = np.random.default_rng(seed)
    alpha = alpha + np.radians(alpha_bias_deg + rng.uniform(-alpha_noise_deg, alpha_noise_deg, alpha.shape))
    span = float(np.nanmax(truth) - np.nanmin(truth))
    height = truth + height_noise * span * rng.uniform(-1.0, 1.0, truth.shape)
    (x0, x1), (y0, y1) = surface.domain
    dx, dy = (x1 - x0) / side, (y1 - y0) / side
    grid = PixelGrid(np.diag([dy, dx]), (y0 + dy / 2, x0 + dx / 2))
    return SyntheticInput(np.clip(alpha, 0.0, np.pi / 2), height, truth, mask, grid)


class LambertCalibration:
    """Exact inverse of the simulator's radiometric chain for a Lambertian target of assumed reflectance.

    ``I = I_ref + k ln(P / P_ref)`` with ``P = rho cos(alpha) g(d)``
    (:mod:`tlssim.detector`, :mod:`tlssim.radiometry`), solved for alpha.
    A stand-in for a fitted :class:`tlssim.calibration.Calibration` on
    simulated scans; an assumed reflectance different from the target's
    gives a biased calibration (used by ``leafsfs compare``).

    Parameters
    ----------
    model : ScannerModel or dict
        The scanner model (a scan's ``scanner_model``).
    reflectance : float
        Assumed reflectance of the targets (pear leaf: 0.48).
    limit_deg : float
        Validity limit of :meth:`reliable`, degrees.
    """

    def __init__(self, model, reflectance: float, limit_deg: float = 60.0):
        from tlssim.scanner import ScannerModel

        if isinstance(model, dict):
            known = {f for f in ScannerModel.__dataclass_fields__}
            model = ScannerModel(**{k: v for k, v in model.items() if k in known})
        self.model, self.reflectance, self.limit = model, float(reflectance), np.radians(limit_deg)

    def alpha(self, intensity_dn, range_m) -> np.ndarray:
        """Incidence from raw intensity and range, rad in [0, pi/2].

        Parameters
        ----------
        intensity_dn : array_like
            Raw intensities, DN.
        range_m : array_like
            Ranges, m (same shape).

        Returns
        -------
        ndarray
            Incidence angles, rad.
        """
        from tlssim.radiometry import range_gain, reference_power

        power = np.exp((np.asarray(intensity_dn, float) - self.model.intensity_ref_dn) / self.model.log_gain_dn) \
            * reference_power(self.model)
        cosine = power / (self.reflectance * range_gain(self.model, np.asarray(range_m, float)))
        return np.arccos(np.clip(cosine, 0.0, 1.0))

    def reliable(self, intensity_dn, range_m) -> np.ndarray:
        """Whether the incidence lies below the validity limit.

        Parameters
        ----------
        intensity_dn : array_like
            Raw intensities, DN.
        range_m : array_like
            Ranges, m (same shape).

        Returns
        -------
        ndarray of bool
            Whether :meth:`alpha` is below ``limit_deg``.
        """
        return self.alpha(intensity_dn, range_m) < self.limit

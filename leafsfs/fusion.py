"""The ``fused`` variant: Kalman fusion of intensity- and point-cloud-derived slopes and heights.

Not in the thesis: the FSPM 2013 abstract proposed it and the thesis left it
as future work (digest §6). The digest's minimal design fuses the greatest-
slope *azimuth*; this one fuses the full surface gradient and the height,
so that the point cloud also corrects the slope magnitude (a biased
intensity calibration) and the drift of the heights with the distance from
the seed, while the gates keep the mixed ("outlier") points out.

Per inner-curve point and annulus:

1. *Gradient prediction* from the intensity: ``g_p = s tan(alpha) d`` (eqs
   2.7-2.10), with covariance ``var_r = (sigma_alpha / cos^2 alpha)^2`` plus
   the spread of ``tan(alpha)`` over the annulus (the quantisation error of
   the one-alpha-per-domain model) along ``d`` and ``tan^2(alpha) var_phi``
   across it, ``var_phi`` from the
   linearisation of eq 2.7 in ``alpha`` and ``gamma`` (it grows without bound
   near toggle points, where the intensity says little about the azimuth).
2. *Gradient measurement*: the tangent plane of a least-squares quadratic
   surface fitted to the measured heights within ``lsr_radius_px`` (a plane,
   as in the thesis' sign initialisation, is biased by curvature), with the
   regression covariance plus a floor.
3. *Gate and update*: a fit whose residual RMS exceeds ``gate_sigma``
   times the range noise is rejected (mixed points spoil it); the others
   update ``g`` with the Kalman gain, whatever their disagreement with the
   prediction, so that a biased intensity calibration cannot lock the point
   cloud out (an innovation gate did: with the leaf reflectance mistaken by
   20 %, it rejected 99 % of the measurements). The ray follows the fused
   gradient (outward, or the curve normal if it is nearly tangent).
4. *Height*: predicted ``h' = h + g . (x' - x)`` with variance
   ``P + dx^T P_g dx``; measured ``Mh(x')`` with ``sigma_range^2``; a
   measurement is rejected when its innovation is beyond ``gate_sigma``
   standard deviations and it also leaves the quadratic surface of its
   neighbours' measured heights by more than ``gate_sigma`` range-noise
   deviations (these are the measured outliers; the innovation gate alone
   let the heights drift away for good once they passed it), otherwise the
   Kalman update moves the end
   height and the line's plane is tilted to reach it, so that the fill and
   the next curve follow.

After the propagation, :func:`noise_tails` refines the pure pulses: the
fused surface follows the measured heights (its error on the pure pulses of
the leafy tree at 0.018 deg scatters by 0.96 range-noise deviations, the
measurement's own), so it is no better estimate of a pure pulse than the
pulse; the plane of the pulse's neighbours is, where the pulse leaves it by
more than the noise explains.
"""

from __future__ import annotations

import math

import numpy as np

from leafsfs.grid import PixelGrid, bilinear, local_planes
from leafsfs.slope import outward_normal

#: Smallest gradient standard deviation of a measured plane (per unit), whatever its residuals say.
GRADIENT_FLOOR = 0.02
#: Radius of the plane fitted to a pure pulse's neighbours (:func:`noise_tails`), pixels.
TAIL_RADIUS_PX = 5.0
#: A pure pulse farther than this many range-noise deviations from its neighbours' plane is a noise tail.
TAIL_SIGMA = 2.0
#: Largest residual RMS of the neighbours' plane, in range-noise deviations, for it to stand for their surface.
TAIL_RMS_SIGMA = 1.5
#: Fewest neighbours the plane is fitted to (of the 81 pixels within :data:`TAIL_RADIUS_PX`).
TAIL_MIN_COUNT = 10


class Fusion:
    """Measurement model of the fused variant over one height image.

    Parameters
    ----------
    height : ndarray, 2-D
        Measured heights (the range image in the local frame).
    valid : ndarray of bool, 2-D
        Pixels whose heights may be used.
    grid : PixelGrid
        Pixel-to-continuous map of ``height``.
    params : SfsParams
        ``sigma_alpha_deg``, ``sigma_range_m``, ``gate_sigma``, ``lsr_radius_px``.
    """

    def __init__(self, height: np.ndarray, valid: np.ndarray, grid: PixelGrid, params):
        self.height, self.valid, self.grid = height, valid, grid
        self.sigma_alpha = math.radians(params.sigma_alpha_deg)
        self.sigma_range = params.sigma_range_m
        self.radius = params.lsr_radius_px
        self.gate_sigma = float(params.gate_sigma)
        self.stats = {"gradient_updates": 0, "gradient_rejected": 0, "height_updates": 0, "height_rejected": 0}

    def _pixels(self, points: np.ndarray) -> np.ndarray:
        return self.grid.to_pixels(points)

    def fuse_gradients(self, inner, alpha: float, alpha_spread: float, direction: np.ndarray, gradient: np.ndarray):
        """Fused directions, gradients and gradient covariances ``(n, 2, 2)`` for the inner curve's points.

        ``alpha_spread`` is the standard deviation of ``tan(alpha)`` over the
        annulus' pixels: one alpha stands for the whole domain, so the slope
        of the sand-pile model is uncertain by that much (quantisation error).

        Parameters
        ----------
        inner : leafsfs.seed.CurveState
            The inner 3-D curve of the annulus (points in continuous units, m in a scan's local frame).
        alpha : float
            Alpha of the annulus' domain, rad.
        alpha_spread : float
            Standard deviation of ``tan(alpha)`` over the annulus (dimensionless).
        direction : ndarray, (n, 2)
            Predicted unit horizontal propagation directions.
        gradient : ndarray, (n, 2)
            Predicted height gradients (height per continuous unit).

        Returns
        -------
        direction : ndarray, (n, 2)
            Fused unit propagation directions (unchanged at toggle points).
        gradient : ndarray, (n, 2)
            Fused height gradients.
        covariance : ndarray, (n, 2, 2)
            Their covariances (squared gradient units).
        """
        n = len(inner)
        t = inner.tangents
        tan_a = math.tan(max(alpha, 1e-3))
        ratio = np.clip(np.tan(np.abs(inner.gamma)) / tan_a, 0.0, 0.999)
        root = np.sqrt(1 - ratio**2)
        dphi_dgamma = (1 / np.cos(inner.gamma) ** 2) / tan_a / root
        dphi_dalpha = np.tan(np.abs(inner.gamma)) / math.cos(alpha) ** 2 / tan_a**2 / root
        var_phi = np.minimum((dphi_dgamma**2 + dphi_dalpha**2) * self.sigma_alpha**2, (math.pi / 2) ** 2)
        var_along = (self.sigma_alpha / math.cos(alpha) ** 2) ** 2 + alpha_spread**2
        var_across = tan_a**2 * var_phi
        across = np.stack([-direction[:, 1], direction[:, 0]], axis=1)
        prior = var_along * direction[:, :, None] * direction[:, None, :] \
            + var_across[:, None, None] * across[:, :, None] * across[:, None, :]
        prior[inner.sign == 0] = np.eye(2) * max(var_along, tan_a**2)
        centres = np.rint(self._pixels(inner.points)).astype(int)
        planes = local_planes(self.height, self.valid, self.grid, centres, self.radius, order=2)
        measured = np.isfinite(planes.gradient).all(axis=1) & (planes.count >= 10)
        fused, covariance = gradient.copy(), prior.copy()
        if measured.any():
            g_m = planes.gradient[measured]
            noise = planes.covariance[measured] + GRADIENT_FLOOR**2 * np.eye(2)
            total = prior[measured] + noise
            innovation = g_m - gradient[measured]
            # Gate on the fit's own consistency (mixed points spoil it), not on the disagreement with the
            # prediction: a biased calibration must not lock the point cloud out.
            accept = planes.rms[measured] <= self.gate_sigma * self.sigma_range
            try:
                inverse = np.linalg.inv(total)
            except np.linalg.LinAlgError:  # a prior so wide (alpha near 90 deg) that adding the noise rounds away
                inverse = np.linalg.pinv(total)
            gain = prior[measured] @ inverse
            update = gradient[measured] + np.einsum("nij,nj->ni", gain, innovation)
            index = np.nonzero(measured)[0][accept]
            fused[index] = update[accept]
            covariance[index] = (np.eye(2) - gain[accept]) @ prior[measured][accept]
            self.stats["gradient_updates"] += int(accept.sum())
            self.stats["gradient_rejected"] += int((~accept).sum())
        # Propagate along the fused gradient, outward; along the curve normal if it is nearly tangent.
        normal = outward_normal(t)
        norm = np.linalg.norm(fused, axis=1)
        unit = fused / np.maximum(norm, 1e-12)[:, None]
        unit *= np.where(np.sum(unit * normal, axis=1) >= 0, 1.0, -1.0)[:, None]
        tangent_like = (norm < 1e-9) | (np.sum(unit * normal, axis=1) < math.sin(math.radians(5)))
        new_direction = np.where(tangent_like[:, None], normal, unit)
        new_direction[inner.sign == 0] = direction[inner.sign == 0]
        return new_direction, fused, covariance

    def fuse_heights(self, lines, gradient_covariance: np.ndarray) -> None:
        """Kalman update of the lines' end heights with the measured heights there (in place).

        Parameters
        ----------
        lines : leafsfs.propagate.Lines
            The annulus' propagation lines; ``end_h``, ``end_variance`` and
            ``gradient`` are updated.
        gradient_covariance : ndarray, (n, 2, 2)
            Covariance of each line's gradient (squared height per continuous
            unit), from :meth:`fuse_gradients`.
        """
        step = lines.end - lines.start
        predicted_var = lines.end_variance + np.einsum("ni,nij,nj->n", step, gradient_covariance, step)
        measured = bilinear(self.height, self.valid, self._pixels(lines.end))
        ok = lines.valid & np.isfinite(measured)
        r = self.sigma_range**2
        innovation = measured - lines.end_h
        # A measurement is accepted when the prediction expects it (within ``gate_sigma`` deviations), or when it
        # agrees with the measured surface around it (within the gate of a quadratic surface of its neighbours that
        # fits them that well): once the propagated height had drifted beyond the gate, the innovation gate alone
        # rejected every later measurement and the drift grew unchecked from the seed outwards. A measured outlier
        # fails both.
        centres = np.rint(self._pixels(lines.end)).astype(int)
        planes = local_planes(self.height, self.valid, self.grid, centres, self.radius, order=2)
        local = planes.height + np.sum(planes.gradient * (lines.end - self.grid.to_continuous(centres)), axis=1)
        tolerance = self.gate_sigma * self.sigma_range
        with np.errstate(invalid="ignore"):
            consistent = (planes.count >= 10) & (planes.rms <= tolerance) & (np.abs(measured - local) <= tolerance)
            accept = ok & ((innovation**2 <= self.gate_sigma**2 * (predicted_var + r)) | consistent)
        gain = predicted_var / (predicted_var + r)
        change = np.where(accept, gain * innovation, 0.0)
        lines.end_h = lines.end_h + change
        lines.end_variance = np.where(accept, (1 - gain) * predicted_var, predicted_var)
        # Tilt each line's plane so that it reaches the updated end height: the fill, the outer curve and
        # the candidates all follow the plane.
        length = np.linalg.norm(step, axis=1)
        tilt = np.where(length > 1e-9, change / np.maximum(length, 1e-12), 0.0)
        lines.gradient = lines.gradient + tilt[:, None] * lines.direction
        self.stats["height_updates"] += int(accept.sum())
        self.stats["height_rejected"] += int((ok & ~accept).sum())


def noise_tails(height: np.ndarray, pure: np.ndarray, grid: PixelGrid, sigma_m: float,
                sigma_pulse_m: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Pure pulses in the tails of the range noise, and the height of their neighbours' plane there, m.

    Around every pure pulse a plane is fitted to the pure pulses within
    :data:`TAIL_RADIUS_PX` (:func:`leafsfs.grid.local_planes`), refitted
    without those farther than 3 of their own noise deviations
    (``sigma_pulse_m``) from the first plane. A pulse is a tail when it lies
    more than :data:`TAIL_SIGMA` ``sigma_m`` from that plane and the plane
    fits its neighbours within :data:`TAIL_RMS_SIGMA` ``sigma_m`` RMS (a
    rim, a fold or a mixed neighbour spoils it, and the pulse keeps its
    measurement): the plane's height, averaged over dozens of pulses, is
    then the more likely one. Measured on the leafy tree and conference pear
    seed 7 at 0.018 deg against the truth (their 231,918 / 377,055 leaf
    pulses that the segmentation takes for pure): pulses beyond the scored
    3-sigma threshold 2,910 / 4,781 measured, 2,847 / 4,666 after the fused
    surface's refine (``inliers="refine"`` before this test), 1,386 / 2,455
    after this test, which pushes 54 / 43 good pulses beyond it (radius 3 px:
    1,841 / 3,073 left, 36 / 39 pushed; 4 px with a 1.5-sigma test: 1,331 /
    2,424 left, 71 / 95 pushed). In the benchmark (``fused`` at 0.018 deg,
    mean per-leaf ROP reduction 3 sigma, before -> after): leafy tree 0.623
    -> 0.633, pear seed 7 at 3 m 0.634 -> 0.645, seed 23 at 4 m 0.642 ->
    0.653; not tuned on: seed 31 at 2.5 m 0.671 -> 0.680, seed 41 at 5 m
    0.639 -> 0.651; good points lost unchanged.

    Parameters
    ----------
    height : ndarray, 2-D
        Measured heights, m (NaN without return).
    pure : ndarray of bool, 2-D
        The leaf's pure pulses (the only ones fitted and tested).
    grid : PixelGrid
        Pixel-to-continuous map of ``height``.
    sigma_m : float
        The leaf's range noise, m.
    sigma_pulse_m : ndarray or float
        Each pulse's range noise (:func:`leafsfs.canopy.pulse_noise`), m.

    Returns
    -------
    tails : ndarray of bool, 2-D
        Pure pulses that take their neighbours' plane.
    plane : ndarray, 2-D
        That plane's height at every pure pulse, m (NaN elsewhere and where no plane was fitted).
    """
    tails, plane = np.zeros(pure.shape, dtype=bool), np.full(pure.shape, np.nan)
    pure = pure & np.isfinite(height)
    centres = np.argwhere(pure)
    if not len(centres) or not np.isfinite(sigma_m) or sigma_m <= 0:
        return tails, plane
    own = height[pure]
    first = local_planes(height, pure, grid, centres, TAIL_RADIUS_PX, order=1)
    noise = np.broadcast_to(sigma_pulse_m, pure.shape)[pure]
    with np.errstate(invalid="ignore"):
        off = np.abs(own - first.height) > 3.0 * noise
    fitted = pure.copy()
    fitted[tuple(centres[off].T)] = False
    second = local_planes(height, fitted, grid, centres, TAIL_RADIUS_PX, order=1)
    with np.errstate(invalid="ignore"):
        tail = (np.abs(own - second.height) > TAIL_SIGMA * sigma_m) & (second.rms <= TAIL_RMS_SIGMA * sigma_m) \
            & (second.count >= TAIL_MIN_COUNT)
    tails[pure] = tail
    plane[pure] = second.height
    return tails, plane

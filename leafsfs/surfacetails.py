"""Noise tails of the pulses that no leaf region holds (wood, the background, leaves the segmentation missed).

:func:`leafsfs.fusion.noise_tails` moves a leaf's pure pulses in the tails
of the range noise onto the plane of their neighbours, inside the leaf's
frame. Pure pulses outside every leaf region are never seen there, yet a
leaf the segmentation did not find (taken for wood, joined to a branch, or
dropped) still has its pulses' noise tails: on the leafy tree at 0.018 deg
(``fused``, truth) they held 13 % of the per-leaf ROP left. Here every
pure pulse outside the leaf regions is compared with the least-squares
plane of the range image's pure pulses (outside the regions) in a square
window around it, refitted without the pulses farther than 3 of their own
noise deviations (:func:`leafsfs.canopy.pulse_noise`) from the first
plane. A pulse more than :data:`SURFACE_TAIL_SIGMA` times the refitted
plane's RMS residual off it takes the plane's range (moved, not deleted),
where that RMS is at most the pulse's own noise and the plane has at least
:data:`SURFACE_TAIL_MIN_COUNT` pulses: a window across a surface's outline,
a fold or a branch's curvature leaves larger residuals and the pulse keeps
its range. Within the window's half-width of a silhouette the refit keeps
the surface's side only, and on a branch's curved flank that one-sided
plane is off by up to about 3 noise deviations (a 2 cm branch at 2 m,
1 mm between pulses: ``tests/test_surfacetails.py``); a local cylinder
(:mod:`leafsfs.woodfit`) would follow it and is not fitted here.

The test is on the window's measured noise, not the pulse's modelled one:
those tails lie 1.3 (median; 0.6-2.4 for 80 %) modelled deviations off
their plane, the modelled noise of these dim pulses being about three times
the scorer's 3-sigma threshold's sigma, and 1.9 (0.8-2.9) of the window's
RMS. Measured on the leafy tree at 0.018 deg (``fused``, whole scan, truth,
mean per-leaf ROP reduction 3 sigma / good points damaged; 0.6655 /
1.42 % without): offset beyond 3 modelled deviations, RMS at most 1.5 of
them, 0.6641 / 1.50 % (728 pulses moved); beyond 2.5 RMS 0.6683 / 1.44 %
(3,479); beyond 2 RMS 0.6722 / 1.45 % (10,361 of the 256,337 tested, 798
of them on leaves); every tested pulse onto its plane 0.6800 / 1.52 %
(180,351 moved: a smoothing of the wood, not kept). In the benchmark
(``fused`` at 0.018 deg, mean per-leaf ROP reduction 3 sigma / 1 cm, before
-> after; good points lost, found leaves and traits unchanged): leafy tree
0.639 / 0.786 -> 0.646 / 0.788, pear seed 7 at 3 m 0.655 / 0.786 -> 0.661 /
0.787, seed 23 at 4 m 0.663 / 0.798 -> 0.670 / 0.798; not tuned on: seed 31
at 2.5 m 0.682 / 0.822 -> 0.691 / 0.823, seed 41 at 5 m 0.656 / 0.771 ->
0.661 / 0.772. At the quick suite's 0.08 deg (leafy tree; a window 4 times
wider in metres) it costs a little: ``fused`` ROP reduction 1 cm 0.5224 ->
0.5210, outlier flag precision 0.506 -> 0.499, recall 0.783 -> 0.785.

The pulses the segmentation flags as straddling two surfaces but that no
surface pairs or owns and no region holds (``tested``) are kept as
measured otherwise; most are pure (on the leafy tree at 0.018 deg 6,139
pulses: 61 % on wood, 30 % on leaves, 9 % mixed), and pure leaf pulses
among them held 6.6 % of the per-leaf ROP that ``fused`` leaves (truth,
3 sigma). They are tested against the plane of every reliable pulse
around them, the leaf regions' at their corrected ranges, and are not
fitted themselves; :func:`leafsfs.reconstruct.reconstruct` moves those
within ``LONE_TAIL_SIGMA`` (4) modelled deviations of the plane (at
0.08 deg the window reaches other surfaces: without that bound the leafy
tree's ``fused`` ROP reduction 3 sigma / 1 cm falls 0.381 / 0.521 -> 0.365
/ 0.499, with it 0.383 / 0.521). Leafy tree at 0.018 deg (whole scan,
scratch scoring of :func:`benchmarks.scoring.score_scan`, mean per-leaf
ROP reduction 3 sigma / 1 cm, good points lost / damaged): 0.6722 /
0.8033, 0.36 / 1.45 % -> 0.6799 / 0.8059, 0.36 / 1.48 % (same constants
as above, none tuned). In the benchmark, without the bound (``fused`` at
0.018 deg, before -> after; good points lost, found leaves and traits
unchanged): leafy tree 0.646 / 0.788 -> 0.653 / 0.787, pear seed 7 at 3 m
0.661 / 0.787 -> 0.667 / 0.789, seed 23 at 4 m 0.670 / 0.798 -> 0.679 /
0.801; not tuned on: seed 31 at 2.5 m 0.691 / 0.823 -> 0.703 / 0.825, seed
41 at 5 m 0.661 / 0.772 -> 0.665 / 0.773.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from leafsfs.grid import window_moments

#: Half-width of the square window the plane is fitted on, pixels (81 pulses; :data:`leafsfs.fusion.TAIL_RADIUS_PX`
#: fits a disc of the same count on leaves).
SURFACE_TAIL_HALF_PX = 4
#: Offset from the refitted plane, in that plane's RMS residuals, beyond which a pure pulse is a tail (as
#: :data:`leafsfs.fusion.TAIL_SIGMA` on leaves).
SURFACE_TAIL_SIGMA = 2.0
#: Largest RMS residual of the refitted plane, in the pulse's modelled range-noise deviations (a window across two
#: surfaces, a fold or a branch's curvature leaves larger ones).
SURFACE_TAIL_RMS_SIGMA = 1.0
#: Fewest pulses the refitted plane is fitted to.
SURFACE_TAIL_MIN_COUNT = 20


def surface_tails(range_m: np.ndarray, pure: np.ndarray, noise_m: np.ndarray | float,
                  half_px: int = SURFACE_TAIL_HALF_PX, tested: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Pulses in the tails of their window's range noise, and their neighbours' plane's range there, m.

    Parameters
    ----------
    range_m : ndarray, 2-D
        Ranges, m (NaN: no return).
    pure : ndarray of bool, 2-D
        The pulses fitted (pure pulses outside the leaf regions; with ``tested``, every pure pulse).
    noise_m : ndarray or float
        Each pulse's range noise (:func:`leafsfs.canopy.pulse_noise`), m.
    half_px : int
        Half-width of the square window, pixels.
    tested : ndarray of bool, 2-D, optional
        The pulses tested (default: ``pure``); pulses tested but not in ``pure`` are not fitted.

    Returns
    -------
    tails : ndarray of bool, 2-D
        Tested pulses that take the plane's range (more than :data:`SURFACE_TAIL_SIGMA` of its RMS residuals off
        it).
    plane : ndarray, 2-D
        The refitted plane's range at every tested pulse, m (NaN elsewhere and where no plane was fitted).
    """
    pure = pure & np.isfinite(range_m)
    tested = pure if tested is None else tested & np.isfinite(range_m)
    noise = np.broadcast_to(np.asarray(noise_m, dtype=float), range_m.shape)
    # The first plane is needed only at the pure pulses that share a window with a tested one.
    at = pure if tested is pure else pure & ndimage.maximum_filter(tested, size=2 * half_px + 1, mode="constant")
    first, _, _ = _window_planes(range_m, pure, half_px, at)
    with np.errstate(invalid="ignore"):
        fitted = pure & ~(np.abs(range_m - first) > 3.0 * noise)
    plane, rms, count = _window_planes(range_m, fitted, half_px, tested)
    with np.errstate(invalid="ignore"):
        tails = tested & (np.abs(range_m - plane) > SURFACE_TAIL_SIGMA * rms) \
            & (rms <= SURFACE_TAIL_RMS_SIGMA * noise) & (count >= SURFACE_TAIL_MIN_COUNT)
    return tails, np.where(tested, plane, np.nan)


def _window_planes(range_m: np.ndarray, valid: np.ndarray, half_px: int, at: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares plane of the valid ranges in the square window around every pixel ``at``.

    Returns, on the pixels ``at`` (NaN elsewhere), the plane's range at the pixel (m), its RMS residual (m, ``n - 3``
    degrees of freedom) and the count of pulses fitted (0 elsewhere); NaN range and RMS where fewer than 4 pulses or
    a degenerate window. Ranges are taken relative to the valid pulses' median so that the window sums keep their
    precision.
    """
    offsets = np.arange(-half_px, half_px + 1, dtype=float)
    kernels = [np.ones_like(offsets), offsets, offsets ** 2]
    w = valid.astype(float)
    base = float(np.median(range_m[valid])) if valid.any() else 0.0
    h = np.where(valid, range_m - base, 0.0)

    m = window_moments(w, kernels, ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)), at)
    normal = np.stack([np.stack([m[0, 0], m[1, 0], m[0, 1]], -1), np.stack([m[1, 0], m[2, 0], m[1, 1]], -1),
                       np.stack([m[0, 1], m[1, 1], m[0, 2]], -1)], -2)
    mh = window_moments(h, kernels, ((0, 0), (1, 0), (0, 1)), at)
    rhs = np.stack([mh[0, 0], mh[1, 0], mh[0, 1]], -1)
    count = np.rint(m[0, 0]).astype(int)
    ok = (count >= 4) & (np.abs(np.linalg.det(normal)) > 1e-6)
    normal[~ok] = np.eye(3)
    coef = np.linalg.solve(normal, rhs[..., None])[..., 0]
    rss = window_moments(h * h, kernels, ((0, 0),), at)[0, 0] - np.einsum("na,na->n", coef, rhs)
    rms = np.sqrt(np.clip(rss, 0, None) / np.maximum(count - 3, 1))
    plane, spread, counts = np.full(at.shape, np.nan), np.full(at.shape, np.nan), np.zeros(at.shape, dtype=int)
    plane[at], spread[at], counts[at] = np.where(ok, coef[:, 0] + base, np.nan), np.where(ok, rms, np.nan), count
    return plane, spread, counts

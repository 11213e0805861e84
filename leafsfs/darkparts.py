"""Bark in leaf surfaces: surfaces shaped like a branch, and dark bark-shaped parts, are no leaves.

A leaf surface of :func:`leafsfs.leaves.segment_scan` may be a piece of a
branch the leaf tests let through (broad enough, not elongated, not darker
than its range plane), or hold a piece of the branch a leaf lies against when
the linking joined the two and neither the neck, crease nor merge cuts parted
them. Bark has a shape no leaf has: a narrow, straight cylinder that bulges
towards the scanner across its width (:func:`is_bark`); a leaf is a plane, a
gentle roll (a radius of a width or more), or a dome or saddle (curved along
its length too). And bark reads darker than a leaf on its local range plane
would: it reflects less than the calibrated leaf and its pulses see a bulging
surface, so the intensity-derived incidence ``alpha`` exceeds the incidence
of the local plane of the ranges. A leaf seen through another leaf
(transmission) or a leaf darker than the calibrated one also reads dark, but
on a plane, and mostly over its whole surface.

So

* a leaf surface shaped like bark is no leaf (:func:`bark_surfaces`);
* a connected dark part of a leaf surface is cut off (:func:`dark_parts`)
  only when ``alpha`` exceeds the local plane's incidence by more than a
  threshold over a part at least a surface in size once the outline strips
  (one or two pulses wide, darkened by the footprint's share off the leaf)
  are opened away, the surface is not dark over most of its pulses (that is
  :func:`leafsfs.canopy.dark_surfaces`' business), and the part is shaped
  like bark.

The caller (:func:`leafsfs.leaves.segment_scan`) keeps a cut only when what
remains of the surface is still a leaf by its leaf tests; the cut parts are
no leaves. The thresholds were chosen on the development canopies (suite
canopy5: leafy tree, pears s7, s23, s41 at 0.018 deg); the pears s101 and
s173 (suite fresh17) are the check.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from leafsfs.canopy import plane_fits
from leafsfs.errors import SfsError
from tlssim.pattern import beam_frame

#: Radius of the local range plane whose incidence a pulse's ``alpha`` is compared with, m (at the surface's median
#: range; at least :data:`MIN_PLANE_RADIUS_PX`). Assumption: 5 mm, a bark surface's curvature is followed by the plane
#: on a branch of 1 cm radius or more, and on a 4 m scan at 0.018 deg (1.3 mm pulses) the plane's slope noise is
#: 0.05 in tangent for 1.5 mm of range noise.
PLANE_RADIUS_M = 0.005
#: Smallest radius of the local plane, pixels (a 7 x 7 disc of 29 pulses).
MIN_PLANE_RADIUS_PX = 3.0
#: A surface whose dark pulses are more than this share of its pulses is not cut (a leaf seen through another leaf
#: reads dark all over; :func:`leafsfs.canopy.dark_surfaces` judges the whole surface). Assumption: one half.
MAX_DARK_SHARE = 0.5
#: Smallest evidence for a cylinder across a patch's width: the drop of the sum of squared range residuals, in range
#: noise variances, when a curvature across the patch's narrow axis is added to its plane (a chi-square of one degree
#: of freedom under a plane; assumption: 25, five standard deviations).
MIN_CYLINDER_EVIDENCE = 25.0
#: Largest radius of a cylinder taken for bark, m (assumption: 3 cm, the thickest branches of a fruit tree's crown
#: that leaves lie against and the linking joins to them).
MAX_BARK_RADIUS_M = 0.03
#: Largest radius of a cylinder taken for bark, as a share of the patch's width (four spreads along its second
#: principal axis, 1.15 times the chord for pulses spread evenly across it). A branch seen from the side over an arc
#: of +-60-80 deg has a width of 2.0-2.3 radii (0.44-0.5); a leaf rolled across its width, its margins turned by
#: ``roll`` rad, has a radius of ``1 / (2.3 roll)`` widths, above 0.7 for a roll under 0.62 rad (assumption; the
#: pear leaves of :mod:`scenes.leaf` roll by at most 0.5 rad). Measured on canopy5's leaf surfaces (main's
#: segmentation; leafy tree, pears s7, s23, s41): the surfaces :func:`is_bark` takes at 0.7 held 6,444 wood and 71
#: leaf pulses; at 0.8, 7,256 and 71; at 1.0, 10,200 and 301 (a rolled leaf of the leafy tree and two pieces).
MAX_RADIUS_WIDTH = 0.7
#: Smallest radius of the curvature along a bark patch's length, in radii across it: a branch is nearly straight
#: over a patch, a rolled leaf that is also bent (a dome or saddle) is not (assumption: 3; on the leafy tree a
#: rolled leaf of 2.3 cm radius measured 2.5).
MIN_AXIS_RATIO = 3.0


def local_incidence(range_m: np.ndarray, inside: np.ndarray, step_rad: float) -> np.ndarray:
    """Incidence of the local range plane of a surface's pulses, rad (NaN off the surface or with too few pulses).

    Parameters
    ----------
    range_m : ndarray, 2-D
        Ranges, m.
    inside : ndarray of bool, 2-D
        The surface's pulses (only they enter its planes).
    step_rad : float
        Angle between neighbouring beams, rad.

    Returns
    -------
    ndarray, 2-D
        ``arctan(|gradient| / (r step))`` of the plane within
        :data:`PLANE_RADIUS_M` of each pulse, rad.
    """
    masked = np.where(inside, range_m, np.nan)
    median = float(np.nanmedian(masked))
    radius = max(MIN_PLANE_RADIUS_PX, PLANE_RADIUS_M / (median * step_rad))
    _, slope, _, _ = plane_fits(masked, radius)
    return np.arctan(slope / (masked * step_rad))


def cylinder_fit(xyz: np.ndarray, noise_m: float) -> tuple[float, float, float, float]:
    """How much better a cylinder across a patch's narrow axis fits its points than a plane, and its radii.

    The points are taken in their principal frame (``u`` along the longest
    axis, ``v`` across, ``w`` the depth, oriented away from the scanner at the
    origin); ``w = a + b u + c v`` is compared with ``w = a + b u + c v + e
    v^2``, and the quadric ``w = a + b u + c v + e v^2 + f u^2 + g u v`` gives
    the radii across and along.

    Parameters
    ----------
    xyz : ndarray, (n, 3)
        Points in the scanner's frame, m.
    noise_m : float
        Range noise (standard deviation), m.

    Returns
    -------
    evidence : float
        Drop of the sum of squared residuals from the plane to the cylinder, in noise variances (0 with fewer
        than 8 points).
    radius : float
        Radius across, ``1 / (2 e)`` of the quadric, m: positive when the patch bulges towards the scanner (inf
        when it does not).
    along : float
        Radius along, ``1 / (2 |f|)``, m (inf when straight).
    width : float
        Four spreads along the second principal axis, m.
    """
    if len(xyz) < 8:
        return 0.0, math.inf, math.inf, 0.0
    centre = xyz.mean(axis=0)
    d = xyz - centre
    values, vectors = np.linalg.eigh(d.T @ d)
    u, v, w = vectors[:, 2], vectors[:, 1], vectors[:, 0]
    if w @ centre < 0:
        w = -w
    pu, pv, pw = d @ u, d @ v, d @ w
    plane = np.stack([np.ones(len(d)), pu, pv], axis=1)
    cylinder = np.column_stack([plane, pv ** 2])
    quadric = np.column_stack([cylinder, pu ** 2, pu * pv])
    rss = [float(np.sum((pw - m @ np.linalg.lstsq(m, pw, rcond=None)[0]) ** 2)) for m in (plane, cylinder)]
    e, f = np.linalg.lstsq(quadric, pw, rcond=None)[0][3:5]
    with np.errstate(divide="ignore"):
        radius = float(1 / (2 * e)) if e > 0 else math.inf
        along = float(1 / (2 * abs(f)))
    return (rss[0] - rss[1]) / noise_m ** 2, radius, along, 4 * math.sqrt(max(values[1], 0) / len(d))


def is_bark(xyz: np.ndarray, noise_m: float) -> bool:
    """Whether a patch of points is a piece of a branch seen from the side: a narrow, straight cylinder.

    The cylinder across the patch (:func:`cylinder_fit`) beats the plane by
    :data:`MIN_CYLINDER_EVIDENCE`, bulges towards the scanner with a radius of
    at most :data:`MAX_BARK_RADIUS_M` and :data:`MAX_RADIUS_WIDTH` of the
    patch's width, and the patch is nearly straight along its length
    (:data:`MIN_AXIS_RATIO`).

    Parameters
    ----------
    xyz : ndarray, (n, 3)
        Points in the scanner's frame, m.
    noise_m : float
        Range noise (standard deviation), m.

    Returns
    -------
    bool
        True for a branch piece.
    """
    evidence, radius, along, width = cylinder_fit(xyz, noise_m)
    return (evidence >= MIN_CYLINDER_EVIDENCE and radius <= MAX_BARK_RADIUS_M and radius <= MAX_RADIUS_WIDTH * width
            and along >= MIN_AXIS_RATIO * radius)


def bark_surfaces(surfaces: np.ndarray, candidates: np.ndarray, range_m: np.ndarray, theta: np.ndarray,
                  psi: np.ndarray, noise_m: float) -> np.ndarray:
    """Which candidate surfaces are pieces of a branch (:func:`is_bark`; index = label, False for 0).

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    candidates : ndarray of bool
        Labels to test (index = label).
    range_m, theta, psi : ndarray, 2-D
        Scan grids (m, rad).
    noise_m : float
        Range noise (standard deviation), m.

    Returns
    -------
    ndarray of bool
        Bark per label (length of ``candidates``).
    """
    bark = np.zeros(len(candidates), dtype=bool)
    for k, box in enumerate(ndimage.find_objects(surfaces), start=1):
        if box is None or k >= len(candidates) or not candidates[k]:
            continue
        sel = (surfaces[box] == k) & np.isfinite(range_m[box])
        bark[k] = is_bark(beam_frame(theta[box][sel], psi[box][sel])[0] * range_m[box][sel][:, None], noise_m)
    return bark


def dark_parts(surfaces: np.ndarray, leaf: np.ndarray, range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray,
               alpha: np.ndarray, step_rad: float, noise_m: float, excess_rad: float,
               min_pixels: int) -> tuple[np.ndarray, np.ndarray]:
    """Leaf surfaces with their dark parts shaped like bark (:func:`is_bark`) labelled apart.

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    leaf : ndarray of bool
        Which labels are leaves (only they are cut).
    range_m, theta, psi : ndarray, 2-D
        Scan grids (m, rad).
    alpha : ndarray, 2-D
        Intensity-derived incidence, rad (NaN: unknown).
    step_rad : float
        Angle between neighbouring beams, rad.
    noise_m : float
        Range noise (standard deviation), m.
    excess_rad : float
        A pulse is dark when its ``alpha`` exceeds the incidence of its local
        range plane (:func:`local_incidence`) by more than this, rad.
    min_pixels : int
        Fewest pulses of a part cut off.

    Returns
    -------
    surfaces : ndarray of int, 2-D
        The labels, each part cut off numbered after the existing labels.
    parents : ndarray of int
        The surface each new label was cut from (new label ``max + 1 + i`` from ``parents[i]``).
    """
    if not excess_rad > 0 or not step_rad > 0 or not noise_m > 0:
        raise SfsError(f"excess_rad, step_rad and noise_m must be positive, got {excess_rad!r}, {step_rad!r} and "
                       f"{noise_m!r}")
    out = surfaces.copy()
    count = int(surfaces.max(initial=0))
    parents = []
    opening = np.ones((3, 3), dtype=bool)
    for k, box in enumerate(ndimage.find_objects(surfaces), start=1):
        if box is None or k >= len(leaf) or not leaf[k]:
            continue
        inside = (surfaces[box] == k) & np.isfinite(range_m[box])
        if inside.sum() < 2 * min_pixels:
            continue
        excess = alpha[box] - local_incidence(range_m[box], inside, step_rad)
        with np.errstate(invalid="ignore"):
            dark = inside & (excess > excess_rad)
        if dark.sum() > MAX_DARK_SHARE * inside.sum():
            continue
        dark = ndimage.binary_opening(dark, opening)
        parts, n = ndimage.label(dark)
        sizes = np.bincount(parts.ravel(), minlength=n + 1)
        for p in (p for p in range(1, n + 1) if sizes[p] >= min_pixels):
            sel = parts == p
            if not is_bark(beam_frame(theta[box][sel], psi[box][sel])[0] * range_m[box][sel][:, None], noise_m):
                continue
            count += 1
            out[box][sel] = count
            parents.append(k)
    return out, np.asarray(parents, dtype=int)

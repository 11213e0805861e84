"""Bark parts of leaf surfaces cut off by their intensity and their shape.

A leaf surface of :func:`leafsfs.leaves.segment_scan` may hold a piece of the
branch it lies against when the linking joined the two and neither the neck,
crease nor merge cuts parted them. Such a piece reads darker than a leaf on
its local range plane would: bark reflects less than the calibrated leaf, and
its pulses see a bulging surface, so the intensity-derived incidence
``alpha`` exceeds the incidence of the local plane of the ranges. A leaf
seen through another leaf (transmission) or a leaf darker than the
calibrated one also reads dark, but over its whole surface and on a plane.

So a connected dark part of a leaf surface is cut off (:func:`dark_parts`)
only when

* it is dark: ``alpha`` exceeds the local plane's incidence by more than a
  threshold, over a part at least a surface in size once the outline strips
  (one or two pulses wide, darkened by the footprint's share off the leaf) are
  opened away;
* the surface is not dark over most of its pulses (that is
  :func:`leafsfs.canopy.dark_surfaces`' business, and a leaf behind another
  leaf);
* the part is shaped like wood: elongated or sparse by the wood tests of
  :func:`leafsfs.canopy.wood_surfaces`, or a cylinder across its width
  (:func:`cylinder_evidence`: its ranges bulge towards the scanner across its
  narrow axis much more than the noise allows for a plane).

The caller (:func:`leafsfs.leaves.segment_scan`) keeps a cut only when what
remains of the surface is still a leaf by its leaf tests, and the cut parts
are no leaves.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from leafsfs.canopy import plane_fits, principal_spreads, wood_surfaces
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
#: Smallest evidence for a cylinder across a part's width: the drop of the sum of squared range residuals, in range
#: noise variances, when a curvature across the part's narrow axis is added to its plane (a chi-square of one degree
#: of freedom under a plane; assumption: 25, five standard deviations).
MIN_CYLINDER_EVIDENCE = 25.0
#: Largest radius of a cylinder taken for bark, m (assumption: 5 cm, the thickest branches of a fruit tree's crown
#: that leaves lie against; a leaf's curl across a part is gentler).
MAX_BARK_RADIUS_M = 0.05


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


def cylinder_evidence(xyz: np.ndarray, beam: np.ndarray, noise_m: float) -> tuple[float, float]:
    """How much better a cylinder across a patch's narrow axis fits its points than a plane.

    The points are taken in their principal frame (``u`` along the longest
    axis, ``v`` across, ``w`` the depth, oriented away from the scanner);
    ``w = a + b u + c v`` is compared with ``w = a + b u + c v + e v^2``.

    Parameters
    ----------
    xyz : ndarray, (n, 3)
        Points, m.
    beam : ndarray, (3,)
        Mean beam direction (unit, from the scanner).
    noise_m : float
        Range noise (standard deviation), m.

    Returns
    -------
    evidence : float
        Drop of the sum of squared residuals in noise variances (0 with fewer than 8 points).
    radius : float
        Radius of the fitted curvature, m, positive when the patch bulges towards the scanner (inf when flat).
    """
    if len(xyz) < 8:
        return 0.0, math.inf
    d = xyz - xyz.mean(axis=0)
    _, vectors = np.linalg.eigh(d.T @ d)
    u, v, w = vectors[:, 2], vectors[:, 1], vectors[:, 0]
    if w @ beam < 0:
        w = -w
    pu, pv, pw = d @ u, d @ v, d @ w
    plane = np.stack([np.ones(len(d)), pu, pv], axis=1)
    curved = np.column_stack([plane, pv ** 2])
    rss = [float(np.sum((pw - m @ np.linalg.lstsq(m, pw, rcond=None)[0]) ** 2)) for m in (plane, curved)]
    e = np.linalg.lstsq(curved, pw, rcond=None)[0][3]
    radius = 1 / (2 * e) if e > 0 else math.inf
    return (rss[0] - rss[1]) / noise_m ** 2, radius


def dark_parts(surfaces: np.ndarray, leaf: np.ndarray, range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray,
               alpha: np.ndarray, step_rad: float, noise_m: float, excess_rad: float, min_pixels: int, *,
               max_aspect: float = 4.0, min_fill: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Leaf surfaces with their dark, wood-shaped parts labelled apart.

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
    max_aspect, min_fill : float
        The wood tests of :func:`leafsfs.canopy.wood_surfaces`.

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
        candidates = [p for p in range(1, n + 1) if sizes[p] >= min_pixels]
        if not candidates:
            continue
        labels = np.where(np.isin(parts, candidates), parts, 0)
        woody = wood_surfaces(labels, range_m[box], theta[box], psi[box], step_rad, alpha[box],
                              max_aspect=max_aspect, min_fill=min_fill)
        spread = principal_spreads(labels, range_m[box], theta[box], psi[box])
        for p in candidates:
            sel = parts == p
            xyz = beam_frame(theta[box][sel], psi[box][sel])[0] * range_m[box][sel][:, None]
            beam = xyz.mean(axis=0) / np.linalg.norm(xyz.mean(axis=0))
            evidence, radius = cylinder_evidence(xyz, beam, noise_m)
            bark = evidence >= MIN_CYLINDER_EVIDENCE and radius <= MAX_BARK_RADIUS_M
            if not (woody[p] or bark) or not np.isfinite(spread[p, 1]):
                continue
            count += 1
            out[box][sel] = count
            parents.append(k)
    return out, np.asarray(parents, dtype=int)

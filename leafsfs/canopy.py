"""Leaves among leaves and wood: edge pulses, necks and wood-shaped surfaces of a canopy scan.

In a canopy the surfaces that :func:`leafsfs.leaves.link_components` joins
are not yet leaves: a leaf lies a few centimetres in front of another one,
its petiole runs into a twig, twigs and branches are surfaces too. Three
steps, all from range and the scan grid (no truth), separate them:

* :func:`edge_pulses`: pulses on no side of which the neighbourhood (about
  a footprint) is one plane within the range noise. A footprint across
  the edge between two leaves a few centimetres apart returns a chain of
  intermediate ranges whose pulse-to-pulse steps stay within the noise,
  so such pulses would join the two leaves; left out of the linking they
  go to the surfaces they straddle by their power shares
  (:mod:`leafsfs.edges`). A pure pulse next to the edge is no edge pulse:
  the half of its neighbourhood on its own surface is one plane.
* :func:`split_necks`: a surface is cut where it narrows below a fraction
  of its own widest part (a petiole or twig attached to a leaf blade, a
  branch leaving the trunk); the test is relative to the surface's own
  width, so it holds at any distance and angular step.
* :func:`wood_surfaces`: surfaces elongated in 3-D (their points' second
  principal axis much shorter than the first) are twigs, branches and
  trunks. Points in 3-D are free of the foreshortening that makes a leaf
  seen edge-on look thin in the scan image.
* :func:`split_creases`: a surface taken for a leaf is cut where two
  planes meet at an angle with no range step (:func:`crease_pulses`: a
  leaf touching another at the same distance, a leaf lying on a branch),
  and its parts are judged again.
* :func:`narrow_surfaces`: surfaces narrower in 3-D than a leaf (four
  second principal spreads under 1.6 cm) are no leaves: strips of leaves
  split off by an occluder or the linking, and short twig pieces.
* :func:`dark_surfaces`: surfaces whose intensity says a steeper incidence
  than the plane of their ranges by more than the intensity's tolerance
  are no leaves: short twig and branch pieces (a bulging front that a
  plane fits as facing the beam, and bark darker than a leaf).

Where it fails: a leaf touching another at the same distance and turned
less than the crease angle (40 deg) from it stays merged with it; a leaf narrower
than ``1 / max_aspect`` of its length (grass, willow) is taken for wood; a
short twig piece seen between two leaves (shorter than ``max_aspect`` times
its diameter) is taken for a leaf unless it is dark for its plane; a leaf
darker than the calibrated leaf (seen through another, or of a lower
reflectance) is taken for wood; a leaf narrower than 1.6 cm (olive, grass),
or a visible strip of a leaf that narrow (most of it hidden, or turned
edge-on), is no leaf.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from leafsfs.errors import SfsError
from leafsfs.grid import gaussian_planes
from tlssim.pattern import beam_frame

#: Incidence at which the area of a pulse stops growing as 1 / cos(alpha) in the sparse test of
#: :func:`wood_surfaces`, deg (the intensity is unreliable beyond about 60 deg, thesis ch.6; at 75 deg a curled leaf
#: seen beyond it filled less than half of its ellipse and was taken for wood; the wood pieces that 85 deg let
#: through are mostly narrower than a leaf, :func:`narrow_surfaces`).
MAX_AREA_INCIDENCE_DEG = 85.0
#: Share of the ring around a leaf region nearer than the leaf above which the leaf is cut by an occluder
#: (assumption: a twig 1/20 of the leaf's outline long crossing it).
OCCLUDED_RING_SHARE = 0.05
#: Exponent of the range noise against received power (tls-physics §7.11 and §A.3: 0.336).
NOISE_POWER_EXPONENT = 0.336
#: Pixels fitted at once by :func:`plane_residuals` (memory bound: about 0.5 kB per pixel at a 3 px radius).
CHUNK = 65536


def pulse_noise(noise_m: float, intensity: np.ndarray | None, gain_dn: float | None) -> np.ndarray | float:
    """Range noise of every pulse from the scan's typical noise and the pulse's intensity, m.

    Range noise grows as the received power falls, ``sigma ~ P^-gamma``
    (tls-physics §7.11, gamma = :data:`NOISE_POWER_EXPONENT` from the
    LS880 specification points); a log amplifier of gain ``gain_dn`` DN per
    e-fold turns that into ``sigma = noise_m exp(-gamma (I - I_median) /
    gain_dn)``, ``noise_m`` being the noise at the median intensity. Without
    an intensity or a gain, ``noise_m`` for every pulse.

    Parameters
    ----------
    noise_m : float
        Range noise at the median intensity, m.
    intensity : ndarray, 2-D, optional
        Intensities, DN.
    gain_dn : float, optional
        Log-amplifier gain, DN per e-fold.
    """
    if intensity is None or gain_dn is None:
        return noise_m
    level = np.nan_to_num(intensity - np.nanmedian(intensity), nan=0.0)
    return noise_m * np.exp(-NOISE_POWER_EXPONENT * np.clip(level, -3 * gain_dn, 3 * gain_dn) / gain_dn)


def plane_fits(range_m: np.ndarray, radius_px: float, side: tuple[int, int] | None = None,
               where: np.ndarray | None = None, behind_rise_m: np.ndarray | float | None = None,
               behind_tol_m: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares plane fitted to the ranges within ``radius_px`` of every pulse.

    Parameters
    ----------
    range_m : ndarray, 2-D
        Ranges, m (NaN: no return).
    radius_px : float
        Neighbourhood radius, pixels (at least 1).
    side : pair of int, optional
        Only the half of the disc on this side of the pulse: the offsets
        ``(di, dj)`` with ``di * side[0] + dj * side[1] >= 0`` (the pulse and
        the diameter through it included; default: the whole disc).
    where : ndarray of bool, 2-D, optional
        Pulses to fit a plane around (default: every pulse with a range).
    behind_rise_m, behind_tol_m : ndarray or float, optional
        With ``behind_rise_m`` (per pulse or one for all, m per pixel), a
        neighbour farther than the pulse by more than its pixel distance times
        ``behind_rise_m`` plus ``behind_tol_m`` (m) counts as no return: it
        lies behind a range step no plausible slope explains (the background
        beyond a leaf's outline), as when nothing returned there; a plane then
        needs at least half the (half) disc's pulses (one line of pulses at one
        range, a mixed band's row along the edge, is no plane).

    Returns
    -------
    rms : ndarray, 2-D
        Residual RMS (``n - 3`` degrees of freedom), m.
    slope : ndarray, 2-D
        Magnitude of the plane's range gradient, m per pixel.
    slope_noise : ndarray, 2-D
        Standard deviation of that gradient per metre of range noise
        (``sqrt`` of the larger diagonal term of the inverse normal matrix),
        1 / pixel.
    deviation : ndarray, 2-D
        The pulse's own residual divided by ``sqrt(1 - h)`` (``h`` its
        leverage), m: its standard deviation is the range noise's, so one
        pulse off the plane of the others shows at its full offset however
        many pulses share the residuals.

    All NaN where fewer than 5 neighbours returned, and off ``where``.
    """
    centres = np.argwhere(np.isfinite(range_m) if where is None else np.isfinite(range_m) & where)
    out = np.full((4, *range_m.shape), np.nan)
    out[:, centres[:, 0], centres[:, 1]] = plane_fits_at(range_m, radius_px, centres, side, behind_rise_m,
                                                         behind_tol_m)
    return out[0], out[1], out[2], out[3]


def plane_fits_at(range_m: np.ndarray, radius_px: float, centres: np.ndarray, side: tuple[int, int] | None = None,
                  behind_rise_m: np.ndarray | float | None = None, behind_tol_m: np.ndarray | float = 0.0
                  ) -> np.ndarray:
    """:func:`plane_fits` at the pulses ``centres`` only, without its whole-scan images.

    :func:`edge_pulses` needs the fits at a few pulses per side; four images
    of the scan per side took a second of the leafy tree at 0.018 deg.

    Parameters
    ----------
    range_m : ndarray, 2-D
        Ranges, m (NaN: no return).
    radius_px : float
        Neighbourhood radius, pixels (at least 1).
    centres : ndarray of int, (n, 2)
        The pulses (row, column), each with a range.
    side : pair of int, optional
        As for :func:`plane_fits`.
    behind_rise_m, behind_tol_m : ndarray or float, optional
        As for :func:`plane_fits`.

    Returns
    -------
    ndarray, (4, n)
        :func:`plane_fits`' ``rms``, ``slope``, ``slope_noise`` and ``deviation`` at the pulses.
    """
    offsets = _disc_offsets(radius_px, side)
    r = int(np.abs(offsets).max())
    design = np.stack([np.ones(len(offsets)), offsets[:, 0], offsets[:, 1]], axis=1).astype(float)
    outer = (design[:, :, None] * design[:, None, :]).reshape(len(design), 9)  # weights are 0/1: same sums
    padded = np.pad(range_m, r, constant_values=np.nan)
    out = np.full((4, len(centres)), np.nan)
    for start in range(0, len(centres), CHUNK):
        c = centres[start:start + CHUNK]
        h = padded[c[:, None, 0] + r + offsets[None, :, 0], c[:, None, 1] + r + offsets[None, :, 1]]
        w = np.isfinite(h)
        h = np.where(w, h - range_m[c[:, 0], c[:, 1]][:, None], 0.0)  # relative ranges: no cancellation
        if behind_rise_m is not None:
            rise, tol = (np.asarray(v, dtype=float)[c[:, 0], c[:, 1]][:, None] if np.ndim(v) else v
                         for v in (behind_rise_m, behind_tol_m))
            with np.errstate(invalid="ignore"):  # an infinite rise at the pulse itself
                w &= (h <= tol) | (h <= np.hypot(offsets[:, 0], offsets[:, 1])[None, :] * rise + tol)
        w = w.astype(float)
        n = w.sum(axis=1)
        if behind_rise_m is None:
            ok = n >= 5
        else:  # a pulse whose behind neighbours may count as no return needs half the (half) disc
            ok = n >= np.where(np.isfinite(rise[:, 0] if np.ndim(rise) else np.full(len(c), rise)),
                               max(5, len(offsets) / 2), 5)
        normal = np.einsum("nk,kc->nc", w[ok], outer).reshape(-1, 3, 3) + 1e-9 * np.eye(3)
        inverse = np.linalg.inv(normal)
        beta = np.einsum("nab,nb->na", inverse, np.einsum("nk,ka->na", w[ok] * h[ok], design))
        rss = np.sum(w[ok] * (h[ok] - beta @ design.T) ** 2, axis=1)
        fitted = start + np.nonzero(ok)[0]
        out[0, fitted] = np.sqrt(rss / np.maximum(n[ok] - 3, 1))
        out[1, fitted] = np.hypot(beta[:, 1], beta[:, 2])
        out[2, fitted] = np.sqrt(np.maximum(inverse[:, 1, 1], inverse[:, 2, 2]))
        # the pulse's own relative range is 0 and its design row (1, 0, 0): residual -beta_0, leverage inverse_00
        out[3, fitted] = -beta[:, 0] / np.sqrt(np.maximum(1 - inverse[:, 0, 0], 1e-6))
    return out


def _disc_offsets(radius_px: float, side: tuple[int, int] | None) -> np.ndarray:
    """Pixel offsets ``(di, dj)`` of the disc (or half disc) of :func:`plane_fits`, (n, 2)."""
    if radius_px < 1:
        raise SfsError(f"radius_px must be at least 1, got {radius_px!r}")
    r = int(math.floor(radius_px))
    di, dj = np.mgrid[-r:r + 1, -r:r + 1]
    keep = di ** 2 + dj ** 2 <= radius_px ** 2 + 1e-9
    if side is not None:
        keep &= di * side[0] + dj * side[1] >= 0
    return np.stack([di[keep], dj[keep]], axis=1)


def _least_at(image: np.ndarray, offsets: np.ndarray, at: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Smallest value of ``image`` over the pixel offsets around the pixels ``at`` (outside the image: ignored)."""
    r = int(np.abs(offsets).max())
    padded = np.pad(np.asarray(image, dtype=float), r, constant_values=np.inf)
    out = np.empty(len(at[0]))
    for start in range(0, len(out), CHUNK):
        rows, cols = at[0][start:start + CHUNK, None] + r, at[1][start:start + CHUNK, None] + r
        out[start:start + CHUNK] = padded[rows + offsets[None, :, 0], cols + offsets[None, :, 1]].min(axis=1)
    return out


#: Sides of the half discs of :func:`edge_pulses` (every 45 deg: a straight edge is within 22.5 deg of one
#: diameter, so the half disc away from it reaches at most ``radius sin(22.5 deg)`` (< 1 pixel at 2.5) across it).
HALF_DISC_SIDES = ((1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1))


def edge_pulses(range_m: np.ndarray, radius_px: float, noise_m: np.ndarray | float, factor: float = 2.5,
                max_slope: np.ndarray | float = math.inf, spacing_m: np.ndarray | float = 1.0,
                behind_gap: bool | np.ndarray = False) -> np.ndarray:
    """Pulses on no side of which the neighbourhood is one plausible plane within the range noise (mixed pulses).

    A neighbourhood is implausible when its plane leaves residuals above
    ``factor`` noise standard deviations (two surfaces in it), when the
    pulse itself lies off it by more than ``factor`` standard deviations
    (:func:`plane_fits`' ``deviation``: a mixed pulse on the rim of one
    surface's half disc), or when the
    plane is steeper than the surface can be (``max_slope``) by more than
    ``factor`` standard deviations of the fitted slope: in a neighbourhood
    hardly wider than the edge a plane turns the step between two surfaces
    into a steep ramp instead of leaving residuals. A neighbourhood's
    steepest plausible slope is the least of its pulses' ``max_slope``: the
    intensity of a mixed pulse, lowered by the part of its footprint on
    the far surface, says steep whatever the surfaces' slopes; likewise
    its residuals are held to the noise of its strongest pulse (a mixed
    pulse's low power widens its own noise), the RMS within ``factor``
    standard deviations of the chi-square spread of ``n - 3`` residuals.

    The neighbourhoods are the eight half discs of radius ``radius_px``
    through the pulse (:data:`HALF_DISC_SIDES`): a pure pulse near a
    surface's outline has one half disc on its own surface, however narrow
    the surface is in pixels (a leaf of a few footprints at a coarse
    angular step), and stays out of the edge pulses; a mixed pulse lies off
    the plane of either side.

    Parameters
    ----------
    range_m : ndarray, 2-D
        Ranges, m (NaN: no return).
    radius_px : float
        Neighbourhood radius, pixels (about a footprint radius: the mixed
        pulses of an edge lie within it).
    noise_m : ndarray or float
        Standard deviation of the range noise (per pulse or one for all), m.
    factor : float
        Tolerance, in standard deviations.
    max_slope : ndarray or float
        Steepest plausible slope (``tan`` of the incidence) per pulse.
    spacing_m : ndarray or float
        Distance between neighbouring pulses on a surface facing the beam
        (range times the angular step), m.
    behind_gap : bool or ndarray of bool, 2-D
        For every pulse (True) or the pulses of a mask (elsewhere as False),
        fit each half disc without the pulses behind the pulse by more than
        its own steepest plausible slope (``spacing_m * max_slope`` per
        pixel) and ``factor`` noise deviations allow, as if nothing had
        returned there (:func:`plane_fits`' ``behind_rise_m``): a pure pulse
        at a leaf's outline before a wall has the wall's mixed band in every
        half disc when the leaf is a few footprints wide, and is judged as
        before the open sky; a mixed pulse still lies off the leaf's plane.

    Returns
    -------
    ndarray of bool, 2-D
    """
    if not np.all(np.asarray(noise_m) > 0) or not factor > 0:
        raise SfsError(f"noise_m and factor must be positive, got {noise_m!r} and {factor!r}")
    plausible = np.zeros(range_m.shape, dtype=bool)
    rise = spacing_m * max_slope
    if np.ndim(behind_gap):  # only the given pulses: elsewhere no neighbour lies behind an implausible step
        rise = np.where(behind_gap, rise, math.inf)
    behind = {"behind_rise_m": rise, "behind_tol_m": factor * noise_m} if np.ndim(behind_gap) or behind_gap else {}
    for side in HALF_DISC_SIDES:
        # Only the pulses no side has shown plausible yet: most are plausible on the first side.
        todo = np.isfinite(range_m) & ~plausible
        at = np.nonzero(todo)
        rms, slope, slope_noise, deviation = plane_fits_at(range_m, radius_px, np.stack(at, axis=1), side, **behind)
        offsets = _disc_offsets(radius_px, side)
        steepest = _least_at(max_slope, offsets, at) if np.ndim(max_slope) else max_slope
        # rms^2 / sigma^2 of a plane is chi-square over its n - 3 degrees of freedom: mean 1, variance 2 / (n - 3)
        spread = 1 + factor * math.sqrt(2 / max(len(offsets) - 3, 1))
        least_noise = _least_at(noise_m, offsets, at) if np.ndim(noise_m) else noise_m
        spacing = spacing_m[at] if np.ndim(spacing_m) else spacing_m
        noise = noise_m[at] if np.ndim(noise_m) else noise_m
        with np.errstate(invalid="ignore"):
            plausible[at] = (rms ** 2 <= spread * least_noise ** 2) & (np.abs(deviation) <= factor * least_noise) \
                & (slope <= spacing * steepest + factor * noise * slope_noise)
    return np.isfinite(range_m) & ~plausible


#: Narrowest leaf, m, for :func:`narrow_surfaces` (assumption: pear, apple and vine leaves are 3-10 cm wide; a
#: surface narrower than 1.6 cm is a leaf or twig piece).
MIN_LEAF_WIDTH_M = 0.016
#: Fewest core pulses of a surface that :func:`rim_mixed` fits its smooth surface to (two planes' worth).
MIN_CORE_PULSES = 6


def rim_mixed(range_m: np.ndarray, surfaces: np.ndarray, noise_m: np.ndarray | float, margin_px: float,
              factor: float = 3.0) -> np.ndarray:
    """Pulses linked into a surface, near its outline, whose range lies off the surface's own smooth surface.

    :func:`edge_pulses` judges a pulse by the planes of the half discs
    through it, before any surface exists; a mixed pulse at a surface's
    outline passes it when one half disc (the ramp of mixed ranges across
    the edge, or a disc reaching both sides) is a plausible plane within
    the noise. After the linking the surface itself says where it lies:
    the Gaussian-weighted local plane of its pulses more than
    ``margin_px`` inside its outline (:func:`leafsfs.grid.gaussian_planes`,
    sigma ``1.5 margin_px``), extrapolated to its outermost pulses. An
    outermost pulse more than ``factor`` noise standard deviations off it
    mixes in another surface (a leaf over a branch, a branch over a leaf,
    a leaf over a leaf a few centimetres behind).

    Parameters
    ----------
    range_m : ndarray, 2-D
        Ranges, m (NaN: no return).
    surfaces : ndarray of int, 2-D
        Surface label of every linked pulse (0: none).
    noise_m : ndarray or float
        Range noise standard deviation (per pulse or one for all), m.
    margin_px : float
        How far inside its outline a surface's pulses may still mix in
        another one, pixels (about a footprint radius; at least 1).
    factor : float
        Tolerance, in noise standard deviations.

    Returns
    -------
    ndarray of bool, 2-D
        Pulses within ``margin_px`` of their surface's outline off its core's plane (surfaces with fewer than
        :data:`MIN_CORE_PULSES` core pulses are not judged).
    """
    margin = max(1.0, float(margin_px))
    noise = np.broadcast_to(np.asarray(noise_m, dtype=float), range_m.shape)
    out = np.zeros(range_m.shape, dtype=bool)
    for k, box in enumerate(ndimage.find_objects(surfaces), start=1):
        if box is None:
            continue
        box = tuple(slice(max(s.start - 1, 0), min(s.stop + 1, n)) for s, n in zip(box, range_m.shape))
        inside = surfaces[box] == k
        depth = ndimage.distance_transform_edt(np.pad(inside, 1))[1:-1, 1:-1]
        core = depth > margin
        if core.sum() < MIN_CORE_PULSES:
            continue
        height, _, fitted = gaussian_planes(np.where(core, range_m[box], 0.0), core, 1.5 * margin)
        rim = inside & ~core & fitted
        with np.errstate(invalid="ignore"):
            out[box] |= rim & (np.abs(range_m[box] - height) > factor * noise[box])
    return out


def grow_outline(labels: np.ndarray, range_m: np.ndarray, candidates: np.ndarray, pure: np.ndarray,
                 noise_m: np.ndarray | float, radius_px: float, factor: float = 3.0) -> np.ndarray:
    """Leaf regions grown over the unpaired pulses at their outline that lie on their smooth surface.

    A pulse at a leaf's outline whose footprint is partly off the leaf with
    nothing returning behind it (sky, or a surface too far to mix with it in
    range) returns the range of its lit part: near the leaf's surface, yet
    off the half-disc planes of :func:`edge_pulses` by a little more than
    the noise on a tilted leaf, so it is linked into no surface, and no pair
    of surfaces brackets it. It is the leaf's all the same: it joins the
    region when it lies within ``radius_px`` of it and within ``factor``
    noise standard deviations of the region's Gaussian-weighted local plane
    (:func:`leafsfs.grid.gaussian_planes`, sigma ``1.5 radius_px``, as
    :func:`rim_mixed`), extrapolated from the region's pure pulses. Where two
    regions qualify the pulse joins the one it lies nearer to in noise units.

    Parameters
    ----------
    labels : ndarray of int, 2-D
        Leaf region per pulse (0: none).
    range_m : ndarray, 2-D
        Ranges, m (NaN: no return).
    candidates : ndarray of bool, 2-D
        Pulses that may join a region (unlinked and unpaired).
    pure : ndarray of bool, 2-D
        The regions' pulses their planes are fitted to.
    noise_m : ndarray or float
        Range noise standard deviation (per pulse or one for all), m.
    radius_px : float
        How far outside a region its outline pulses may lie, pixels (about a
        footprint radius; at least 1).
    factor : float
        Tolerance, in noise standard deviations.

    Returns
    -------
    ndarray of int, 2-D
        ``labels`` with the grown pulses labelled.
    """
    radius = max(1.0, float(radius_px))
    reach = int(math.ceil(radius))
    noise = np.broadcast_to(np.asarray(noise_m, dtype=float), range_m.shape)
    todo = candidates & (labels == 0) & np.isfinite(range_m)
    best = np.full(range_m.shape, np.inf)
    out = labels.copy()
    if not todo.any():
        return out
    for k, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is None:
            continue
        box = tuple(slice(max(s.start - reach, 0), min(s.stop + reach, n)) for s, n in zip(box, range_m.shape))
        inside = labels[box] == k
        near = todo[box] & (ndimage.distance_transform_edt(~inside) <= radius)
        if not near.any():
            continue
        known = inside & pure[box]
        if known.sum() < MIN_CORE_PULSES:
            continue
        height, _, fitted = gaussian_planes(np.where(known, range_m[box], 0.0), known, 1.5 * radius)
        with np.errstate(invalid="ignore"):
            off = np.abs(range_m[box] - height) / noise[box]
        take = near & fitted & (off <= factor) & (off < best[box])
        out[box][take] = k
        best[box][take] = off[take]
    return out


#: Rows of the scan whose local planes :func:`crease_pulses` fits at once (memory: about 1 kB per pixel).
CREASE_STRIP_ROWS = 256


def crease_pulses(range_m: np.ndarray, known: np.ndarray, spacing_m: np.ndarray | float, noise_m: np.ndarray | float,
                  sigma_px: float = 3.0, max_angle_deg: float = 40.0, factor: float = 3.0) -> np.ndarray:
    """Pulses where two surfaces meet at an angle with no step in range (a crease of the normal).

    Two leaves touching at the same distance, or a leaf lying on a branch,
    leave no range step between them that the linking could cut, only a
    change of the normal. Around every pulse ``p`` and along the four grid
    directions ``u``, the local planes at ``p + d u`` and ``p - d u`` (``d =
    2 sigma_px``: Gaussian-weighted least-squares planes of the ranges,
    :func:`leafsfs.grid.gaussian_planes`, which see little of each other)
    are compared: ``p`` is a crease pulse when their normals differ by more
    than ``max_angle_deg`` and both planes, extrapolated to ``p``, predict
    its range within ``factor`` noise standard deviations (the two surfaces
    meet there). A leaf's own
    curvature turns its normal by far less over ``2 d`` pixels (about 1 cm
    at the FARO protocol's step and 3 m). The normal of a plane of range
    gradient ``g`` (m per pixel) is ``(g / spacing, -1)`` in the beam's frame.

    Parameters
    ----------
    range_m : ndarray, 2-D
        Ranges, m (NaN: no return).
    known : ndarray of bool, 2-D
        Pulses the planes are fitted to (the pure ones: not edge pulses).
    spacing_m : ndarray or float
        Distance between neighbouring pulses on a surface facing the beam (range times the angular step), m.
    noise_m : ndarray or float
        Range noise per pulse (or one for all), m.
    sigma_px : float
        Standard deviation of the planes' Gaussian weights, pixels (the
        slope noise falls as ``sigma_px ** -2``: 3 pixels keep it to about 4
        deg at a noise of three pulse spacings).
    max_angle_deg : float
        Largest angle between the normals of one surface's two sides, deg
        (assumption: 40; the leaves and branches merged in the leafy tree at
        0.018 deg meet at 50-90 deg).
    factor : float
        Range tolerance of the meeting test, in noise standard deviations.

    Returns
    -------
    ndarray of bool, 2-D
    """
    if not sigma_px > 0 or not 0 < max_angle_deg < 180 or not factor > 0:
        raise SfsError(f"sigma_px and factor must be positive and max_angle_deg lie in ]0, 180[, got {sigma_px!r}, "
                       f"{max_angle_deg!r} and {factor!r}")
    d = max(1, int(round(2 * sigma_px)))
    margin = d + int(math.ceil(3 * sigma_px))
    rows = range_m.shape[0]
    crease = np.zeros(range_m.shape, dtype=bool)
    spacing = np.broadcast_to(spacing_m, range_m.shape)
    noise = np.broadcast_to(noise_m, range_m.shape)
    limit = math.cos(math.radians(max_angle_deg))
    for start in range(0, rows, CREASE_STRIP_ROWS):
        part = slice(max(start - margin, 0), min(start + CREASE_STRIP_ROWS + margin, rows))
        r = range_m[part]
        height, slope, fitted = gaussian_planes(np.nan_to_num(r), known[part] & np.isfinite(r), sigma_px)
        tangent = slope / np.asarray(spacing[part])[..., None]
        tolerance = factor * np.asarray(noise[part])
        found = np.zeros(r.shape, dtype=bool)
        for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1)):
            sides = []
            for sign in (1, -1):
                a, b = sign * d * di, sign * d * dj
                ok = shifted(fitted, a, b, False)
                t = shifted(tangent, a, b, 0.0)
                # the plane at p + (a, b), extrapolated back to p
                at_p = shifted(height, a, b, np.nan) - a * shifted(slope[..., 0], a, b, 0.0) \
                    - b * shifted(slope[..., 1], a, b, 0.0)
                with np.errstate(invalid="ignore"):
                    sides.append((ok & (np.abs(at_p - r) <= tolerance), t))
            (ok_a, t_a), (ok_b, t_b) = sides
            cosine = (1 + np.sum(t_a * t_b, axis=-1)) / np.sqrt((1 + np.sum(t_a ** 2, axis=-1))
                                                                * (1 + np.sum(t_b ** 2, axis=-1)))
            found |= ok_a & ok_b & (cosine < limit)
        keep = slice(start - part.start, start - part.start + min(CREASE_STRIP_ROWS, rows - start))
        crease[start:start + CREASE_STRIP_ROWS] = found[keep]
    return crease & np.isfinite(range_m)


def split_creases(surfaces: np.ndarray, range_m: np.ndarray, candidates: np.ndarray, spacing_m: np.ndarray,
                  noise_m: np.ndarray | float, max_angle_deg: float, min_pixels: int) -> tuple[np.ndarray, bool]:
    """Candidate surfaces cut along their creases (:func:`crease_pulses`) into parts of at least ``min_pixels``.

    Each candidate's planes are fitted to its own pulses only, so a
    neighbouring surface does not bend them. Where the crease pulses cut a
    surface into two or more parts of at least ``min_pixels``, the first
    part keeps the label, the others are numbered after the existing
    labels, and the crease pulses and smaller pieces go to the nearest part.

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    range_m : ndarray, 2-D
        Ranges, m.
    candidates : ndarray of bool
        Surfaces that may be cut (index = label), e.g. the leaves.
    spacing_m : ndarray, 2-D
        Distance between neighbouring pulses on a surface facing the beam, m.
    noise_m : ndarray or float
        Range noise per pulse (or one for all), m.
    max_angle_deg : float
        Crease angle (:func:`crease_pulses`), deg.
    min_pixels : int
        Smallest part, pixels.

    Returns
    -------
    surfaces : ndarray of int, 2-D
        Surface labels.
    cut : bool
        Whether any surface was cut.
    """
    out = surfaces.copy()
    count = int(surfaces.max(initial=0))
    noise = np.broadcast_to(noise_m, range_m.shape)
    cut = False
    for k, box in enumerate(ndimage.find_objects(surfaces), start=1):
        if box is None or k >= len(candidates) or not candidates[k]:
            continue
        inside = surfaces[box] == k
        if inside.sum() < 2 * min_pixels:
            continue
        crease = crease_pulses(range_m[box], inside, spacing_m[box], noise[box], max_angle_deg=max_angle_deg) & inside
        if not crease.any():
            continue
        parts, n = ndimage.label(inside & ~crease)
        sizes = np.bincount(parts.ravel(), minlength=n + 1)
        sizes[0] = 0
        big = np.nonzero(sizes >= min_pixels)[0]
        if len(big) < 2:
            continue
        lookup = np.zeros(n + 1, dtype=int)
        lookup[big] = np.r_[k, count + 1 + np.arange(len(big) - 1)]
        count += len(big) - 1
        labels = lookup[parts]
        nearest = tuple(ndimage.distance_transform_edt(labels == 0, return_distances=False, return_indices=True))
        out[box][inside] = labels[nearest][inside]
        cut = True
    return out, cut


def shifted(image: np.ndarray, di: int, dj: int, fill) -> np.ndarray:
    """An image shifted on the scan grid: ``out[i, j] = image[i + di, j + dj]``, ``fill`` outside.

    Parameters
    ----------
    image : ndarray, (rows, cols, ...)
        Any per-pulse image.
    di, dj : int
        Shift in rows and columns, pulses (either sign; a shift as large as the image gives all ``fill``).
    fill : scalar
        Value where ``image[i + di, j + dj]`` lies outside the image.

    Returns
    -------
    ndarray
        The shifted image, same shape and dtype.
    """
    out = np.full_like(image, fill)
    rows, cols = image.shape[:2]
    if abs(di) >= rows or abs(dj) >= cols:
        return out
    out[max(-di, 0):rows - max(di, 0), max(-dj, 0):cols - max(dj, 0)] = \
        image[max(di, 0):rows + min(di, 0) or None, max(dj, 0):cols + min(dj, 0) or None]
    return out


def split_necks(surfaces: np.ndarray, ratio: float = 0.3, min_pixels: int = 30) -> np.ndarray:
    """Surfaces cut where they narrow below ``ratio`` of their widest part.

    The opening of a surface by a disc of radius ``ratio`` times its largest
    inscribed radius keeps its wide parts (a leaf blade) and removes what is
    narrower than the disc (a twig or petiole running into it, a branch
    leaving the trunk, and the blade's own tips and rim). Each connected
    piece of the opening becomes a surface; each removed piece becomes one
    too when it is larger than twice the disc's area and ``min_pixels``
    (an appendage), and otherwise goes back to the piece it touches most (a
    tip). Labels are renumbered from 1 (0 stays 0).

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    ratio : float
        Neck width relative to the widest part, in ]0, 1[.
    min_pixels : int
        Smallest piece split off, pixels.
    """
    if not 0 < ratio < 1:
        raise SfsError(f"ratio must lie in ]0, 1[, got {ratio!r}")
    out = np.zeros_like(surfaces)
    count = 0
    for k, box in enumerate(ndimage.find_objects(surfaces), start=1):
        if box is None:
            continue
        box = tuple(slice(max(s.start - 1, 0), s.stop + 1) for s in box)
        inside = surfaces[box] == k
        depth = ndimage.distance_transform_edt(np.pad(inside, 1))[1:-1, 1:-1]
        radius = ratio * float(depth.max())
        if radius < 1.5:
            count += 1
            out[box][inside] = count
            continue
        size = int(math.ceil(radius))
        disc = np.hypot(*np.mgrid[-size:size + 1, -size:size + 1]) <= radius
        core = ndimage.binary_opening(inside, disc) & inside
        pieces, n_core = ndimage.label(core, structure=np.ones((3, 3), bool))
        rest, n_rest = ndimage.label(inside & ~core, structure=np.ones((3, 3), bool))
        if n_core == 0:
            count += 1
            out[box][inside] = count
            continue
        labels = pieces.copy()
        big = max(2 * disc.sum(), min_pixels)
        sizes = np.bincount(rest.ravel(), minlength=n_rest + 1)
        grown = ndimage.grey_dilation(pieces, footprint=np.ones((3, 3), bool))
        for part in range(1, n_rest + 1):
            sel = rest == part
            if sizes[part] >= big:
                n_core += 1
                labels[sel] = n_core
                continue
            touching = grown[sel]
            touching = touching[touching > 0]
            labels[sel] = np.bincount(touching).argmax() if len(touching) else 0
        # Pieces given to no core (a sliver touching none) stay with the first one.
        labels[inside & (labels == 0)] = 1
        out[box][inside] = labels[inside] + count
        count += n_core
    return out


def principal_spreads(surfaces: np.ndarray, range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Standard deviations of each surface's points along its three principal axes, m, largest first.

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    range_m, theta, psi : ndarray, 2-D
        Scan grids (m, rad).

    Returns
    -------
    ndarray, (K + 1, 3)
        Row ``k`` for surface ``k`` (row 0 and missing labels: NaN).
    """
    count = int(surfaces.max())
    out = np.full((count + 1, 3), np.nan)
    sel = (surfaces > 0) & np.isfinite(range_m)
    if not sel.any():
        return out
    label = surfaces[sel]
    xyz = beam_frame(theta[sel], psi[sel])[0] * range_m[sel][:, None]
    n = np.bincount(label, minlength=count + 1).astype(float)
    mean = np.stack([np.bincount(label, xyz[:, a], minlength=count + 1) for a in range(3)], axis=1)
    mean = mean / np.maximum(n, 1)[:, None]
    d = xyz - mean[label]
    cov = np.zeros((count + 1, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            cov[:, a, b] = cov[:, b, a] = np.bincount(label, d[:, a] * d[:, b], minlength=count + 1)
    cov /= np.maximum(n, 1)[:, None, None]
    present = n >= 3
    out[present] = np.sqrt(np.clip(np.linalg.eigvalsh(cov[present])[:, ::-1], 0, None))
    return out


def narrow_surfaces(surfaces: np.ndarray, range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray,
                    min_width_m: float) -> np.ndarray:
    """Which surfaces are narrower in 3-D than a leaf (index = label; False for 0).

    A surface's width is four times the spread of its points along their
    second principal axis (a filled ellipse of width ``w`` has a spread of
    ``w / 4`` across it, a rectangle ``w / sqrt(12)``). Points in 3-D are
    free of foreshortening, so a leaf seen at grazing incidence keeps its
    width; what is narrower is a piece of a leaf (a strip between an
    occluder and the leaf's outline, or a rim the linking split off) or a
    short twig piece, neither of which holds a leaf's traits.

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    range_m, theta, psi : ndarray, 2-D
        Scan grids (m, rad).
    min_width_m : float
        Narrowest leaf, m (0: none is narrow).
    """
    if not min_width_m >= 0:
        raise SfsError(f"min_width_m must be non-negative, got {min_width_m!r}")
    with np.errstate(invalid="ignore"):
        narrow = 4 * principal_spreads(surfaces, range_m, theta, psi)[:, 1] < min_width_m
    narrow[0] = False
    return narrow


def wood_surfaces(surfaces: np.ndarray, range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray, step_rad: float,
                  alpha: np.ndarray | None = None, *, max_aspect: float = 4.0, min_fill: float = 0.5) -> np.ndarray:
    """Which surfaces are shaped like wood (index = label; False for 0).

    Two scale-free tests on a surface's points in 3-D:

    * elongated: the spread along the first principal axis exceeds
      ``max_aspect`` times that along the second (for a rectangle or an
      ellipse the ratio is its length over its width, whatever its size,
      distance or orientation to the beam): a twig, branch or trunk piece;
    * sparse: its area (pixel footprints divided by ``cos(alpha)``, the
      intensity-derived incidence capped at :data:`MAX_AREA_INCIDENCE_DEG`) covers less than
      ``min_fill`` of the ellipse its two principal spreads span (``4 pi s1
      s2``; a filled ellipse or rectangle gives about 1): a fork or a
      network of branches.

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    range_m, theta, psi : ndarray, 2-D
        Scan grids (m, rad).
    step_rad : float
        Angle between neighbouring beams, rad.
    alpha : ndarray, 2-D, optional
        Intensity-derived incidence, rad (without it, 60 deg everywhere).
    max_aspect : float
        Longest length-to-width ratio of a leaf (assumption: 4; broad
        leaves such as pear, apple or vine have 1-2.5).
    min_fill : float
        Smallest fill of a leaf (assumption: 0.5; a leaf cut by occluders
        or cupped stays above it on the tree it was checked on).
    """
    if not max_aspect > 1 or not 0 <= min_fill < 1:
        raise SfsError(f"max_aspect must exceed 1 and min_fill lie in [0, 1[, got {max_aspect!r} and {min_fill!r}")
    spread = principal_spreads(surfaces, range_m, theta, psi)
    incidence = np.full(range_m.shape, math.radians(60.0)) if alpha is None else \
        np.minimum(np.nan_to_num(alpha, nan=math.radians(60.0)), math.radians(MAX_AREA_INCIDENCE_DEG))
    sel = (surfaces > 0) & np.isfinite(range_m)
    area = np.bincount(surfaces[sel], range_m[sel] ** 2 * step_rad ** 2 / np.cos(incidence[sel]),
                       minlength=len(spread))
    with np.errstate(invalid="ignore", divide="ignore"):
        wood = (spread[:, 0] > max_aspect * spread[:, 1]) | (area < min_fill * 4 * math.pi * spread[:, 0] * spread[:, 1])
    wood[0] = False
    return wood



def dark_surfaces(surfaces: np.ndarray, range_m: np.ndarray, alpha: np.ndarray, step_rad: float,
                  tolerance_rad: float, noise_m: float) -> np.ndarray:
    """Which surfaces return less power than a leaf on their own plane would (index = label; False for 0).

    A leaf is a flat Lambertian surface of the calibrated reflectance: the
    incidence its intensity gives (``alpha``, through the leaf calibration)
    is the incidence of the plane its ranges span. A surface whose median
    ``alpha`` exceeds the incidence of its least-squares range plane (range
    against the pulses' row and column, ``tan = |gradient| / (r step)`` at
    its median range) by more than ``tolerance_rad`` is no leaf: a piece of
    twig or branch, whose front faces the beam as a plane while its pulses
    see the bulging surface at up to 90 deg and bark reflects less than a
    leaf. Range noise only steepens a fitted plane, so a narrow piece is
    spared rather than taken. Surfaces without a finite ``alpha`` are not dark,
    nor are surfaces whose ranges leave their plane by more than three times
    the range noise (RMS): their curvature is resolved (a dome, a rolled leaf),
    so the plane says nothing of the incidence their pulses see.

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    range_m : ndarray, 2-D
        Ranges, m (NaN: no return).
    alpha : ndarray, 2-D
        Intensity-derived incidence, rad (NaN: unknown).
    step_rad : float
        Angle between neighbouring beams, rad.
    tolerance_rad : float
        Largest excess of the intensity's incidence over the plane's, rad.
    noise_m : float
        Range noise (standard deviation), m.
    """
    if not tolerance_rad >= 0 or not step_rad > 0:
        raise SfsError(f"tolerance_rad must be non-negative and step_rad positive, got {tolerance_rad!r} and "
                       f"{step_rad!r}")
    count = int(surfaces.max(initial=0)) + 1
    dark = np.zeros(count, dtype=bool)
    sel = (surfaces > 0) & np.isfinite(range_m)
    if not sel.any():
        return dark
    label = surfaces[sel]
    rows, cols = np.nonzero(sel)
    n = np.bincount(label, minlength=count).astype(float)
    safe = np.maximum(n, 1)
    centred = [v - (np.bincount(label, v, minlength=count) / safe)[label] for v in (rows.astype(float),
                                                                                 cols.astype(float), range_m[sel])]
    di, dj, dr = centred
    moments = [[np.bincount(label, a * b, minlength=count) for b in (di, dj)] for a in (di, dj)]
    rhs = [np.bincount(label, a * dr, minlength=count) for a in (di, dj)]
    det = moments[0][0] * moments[1][1] - moments[0][1] * moments[1][0]
    with np.errstate(invalid="ignore", divide="ignore"):
        gi = (moments[1][1] * rhs[0] - moments[0][1] * rhs[1]) / det
        gj = (moments[0][0] * rhs[1] - moments[1][0] * rhs[0]) / det
    median_range = labelled_medians(range_m[sel], label, count)
    plane = np.arctan(np.hypot(gi, gj) / (median_range * step_rad))
    residual = dr - gi[label] * di - gj[label] * dj
    flat = np.bincount(label, residual ** 2, minlength=count) / safe <= (3 * noise_m) ** 2
    known = sel & np.isfinite(alpha)
    median_alpha = labelled_medians(alpha[known], surfaces[known], count)
    with np.errstate(invalid="ignore"):
        dark = (median_alpha > plane + tolerance_rad) & (n >= 3) & flat
    dark[0] = False
    return dark


def labelled_medians(values: np.ndarray, labels: np.ndarray, count: int) -> np.ndarray:
    """Median of the values of each label, as :func:`scipy.ndimage.median` gives it (the same bits).

    ``scipy.ndimage.median`` sorts every pixel of the image, those of no
    label included (on the leafy tree at 0.018 deg, 5.6 M pulses, 0.4 s a
    call); this sorts only the labelled values, by label then value, and
    takes the middle one, or the mean of the middle two, as it does.

    Parameters
    ----------
    values : ndarray, 1-D
        The labelled values (no NaN).
    labels : ndarray of int, 1-D
        Their labels, in ``[0, count)``.
    count : int
        Number of labels.

    Returns
    -------
    ndarray, (count,)
        Median per label; NaN for labels without values.

    Examples
    --------
    >>> labelled_medians(np.array([3.0, 1.0, 2.0, 5.0, 4.0]), np.array([1, 1, 1, 2, 2]), 4)
    array([nan, 2. , 4.5, nan])
    """
    order = np.lexsort((values, labels))
    values, labels = values[order], labels[order]
    n = np.bincount(labels, minlength=count)
    first = np.cumsum(n) - n  # where each label's sorted values start
    lo = first + (n - 1) // 2
    hi = first + n // 2
    out = np.full(count, np.nan)
    present = n > 0
    out[present] = (values[lo[present]] + values[hi[present]]) / 2.0
    return out


def _range_plane(rows: np.ndarray, cols: np.ndarray, range_m: np.ndarray) -> np.ndarray:
    """Least-squares plane of the ranges over the pixel rows and columns: ``(r0, dr/drow, dr/dcol)``."""
    design = np.stack([np.ones(len(range_m)), rows, cols], axis=1).astype(float)
    return np.linalg.lstsq(design, range_m, rcond=None)[0]


#: Largest median absolute residual of a leaf piece's ranges from the plane of the blade it touches near the cut,
#: as a share of :func:`join_occluded`'s tolerance (2 sigma of a 3-sigma tolerance; chosen on the leafy tree and
#: pear seed 7: at 1.5 sigma, the fragments' value, half the pieces of one leaf stay apart).
PIECE_TOLERANCE = 2.0 / 3.0


def join_occluded(surfaces: np.ndarray, range_m: np.ndarray, candidates: np.ndarray, gap_px: float,
                  tolerance_m: float, local_px: float = 0.0, fragments: np.ndarray | None = None,
                  lobe_ratio: float = 0.0, piece_ratio: float = 0.0, bands_px: float = 0.0) -> np.ndarray:
    """Surfaces cut apart by an occluder in front of them joined into one (the label of the first).

    Two candidate surfaces are the parts of one leaf when they come within
    ``gap_px`` of each other, most valid pulses of the gap between them
    (within ``gap_px`` of both, on neither) lie nearer than both their range
    planes by more than ``tolerance_m`` (something in front of the leaf cut
    it: a twig or a petiole; a gap showing what lies behind, or nothing,
    separates two leaves), and each part's range plane predicts the other's
    ranges within ``tolerance_m`` (median absolute residual: one plane) --
    the planes of the whole parts, or (a curved or curled leaf, whose whole
    parts are on no common plane) those of the pulses of each part within
    ``local_px`` of the other. The parts lie up to ``gap_px + bands_px``
    apart: the occluder, and on either side of it the band of edge pulses
    left out of the linking; the gap is then the pixels within half the
    parts' distance (plus a pixel) of both, where that is more than
    ``gap_px``.

    A ``fragments`` surface (one judged no leaf on its own: a leaf's tip or
    lobe cut off by a twig is too narrow, too elongated or too dark for a
    leaf) joins a candidate by the same tests when it holds fewer pulses than
    the candidate (the leaf's main part holds most of the leaf; a larger
    surface on the leaf's plane behind a twig is the branch the leaf lies
    against), and joins one candidate at most (it never links two leaves).

    A fragment that touches a candidate (a lobe or tip the neck cut took off
    the blade) joins it without the gap test when it holds at most
    ``lobe_ratio`` of the candidate's pulses and continues the candidate's
    plane near the cut: the median absolute residual of all its ranges from
    the plane of the candidate's pulses within ``local_px`` of it is at most
    half ``tolerance_m`` (1.5 sigma for a 3-sigma tolerance). A twig or branch
    the neck cut off a leaf is larger than a lobe or leaves that plane.

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    range_m : ndarray, 2-D
        Ranges, m (NaN: no return).
    candidates : ndarray of bool
        Surfaces that may be joined (index = label), e.g. the leaves.
    gap_px : float
        Widest occluder, pixels.
    tolerance_m : float
        Range tolerance of the plane tests, m.
    local_px : float
        Reach of the planes fitted near the cut, pixels (0: whole parts' planes only).
    fragments : ndarray of bool, optional
        Surfaces that may join one candidate (index = label), e.g. the
        surfaces that are no leaves and do not touch the window's border.
    lobe_ratio : float
        Largest share of a touching candidate's pulses a fragment joined on its plane holds (0: none; assumption:
        0.15, leaf lobes cut at a neck on the leafy tree held 2-13 % of their blade, the twigs and branches the
        neck cut off leaves 10-66 % of them).
    piece_ratio : float
        Largest share of a touching candidate's pulses another candidate joined on its plane holds (0: none;
        assumption: 0.5, the larger part is the blade; with :data:`PIECE_TOLERANCE`, chosen with the truth on the
        touching leaf surfaces of the leafy tree and pear seed 7 at 0.018 deg: 7 pairs of pieces of one leaf joined,
        2 leaf-and-wood pairs, both on the pear).
    bands_px : float
        Width of the two edge bands beside an occluder, pixels (0: the parts lie at most ``gap_px`` apart).

    Returns
    -------
    ndarray of int, 2-D
        Surface labels, each joined group under its smallest candidate label (the others no longer used).
    """
    if not gap_px > 0 or not tolerance_m > 0:
        raise SfsError(f"gap_px and tolerance_m must be positive, got {gap_px!r} and {tolerance_m!r}")
    parent = np.arange(int(surfaces.max(initial=0)) + 1)

    def root(k):
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    boxes = ndimage.find_objects(surfaces)
    reach = int(math.ceil(gap_px + bands_px))
    leaf = np.zeros(len(parent), dtype=bool)
    leaf[:len(candidates)] = candidates[:len(parent)]
    joinable = leaf.copy()
    if fragments is not None:
        joinable[:len(fragments)] |= fragments[:len(parent)]
    planes = {}
    for k in np.nonzero(joinable)[0]:
        if k > 0 and boxes[k - 1] is not None:
            rows, cols = np.nonzero(surfaces[boxes[k - 1]] == k)
            rows, cols = rows + boxes[k - 1][0].start, cols + boxes[k - 1][1].start
            planes[k] = (rows, cols, _range_plane(rows, cols, range_m[rows, cols]))
    for k, (rows_k, cols_k, plane_k) in planes.items():
        box = tuple(slice(max(s.start - 2 * reach, 0), min(s.stop + 2 * reach, n))
                    for s, n in zip(boxes[k - 1], surfaces.shape))
        sub = surfaces[box]
        inside = sub == k
        apart = ndimage.distance_transform_edt(~inside)
        grown = apart <= gap_px + bands_px
        for m in np.unique(sub[grown & ~inside]):
            if m <= k or m not in planes or root(m) == root(k) or not (leaf[k] or leaf[m]):
                continue
            if not (leaf[k] and leaf[m]):
                # A fragment joins one leaf, and only one larger than itself.
                piece, whole = (k, m) if leaf[m] else (m, k)
                if root(piece) != piece or len(planes[piece][0]) >= len(planes[whole][0]):
                    continue
            other = sub == m
            if leaf[k] and leaf[m] and piece_ratio > 0:
                small, large = (k, m) if len(planes[k][0]) <= len(planes[m][0]) else (m, k)
                if len(planes[small][0]) <= piece_ratio * len(planes[large][0]) and \
                        _lobe(planes[small][:2], *((inside, other) if small == k else (other, inside)), box, range_m,
                              local_px, PIECE_TOLERANCE * tolerance_m):
                    parent[root(m)] = root(k)
                    continue
            if not (leaf[k] and leaf[m]) and len(planes[piece][0]) <= lobe_ratio * len(planes[whole][0]) and \
                    _lobe(planes[piece][:2], *((inside, other) if piece == k else (other, inside)), box, range_m,
                          local_px, 0.5 * tolerance_m):
                parent[piece] = root(whole)
                continue
            half = max(gap_px, 0.5 * float(apart[other].min()) + 1.0)
            gap = (apart <= half) & _dilated(other, half) & ~inside & ~other
            rows, cols = np.nonzero(gap)
            rows, cols = rows + box[0].start, cols + box[1].start
            fits = [((rows_k, cols_k, plane_k), planes[m])]  # the whole parts' planes; then the planes near the cut
            near_k, near_m = _facing(inside, other, box, local_px), _facing(other, inside, box, local_px)
            if local_px > 0 and len(near_k[0]) >= 3 and len(near_m[0]) >= 3:
                fits.append(tuple((r, c, _range_plane(r, c, range_m[r, c])) for r, c in (near_k, near_m)))
            for (rk, ck, pk), (rm, cm, pm) in fits:
                plane = 0.5 * (pk + pm)
                with np.errstate(invalid="ignore"):
                    nearer = np.mean(range_m[rows, cols] < plane[0] + plane[1] * rows + plane[2] * cols - tolerance_m)
                off_m = np.median(np.abs(range_m[rm, cm] - pk[0] - pk[1] * rm - pk[2] * cm))
                off_k = np.median(np.abs(range_m[rk, ck] - pm[0] - pm[1] * rk - pm[2] * ck))
                if len(rows) and nearer >= 0.5 and max(off_m, off_k) <= tolerance_m:
                    if leaf[k] and leaf[m]:
                        parent[root(m)] = root(k)
                    else:
                        parent[piece] = root(whole)
                    break
    roots = np.array([root(k) for k in range(len(parent))])
    return roots[surfaces]


def _lobe(pixels: tuple[np.ndarray, np.ndarray], piece: np.ndarray, whole: np.ndarray, box: tuple,
          range_m: np.ndarray, local_px: float, tolerance_m: float) -> bool:
    """Whether a piece (whole-image ``pixels``; ``piece`` its mask in ``box``) continues ``whole`` (a mask in
    ``box``): it touches it and its ranges lie on the plane of ``whole``'s pulses within ``local_px`` of it (median
    absolute residual at most ``tolerance_m``)."""
    if not (ndimage.binary_dilation(piece, np.ones((3, 3), bool)) & whole).any():
        return False
    near = _facing(whole, piece, box, local_px)
    if len(near[0]) < 3:
        return False
    plane = _range_plane(*near, range_m[near])
    rows, cols = pixels
    with np.errstate(invalid="ignore"):
        return bool(np.median(np.abs(range_m[rows, cols] - plane[0] - plane[1] * rows - plane[2] * cols))
                    <= tolerance_m)


def _facing(region: np.ndarray, other: np.ndarray, box: tuple, radius_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Whole-image rows and columns of the pixels of ``region`` within ``radius_px`` of ``other`` (both in ``box``)."""
    rows, cols = np.nonzero(region & _dilated(other, radius_px)) if radius_px > 0 else (np.zeros(0, int),) * 2
    return rows + box[0].start, cols + box[1].start


def _dilated(region: np.ndarray, radius_px: float) -> np.ndarray:
    """``region`` dilated by the disc of pixel offsets within ``radius_px`` (a distance transform: the same pixels
    as a binary dilation by that disc, at a cost that does not grow with the disc)."""
    if not region.any():
        return region.copy()
    return ndimage.distance_transform_edt(~region) <= radius_px


def rim_shares(region: np.ndarray, intensity: np.ndarray, gain_dn: float, rim_px: float) -> np.ndarray:
    """Share of each pulse's footprint on a region, from its intensity deficit at the region's outline (1 inside).

    Where nothing returns beside a leaf (sky, or a surface too far to mix
    with it in range), a pulse whose footprint is partly on the leaf
    returns the leaf's range, so the range test takes it for a pure pulse,
    but only the power of the part of its footprint on the leaf: with a
    log amplifier of gain ``gain_dn`` DN per e-fold its intensity is
    ``I_full + gain_dn ln(share)`` (tls-physics: received power
    proportional to the lit area of a Lambertian surface). ``I_full`` is
    taken from the region's pulses deeper than ``rim_px`` from its outline
    (averaged over 5 x 5 of them, the nearest), which lie wholly on it.
    Counted whole, such pulses dilate the leaf's area by about its
    perimeter times a footprint radius (+10 to +15 % on 3-6 cm pear leaves
    at 4 m and 0.018 deg).

    Parameters
    ----------
    region : ndarray of bool, 2-D
        The region's pulses.
    intensity : ndarray, 2-D
        Intensities, DN.
    gain_dn : float
        Log-amplifier gain, DN per e-fold.
    rim_px : float
        Depth from the region's outline within which a footprint may reach
        past it, pixels (a footprint radius).

    Returns
    -------
    ndarray of float, 2-D
        Share in [0, 1] per pulse (0 off the region; 1 where the region has
        no pulse deeper than ``rim_px``, no reference intensity).
    """
    if not gain_dn > 0 or not rim_px >= 0:
        raise SfsError(f"gain_dn must be positive and rim_px non-negative, got {gain_dn!r} and {rim_px!r}")
    depth = ndimage.distance_transform_edt(np.pad(region, 1))[1:-1, 1:-1]
    interior = region & (depth > rim_px) & np.isfinite(intensity)
    share = region.astype(float)
    if not interior.any():
        return share
    level = np.where(interior, intensity, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = ndimage.uniform_filter(level, 5, mode="constant") / ndimage.uniform_filter(interior.astype(float), 5,
                                                                                           mode="constant")
    nearest = tuple(ndimage.distance_transform_edt(~interior, return_distances=False, return_indices=True))
    rim = region & ~interior & np.isfinite(intensity)
    share[rim] = np.clip(np.exp((intensity[rim] - mean[nearest][rim]) / gain_dn), 0.0, 1.0)
    return share


def visibility(labels: np.ndarray, range_m: np.ndarray, tolerance_m: float, ring_px: int = 2) -> dict[int, dict]:
    """How each leaf region is cut: by something in front of it, or by the scan window's border.

    The ring of pixels up to ``ring_px`` outside a region is where its
    outline lies: an occluder in front of the leaf shows there as pulses
    nearer than the leaf's nearest pulse by more than ``tolerance_m``; the
    leaf's own edge shows as what lies behind it or no return.

    Parameters
    ----------
    labels : ndarray of int, 2-D
        Leaf regions (0: none).
    range_m : ndarray, 2-D
        Measured ranges, m (NaN: no return).
    tolerance_m : float
        Range noise margin, m.
    ring_px : int
        Width of the ring, pixels (about a footprint, where the mixed pulses of the outline lie).

    Returns
    -------
    dict
        Per label: ``occluded_fraction`` (share of the ring nearer than the
        leaf), ``border`` (the region touches the window's border) and
        ``cut`` (either: the measured area is only a part of the leaf's,
        assumption: an occluded ring share of at least
        :data:`OCCLUDED_RING_SHARE`).
    """
    out = {}
    shape = labels.shape
    size = 2 * int(ring_px) + 1
    for k, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is None:
            continue
        border = any(s.start == 0 or s.stop == n for s, n in zip(box, shape))
        box = tuple(slice(max(s.start - ring_px, 0), min(s.stop + ring_px, n)) for s, n in zip(box, shape))
        inside = labels[box] == k
        ring = ndimage.binary_dilation(inside, np.ones((size, size), bool)) & ~inside
        nearer = nearer_ring(inside, range_m[box], tolerance_m, ring_px)
        fraction = float(nearer.sum() / max(ring.sum(), 1))
        out[k] = {"occluded_fraction": fraction, "border": bool(border),
                  "cut": bool(border or fraction >= OCCLUDED_RING_SHARE)}
    return out


def nearer_ring(inside: np.ndarray, range_m: np.ndarray, tolerance_m: float, ring_px: int | None = 2) -> np.ndarray:
    """Pulses of the ring around a region that lie in front of it: an occluder's, not the region's edge.

    Parameters
    ----------
    inside : ndarray of bool, 2-D
        The region.
    range_m : ndarray, 2-D
        Measured ranges on the same pixels, m (NaN: no return).
    tolerance_m : float
        Range noise margin, m: a ring pulse is in front where it is nearer
        than the region's nearest pulse (in the grid) by more than this.
    ring_px : int or None
        Width of the ring, pixels (about a footprint, where the mixed pulses of the outline lie); None: every pulse
        outside the region.

    Returns
    -------
    ndarray of bool, 2-D
        The ring's pulses in front of the region.
    """
    if ring_px is None:
        ring = ~inside
    else:
        size = 2 * int(ring_px) + 1
        ring = ndimage.binary_dilation(inside, np.ones((size, size), bool)) & ~inside
    if not inside.any():
        return np.zeros_like(ring)
    ii, jj = ndimage.distance_transform_edt(~inside, return_distances=False, return_indices=True)
    own = range_m[ii, jj]  # the range of the region's nearest pulse
    with np.errstate(invalid="ignore"):
        return ring & (range_m < own - tolerance_m)

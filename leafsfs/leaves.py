"""Split a scan into leaf regions at range discontinuities that the intensity does not explain.

Between two neighbouring pulses on one smooth surface, the range changes by
at most ``r * dtheta * tan(alpha)`` (``dtheta`` the angle between the beams,
``alpha`` the incidence). The intensity gives ``alpha``; a range step larger
than that slope allows (plus a margin and the range noise) is where the
intensity and the geometry disagree: an object edge, or the mixed
("outlier") points of a phase-shift scanner that lie between two surfaces
(thesis ch.1 §2.3 and its general conclusion). Without an alpha image a fixed
steepest slope is used.

Pixels joined by plausible steps (4-neighbour links) form connected
regions; those of at least ``min_pixels`` are *surfaces*. Mixed points,
whose ranges lie between two surfaces, end up alone or in small groups;
:func:`leafsfs.edges.attribute_mixed` finds the two surfaces each one
straddles and gives it to the one that returned most of its power. A leaf
region is a surface with the mixed pulses it dominates. Surfaces touching
the scan window's border (the background behind the leaves) are not leaves
by default.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from leafsfs.canopy import (MIN_LEAF_WIDTH_M, dark_surfaces, edge_pulses, grow_outline, join_occluded,
                            narrow_surfaces, principal_spreads, pulse_noise, rim_mixed, shifted, split_creases,
                            split_necks, wood_surfaces)
from leafsfs.darkparts import bark_surfaces, dark_parts
from leafsfs.edges import MixedPulses, attribute_mixed, band_pixels
from leafsfs.errors import SfsError
from leafsfs.splits import split_merged
from tlssim.pattern import beam_axis

#: Smallest neighbourhood radius of the edge test, pixels, for a footprint of a pixel or more (a 5 x 5 disc: the mixed
#: pulses between two surfaces then form a ramp, which a plane in fewer pixels takes for a steep surface).
MIN_EDGE_RADIUS_PX = 2.5
#: Smallest neighbourhood radius of the edge test beyond the footprint's, pixels (a 3 x 3 disc, whose half discs hold
#: 6 pulses, the fewest that fit a plane with residuals left to judge it): under a pixel, as at 0.08 deg, a footprint
#: mixes two surfaces over one pulse, and a 5 x 5 neighbourhood reaches past the outline of a leaf a few pulses wide
#: from most of its pulses, so its darkened outline pulses stay in its surface and make it darker than its plane
#: (no leaf). The floor is ``min(MIN_EDGE_RADIUS_PX, COARSE_EDGE_RADIUS_PX + footprint radius)``. Measured at 0.08 deg
#: (`fused`, mean per-leaf ROP reduction 3 sigma / good points lost; leafy tree, footprint 0.45 px / pear s31 2.5 m,
#: 0.73 px / pear s41 5 m, 0.36 px): floor 2.5: 0.31 / 0.42 / 0.41 with 3.0 / 1.8 / 6.2 % lost; this rule (1.95 / 2.23 /
#: 1.86): 0.35 / 0.42 / 0.40 with 1.6 / 1.3 / 3.9 %; 1.5 everywhere: 0.35 / 0.47 / 0.40, but at 0.018 deg (footprint
#: 2.0 px at 4 m) the leafy tree found 90.7 -> 89.7 %, false 66 -> 75, pear s23 4 m ROP reduction 0.62 -> 0.58.
COARSE_EDGE_RADIUS_PX = 1.5
#: Range noise assumed when a scan has too few consecutive returns to measure it, m.
NOISE_FLOOR_M = 0.001


def neighbour_steps(theta: np.ndarray, psi: np.ndarray, alpha: np.ndarray | None = None, *,
                    max_slope_deg: float = 80.0, alpha_margin_deg: float = 25.0) -> list:
    """What :func:`link_components` needs of the scan grid, per neighbour (the next row, the next column).

    It does not depend on the ranges, so :func:`segment_scan`, which links
    the pulses twice on one grid, computes it once (on the leafy tree at
    0.018 deg the beam axes and their angles took 3 s a linking).

    Parameters
    ----------
    theta, psi : ndarray, 2-D
        Azimuth and zenith of every beam, rad.
    alpha : ndarray, 2-D, optional
        Incidence from the intensity, rad (as for :func:`link_components`).
    max_slope_deg, alpha_margin_deg : float
        As for :func:`link_components`, degrees.

    Returns
    -------
    list of (int, int, ndarray, ndarray)
        Per neighbour its offset ``(di, dj)``, the angle between each beam
        and that neighbour's, rad (the image's last row or column: the angle
        to no beam, ``pi / 2``), and the tangent of the steepest slope
        allowed between the two pulses.
    """
    if not 0 < max_slope_deg < 90:
        raise SfsError(f"max_slope_deg must lie in ]0, 90[ degrees, got {max_slope_deg!r}")
    axis = beam_axis(theta, psi)
    limit = math.radians(max_slope_deg)
    slope = np.full(theta.shape, limit) if alpha is None else \
        np.minimum(np.nan_to_num(alpha, nan=limit) + math.radians(alpha_margin_deg), limit)
    steps = []
    for di, dj in ((1, 0), (0, 1)):
        angle = np.arccos(np.clip(np.sum(axis * shifted(axis, di, dj, 0.0), axis=-1), -1, 1))
        steps.append((di, dj, angle, np.tan(np.minimum(slope, shifted(slope, di, dj, limit)))))
    return steps


def link_components(range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray, alpha: np.ndarray | None = None, *,
                    max_slope_deg: float = 80.0, alpha_margin_deg: float = 25.0, noise_m: float = 0.002,
                    steps: list | None = None) -> np.ndarray:
    """Connected components of the valid pixels joined by plausible range steps (labels 1.., 0 = no return).

    Parameters
    ----------
    range_m : ndarray, 2-D
        Ranges, m (NaN: no return).
    theta, psi : ndarray, 2-D
        Azimuth and zenith of every beam, rad.
    alpha : ndarray, 2-D, optional
        Incidence from the intensity, rad: two neighbours may differ by the
        range step of a surface inclined by ``alpha + alpha_margin_deg``
        (without it, by ``max_slope_deg``).
    max_slope_deg : float
        Steepest surface inclination allowed, degrees, in ]0, 90[.
    alpha_margin_deg : float
        Margin added to ``alpha``, degrees.
    noise_m : float
        Range step allowed on top of the slope's, m.
    steps : list, optional
        :func:`neighbour_steps` of ``theta``, ``psi``, ``alpha``,
        ``max_slope_deg`` and ``alpha_margin_deg``, if already computed
        (default: computed here).

    Returns
    -------
    ndarray of int, 2-D
        Component label per pixel (1.., 0 = no return).
    """
    if steps is None:
        steps = neighbour_steps(theta, psi, alpha, max_slope_deg=max_slope_deg, alpha_margin_deg=alpha_margin_deg)
    valid = np.isfinite(range_m)
    r = np.where(valid, range_m, np.nan)
    index = np.arange(r.size).reshape(r.shape)
    rows, cols = [], []
    for di, dj, angle, tan_slope in steps:
        other = shifted(r, di, dj, np.nan)
        allowed = np.fmin(r, other) * angle * tan_slope + noise_m
        with np.errstate(invalid="ignore"):
            ok = valid & np.isfinite(other) & (np.abs(r - other) <= allowed)
        rows.append(index[ok])
        cols.append(shifted(index, di, dj, -1)[ok])
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(r.size, r.size))
    _, component = csgraph.connected_components(graph, directed=False)
    return np.where(valid.ravel(), component + 1, 0).reshape(r.shape)


@dataclass
class Segmentation:
    """Leaf regions of a scan and the surfaces and mixed pulses they were built from.

    Attributes
    ----------
    leaves : ndarray of int, 2-D
        Leaf region per pulse, 1..K (0: none): a leaf's pure pulses and the
        mixed pulses it returned most of the power of.
    leaf_surfaces : ndarray of int, (K,)
        Surface label of each leaf region (``leaf_surfaces[k - 1]`` for region ``k``).
    mixed : MixedPulses
        The surfaces (large linked components) and the attribution of the mixed pulses.
    footprint_px : float
        How far inside a surface's outline a pulse's footprint may reach
        past it, pixels (at least 1): two footprint radii at the scan's
        median range, one for the outermost pulses the range test keeps
        (about a radius outside the surface's edge) and one inside the
        edge, beyond which less than 3 % of a Gaussian footprint lies
        across it.
    band_px : int
        How far from a surface its mixed pulses may lie, pixels (``band_m``).
    noise_m : float
        Range noise the pairing allowed (a third of its tolerance), m.
    reach_m : float
        How far from a surface a thin part's mixed pulses were paired with it, m (``segment_scan``'s ``reach_m``).
    """

    leaves: np.ndarray
    leaf_surfaces: np.ndarray
    mixed: MixedPulses
    footprint_px: float = 1.0
    band_px: int = 2
    noise_m: float = NOISE_FLOOR_M
    reach_m: float = 0.05

    def region_surface(self, label: int) -> int:
        """Surface label of leaf region ``label``."""
        return int(self.leaf_surfaces[label - 1])


def angular_step(theta: np.ndarray, psi: np.ndarray, samples: int = 64) -> float:
    """Median angle between neighbouring beams of a scan grid, rad.

    Parameters
    ----------
    theta, psi : ndarray, 2-D
        Azimuth and zenith of every beam, rad.
    samples : int
        Evenly spaced row pairs and column pairs measured (a scan grid's
        steps vary smoothly).

    Returns
    -------
    float
        Angular step, rad.
    """
    rows = np.unique(np.linspace(0, theta.shape[0] - 2, min(samples, theta.shape[0] - 1)).astype(int))
    cols = np.unique(np.linspace(0, theta.shape[1] - 2, min(samples, theta.shape[1] - 1)).astype(int))
    pairs = (((rows, slice(None)), (rows + 1, slice(None))), ((slice(None), cols), (slice(None), cols + 1)))
    steps = []
    for first, second in pairs:
        dot = np.sum(beam_axis(theta[first], psi[first]) * beam_axis(theta[second], psi[second]), axis=-1)
        steps.append(np.arccos(np.clip(dot, -1, 1)).ravel())
    return float(np.median(np.concatenate(steps)))


def range_noise(range_m: np.ndarray) -> float:
    """Robust standard deviation of the pulse-to-pulse range noise of a scan grid, m.

    From second differences along rows and columns (``r[k-1] - 2 r[k] +
    r[k+1]``, variance ``6 sigma^2`` on a locally planar surface, free of its
    slope): ``sigma = 1.4826 median|d2| / sqrt(6)``; edges are few enough
    for the median to ignore them. NaN without three consecutive returns.
    """
    second = [np.diff(range_m, 2, axis=0).ravel(), np.diff(range_m, 2, axis=1).ravel()]
    second = np.concatenate(second)
    second = second[np.isfinite(second)]
    return float(1.4826 * np.median(np.abs(second)) / math.sqrt(6)) if len(second) else math.nan


def segment_scan(range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray, alpha: np.ndarray | None = None, *,
                 min_pixels: int = 9, min_area_m2: float = 1e-4, max_slope_deg: float = 80.0,
                 alpha_margin_deg: float = 25.0, noise_m: float | None = None, drop_border: bool = True,
                 band_m: float = 0.01, min_width_m: float = 0.004, reach_m: float = 0.05,
                 intensity: np.ndarray | None = None, edge_radius_m: float = 0.0025, edge_factor: float = 2.5,
                 neck_ratio: float = 0.3, gain_dn: float | None = None, max_aspect: float = 4.0,
                 min_fill: float = 0.5, occluder_gap_m: float = 0.01, crease_angle_deg: float = 40.0,
                 min_piece_px: int = 3, min_leaf_width_m: float = MIN_LEAF_WIDTH_M,
                 lobe_ratio: float = 0.15, piece_ratio: float = 0.5, rim_sigma: float = 0.0,
                 grow_sigma: float = 0.0, split_merged_surfaces: bool = True,
                 bark_cylinders: bool = True, dark_excess_deg: float = 20.0) -> Segmentation:
    """Surfaces, mixed pulses and leaf regions of a scan.

    Parameters
    ----------
    range_m, theta, psi : ndarray, 2-D
        Scan grids (m, rad; NaN range = no return).
    alpha : ndarray, 2-D, optional
        Intensity-derived incidence, rad; sets the steepest plausible slope
        per pixel to ``alpha + alpha_margin_deg`` (capped at ``max_slope_deg``).
    min_pixels : int
        Fewest pulses of a linked region kept as a surface of its own.
    min_area_m2 : float
        Smallest area (beam-normal, ``r^2`` times the pixel's solid angle)
        of a linked region kept as a surface, m^2 (assumption: 1 cm^2, a
        fifth of the smallest pear leaves; the same physical size at any
        step and distance).
    max_slope_deg : float
        Steepest plausible slope without (or beyond) alpha, degrees.
    alpha_margin_deg : float
        Tolerance on the intensity-derived incidence, degrees; a surface
        whose median intensity-derived incidence exceeds that of its range
        plane by more than it is no leaf (:func:`leafsfs.canopy.dark_surfaces`).
    noise_m : float, optional
        Standard deviation of the range noise, m (default: estimated,
        :func:`range_noise`). Links allow 3 sigma of the difference of two
        pulses on top of the slope; a pulse within 3 sigma of a surface
        belongs to it.
    drop_border : bool
        Surfaces touching the window's border (the background) are not leaves.
    band_m : float
        How far from a surface its mixed pulses may lie, m (assumption: three
        1/e^2 footprint radii of a FARO-class beam up to ~7 m, across which
        the footprint's share of a surface falls from 99.9 % to 0.1 %).
    min_width_m : float
        Narrower surfaces are not leaves, m: twigs, petioles and wires, whose
        pulses are nearly all mixed and which have no sand-pile surface to
        propagate (assumption: 4 mm, a footprint diameter of a FARO-class
        beam at 2 m; a 9 cm pear leaf seen at 80 deg is still 6 mm wide at 5 m).
    reach_m : float
        How far along a thin part attached to a surface (a petiole, too
        narrow to have pure pulses) its mixed pulses are paired with that
        surface, m (``reach_px`` of :func:`leafsfs.edges.attribute_mixed`;
        assumption: 5 cm, the longest pear petioles). They belong to no leaf
        region.
    intensity : ndarray, 2-D, optional
        Intensities, DN, for the geometric shares of the mixed pulses
        (:meth:`leafsfs.edges.MixedPulses.share_of`).
    edge_radius_m : float
        Neighbourhood of the edge test (:func:`leafsfs.canopy.edge_pulses`),
        m at the scan's median range, at least :data:`MIN_EDGE_RADIUS_PX` pixels or, if less,
        :data:`COARSE_EDGE_RADIUS_PX` pixels more than itself (assumption:
        2.5 mm, a FARO-class footprint radius at 4 m); also the footprint
        radius of :attr:`Segmentation.footprint_px`.
    edge_factor : float
        Residual RMS of an edge pulse's neighbourhood, in range-noise
        standard deviations (0: no edge test).
    neck_ratio : float
        Surfaces are cut where they narrow below this fraction of their
        widest part (:func:`leafsfs.canopy.split_necks`; 0: not cut).
    gain_dn : float, optional
        Log-amplifier gain of the scanner, DN per e-fold: with ``intensity``,
        the edge test allows each pulse the noise of its received power
        (:func:`leafsfs.canopy.pulse_noise`).
    max_aspect, min_fill : float
        Surfaces more elongated or sparser than a leaf are wood
        (:func:`leafsfs.canopy.wood_surfaces`; ``max_aspect=inf`` and
        ``min_fill=0``: none).
    occluder_gap_m : float
        Leaf surfaces up to this far apart (at the scan's median range; plus
        the band of edge pulses on either side of the occluder, two edge
        radii, left out of the linking), separated by something nearer than
        both and on one range plane within 3 sigma, are one leaf cut by an
        occluder, and so is a smaller surface that is no leaf on its own
        with a leaf surface (:func:`leafsfs.canopy.join_occluded`;
        assumption: 1 cm, twigs and petioles in front of a leaf; 0: not
        joined). The common plane is that
        of the whole parts or, for curved leaves, that of each part's pulses
        within 1.5 times this of the other part. A joined group the leaf tests
        (width, wood shape, darkness) refuse as a whole is parted again; when
        it joined two or more leaf surfaces they are the pieces of one branch
        and none is a leaf when it is more elongated than a leaf (``max_aspect``).
    crease_angle_deg : float
        Surfaces meeting with no range step but normals this far apart are
        cut there (:func:`leafsfs.canopy.split_creases`: two leaves touching
        at the same distance, a leaf lying on a branch), deg; only surfaces
        taken for leaves are cut, and their parts are judged again (0: not cut).
    min_piece_px : int
        Linked pieces smaller than a surface (``min_pixels``, ``min_area_m2``)
        but of at least this many pulses are surfaces for the mixed pulses
        only (:func:`leafsfs.edges.attribute_mixed`): the mixed pulses between
        a piece of a mostly hidden leaf or a twig and what lies behind it are
        paired with both, never leaves themselves (3: the fewest pulses that
        fix a plane; 0: none).
    min_leaf_width_m : float
        Surfaces narrower in 3-D (four second principal spreads,
        :func:`leafsfs.canopy.narrow_surfaces`) are no leaves: leaf pieces and
        twig pieces (:data:`leafsfs.canopy.MIN_LEAF_WIDTH_M`; 0: none).
    lobe_ratio : float
        A surface that is no leaf on its own, touches a leaf surface, holds at
        most this share of its pulses and lies on its plane near the cut
        (median absolute residual at most 1.5 sigma) is a lobe or tip of that
        leaf the neck cut took off, and joins it
        (:func:`leafsfs.canopy.join_occluded`'s ``lobe_ratio``; needs
        ``occluder_gap_m`` > 0; 0: not joined).
    piece_ratio : float
        A leaf surface that touches another, holds at most this share of its
        pulses and continues its plane near the cut (median absolute residual
        at most 2 sigma) is a piece of that leaf split off by the neck cut,
        a crease or the linking, and joins it
        (:func:`leafsfs.canopy.join_occluded`'s ``piece_ratio``; needs
        ``occluder_gap_m`` > 0; 0: not joined).
    rim_sigma : float
        The pulses linked into a surface's outline whose range lies more than
        this many of their range-noise standard deviations off the surface's
        core (:func:`leafsfs.canopy.rim_mixed`, footprint radius margin) are
        mixed: they leave their surface before the mixed pulses are
        attributed (0: none leave).
    grow_sigma : float
        A leaf region takes the pulses within a footprint radius
        (``footprint_px / 2``) of it that no surface holds or pairs and that
        lie within this many of their range-noise standard deviations of its
        local plane (:func:`leafsfs.canopy.grow_outline`: outline pulses
        partly off the leaf with nothing behind; 0: none).
    split_merged_surfaces : bool
        A leaf surface whose two parts lie each on its own smooth surface much
        better than the whole on one is two surfaces the linking joined (two
        leaves overlapping in the image, a leaf on its branch): split, and each
        part judged again; kept whole when neither part is a leaf
        (:func:`leafsfs.splits.split_merged`).
    bark_cylinders : bool
        Leaf surfaces that are a narrow, straight cylinder bulging towards the
        scanner are pieces of a branch seen from the side, no leaves
        (:func:`leafsfs.darkparts.bark_surfaces`).
    dark_excess_deg : float
        With ``alpha``, the connected parts of a leaf surface whose
        intensity-derived incidence exceeds that of their local range plane by
        more than this, degrees, and that are bark-shaped (a narrow, straight
        cylinder, :func:`leafsfs.darkparts.is_bark`), are cut off as no
        leaves: the bark of a branch the linking joined to a leaf
        (:func:`leafsfs.darkparts.dark_parts`); a surface dark over most of
        its pulses is not cut, and a cut is undone when what remains is no
        leaf by the leaf tests (0: none cut).
    """
    valid = np.isfinite(range_m)
    if not valid.any():
        raise SfsError("the scan has no valid pixels (no returns) to segment")
    sigma = range_noise(range_m) if noise_m is None else noise_m
    sigma = sigma if np.isfinite(sigma) and sigma > 0 else NOISE_FLOOR_M
    noise = pulse_noise(sigma, intensity, gain_dn)
    step = angular_step(theta, psi)
    linked = range_m
    steps = neighbour_steps(theta, psi, alpha, max_slope_deg=max_slope_deg, alpha_margin_deg=alpha_margin_deg)
    footprint = edge_radius_m / (float(np.nanmedian(range_m)) * step)
    if edge_factor > 0:
        radius = max(footprint, min(MIN_EDGE_RADIUS_PX, COARSE_EDGE_RADIUS_PX + footprint))
        limit = math.radians(max_slope_deg)
        slope = np.tan(limit if alpha is None else
                       np.minimum(np.nan_to_num(alpha, nan=limit) + math.radians(alpha_margin_deg), limit))
        edges = edge_pulses(range_m, radius, noise, edge_factor, max_slope=slope, spacing_m=range_m * step,
                            behind_gap=_near_background(range_m, theta, psi, alpha, radius, max_slope_deg,
                                                        alpha_margin_deg, sigma, min_pixels, steps=steps))
        linked = np.where(edges, np.nan, range_m)
    component = link_components(linked, theta, psi, alpha, max_slope_deg=max_slope_deg,
                                alpha_margin_deg=alpha_margin_deg, noise_m=3 * math.sqrt(2) * sigma, steps=steps)
    del steps  # four images of the scan, not needed further (0.3 GB for a pear at 0.018 deg)
    sizes = np.bincount(component.ravel())
    areas = np.bincount(component.ravel(), np.nan_to_num(range_m.ravel()) ** 2 * step ** 2)
    large = (sizes >= min_pixels) & (areas >= min_area_m2)
    large[0] = False
    lookup = np.zeros(len(sizes), dtype=int)
    lookup[large] = np.arange(1, large.sum() + 1)
    surfaces = lookup[component]
    # Pieces split off are surfaces when they hold min_area_m2 at the scan's median range.
    piece_px = max(min_pixels, int(round(min_area_m2 / (float(np.nanmedian(range_m)) * step) ** 2)))
    surfaces = split_thin_parts(surfaces, range_m, step, min_width_m, piece_px)
    border = _border_labels(surfaces) if drop_border else np.zeros(int(surfaces.max()) + 1, dtype=bool)
    origin = surfaces
    if neck_ratio > 0:
        surfaces = split_necks(surfaces, neck_ratio, piece_px)

    def leaves_of(surfaces):
        leaf = (surface_widths(surfaces, range_m, step) >= min_width_m) & \
            ~wood_surfaces(surfaces, range_m, theta, psi, step, alpha, max_aspect=max_aspect, min_fill=min_fill) \
            & ~narrow_surfaces(surfaces, range_m, theta, psi, min_leaf_width_m)
        if alpha is not None:
            leaf &= ~dark_surfaces(surfaces, range_m, alpha, step, math.radians(alpha_margin_deg), sigma)
        leaf[0] = False
        return leaf & ~_border_labels(surfaces) if drop_border else leaf

    leaf = leaves_of(surfaces)
    if neck_ratio > 0 and border.any():
        surfaces = _rejoin_background(surfaces, origin, border, leaf)
    if crease_angle_deg > 0:
        # A leaf surface that creases cut into parts is two leaves touching, or a leaf and a branch: judged again.
        surfaces, cut = split_creases(surfaces, range_m, leaf, range_m * step, noise,
                                      crease_angle_deg, piece_px)
        if cut:
            leaf = leaves_of(surfaces)
    if occluder_gap_m > 0:
        gap = occluder_gap_m / (float(np.nanmedian(range_m)) * step)
        # Surfaces no leaf on their own (a tip or lobe cut off by a twig) may join the leaf they were cut from.
        fragments = ~leaf & ~_border_labels(surfaces)
        fragments[0] = False
        bands = 2 * radius if edge_factor > 0 else 0.0  # the edge pulses either side of the occluder
        joined = join_occluded(surfaces, range_m, leaf, gap, 3 * sigma, 1.5 * gap, fragments, lobe_ratio, piece_ratio,
                               bands)
        # A joined group the leaf tests refuse as a whole is not joined: a leaf and the branch piece behind its
        # twig part again (each keeps its own judgement); a group of two or more leaf surfaces more elongated than a
        # leaf is the pieces of one branch cut by what lies in front of it, and none is a leaf (two leaves joined
        # side by side, refused as sparse, part again).
        grown = np.bincount(joined.ravel(), minlength=len(leaf)) > np.bincount(surfaces.ravel(), minlength=len(leaf))
        judged = leaves_of(joined)  # as long as the labels still used
        refused = grown & ~np.pad(judged, (0, len(leaf) - len(judged)))
        group = np.zeros(len(leaf), dtype=int)
        group[surfaces.ravel()] = joined.ravel()
        pieces = np.bincount(group[np.nonzero(leaf)[0]], minlength=len(leaf))
        spread = principal_spreads(joined, range_m, theta, psi)
        with np.errstate(invalid="ignore"):
            elongated = np.pad(spread[:, 0] > max_aspect * spread[:, 1], (0, len(leaf) - len(spread)))
        leaf &= ~(refused & (pieces >= 2) & elongated)[group]
        surfaces = np.where(refused[joined], surfaces, joined)
        leaf &= np.bincount(surfaces.ravel(), minlength=len(leaf)) > 0  # the labels joined into another
    if split_merged_surfaces:
        parted, parents = split_merged(surfaces, leaf, range_m, theta, psi, noise, piece_px)
        if len(parents):
            new = int(surfaces.max(initial=0)) + 1 + np.arange(len(parents))
            judged = leaves_of(np.where(np.isin(parted, np.concatenate([parents, new])), parted, 0))  # the parts only
            whole = ~judged[parents] & ~judged[new]
            lookup = np.arange(int(parted.max()) + 1)
            lookup[new[whole]] = parents[whole]
            parted = lookup[parted]
            leaf = np.pad(leaf, (0, max(len(judged) - len(leaf), 0)))
            leaf[parents[~whole]], leaf[new[~whole]] = judged[parents[~whole]], judged[new[~whole]]
            surfaces = parted
    if dark_excess_deg > 0 and alpha is not None:
        # Bark parts of leaf surfaces: kept apart (no leaves) when what remains of the surface is still a leaf.
        parted, parents = dark_parts(surfaces, leaf, range_m, theta, psi, alpha, step, sigma,
                                     math.radians(dark_excess_deg), piece_px)
        if len(parents):
            new = int(surfaces.max(initial=0)) + 1 + np.arange(len(parents))
            judged = leaves_of(np.where(np.isin(parted, parents), parted, 0))  # what remains of the cut surfaces
            undone = ~judged[parents]
            lookup = np.arange(int(parted.max()) + 1)
            lookup[new[undone]] = parents[undone]
            surfaces = lookup[parted]
            leaf = np.pad(leaf, (0, max(int(parted.max()) + 1 - len(leaf), 0)))
            leaf[new] = False
    if bark_cylinders:
        leaf &= ~bark_surfaces(surfaces, leaf, range_m, theta, psi, sigma)
    band = band_pixels(band_m, range_m, surfaces, step)
    reach = band_pixels(reach_m, range_m, surfaces, step) if reach_m > 0 else 0
    if min_piece_px > 0:
        # Pieces too small to be surfaces (a leaf mostly hidden, a twig) still pair the mixed pulses around them.
        piece = (component > 0) & ~large[component] & (sizes[component] >= min_piece_px) & (surfaces == 0)
        pieces = np.where(piece, component, 0)
        # each label's rank among the labels present: np.unique's inverse without its sort of every pulse (1.5 s of
        # the leafy tree at 0.018 deg)
        present = np.zeros(int(pieces.max()) + 1, dtype=bool)
        present[pieces] = True
        index = (np.cumsum(present) - 1)[pieces]
        # numbered after every label used so far (a joined top label leaves its number unused)
        surfaces = np.where(piece, index + len(leaf) - 1, surfaces)
        leaf = np.concatenate([leaf, np.zeros(max(int(surfaces.max()) + 1 - len(leaf), 0), dtype=bool)])
    footprint_px = max(1.0, 2 * footprint)
    if rim_sigma > 0:
        rim = rim_mixed(range_m, surfaces, noise, footprint_px / 2, rim_sigma)
        surfaces = np.where(rim, 0, surfaces)
        reach = band_pixels(reach_m, range_m, surfaces, step) if reach_m > 0 else 0
    mixed = attribute_mixed(range_m, surfaces, band, intensity, tolerance_m=3 * sigma,
                            reach_px=reach)
    leaf_surfaces = np.nonzero(leaf)[0]
    relabel = np.zeros(len(leaf), dtype=int)
    relabel[leaf_surfaces] = np.arange(1, len(leaf_surfaces) + 1)
    leaves = np.where(mixed.thin, 0, relabel[mixed.owner])
    if grow_sigma > 0:
        unpaired = valid & (mixed.surfaces == 0) & (mixed.pair[..., 0] == 0)
        leaves = grow_outline(leaves, range_m, unpaired, mixed.surfaces > 0, noise, footprint_px / 2, grow_sigma)
    return Segmentation(leaves, leaf_surfaces, mixed, footprint_px, band, sigma, reach_m)


def _rejoin_background(cut: np.ndarray, surfaces: np.ndarray, border: np.ndarray, leaf: np.ndarray) -> np.ndarray:
    """Pieces cut at necks from a surface that reaches the window's border joined again, except its leaves.

    A leaf whose petiole links it to a twig, and the twig through the tree to
    the ground, is cut from that surface at its neck; the pieces that are no
    leaves (the ground, the wall behind the leaves, the wood) stay one
    surface, as the background of a leaf's mixed pulses.

    Parameters
    ----------
    cut : ndarray of int, 2-D
        Surface labels after :func:`leafsfs.canopy.split_necks`.
    surfaces : ndarray of int, 2-D
        The labels before the cut.
    border : ndarray of bool
        Which labels of ``surfaces`` reach the window's border.
    leaf : ndarray of bool
        Which labels of ``cut`` are leaves.

    Returns
    -------
    ndarray of int, 2-D
        ``cut`` with each border surface's pieces that are no leaves under the
        smallest of their labels (the others left unused).
    """
    count = int(cut.max()) + 1
    origin = np.zeros(count, dtype=int)
    origin[cut.ravel()] = surfaces.ravel()
    rejoin = border[origin] & ~leaf[:count]
    rejoin[0] = False
    first = np.full(len(border), count, dtype=int)
    np.minimum.at(first, origin[rejoin], np.nonzero(rejoin)[0])
    lookup = np.arange(count)
    lookup[rejoin] = first[origin[rejoin]]
    return lookup[cut]


def _near_background(range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray, alpha: np.ndarray | None,
                     reach_px: float, max_slope_deg: float, alpha_margin_deg: float, sigma: float,
                     min_pixels: int, steps: list | None = None) -> np.ndarray:
    """Pulses within ``reach_px`` of a background (a linked surface touching the window's border) or its mixed band.

    The edge test may treat the neighbours behind an implausible step as no
    return only there (:func:`leafsfs.canopy.edge_pulses`' ``behind_gap``):
    before a background (a wall, the ground) as before the open sky, while
    the canopy's own leaves and twigs behind a leaf, inside the window, stay
    neighbours (the plain edge test). The mixed band is the pulses linked into no
    surface (components under ``min_pixels``) joined to the background by
    8-adjacency; ``reach_px`` is the edge test's disc radius.

    Parameters
    ----------
    range_m : ndarray, 2-D
        Ranges, m (NaN: no return).
    theta, psi, alpha, max_slope_deg, alpha_margin_deg
        As for :func:`link_components`.
    reach_px : float
        Distance from the background, pixels.
    sigma : float
        Range noise, m (the linking allows 3 sqrt(2) of it, as the segmentation).
    min_pixels : int
        Fewest pulses of a surface (:func:`segment_scan`'s).
    steps : list, optional
        As for :func:`link_components`.

    Returns
    -------
    ndarray of bool, 2-D
        Pulses near a background (the background's own included).
    """
    component = link_components(range_m, theta, psi, alpha, max_slope_deg=max_slope_deg,
                                alpha_margin_deg=alpha_margin_deg, noise_m=3 * math.sqrt(2) * sigma, steps=steps)
    background = _border_labels(component)[component]
    # the background's mixed band: the pulses linked into no surface (fewer than min_pixels) touching it
    loose = (np.bincount(component.ravel()) < min_pixels)[component] & (component > 0)
    pieces, _ = ndimage.label(background | loose, structure=np.ones((3, 3), dtype=bool))
    reached = np.zeros(int(pieces.max()) + 1, dtype=bool)
    reached[pieces[background]] = True
    background = reached[pieces] & (pieces > 0)
    r = int(math.ceil(reach_px))
    i, j = np.mgrid[-r:r + 1, -r:r + 1]
    return ndimage.binary_dilation(background, structure=i ** 2 + j ** 2 <= reach_px ** 2)


def _border_labels(surfaces: np.ndarray) -> np.ndarray:
    """Which surfaces touch the scan window's border (index = label)."""
    border = np.zeros(int(surfaces.max()) + 1, dtype=bool)
    border[np.unique(np.concatenate([surfaces[0], surfaces[-1], surfaces[:, 0], surfaces[:, -1]]))] = True
    border[0] = False
    return border


def split_thin_parts(surfaces: np.ndarray, range_m: np.ndarray, step_rad: float, min_width_m: float,
                     min_pixels: int) -> np.ndarray:
    """Surfaces with their thin appendages (a twig a leaf's petiole links it to) split off as surfaces of their own.

    The parts of a surface that an opening by a disc of diameter
    ``min_width_m`` removes, where they hold at least ``min_pixels`` pulses
    or reach the window's border (smaller ones inside the window are the
    corners and tips of the surface itself; a thin part that leaves the
    window is a twig or stem, however few of its pulses the window holds,
    and must not make its leaf a border surface).

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    range_m : ndarray, 2-D
        Ranges, m.
    step_rad : float
        Angular step of the scan grid, rad.
    min_width_m : float
        Diameter of the opening disc, m (at each surface's median range).
    min_pixels : int
        Smallest part split off inside the window, pixels.

    Returns
    -------
    ndarray of int, 2-D
        Surface labels, the split-off parts numbered after the existing ones.
    """
    out = surfaces.copy()
    count = int(surfaces.max())
    edge = np.ones(surfaces.shape, dtype=bool)
    edge[1:-1, 1:-1] = False
    for k, box in enumerate(ndimage.find_objects(surfaces), start=1):
        if box is None:
            continue
        inside = surfaces[box] == k
        radius = int(round(min_width_m / 2 / (step_rad * float(np.median(range_m[box][inside])))))
        if radius < 1:
            continue
        disc = np.hypot(*np.mgrid[-radius:radius + 1, -radius:radius + 1]) <= radius
        parts, _ = ndimage.label(inside & ~ndimage.binary_opening(inside, disc))
        sizes = np.bincount(parts.ravel())
        sizes[0] = 0
        split = sizes >= min_pixels
        split[np.unique(parts[edge[box]])] = True
        split[0] = False
        for part in np.nonzero(split)[0]:
            count += 1
            out[box][parts == part] = count
    return out


def surface_widths(surfaces: np.ndarray, range_m: np.ndarray, step_rad: float) -> np.ndarray:
    """Width of every surface: the diameter of the largest disc inside its pulses, m (index = label; 0 for 0).

    The pixel distance transform's maximum, times the pixel spacing at the
    surface's median range.

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    range_m : ndarray, 2-D
        Ranges, m.
    step_rad : float
        Angular step of the scan grid, rad.

    Returns
    -------
    ndarray of float, (max label + 1,)
        Width per label, m.
    """
    labels = np.arange(1, int(surfaces.max()) + 1)
    widths = np.zeros(len(labels) + 1)
    for k, box in zip(labels, ndimage.find_objects(surfaces)):
        if box is not None:
            inside = surfaces[box] == k
            depth = ndimage.distance_transform_edt(np.pad(inside, 1)).max()
            widths[k] = 2 * depth * step_rad * float(np.median(range_m[box][inside]))
    return widths


def segment_leaves(range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray, alpha: np.ndarray | None = None,
                   **options) -> np.ndarray:
    """Label the leaf regions of a scan (1..K, 0 for none): :attr:`Segmentation.leaves` of :func:`segment_scan`.

    Parameters
    ----------
    range_m : ndarray, 2-D
        Ranges, m (NaN: no return).
    theta, psi : ndarray, 2-D
        Azimuth and zenith of every beam, rad.
    alpha : ndarray, 2-D, optional
        Incidence from the intensity, rad.
    **options
        Keyword arguments of :func:`segment_scan`.

    Returns
    -------
    ndarray of int, 2-D
        Leaf region per pulse.
    """
    return segment_scan(range_m, theta, psi, alpha, **options).leaves

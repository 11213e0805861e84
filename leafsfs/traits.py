"""Leaf traits from the corrected surface: one-sided area, mean normal, midrib elevation and azimuth.

Thesis ch.7 §1.5 sums the areas of the PROP-SFS mesh triangles and takes the
leaf orientation from their area-weighted mean normal, assuming a symmetric
leaf whose lateral axis is horizontal. With sub-millimetre pixels, range
noise of a millimetre makes such a mesh rough and its area several times too
large (and the cliffs where propagation lines cross inflate it further), so
here every pixel gets the Gaussian-weighted least-squares plane of the
surface around it (``smoothing_m``, the scale on which a leaf's shape
varies; a plane, unlike a mean, keeps the slope of a steep leaf up to its
border), and the area is the sum of the world area elements ``|dP/di x
dP/dj|`` of those planes, each weighted by the leaf's share of the pixel's
footprint: mixed edge pulses count for the part of the footprint on the
leaf, also those the background dominates, so the outline is neither
dilated by the footprint nor eroded (:mod:`leafsfs.edges`). The slopes of
those planes come from the pure pulses (weight 1) alone where there are at
least :data:`PURE_SLOPE_MIN_PX` of them: the corrected heights of edge
pulses lean towards the leaf's middle, and near grazing incidence, where an
area element grows as ``1 / cos``, a slightly flattened leaf loses much of
its area (a flat 9 cm leaf at 80 deg and 3.5 m, 0.018 deg, whose band of
edge pulses is as wide as its pure part: -21 % from all pulses, +2 % from
the pure ones), on half the smoothing (:data:`AREA_SMOOTHING_FRACTION`).
Beyond 78 deg a pure pulse's slope is that of the differences of its height
to its neighbours' instead (:func:`_grazing_differences`): a wrinkled leaf
turns edge-on on the scale of a few pulses, which a plane averages away
(grazing leaves' pure pulses of the leafy tree: 11 % short of their true
secants with the planes, 2.5 % with the differences). Beyond 70 deg (78 before round 36; :data:`EDGE_MIN_SECANT`) a
mixed pulse at the outline counts, for its share, at the larger of the
planes' secant and the steepest secant of the pure pulses at the edge
beside it, less the expected excess of the steepest of that many noisy
secants (:func:`_edge_secants`): the leaf goes on turning edge-on into its
band of mixed pulses, which the planes of its flatter inside miss, and
where the range noise is of the order of the pulse spacing (the canopy5
pears' leaves, 10-90 %: seed 31 at 2.5 m 1.8-3.3 spacings, seed 7 at 3 m
1.6-3.0) the plain steepest of nine noisy differences overshot. Measured
offline on the canopy5 trees' recorded leaves (round 25's inputs, before
the dark parts; 0.018 deg, `fused`), the mixed pulses this rule counts
that the leaf dominates, their shares times the secant of the planes / the
plain steepest / the noise-corrected steepest / the true incidence of
their central rays (at most 88 deg): leafy tree 247 / 299 / 261 / 246 cm²,
pear seed 7 at 3 m 291 / 399 / 322 / 324, seed 23 at 4 m 177 / 240 / 197 /
211, seed 31 at 2.5 m 210 / 299 / 231 / 257, seed 41 at 5 m 221 / 280 / 236
/ 230 (together 1145 / 1517 / 1247 / 1268); the found leaves (>= 80 %
visible) of median true incidence >= 70 deg, summed visible area, planes /
plain / corrected: 1180 / 1231 / 1194, 1560 / 1651 / 1586, 1231 / 1287 /
1249, 1152 / 1240 / 1173, 1172 / 1222 / 1184 cm². Most of their shortfall
is beyond what these pulses tell: past 84 deg even the differences fall
short, and leaf pulses outside the leaf's region are not counted. The
correction was derived, not tuned (the expected largest of normal
deviates); canopy5 is where it was measured, fresh17 and singles.yaml the
checks. A flat leaf's band still rises with the noise by the positive part
of the corrected secant's noise, where it exceeds the planes' (a plate at
82 deg, 3.5 m, noise of 1 / 2 spacings: +2 to 5 / +5 to 11 %, the plain
steepest +16 to 21 / +34 to 43 %). Benchmarked (`fused`, area R2 /
median |area error| of main 242c067 -> this): leafy tree 0.6967 -> 0.7006 /
6.24 %, seed 7 0.6943 -> 0.6999 / 8.91 -> 8.67 %, seed 23 0.6810 -> 0.6904 /
7.35 %, seed 31 0.7284 -> 0.7364 / 5.62 %, seed 41 0.7192 -> 0.7197 / 6.79
%; fresh17 seed 101 at 3.5 m 0.7849 -> 0.7908 / 5.60 -> 5.20 %, seed 173
with a wall 0.8554 -> 0.8553 / 6.69 %; singles.yaml 58 of 60 the same, 9 cm
leaf at 80 deg 2.5 m -7.9 -> -6.6 %, 1.5 m +2.7 -> +4.3 % (the plain
steepest: -4.0 and +8.6 %; that leaf's edge pulses counted here, planes /
corrected / true, 1.5 / 2.1 / 1.8 cm²). Where the decomposition below counts a
mixed pulse, its own rule stands, and where it raised the leaf's mixed
pulses the planes' area stands for the others.
In the band of mixed pulses beyond the reach of those planes the slope is
that of the quadratic surface fitted to all pure pulses, not the nearest
plane's: a rolled or cupped leaf is steeper towards its margins, and at
grazing incidence, where most of a leaf's pulses are mixed, the flatter
middle's slope carried out to the border lost area (the standard suite's 80
deg leaves: median -37.6 -> -32.5 %). Where a mixed pulse's range and
intensity tell the leaf's own share of the footprint and the incidence of
that part (:func:`mixed_band`: the leaf's amplitude is what the pulse's
amplitude leaves after the other surface's share), a mixed pulse beyond 70
deg counts for that share at the larger of the two secants, the planes' and
the intensity's (a curled leaf turns edge-on towards its outline, which its
mixed pulses alone see); a leaf's mixed pulses count at most twice what the
planes give them (in a canopy the other surface's extrapolated intensity can
be wrong). The decomposition is trusted only where that other surface is one
evenly lit surface around the pulse (:func:`background_spread` at most
:data:`BAND_MAX_BACKGROUND_SPREAD_DN`): a wall behind a single leaf is, a
leaf or twig behind a canopy leaf mostly is not (its own incidence changes
over the band, or a third surface lights part of it), and there the planes'
area stands.
Parts of a curled leaf turned edge-on or hidden behind its own curl are not
seen; where a leaf seen across its midrib turns its far half edge-on and that
half holds less area than the near one, the far half is completed from the
near one (mirror symmetry about the midrib, :mod:`leafsfs.symmetry`; wrong for
cut, eaten or asymmetric leaves), and ``visible_area_m2`` keeps the measured
area. Where no such half was completed, the slices of a half cut short by
something in front of the leaf (a twig, a branch, a nearer leaf: pulses beside
its outline clearly nearer than it) are completed from the other half
(:func:`leafsfs.symmetry.occluded_area`; ``occluded_slices`` says how many).

The project's truth (docs/contracts.md) is the midrib: elevation above the
horizontal in [-90, 90] deg and azimuth from +x counter-clockwise. The
midrib direction is taken as the principal axis of the area-weighted points
(the leaf's longest extent), which needs no symmetry assumption. A scan
cannot tell the petiole from the tip, so the direction reported is the one
that rises (elevation >= 0); for a horizontal midrib the azimuth is known
only modulo 180 deg. The zenith angle of the mean normal (the thesis'
elevation) is reported as ``normal_zenith_deg``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage
from scipy.special import ndtri

from leafsfs.frame import LocalFrame
from leafsfs.grid import gaussian_planes
from leafsfs.symmetry import occluded_area, symmetric_area

#: Smallest smoothing, pixels: fewer would let the range noise roughen the surface (and inflate the area).
MIN_SMOOTHING_PX = 2.0
#: Fewest pure pulses (wholly on the leaf) from which the area elements take their slope, else from all pulses
#: (assumption: a 4 x 4 patch, enough for the local planes to be fitted over most of a leaf).
PURE_SLOPE_MIN_PX = 16
#: Smoothing of the area's slopes over that of the orientation (assumption: 1/2). A curled leaf's slope varies
#: within the smoothing, and near grazing incidence the area element, convex in the slope, loses what a wide plane
#: averages away; range noise of 2 mm inflates a plate's area by under 1 % at this scale.
AREA_SMOOTHING_FRACTION = 0.5
#: Largest RMS residual of the quadratic fitted to a leaf's pure heights, in units of their noise, for its slopes to
#: be carried to the border (assumption: a leaf's smooth curl fits within a few noise widths; two leaves or a leaf
#: and a twig in one region do not).
QUADRATIC_MAX_NOISE_RATIO = 3.0
#: Smallest noise that ratio is taken of, m (assumption: a scanner's range noise is no finer than half a millimetre;
#: noiseless heights would otherwise hold the quadratic to a leaf's exact shape).
MIN_HEIGHT_NOISE_M = 0.0005
#: Smallest secant of the local planes' incidence from which a pure pulse's area element takes its slope from the
#: differences of its height to its neighbours' (:func:`_grazing_differences`): 1 / cos(78 deg) (assumption: beyond
#: it the height step between pulses is at least 4.7 pulse spacings, so range noise of the order of the spacing
#: inflates the secant by a few per cent at most). Measured on the leaves >= 80 % visible (0.018 deg, `fused`, area
#: R2 / median |area error|): from 70 deg, leafy tree 0.686 -> 0.705, pear seed 41 at 5 m 0.787 -> 0.792, but the
#: median of seed 31 at 2.5 m 6.4 -> 7.0 % and of seed 101 at 3.5 m 5.6 -> 6.3 % (leaves near the median overshot);
#: from 78 deg tree 0.697 / 6.2 %, seed 7 0.667 -> 0.676 / 8.6 -> 7.6 %, seed 31 0.710 / 6.3 %, no R2 down on seven
#: pears and trees (the angle was chosen offline on those seven); at every incidence the tree's R2 fell to 0.598
#: (median 23.7 %: the noise of a facing leaf's differences). Not where the decomposition of the mixed pulses raised
#: them (an evenly lit surface behind the leaf, :func:`mixed_band`): there the differences overshot (pear seed 173 at
#: 4 m, a wall 1 m behind, grazing leaves' pure pulses: planes 547 cm2, differences 609, truth 561; single pear leaves
#: before a wall at 0.8 m, 70 / 80 deg: area error -4.8 / -18.8 % -> +31.5 / +34.2 %, where the height noise exceeds
#: the step between pulses), and the planes' area stands.
DIFFERENCE_MIN_SECANT = 1.0 / math.cos(math.radians(78.0))
#: Largest incidence a mixed pulse's leaf part is counted at, deg (assumption: the area element ``1 / cos`` grows
#: without bound towards 90 deg, where an intensity a few DN above the floor would count for any area).
BAND_MAX_INCIDENCE_DEG = 88.0
#: Smallest secant of the local planes' incidence from which a mixed pulse takes :func:`mixed_band`'s share and
#: secant: 1 / cos(70 deg). Below it the planes' area is right to a few per cent and the decomposition adds mostly
#: its errors: in a canopy the other surface is often another leaf or a twig whose intensity, extrapolated to the
#: pulse, is not what lit it. Measured (`fused`, median |visible area error|, leaves >= 80 % visible; 60 single
#: leaves / pear seed 41 at 5 m, 0.018 deg, not tuned on before this round): 60 deg 0.81 / 6.47 %, 65 deg 0.83 /
#: 5.46 %, 70 deg 0.88 / 5.08 %, 75 deg 0.99 / 5.10 %; planes alone 0.93 / 4.77 %.
BAND_MIN_SECANT = 1.0 / math.cos(math.radians(70.0))
#: Smallest secant of the local planes' incidence from which a mixed pulse at the outline counts at the steepest
#: noise-corrected secant of the pure pulses' height differences at the edge beside it (:func:`_edge_secants`), where
#: that exceeds the planes': :data:`BAND_MIN_SECANT`'s, where the mixed band's own decomposition starts (assumption:
#: the same angle beyond which the planes' area of the band is no longer right to a few per cent). The pure pulses'
#: own area keeps the planes below :data:`DIFFERENCE_MIN_SECANT`. Round 36 (per-pulse truth, found >= 80 %-visible
#: leaves at 65-82 deg of the leafy tree and pear seed 7 at 3 m, 0.018 deg, `fused`): their mixed pulses whose planes
#: lie at 70-78 deg were counted at secant 3.62 against a true 4.39 (tree: 311 of 363 cm2); the edges' differences
#: give 4.00 (344 cm2). The cost: the differences' noise raises a flat leaf's band where the range noise is a pulse
#: spacing or more (a plate at 72 deg, 3.5 m, outer 3 rings mixed, noise of 1 / 2 / 3 spacings: +10 / +25 / +40 % of
#: the band; +0.2 to 0.8 % from 78 deg on).
EDGE_MIN_SECANT = BAND_MIN_SECANT
#: Largest factor by which the decomposition may raise the area that the local planes give a leaf's mixed pulses
#: (together; assumption: a grazing leaf's mixed pulses were counted at most 26-40 % short by the planes on the
#: standard suite's 70-80 deg leaves, truth, and a factor 2 moved none of the singles' medians; in a canopy one
#: wrong background intensity counted a leaf 2-3 times: pear seed 41 leaf 237, 33.9 -> 90.2 cm2, 15.4 visible).
BAND_LEAF_CAP = 2.0
#: Largest standard deviation of the other surface's pure-pulse intensities around a mixed pulse (within the
#: attribution band) for which :func:`mixed_band` is trusted, DN (assumption, measured: the decomposition takes that
#: surface's intensity extrapolated to the pulse as its amplitude per unit beam; a wall behind a single leaf is one
#: smooth surface, a leaf or twig behind a canopy leaf turns and is lit unevenly; 30 DN is 11 % of the amplitude
#: at the default 263 DN per e-fold. Pear seed 41 at 5 m, 0.018 deg, `fused`, leaves >= 80 % visible, area R2 whole /
#: visible: planes alone 0.7205 / 0.7747, every mixed pulse decomposed 0.7097 / 0.7558; spread at most 10 DN
#: 0.7193 / 0.7745, 20 DN 0.7212 / 0.7768, 30 DN 0.7216 / 0.7771, 40 DN 0.7202 / 0.7758. It keeps the single
#: leaves' gain whole but not the canopies' of the uncapped decomposition: pear seed 7 at 3 m 0.6313 / 0.7761 planes,
#: 0.6284 / 0.7730 at 30 DN, 0.6286 / 0.7734 at 20 DN; seed 31 at 2.5 m 0.7030 / 0.8442, 0.7025 / 0.8434, 0.7028 /
#: 0.8439).
BAND_MAX_BACKGROUND_SPREAD_DN = 30.0
#: Largest distance of an outline pulse from a pulse in front of the leaf for it to be an occlusion boundary, pixels
#: (assumption: a footprint, the ring :func:`leafsfs.canopy.visibility` looks at).
OCCLUDER_REACH_PX = 1


def leaf_traits(frame: LocalFrame, height: np.ndarray, weight: np.ndarray, smoothing_m: float,
                band: np.ndarray | None = None, nearer: np.ndarray | None = None) -> dict:
    """Traits of one leaf.

    Parameters
    ----------
    frame : LocalFrame
        The leaf's frame.
    height : ndarray, 2-D
        Corrected heights on the frame's pixel box (NaN = none).
    weight : ndarray, 2-D
        The leaf's share of every pixel's footprint in the box (1 inside, a
        fraction on mixed edge pulses, 0 off the leaf); a boolean region
        counts its pixels whole.
    smoothing_m : float
        Standard deviation of the Gaussian weights of the local planes, m
        (at least :data:`MIN_SMOOTHING_PX` pixels).
    band : ndarray, (rows, cols, 2), optional
        The leaf's geometric share of each mixed pulse's footprint and the
        secant of the incidence of that part, from the pulse's range and
        intensity (:func:`mixed_band`; NaN where unknown). Where known, a
        mixed pulse (``0 < weight < 1``) whose local planes' secant is at
        least :data:`BAND_MIN_SECANT` counts for that share times the larger
        of that secant and the planes' area element; those pulses together
        count at most :data:`BAND_LEAF_CAP` times the planes' area of them.
    nearer : ndarray of bool, 2-D, optional
        Pulses of the box in front of the leaf, beside its region
        (:func:`leafsfs.canopy.nearer_ring`): the leaf's outline pulses within
        :data:`OCCLUDER_REACH_PX` of one the leaf has no share of
        (``weight`` 0) are an occlusion boundary, and the
        slices of a half they cut short are completed from the other half
        (:func:`leafsfs.symmetry.occluded_area`) where no fold was completed.

    Returns
    -------
    dict
        ``area_m2`` (m², with the far half a leaf hides behind its own roll
        completed, :func:`leafsfs.symmetry.symmetric_area`, except where the
        decomposition raised its mixed pulses; else with the parts of a half
        hidden behind an occluder completed), ``visible_area_m2`` (m², the
        measured area), ``completed_side`` (the half completed: +1, -1 or
        0), ``occluded_slices`` (the slices completed behind an occluder,
        ``nearer``), ``normal`` (upward unit mean normal), ``normal_zenith_deg``,
        ``elevation_deg`` and ``azimuth_deg`` of the midrib estimate,
        ``length_m`` (extent along it); NaN orientation without a surface.
    """
    weight = np.asarray(weight, dtype=float)
    known = (weight > 0) & np.isfinite(height)
    empty = {"area_m2": 0.0, "visible_area_m2": 0.0, "completed_side": 0, "occluded_slices": 0,
             "normal": [math.nan] * 3, "normal_zenith_deg": math.nan, "elevation_deg": math.nan,
             "azimuth_deg": math.nan, "length_m": 0.0}
    if known.sum() < 4:
        return empty
    sigma_px = max(smoothing_m / frame.grid.pixel_size, MIN_SMOOTHING_PX)
    smooth, slope, fitted = gaussian_planes(height, known, sigma_px)
    # Where no plane could be fitted (isolated pixels), the pixel's own height and the nearest fit's slope.
    nearest = tuple(ndimage.distance_transform_edt(~fitted, return_distances=False, return_indices=True))
    smooth = np.where(fitted, smooth, np.where(known, height, smooth[nearest]))
    slope = slope[nearest]
    # World area element |dP/di x dP/dj| of P = u(i, j) r(h): beam directions u, range r = d0 exp(h / d0).
    r = frame.range(smooth)[..., None]
    u = frame.directions
    du_row, du_col = np.gradient(u, axis=(0, 1))

    def elements(slope):
        d_row = du_row * r + u * (r / frame.reference_range) * slope[..., :1]
        d_col = du_col * r + u * (r / frame.reference_range) * slope[..., 1:]
        return np.cross(d_row, d_col) @ frame.pose.rotation.T

    element = elements(slope)
    points = u * r @ frame.pose.rotation.T + frame.pose.position
    area_sigma_px = max(AREA_SMOOTHING_FRACTION * sigma_px, MIN_SMOOTHING_PX)
    plane_elements = _area_slope_elements(elements, height, known, weight, area_sigma_px, element)
    pure = known & (weight >= 1)
    # The heights' noise (infinite without three pure pulses in a line: then no edge secants).
    noise = max(_noise(height, pure), MIN_HEIGHT_NOISE_M)
    slope_elements, _ = _grazing_differences(elements, height, pure, plane_elements,
                                             noise if math.isfinite(noise) else 0.0)
    area_elements = weight * np.linalg.norm(slope_elements, axis=-1)
    flat = np.linalg.norm(np.cross(du_row * r, du_col * r), axis=-1)
    # Beyond EDGE_MIN_SECANT a mixed pulse at the outline counts at the steepest secant of the leaf's edge beside it
    # (its pure pulses' height differences from that angle on) less the noise's expected excess, where that exceeds
    # the planes' (_edge_secants); the decomposition's pulses below keep their own rule.
    plane_secant = np.linalg.norm(plane_elements, axis=-1) / flat
    edge_slopes, edge_deviation = _grazing_differences(elements, height, pure, plane_elements,
                                                       noise if math.isfinite(noise) else 0.0, EDGE_MIN_SECANT)
    edge = (weight > 0) & (weight < 1) & (plane_secant >= EDGE_MIN_SECANT) & math.isfinite(noise)
    edge_elements = np.where(edge, weight * flat * np.maximum(plane_secant, _edge_secants(
        np.linalg.norm(edge_slopes, axis=-1) / flat, pure, edge_deviation / flat)), area_elements)
    raised = False
    if band is not None:
        # Both secants of a mixed pulse fall short near grazing incidence: the local planes' (of the pure pulses
        # beside it) where the leaf steepens towards its outline, the intensity's (1 / mean cos of the part of the
        # footprint on the leaf, at most the mean of 1 / cos). The larger one is taken, times the decomposed share,
        # where the planes' incidence is beyond BAND_MIN_SECANT's; together they count at most BAND_LEAF_CAP times
        # what the planes count for them (scaled down alike).
        planes = area_elements / np.where(weight > 0, weight, 1.0)
        mixed = (weight > 0) & (weight < 1) & np.isfinite(band[..., 0]) & (planes >= BAND_MIN_SECANT * flat)
        secant = np.maximum(planes, flat * np.nan_to_num(band[..., 1]))
        counted = np.nan_to_num(band[..., 0]) * secant
        planes_total, band_total = np.sum(area_elements[mixed]), np.sum(counted[mixed])
        if band_total > BAND_LEAF_CAP * planes_total:
            counted = counted * (BAND_LEAF_CAP * planes_total / band_total)
        raised = bool(band_total > planes_total)
        # Where the decomposition raised the mixed pulses (an evenly lit surface behind), the other pulses keep the
        # planes' area: their height differences overshot (DIFFERENCE_MIN_SECANT).
        area_elements = np.where(mixed, counted, weight * np.linalg.norm(plane_elements, axis=-1) if raised
                                 else edge_elements)
    else:
        area_elements = edge_elements
    area = float(np.sum(area_elements))
    element = element[known] * weight[known][:, None]
    facing = np.sign(np.sum(element * (frame.pose.position - points[known]), axis=1))
    total = np.sum(facing[:, None] * element, axis=0)
    if not area > 0 or not np.linalg.norm(total) > 0:
        return empty
    normal = total / np.linalg.norm(total)
    normal = -normal if normal[2] < 0 else normal
    weights = np.linalg.norm(element, axis=1)
    weights /= weights.sum()
    centre = weights @ points[known]
    offsets = points[known] - centre
    axis = np.linalg.eigh(offsets.T @ (weights[:, None] * offsets))[1][:, -1]
    axis = -axis if axis[2] < 0 else axis
    along = offsets @ axis
    # A leaf whose mixed pulses the decomposition counted for more than the planes do has its edge-on part measured
    # already (an evenly lit surface behind it): it is not completed (round 17: completing those too counted the
    # edge-on part twice on the pear with a wall 1 m behind).
    on = area_elements > 0
    rays = points[on] - frame.pose.position
    slope_normals = slope_elements[on] / np.linalg.norm(slope_elements[on], axis=1, keepdims=True)
    cos_incidence = np.abs(np.sum(slope_normals * rays, axis=1)) / np.linalg.norm(rays, axis=1)
    outline = (on & ~ndimage.binary_erosion(on, np.ones((3, 3), bool)))[on]
    completed, side = (area, 0) if raised else symmetric_area(points[on], area_elements[on], cos_incidence, outline,
                                                              normal, axis, centre - frame.pose.position)
    hidden_slices = 0
    if side == 0 and nearer is not None:
        reach = 2 * OCCLUDER_REACH_PX + 1
        # A pulse the leaf has a share of is not an occluder's: a grazing leaf's own mixed pulses beyond its region
        # lie nearer than its outline where it turns towards the scanner.
        front = np.asarray(nearer, bool) & ~(weight > 0)
        occluded = ndimage.binary_dilation(front, np.ones((reach, reach), bool))[on] & outline
        hidden, hidden_slices = occluded_area(points[on], area_elements[on], outline, occluded, normal, axis,
                                              _pixel_lookup(frame, front, on))
        completed += hidden
    return {
        "area_m2": completed,
        "visible_area_m2": area,
        "completed_side": side,
        "occluded_slices": hidden_slices,
        "normal": [float(v) for v in normal],
        "normal_zenith_deg": math.degrees(math.acos(min(1.0, normal[2]))),
        "elevation_deg": math.degrees(math.asin(min(1.0, axis[2]))),
        "azimuth_deg": math.degrees(math.atan2(axis[1], axis[0])) % 360.0,
        "length_m": float(along.max() - along.min()),
    }


def mixed_band(power_share: np.ndarray, intensity: np.ndarray, other_intensity: np.ndarray,
               leaf_range: np.ndarray, gain_dn: float, calibration) -> np.ndarray:
    """A leaf's share of its mixed pulses' footprints and the secant of its incidence there, from range and intensity.

    A mixed pulse's amplitude ``A = exp(I / k)`` (log amplifier of gain
    ``k`` DN per e-fold, tls-physics §2.3) is ``f a_l + (1 - f) a_o``: the
    leaf's share ``f`` of the footprint at its own amplitude per unit beam
    ``a_l``, the other surface's at ``a_o = exp(I_o / k)`` from its pure
    pulses. The range gives the leaf's power share ``w = f a_l / A``
    (:mod:`leafsfs.edges`), so ``f = 1 - (1 - w) A / a_o`` and ``a_l = w A /
    f``, whose intensity ``k ln a_l`` the calibration turns into the
    incidence of the part of the leaf inside the footprint. Near grazing
    incidence that part is steeper than the leaf's pure pulses beside it (a
    curled leaf turns edge-on at its outline): taking their amplitude, as
    :func:`leafsfs.edges.geometric_share` does, makes ``f`` too small, and
    their slope the secant (the standard suite's pear leaf at 2.5 m, 80 deg,
    truth: its mixed pulses hold 72 % of its visible area and were counted
    40 % short; the pure ones 2 % short).

    Parameters
    ----------
    power_share : ndarray
        The leaf's power share of each pulse, in [0, 1].
    intensity : ndarray
        Measured intensity of the pulses, DN.
    other_intensity : ndarray
        Intensity of the pure returns of the other surface each pulse
        straddles, extrapolated to it, DN (NaN where unknown).
    leaf_range : ndarray
        The leaf's distance at each pulse, m.
    gain_dn : float
        Log-amplifier gain, DN per e-fold.
    calibration : Calibration
        Inverse model with ``alpha(intensity, range)`` (rad).

    Returns
    -------
    ndarray, shape + (2,)
        ``f`` and ``1 / cos(alpha)`` (incidence at most
        :data:`BAND_MAX_INCIDENCE_DEG`); NaN where an input is unknown or
        ``f`` is not in (0, 1].
    """
    w = np.asarray(power_share, float)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        total = np.exp(np.asarray(intensity, float) / gain_dn)
        share = 1.0 - (1.0 - w) * total / np.exp(np.asarray(other_intensity, float) / gain_dn)
        ok = np.isfinite(share) & (share > 0) & (share <= 1) & (w > 0) & np.isfinite(leaf_range)
        leaf_intensity = gain_dn * np.log(w[ok] * total[ok] / share[ok])
    out = np.full(w.shape + (2,), np.nan)
    alpha = np.clip(calibration.alpha(leaf_intensity, np.asarray(leaf_range, float)[ok]), 0.0,
                    math.radians(BAND_MAX_INCIDENCE_DEG))
    out[ok] = np.stack([share[ok], 1.0 / np.cos(alpha)], axis=-1)
    return out


def background_spread(surfaces: np.ndarray, intensity: np.ndarray, other: np.ndarray, box: tuple,
                      radius_px: int) -> np.ndarray:
    """Spread of the other surface's pure-pulse intensities around each pulse of a window, DN.

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface label of every pure pulse of the scan (0: none).
    intensity : ndarray, 2-D
        Intensities of the scan, DN (NaN: no return).
    other : ndarray of int, 2-D
        For each pulse of the window ``box``, the surface whose spread is
        wanted (0: none).
    box : tuple of slice
        The window of the scan grid.
    radius_px : int
        Half side of the square of pulses around each pulse, pixels.

    Returns
    -------
    ndarray, 2-D
        Standard deviation of the intensities of the pure pulses of
        ``other`` within ``radius_px`` of each pulse of the window; infinite
        where fewer than two such pulses return.
    """
    (r0, r1), (c0, c1) = ((sl.indices(n)[:2]) for sl, n in zip(box, surfaces.shape))
    h = int(radius_px)
    shape = (r1 - r0 + 2 * h, c1 - c0 + 2 * h)
    lab, val = np.zeros(shape, dtype=surfaces.dtype), np.zeros(shape)
    a0, a1, b0, b1 = max(r0 - h, 0), min(r1 + h, surfaces.shape[0]), max(c0 - h, 0), min(c1 + h, surfaces.shape[1])
    inner = (slice(a0 - r0 + h, a1 - r0 + h), slice(b0 - c0 + h, b1 - c0 + h))
    returned = np.isfinite(intensity[a0:a1, b0:b1])
    lab[inner] = np.where(returned, surfaces[a0:a1, b0:b1], 0)
    val[inner] = np.where(returned, intensity[a0:a1, b0:b1], 0.0)
    count, total, square = (np.zeros(other.shape) for _ in range(3))
    size, core = 2 * h + 1, (slice(h, h + other.shape[0]), slice(h, h + other.shape[1]))
    for label in np.unique(other[other > 0]):
        # sums over the square by a box filter (mean times its size), read where the pulse asks for this surface
        near = (lab == label).astype(float)
        asks = other == label
        for out, values in ((count, near), (total, near * val), (square, near * val * val)):
            out[asks] = (ndimage.uniform_filter(values, size, mode="constant") * size * size)[core][asks]
    count = np.round(count)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
        spread = np.sqrt(np.maximum(square / count - mean * mean, 0.0))
    return np.where(count >= 2, spread, np.inf)


def _area_slope_elements(elements, height: np.ndarray, known: np.ndarray, weight: np.ndarray, sigma_px: float,
                         fallback: np.ndarray) -> np.ndarray:
    """Area elements from the local planes of the pure pulses (weight 1) alone, or ``fallback`` with too few of them.

    Where no local plane of pure pulses could be fitted (the band of mixed
    pulses along the border), the slope is that of the quadratic surface
    fitted to all pure pulses (:func:`_quadratic_slope`): a curled leaf gets
    steeper towards its margins, and the nearest plane's slope would carry
    the flatter middle out to the border. The orientation keeps the planes of
    all pulses; only the area takes these.
    """
    pure = known & (weight >= 1)
    if pure.sum() < PURE_SLOPE_MIN_PX:
        return fallback
    _, slope, fitted = gaussian_planes(height, pure, sigma_px)
    if not fitted.any():
        return fallback
    quadratic = _quadratic_slope(height, pure)
    if quadratic is None:
        return elements(slope[tuple(ndimage.distance_transform_edt(~fitted, return_distances=False,
                                                                   return_indices=True))])
    return elements(np.where(fitted[..., None], slope, quadratic))


def _grazing_differences(elements, height: np.ndarray, pure: np.ndarray, planes: np.ndarray, noise_m: float,
                         min_secant: float = DIFFERENCE_MIN_SECANT) -> tuple[np.ndarray, np.ndarray]:
    """Area elements of the pure pulses at grazing incidence from their own height differences, else ``planes``.

    Where the planes' incidence is at least ``min_secant``'s,
    a pure pulse takes its slope from the differences of its height to its
    pure neighbours' (central where both neighbours along an axis are pure,
    one-sided where one is; the planes' element where neither is). A leaf's
    surface turns on the scale of a few pulses (wrinkles, veins, pleats), and
    near grazing incidence the parts turned further edge-on count for much
    more area than a plane fitted over several pulses gives them: the
    smoothed slope loses the pulse-scale one across the steep direction.
    Measured on the grazing (>= 70 deg) leaves' pure pulses of the leafy tree
    and pear seed 41 at 5 m (0.018 deg, truth: each pulse's true incidence),
    the planes counted 535 / 508 cm2 of 604 / 548, the differences 589 / 558.
    Range noise inflates a difference's secant by about half the square of
    the noise over the height step between pulses, which beyond 78 deg is
    ``tan(78 deg) = 4.7`` pulse spacings or more (assumption: the noise is of
    the order of the spacing or less); below it the noise would dominate
    (:data:`DIFFERENCE_MIN_SECANT`).

    Parameters
    ----------
    elements : callable
        World area elements of a slope field ``(rows, cols, 2)``, m².
    height : ndarray, 2-D
        Heights, m (any value where not pure).
    pure : ndarray of bool, 2-D
        Pulses wholly on the leaf.
    planes : ndarray, (rows, cols, 3)
        The planes' area elements, m².
    noise_m : float
        Standard deviation of the heights' noise, m.
    min_secant : float
        Smallest secant of the planes' incidence from which the differences
        stand (default :data:`DIFFERENCE_MIN_SECANT`, the pure pulses' area;
        :data:`EDGE_MIN_SECANT` for the edge secants of the mixed pulses).

    Returns
    -------
    elements : ndarray, (rows, cols, 3)
        Area elements, m².
    deviation : ndarray, 2-D
        How much one standard deviation of the noise moves each element's
        norm, m²: the norm's rise when its slope gets one deviation of the
        noise of its differences steeper along its own direction (a central
        difference's noise ``noise_m / sqrt(2)``, a one-sided one's ``noise_m
        sqrt(2)``, per axis); 0 where the planes' element stands.
    """
    h = np.where(pure, height, np.nan)
    padded = np.pad(h, 1, constant_values=np.nan)
    slope, spread = np.empty(height.shape + (2,)), np.empty(height.shape + (2,))
    for axis, (ahead, behind) in enumerate([(padded[2:, 1:-1], padded[:-2, 1:-1]),
                                            (padded[1:-1, 2:], padded[1:-1, :-2])]):
        central, forward, backward = (ahead - behind) / 2, ahead - h, h - behind
        slope[..., axis] = np.where(np.isfinite(central), central, np.where(np.isfinite(forward), forward, backward))
        spread[..., axis] = noise_m * np.where(np.isfinite(central), math.sqrt(0.5), math.sqrt(2.0))
    known = pure & np.all(np.isfinite(slope), axis=-1)
    flat = np.linalg.norm(elements(np.zeros(height.shape + (2,))), axis=-1)
    grazing = known & (np.linalg.norm(planes, axis=-1) >= min_secant * flat)
    slope = np.where(known[..., None], slope, 0.0)
    # the noise of the slope's component along its own direction, and the element one such deviation steeper
    norm = np.linalg.norm(slope, axis=-1, keepdims=True)
    direction = np.divide(slope, norm, out=np.zeros_like(slope), where=norm > 0)
    along = np.linalg.norm(direction * spread, axis=-1, keepdims=True)
    own = np.linalg.norm(elements(slope), axis=-1)
    deviation = np.where(grazing, np.linalg.norm(elements(slope + along * direction), axis=-1) - own, 0.0)
    return np.where(grazing[..., None], elements(slope), planes), deviation


def _edge_secants(secant: np.ndarray, pure: np.ndarray, deviation: np.ndarray) -> np.ndarray:
    """Per pixel, the steepest noise-corrected secant of the pure pulses within one pulse of the pure pulse nearest it.

    A grazing leaf turns further edge-on towards its outline, and the
    pure pulses at its edge, whose height differences see that turn
    (:func:`_grazing_differences`), are the nearest measure of the
    incidence of the mixed pulses beyond them; the largest of the 3 x 3
    around the nearest one, because a difference across the edge is
    one-sided and a pulse beside it may carry the steeper step. The largest
    of ``n`` noisy secants exceeds their true largest by about the expected
    largest of ``n`` standard normal deviates times their noise (Blom's
    approximation, ``Phi^-1((n - 0.375) / (n + 0.25))``: 0 for one, 1.49 for
    nine), which each secant gives up before the largest is taken: where
    the range noise is of the order of the pulse spacing (pear seed 31 at
    2.5 m: 1.8-3.3 spacings, 10-90 % of its leaves) the plain largest of
    nine counted the edges too steep (module docstring). Taken as independent:
    neighbouring central differences share pulses, so the correction is
    somewhat too large, and the result errs towards the planes' secant.

    Parameters
    ----------
    secant : ndarray, 2-D
        Secant of each pulse's incidence (any value where not pure).
    pure : ndarray of bool, 2-D
        Pulses wholly on the leaf.
    deviation : ndarray, 2-D
        Standard deviation of each pure pulse's secant from the noise
        (0 where it is noise-free).

    Returns
    -------
    ndarray, 2-D
        The edge secant per pixel (0 without pure pulses).
    """
    if not pure.any():
        return np.zeros(secant.shape)
    rows, cols = secant.shape
    padded = [np.pad(a, 1, constant_values=c) for a, c in ((secant, 0.0), (pure, False), (deviation, 0.0))]
    window = [np.stack([a[i:i + rows, j:j + cols] for i in range(3) for j in range(3)]) for a in padded]
    count = window[1].sum(axis=0)
    excess = ndtri((np.maximum(count, 1) - 0.375) / (np.maximum(count, 1) + 0.25))
    steepest = np.max(np.where(window[1], window[0] - excess * window[2], 0.0), axis=0)
    nearest = tuple(ndimage.distance_transform_edt(~pure, return_distances=False, return_indices=True))
    return steepest[nearest]


def _pixel_lookup(frame: LocalFrame, front: np.ndarray, seen: np.ndarray):
    """``behind(points)``: whether the box pulse each world point (m) falls on is in ``front`` / in ``seen`` (False
    off the box); the pulse is the nearest in beam angles (affine in them over a leaf's box)."""
    u = frame.directions
    theta0 = math.atan2(u[..., 1].mean(), u[..., 0].mean())

    def angles(v):
        theta = np.mod(np.arctan2(v[..., 1], v[..., 0]) - theta0 + np.pi, 2 * np.pi) - np.pi
        return np.stack([theta, np.arccos(np.clip(v[..., 2] / np.linalg.norm(v, axis=-1), -1.0, 1.0))], axis=-1)

    rows, cols = np.indices(front.shape)
    design = np.column_stack([angles(u).reshape(-1, 2), np.ones(rows.size)])
    coef = np.linalg.lstsq(design, np.column_stack([rows.ravel(), cols.ravel()]), rcond=None)[0]

    def behind(points):
        local = (np.asarray(points) - frame.pose.position) @ frame.pose.rotation
        pixel = np.rint(np.column_stack([angles(local), np.ones(len(local))]) @ coef).astype(int)
        inside = np.all((pixel >= 0) & (pixel < front.shape), axis=1)
        r, c = np.where(inside, pixel[:, 0], 0), np.where(inside, pixel[:, 1], 0)
        return inside & front[r, c], inside & seen[r, c]

    return behind


def _quadratic_slope(height: np.ndarray, known: np.ndarray) -> np.ndarray | None:
    """Gradient per pixel step ``(rows, cols, 2)`` of the least-squares quadratic surface through the known heights.

    The quadratic ``h = c0 + c1 i + c2 j + c3 i^2 + c4 i j + c5 j^2`` in the
    pixel indices, centred and scaled on the known pixels so the normal
    equations stay well conditioned. ``None`` where its RMS residual exceeds
    :data:`QUADRATIC_MAX_NOISE_RATIO` times the heights' noise (estimated
    from their second differences along rows and columns): a region that is
    no single smooth leaf, whose extrapolated slopes would be arbitrary.
    """
    rows, cols = np.nonzero(known)
    centre = np.array([rows.mean(), cols.mean()])
    scale = max(float(np.ptp(rows)), float(np.ptp(cols)), 1.0)
    i, j = (rows - centre[0]) / scale, (cols - centre[1]) / scale
    design = np.column_stack([np.ones_like(i), i, j, i * i, i * j, j * j])
    c = np.linalg.lstsq(design, height[known], rcond=None)[0]
    residual = np.sqrt(np.mean((design @ c - height[known]) ** 2))
    if not residual <= QUADRATIC_MAX_NOISE_RATIO * max(_noise(height, known), MIN_HEIGHT_NOISE_M):
        return None
    grid_i, grid_j = ((index - centre[k]) / scale for k, index in enumerate(np.indices(height.shape)))
    return np.stack([c[1] + 2 * c[3] * grid_i + c[4] * grid_j, c[2] + c[4] * grid_i + 2 * c[5] * grid_j],
                    axis=-1) / scale


def _noise(height: np.ndarray, known: np.ndarray) -> float:
    """Robust standard deviation of the known heights' noise, from their second differences (``var = 6 sigma^2``)."""
    steps = []
    for axis in (0, 1):
        a, b = np.moveaxis(height, axis, 0), np.moveaxis(known, axis, 0)
        both = b[:-2] & b[1:-1] & b[2:]
        steps.append((a[:-2] - 2 * a[1:-1] + a[2:])[both])
    second = np.abs(np.concatenate(steps))
    return 1.4826 * float(np.median(second)) / math.sqrt(6.0) if len(second) else math.inf

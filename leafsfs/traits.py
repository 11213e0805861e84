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
In the band of mixed pulses beyond the reach of those planes the slope is
that of the quadratic surface fitted to all pure pulses, not the nearest
plane's: a rolled or cupped leaf is steeper towards its margins, and at
grazing incidence, where most of a leaf's pulses are mixed, the flatter
middle's slope carried out to the border lost area (the standard suite's 80
deg leaves: median -37.6 -> -32.5 %).
Parts of a curled leaf turned edge-on or hidden behind its own curl are not
seen and not counted.

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

from leafsfs.frame import LocalFrame
from leafsfs.grid import gaussian_planes

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


def leaf_traits(frame: LocalFrame, height: np.ndarray, weight: np.ndarray, smoothing_m: float) -> dict:
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

    Returns
    -------
    dict
        ``area_m2``, ``normal`` (upward unit mean normal), ``normal_zenith_deg``,
        ``elevation_deg`` and ``azimuth_deg`` of the midrib estimate,
        ``length_m`` (extent along it); NaN orientation without a surface.
    """
    weight = np.asarray(weight, dtype=float)
    known = (weight > 0) & np.isfinite(height)
    empty = {"area_m2": 0.0, "normal": [math.nan] * 3, "normal_zenith_deg": math.nan, "elevation_deg": math.nan,
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
    area_elements = _area_slope_elements(elements, height, known, weight, area_sigma_px, element)
    area = float(np.sum(weight * np.linalg.norm(area_elements, axis=-1)))
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
    return {
        "area_m2": area,
        "normal": [float(v) for v in normal],
        "normal_zenith_deg": math.degrees(math.acos(min(1.0, normal[2]))),
        "elevation_deg": math.degrees(math.asin(min(1.0, axis[2]))),
        "azimuth_deg": math.degrees(math.atan2(axis[1], axis[0])) % 360.0,
        "length_m": float(along.max() - along.min()),
    }


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

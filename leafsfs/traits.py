"""Leaf traits from the corrected surface: one-sided area, mean normal, midrib elevation and azimuth.

Thesis ch.7 §1.5 sums the areas of the PROP-SFS mesh triangles and takes the
leaf orientation from their area-weighted mean normal, assuming a symmetric
leaf whose lateral axis is horizontal. With sub-millimetre pixels, range
noise of a millimetre makes such a mesh rough and its area several times too
large, so here the corrected heights are first smoothed (a masked Gaussian
of ``smoothing_m``, about the scale on which a leaf's shape varies), turned
into world points on the pixel grid, and the area is the sum of the grid's
area elements ``|dP/di x dP/dj|``.

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


def leaf_traits(frame: LocalFrame, height: np.ndarray, region: np.ndarray, smoothing_m: float) -> dict:
    """Traits of one leaf.

    Parameters
    ----------
    frame : LocalFrame
        The leaf's frame.
    height : ndarray, 2-D
        Corrected heights on the frame's pixel box (NaN = none).
    region : ndarray of bool, 2-D
        The leaf's pixels in the box.
    smoothing_m : float
        Standard deviation of the Gaussian smoothing of the heights, m.

    Returns
    -------
    dict
        ``area_m2``, ``normal`` (upward unit mean normal), ``normal_zenith_deg``,
        ``elevation_deg`` and ``azimuth_deg`` of the midrib estimate,
        ``length_m`` (extent along it); NaN orientation without a surface.
    """
    known = region & np.isfinite(height)
    empty = {"area_m2": 0.0, "normal": [math.nan] * 3, "normal_zenith_deg": math.nan, "elevation_deg": math.nan,
             "azimuth_deg": math.nan, "length_m": 0.0}
    if known.sum() < 4:
        return empty
    sigma = smoothing_m / frame.grid.pixel_size
    weight = ndimage.gaussian_filter(known.astype(float), sigma)
    smooth = ndimage.gaussian_filter(np.where(known, height, 0.0), sigma) / np.maximum(weight, 1e-12)
    rows, cols = np.indices(height.shape)
    pixels = np.stack([rows, cols], axis=-1).reshape(-1, 2).astype(float)
    points = frame.world_points(pixels, smooth.ravel()).reshape(*height.shape, 3)
    d_row, d_col = np.gradient(points, axis=(0, 1))
    element = np.cross(d_row, d_col)[known]
    area = np.linalg.norm(element, axis=1)
    facing = np.sign(np.sum(element * (frame.pose.position - points[known]), axis=1))
    total = np.sum(facing[:, None] * element, axis=0)
    if not area.sum() > 0 or not np.linalg.norm(total) > 0:
        return empty
    normal = total / np.linalg.norm(total)
    normal = -normal if normal[2] < 0 else normal
    weights = area / area.sum()
    centre = weights @ points[known]
    offsets = points[known] - centre
    axis = np.linalg.eigh(offsets.T @ (weights[:, None] * offsets))[1][:, -1]
    axis = -axis if axis[2] < 0 else axis
    along = offsets @ axis
    return {
        "area_m2": float(area.sum()),
        "normal": [float(v) for v in normal],
        "normal_zenith_deg": math.degrees(math.acos(min(1.0, normal[2]))),
        "elevation_deg": math.degrees(math.asin(min(1.0, axis[2]))),
        "azimuth_deg": math.degrees(math.atan2(axis[1], axis[0])) % 360.0,
        "length_m": float(along.max() - along.min()),
    }

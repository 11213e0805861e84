"""Leaf traits from a reconstructed mesh: one-sided area, mean normal, midrib elevation and azimuth.

Thesis ch.7 §1.5: the area is the sum of the mesh triangles and the leaf
orientation comes from the area-weighted mean normal, assuming a symmetric
leaf whose lateral axis is horizontal. The project's truth (docs/contracts.md)
is the midrib: elevation above the horizontal in [-90, 90] deg and azimuth
from +x counter-clockwise. Here the midrib direction is the principal axis of
the area-weighted triangle centroids (the leaf's longest extent), which does
not need the symmetry assumption. A scan cannot tell the petiole from the
tip, so the direction is the one that rises (elevation >= 0); for a
horizontal midrib the azimuth is known only modulo 180 deg. The zenith angle
of the mean normal (the thesis' elevation) is reported as
``normal_zenith_deg``.
"""

from __future__ import annotations

import math

import numpy as np


def mesh_traits(vertices: np.ndarray, faces: np.ndarray, viewpoint: np.ndarray) -> dict:
    """Traits of a leaf mesh in world coordinates.

    Parameters
    ----------
    vertices : ndarray, (V, 3)
        Vertices, m (world frame, +z up).
    faces : ndarray of int, (F, 3)
        Triangles (any winding).
    viewpoint : ndarray, (3,)
        Scanner position; each triangle's normal is turned towards it before
        averaging, so that inconsistent windings do not cancel.

    Returns
    -------
    dict
        ``area_m2``, ``normal`` (upward unit mean normal), ``normal_zenith_deg``,
        ``elevation_deg`` and ``azimuth_deg`` of the midrib estimate,
        ``length_m`` (extent along it). NaN values for an empty mesh.
    """
    nan = {"area_m2": 0.0, "normal": [math.nan] * 3, "normal_zenith_deg": math.nan, "elevation_deg": math.nan,
           "azimuth_deg": math.nan, "length_m": 0.0}
    if not len(faces):
        return nan
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    cross = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cross, axis=1)
    centroid = (a + b + c) / 3
    facing = np.sign(np.sum(cross * (viewpoint - centroid), axis=1))
    total = np.sum(facing[:, None] * cross, axis=0)
    if not area.sum() > 0 or not np.linalg.norm(total) > 0:
        return nan
    normal = total / np.linalg.norm(total)
    if normal[2] < 0:
        normal = -normal
    weights = area / area.sum()
    mean = weights @ centroid
    spread = (centroid - mean).T @ (weights[:, None] * (centroid - mean))
    axis = np.linalg.eigh(spread)[1][:, -1]
    if axis[2] < 0:
        axis = -axis
    along = (vertices[np.unique(faces)] - mean) @ axis
    return {
        "area_m2": float(area.sum()),
        "normal": [float(v) for v in normal],
        "normal_zenith_deg": math.degrees(math.acos(min(1.0, normal[2]))),
        "elevation_deg": math.degrees(math.asin(min(1.0, axis[2]))),
        "azimuth_deg": math.degrees(math.atan2(axis[1], axis[0])) % 360.0,
        "length_m": float(along.max() - along.min()),
    }

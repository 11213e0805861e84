"""Baseline outlier-removal filters and the baseline leaf-trait estimator.

These are the filters people apply today to clean TLS clouds of edge
("mixed pixel", "veiling", "ghost") points; PROP-SFS is compared with them.
Each filter has the signature ``filter(scan, mask, **params) -> kept`` where
``mask`` (bool, the scan's grid shape) selects the points under study (one
leaf, or the whole scan) and ``kept`` is the subset the filter keeps. Filters
decide only for masked points; range-image filters look at every returned
neighbour, point-cloud filters at the masked points only (a segmented leaf
cloud). All work on real scans: none reads the truth arrays.

- :func:`statistical_outlier_removal` — PCL / Open3D ``StatisticalOutlierRemoval``.
- :func:`radius_outlier_removal` — PCL / Open3D radius (neighbour-count) removal.
- :func:`shadow_filter` — the veiling / shadow angle test of ROS
  ``laser_filters::ScanShadowsFilter`` and PCL ``ShadowPoints``, on the
  range image.
- :func:`stray_point_filter` — FARO SCENE's stray-point rule on the range image.
- :func:`intensity_filter` — dark-point removal (FARO "dark scan point").

:func:`leaf_traits` estimates a leaf's area, normal and midrib from the
points a baseline kept, by meshing the range image with an edge-length cap
(as Bailey-style grid triangulations do), so that raw and filtered clouds can
be scored on leaf traits like a reconstruction.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from leafsfs.errors import SfsError
from tlssim.scan import grid_to_xyz

#: The eight neighbours of a pixel in the range image.
_NEIGHBOURS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))

#: FARO SCENE's stray-point rule as the heritage-science study set it (prior-art digest §2.3, its Table 2): a 3 px
#: window, 2 cm range tolerance, 50 % of the neighbours agreeing. The one source of :func:`stray_point_filter`'s,
#: :func:`leafsfs.strays.remove_strays`' and the benchmark variants' settings.
STRAY_POINT_RULE = {"window_px": 3, "max_range_diff_m": 0.02, "min_share": 0.5}


def _checked_mask(scan, mask) -> np.ndarray:
    if mask is None:
        return scan.valid
    mask = np.asarray(mask)
    if mask.shape != scan.shape:
        raise SfsError(f"mask has shape {mask.shape}; it must match the scan grid {scan.shape}")
    return mask.astype(bool) & scan.valid


def _positive(name: str, value) -> float:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise SfsError(f"{name} must be a positive number, got {value!r}")
    return float(value)


def _shifted(array: np.ndarray, dr: int, dc: int, fill) -> np.ndarray:
    """``out[r, c] = array[r + dr, c + dc]`` with ``fill`` outside the grid."""
    out = np.full_like(array, fill)
    rows, cols = array.shape[:2]
    out[max(0, -dr):rows - max(0, dr), max(0, -dc):cols - max(0, dc)] = \
        array[max(0, dr):rows + min(0, dr), max(0, dc):cols + min(0, dc)]
    return out


def statistical_outlier_removal(scan, mask=None, k: int = 8, std_ratio: float = 2.0) -> np.ndarray:
    """Remove points whose mean distance to their ``k`` nearest neighbours is unusually large.

    A point is removed when its mean neighbour distance exceeds the cloud's
    mean plus ``std_ratio`` standard deviations (the PCL / Open3D rule).

    Parameters
    ----------
    scan : tlssim.Scan
        The scan.
    mask : ndarray of bool, optional
        Points under study (default: every return).
    k : int
        Neighbours per point (PCL's ``MeanK``).
    std_ratio : float
        Standard-deviation multiplier (PCL's ``StddevMulThresh``).

    Returns
    -------
    ndarray of bool
        Kept points (grid shape).
    """
    mask = _checked_mask(scan, mask)
    if not (isinstance(k, int) and k >= 1):
        raise SfsError(f"k must be a positive integer, got {k!r}")
    _positive("std_ratio", std_ratio)
    points = scan.xyz[mask]
    if len(points) <= k:
        return mask.copy()
    distance, _ = cKDTree(points).query(points, k=k + 1)
    mean = distance[:, 1:].mean(axis=1)
    kept = mask.copy()
    kept[mask] = mean <= mean.mean() + std_ratio * mean.std()
    return kept


def angular_step(scan) -> float:
    """Angular step of the scan grid, rad (the larger of the two axes)."""
    d_theta = np.abs(np.diff(scan.theta, axis=1)) if scan.shape[1] > 1 else np.zeros(1)
    d_psi = np.abs(np.diff(scan.psi, axis=0)) if scan.shape[0] > 1 else np.zeros(1)
    return float(max(np.median(d_theta), np.median(d_psi)))


def radius_outlier_removal(scan, mask=None, radius_spacings: float = 3.0, min_neighbours: int = 8,
                           radius_m: float | None = None) -> np.ndarray:
    """Remove points with fewer than ``min_neighbours`` others within a radius.

    By default the radius follows the local sample spacing, ``radius_spacings
    × range × angular step``, so that the same setting suits every distance;
    ``radius_m`` fixes it instead (the PCL / Open3D form).

    Parameters
    ----------
    scan : tlssim.Scan
        The scan.
    mask : ndarray of bool, optional
        Points under study (default: every return).
    radius_spacings : float
        Radius in units of the local sample spacing.
    min_neighbours : int
        Neighbours a point needs to be kept.
    radius_m : float, optional
        Fixed radius, m.

    Returns
    -------
    ndarray of bool
        Kept points (grid shape).
    """
    mask = _checked_mask(scan, mask)
    if not (isinstance(min_neighbours, int) and min_neighbours >= 1):
        raise SfsError(f"min_neighbours must be a positive integer, got {min_neighbours!r}")
    points = scan.xyz[mask]
    if radius_m is not None:
        radius = np.full(len(points), _positive("radius_m", radius_m))
    else:
        radius = _positive("radius_spacings", radius_spacings) * scan.range[mask] * angular_step(scan)
    kept = mask.copy()
    if len(points):
        count = cKDTree(points).query_ball_point(points, radius, return_length=True) - 1
        kept[mask] = count >= min_neighbours
    return kept


def shadow_filter(scan, mask=None, min_angle_deg: float = 10.0) -> np.ndarray:
    """Remove veiling ("shadow", mixed-pixel) points by the angle test on the range image.

    For every pair of neighbouring returns (8-neighbourhood), the angle
    between the beam of the farther point and the segment joining the two
    points is computed; below ``min_angle_deg`` the segment runs almost
    along the beam, as mixed points between a foreground edge and its
    background do, and the farther point is removed (the foreground edge is
    kept). Surfaces seen at incidence above ``90 − min_angle_deg`` lose
    points too: that is the filter's known cost.

    Parameters
    ----------
    scan : tlssim.Scan
        The scan.
    mask : ndarray of bool, optional
        Points under study (default: every return).
    min_angle_deg : float
        Smallest accepted angle between beam and neighbour segment, degrees
        (10 deg is the usual ``laser_filters`` setting).

    Returns
    -------
    ndarray of bool
        Kept points (grid shape).
    """
    mask = _checked_mask(scan, mask)
    if not 0.0 < min_angle_deg < 90.0:
        raise SfsError(f"min_angle_deg must lie in (0, 90), got {min_angle_deg!r}")
    beam = scan.xyz - scan.pose.position
    beam /= np.linalg.norm(beam, axis=2, keepdims=True)
    cos_limit = math.cos(math.radians(min_angle_deg))
    veiled = np.zeros(scan.shape, dtype=bool)
    for dr, dc in _NEIGHBOURS:
        other = _shifted(scan.xyz, dr, dc, np.nan)
        other_range = _shifted(scan.range, dr, dc, np.nan)
        segment = other - scan.xyz
        length = np.linalg.norm(segment, axis=2)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos_angle = np.abs(np.einsum("ijk,ijk->ij", segment, beam)) / length
        veiled |= (cos_angle > cos_limit) & (scan.range > other_range)
    return mask & ~veiled


def stray_point_filter(scan, mask=None, window_px: int = STRAY_POINT_RULE["window_px"],
                       max_range_diff_m: float = STRAY_POINT_RULE["max_range_diff_m"],
                       min_share: float = STRAY_POINT_RULE["min_share"]) -> np.ndarray:
    """FARO SCENE's stray-point rule: keep a point whose grid neighbours mostly share its range.

    A point is kept when at least ``min_share`` of the returns in its
    ``window_px × window_px`` grid neighbourhood (itself excluded) lie within
    ``max_range_diff_m`` of its range (defaults: :data:`STRAY_POINT_RULE`).

    Parameters
    ----------
    scan : tlssim.Scan
        The scan.
    mask : ndarray of bool, optional
        Points under study (default: every return).
    window_px : int
        Odd window size, pixels.
    max_range_diff_m : float
        Range tolerance, m.
    min_share : float
        Share of agreeing neighbours needed, in (0, 1].

    Returns
    -------
    ndarray of bool
        Kept points (grid shape).
    """
    mask = _checked_mask(scan, mask)
    if not (isinstance(window_px, int) and window_px >= 3 and window_px % 2 == 1):
        raise SfsError(f"window_px must be an odd integer >= 3, got {window_px!r}")
    _positive("max_range_diff_m", max_range_diff_m)
    if not 0.0 < min_share <= 1.0:
        raise SfsError(f"min_share must lie in (0, 1], got {min_share!r}")
    share = agreeing_share(scan.range, scan.range, window_px, max_range_diff_m)
    return mask & (share >= min_share)


def agreeing_share(measured: np.ndarray, at: np.ndarray, window_px: int, max_range_diff_m: float) -> np.ndarray:
    """Share of the measured returns in each pulse's grid window (itself excluded) within a tolerance of a range.

    Parameters
    ----------
    measured : ndarray, 2-D
        Measured ranges, m (NaN = no return).
    at : ndarray, 2-D
        The range each pulse is compared at, m (its measured one for the
        stray-point rule, a corrected one to judge a correction).
    window_px : int
        Odd window size, pixels.
    max_range_diff_m : float
        Range tolerance, m.

    Returns
    -------
    ndarray of float, 2-D
        Share in [0, 1] (NaN where the window holds no other return).
    """
    half = window_px // 2
    agree = np.zeros(measured.shape)
    total = np.zeros(measured.shape)
    for dr in range(-half, half + 1):
        for dc in range(-half, half + 1):
            if dr == 0 and dc == 0:
                continue
            other = _shifted(measured, dr, dc, np.nan)
            present = np.isfinite(other)
            total += present
            with np.errstate(invalid="ignore"):
                agree += present & (np.abs(other - at) <= max_range_diff_m)
    with np.errstate(invalid="ignore", divide="ignore"):
        return agree / total


def intensity_filter(scan, mask=None, below_median_dn: float | None = 100.0,
                     min_dn: float | None = None) -> np.ndarray:
    """Remove dark points: edge pulses that lost part of their power, and grazing ones.

    Parameters
    ----------
    scan : tlssim.Scan
        The scan.
    mask : ndarray of bool, optional
        Points under study (default: every return).
    below_median_dn : float or None
        Remove points darker than the masked points' median intensity minus
        this many DN (100 DN is a power loss of about a third with the FARO
        LS880 log amplifier, 263 DN per e-fold).
    min_dn : float or None
        Absolute threshold instead, DN (FARO's "dark scan point" filter).

    Returns
    -------
    ndarray of bool
        Kept points (grid shape).
    """
    mask = _checked_mask(scan, mask)
    if (below_median_dn is None) == (min_dn is None):
        raise SfsError("give exactly one of below_median_dn and min_dn")
    if min_dn is None:
        if not mask.any():
            return mask.copy()
        threshold = float(np.median(scan.intensity[mask])) - _positive("below_median_dn", below_median_dn)
    else:
        threshold = float(min_dn)
    with np.errstate(invalid="ignore"):
        return mask & (scan.intensity >= threshold)


def smoothed_range(scan, kept, smoothing_m: float) -> np.ndarray:
    """Range image smoothed over the kept pixels (normalised Gaussian of standard deviation ``smoothing_m``).

    The width in pixels follows the kept points' median range and the grid
    step. NaN outside ``kept``.

    Parameters
    ----------
    scan : tlssim.Scan
        The scan.
    kept : ndarray of bool
        Points whose ranges are smoothed (grid shape).
    smoothing_m : float
        Standard deviation of the Gaussian across the beams at the median range, m (> 0).

    Returns
    -------
    ndarray
        Smoothed ranges, m (grid shape).
    """
    kept = _checked_mask(scan, kept)
    _positive("smoothing_m", smoothing_m)
    if not kept.any():
        return np.full(scan.shape, np.nan)
    sigma = smoothing_m / (float(np.median(scan.range[kept])) * angular_step(scan))
    weight = ndimage.gaussian_filter(kept.astype(float), sigma)
    total = ndimage.gaussian_filter(np.where(kept, scan.range, 0.0), sigma)
    return np.where(kept, total / np.maximum(weight, 1e-12), np.nan)


def grid_mesh(scan, kept, max_edge_m: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate kept points along the scan grid, dropping triangles with a long edge.

    Every 2 × 2 block of pixels gives two triangles; a triangle is kept when
    its three points are kept and none of its edges exceeds ``max_edge_m``
    (which drops the triangles that bridge a leaf and its background).

    Parameters
    ----------
    scan : tlssim.Scan
        The scan.
    kept : ndarray of bool
        Points to mesh.
    max_edge_m : float
        Longest triangle edge, m.

    Returns
    -------
    vertices : ndarray, shape (V, 3)
        The kept points (in grid order), m.
    faces : ndarray, shape (F, 3)
        Triangles, oriented so that their normals face the scanner.
    """
    kept = _checked_mask(scan, kept)
    _positive("max_edge_m", max_edge_m)
    index = np.full(scan.shape, -1, dtype=np.int64)
    index[kept] = np.arange(int(kept.sum()))
    vertices = scan.xyz[kept]
    a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
    c, d = index[:-1, 1:].ravel(), index[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])
    faces = faces[(faces >= 0).all(axis=1)]
    if len(faces):
        tri = vertices[faces]
        edges = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2)
        faces = faces[edges.max(axis=1) <= max_edge_m]
    if len(faces):
        tri = vertices[faces]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        away = np.einsum("ij,ij->i", normal, tri.mean(axis=1) - scan.pose.position) > 0
        faces[away] = faces[away][:, ::-1]
    return vertices, faces.reshape(-1, 3)


def leaf_traits(scan, kept, max_edge_m: float | None = None, smoothing_m: float = 0.002) -> dict:
    """Leaf area, normal and midrib direction from kept points.

    ``max_edge_m`` caps the mesh edges (default: 1 cm, or four sample
    spacings on sparser scans, so that a leaf sampled every 5 mm and tilted
    still meshes).

    The kept points are meshed along the grid (:func:`grid_mesh`); then the
    ranges of the meshed points are smoothed among themselves
    (:func:`smoothed_range`: range noise of a millimetre on sub-millimetre
    pixels would otherwise crumple the mesh and multiply its area; 2 mm is
    the scale of leafsfs' trait smoothing) and the same triangles are
    measured on the smoothed points. Points outside the mesh (veils cut
    off by the edge cap) take no part in the smoothing.
    The normal is the area-weighted mean triangle normal (facing the
    scanner); the midrib is taken as the principal axis of the area-weighted
    triangle centroids (the blade's longest extent; it has no sense, so the
    upward one is returned).

    Parameters
    ----------
    scan : tlssim.Scan
        The scan.
    kept : ndarray of bool
        Points of the leaf (grid shape).
    max_edge_m : float, optional
        Longest mesh edge, m (default above).
    smoothing_m : float
        Standard deviation of the range smoothing across the beams, m.

    Returns
    -------
    dict
        ``area_m2``, ``normal`` (list of 3), ``elevation_deg`` and
        ``azimuth_deg`` of the midrib axis; NaN values when nothing could be
        meshed.
    """
    kept = _checked_mask(scan, kept)
    if max_edge_m is None and kept.any():
        max_edge_m = max(0.01, 4.0 * float(np.median(scan.range[kept])) * angular_step(scan))
    _, faces = grid_mesh(scan, kept, max_edge_m or 0.01)
    if len(faces) == 0:
        return {"area_m2": 0.0, "normal": [math.nan] * 3, "elevation_deg": math.nan, "azimuth_deg": math.nan}
    meshed = np.zeros(int(kept.sum()), dtype=bool)
    meshed[faces.ravel()] = True
    surface = np.zeros(scan.shape, dtype=bool)
    surface[kept] = meshed
    smooth = grid_to_xyz(smoothed_range(scan, surface, smoothing_m), scan.theta, scan.psi, scan.pose)
    tri = smooth[kept][faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normal = cross.sum(axis=0)
    normal /= np.linalg.norm(normal)
    centroid = tri.mean(axis=1)
    mean = np.average(centroid, axis=0, weights=area)
    offset = centroid - mean
    covariance = (offset * area[:, None]).T @ offset / area.sum()
    axis = np.linalg.eigh(covariance)[1][:, -1]
    axis = -axis if axis[2] < 0 else axis
    return {"area_m2": float(area.sum()), "normal": normal.tolist(),
            "elevation_deg": math.degrees(math.asin(float(np.clip(axis[2], -1, 1)))),
            "azimuth_deg": math.degrees(math.atan2(axis[1], axis[0])) % 360.0}

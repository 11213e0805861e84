"""The widest radius a cylinder can have given its points' spread across the line of sight and the beam footprint.

A pulse returns from a branch when its beam touches it, and a single-return
scanner places the point on the beam's central ray. Seen from one scanner
position, the points of a cylinder of radius ``r`` therefore spread across
the line of sight (perpendicular to it and to the axis) over ``2 r + D``, with
``D`` the beam's footprint diameter at that range, whatever the point spacing
(a branch thinner than the beam is widened by it; the README's DBH paragraph
shows the same widening at a stem's silhouette). Range
noise moves points along the line of sight only, so it does not widen that
spread. For points spread evenly across the width (the scan grid is even in
angle), ``sqrt(12 var)`` of their lateral coordinate estimates ``2 r + D``,
so ``r <= (sqrt(12 var) - D) / 2`` bounds the radius from the points alone,
without the pipe model's assumption about the tree's form: on a simulated
leafless apple-like tree (FARO LS880 model, 0.036 deg, 4 m, footprint
4.9 mm) the twigs' points spread over 5.7 / 6.7 / 8.3 / 12.0 mm for true
diameters of 0.5 / 1.4 / 2.9 / 6.5 mm (median per class).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from woody.geometry import segment_distance

#: Fewest points beside a section for its lateral spread to bound its radius (assumption: with 8 points the
#: spread's relative standard error is about a quarter, as for :data:`woody.cylinders.RESOLVED_POINTS`).
MIN_POINTS = 8


def lateral_radius(points: np.ndarray, start, end, viewpoint, footprint_m: float) -> float:
    """Radius bound of one section from its points' spread across the line of sight.

    Parameters
    ----------
    points : ndarray, (n, 3)
        Points beside the section (projecting inside it), m.
    start, end : array_like, (3,)
        Section axis ends, m.
    viewpoint : array_like, (3,)
        Scanner position, m.
    footprint_m : float
        Beam footprint diameter at the section's range, m.

    Returns
    -------
    float
        ``max(0, (sqrt(12 var) - footprint_m) / 2)`` with ``var`` the variance of the points' coordinate across
        the line of sight and the axis, m; infinite with fewer than :data:`MIN_POINTS` points or an axis along
        the line of sight.

    Examples
    --------
    Points spread evenly over 10 mm across a vertical axis seen along x, footprint 4 mm: radius 3 mm.

    >>> y = np.linspace(-0.005, 0.005, 1001)
    >>> pts = np.c_[np.full_like(y, 4.0), y, np.linspace(0, 0.1, y.size)]
    >>> round(lateral_radius(pts, [4, 0, 0], [4, 0, 0.1], [0, 0, 0.05], 0.004) * 1e3, 2)
    3.0
    """
    points = np.asarray(points, float)
    if len(points) < MIN_POINTS:
        return float("inf")
    start, end = np.asarray(start, float), np.asarray(end, float)
    axis = end - start
    length = float(np.linalg.norm(axis))
    view = 0.5 * (start + end) - np.asarray(viewpoint, float)
    across = np.cross(axis / length if length > 0 else axis, view)
    norm = float(np.linalg.norm(across))
    if length == 0 or norm < 1e-6 * float(np.linalg.norm(view)):
        return float("inf")
    spread = float(np.sqrt(12.0 * np.var(points @ (across / norm))))
    return max(0.0, 0.5 * (spread - footprint_m))


def lateral_radii(sections: list[tuple], points: np.ndarray, tree: cKDTree, viewpoint, footprint_m: float) -> list:
    """:func:`lateral_radius` of each section ``(start, end, radius)`` (m) from the cloud's points within its radius
    plus one footprint of its axis (any branch's: a branch's own points near a fork may have gone to a child).

    Parameters
    ----------
    sections : list of tuple
        ``(start, end, radius)`` per section, m.
    points : ndarray, (n, 3)
        The cloud, m.
    tree : scipy.spatial.cKDTree
        KD-tree of ``points``.
    viewpoint : array_like, (3,)
        Scanner position, m.
    footprint_m : float
        Beam footprint diameter, m.

    Returns
    -------
    list of float
        Radius bound per section, m (infinite where the points cannot give one).
    """
    out = []
    for start, end, radius in sections:
        a, b = np.asarray(start, float), np.asarray(end, float)
        reach = radius + footprint_m
        near = tree.query_ball_point(0.5 * (a + b), 0.5 * float(np.linalg.norm(b - a)) + reach)
        if len(near) < MIN_POINTS:
            out.append(float("inf"))
            continue
        cand = points[near]
        distance, t = segment_distance(cand, a, b)
        out.append(lateral_radius(cand[(t > 0) & (t < 1) & (distance <= reach)], a, b, viewpoint, footprint_m))
    return out

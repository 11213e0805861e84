"""The widest radius a cylinder can have given its points' spread across the line of sight and the beam footprint.

A pulse returns from a branch when its beam touches it, and a single-return
scanner places the point on the beam's central ray. Seen from one scanner
position, the points of a cylinder of radius ``r`` therefore spread across
the line of sight (perpendicular to it and to the axis) over ``2 r + D``, with
``D`` the beam's footprint diameter at that range, whatever the point spacing
(a branch thinner than the beam is widened by it; the one-sided stems' DBH
paragraph of docs/notebook/woody.md shows the same widening at a stem's
silhouette). Range
noise moves points along the line of sight only, so it does not widen that
spread. For points spread evenly across the width (the scan grid is even in
angle), ``sqrt(12 var)`` of their lateral coordinate estimates ``2 r + D``,
so ``r <= (sqrt(12 var) - D) / 2`` bounds the radius from the points alone,
without the pipe model's assumption about the tree's form: on a simulated
leafless apple-like tree (FARO LS880 model, 0.036 deg, 4 m, footprint
4.9 mm) the twigs' points spread over 5.7 / 6.7 / 8.3 / 12.0 mm for true
diameters of 0.5 / 1.4 / 2.9 / 6.5 mm (median per class).

The same widening pulls the circle of a resolved branch out: :func:`facing_radius` refits it to the points whose
beam lay wholly on the branch. The spread spans the gaps between twigs side by side; :func:`silhouette_radius`
counts the points instead, which add up only the twigs' own widths.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from woody.geometry import segment_distance

#: Fewest points beside a section for its lateral spread to bound its radius (assumption: with 8 points the
#: spread's relative standard error is about a quarter, as for :data:`woody.cylinders.RESOLVED_POINTS`).
MIN_POINTS = 8

#: Length of the stretches along a section that :func:`silhouette_radius` counts points in, in point spacings
#: (assumption: two spacings span about two scan rows whatever the axis' direction on the scan grid).
SLICE_SPACINGS = 2.0

#: Narrowest arc, each side of the line of sight, whose points :func:`facing_radius` fits, deg (assumption: over
#: +-45 deg the arc's sagitta is 0.29 r, several times the range noise for the sections it is applied to; a
#: narrower arc's circle is left to the range noise).
MIN_ARC_DEG = 45.0
#: Gauss-Newton steps of :func:`facing_radius` (as :func:`woody.cylfit.fit_circle`).
GN_STEPS = 8
#: Lateral bins of the kept arc whose median points :func:`facing_radius` fits, and the fewest points of each
#: (assumptions: every bin must hold some, so that the arc is seen whole; three points give a median).
ARC_BINS = 8
BIN_POINTS = 3


def section_frame(start, end, viewpoint) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Unit vectors of a section seen from the scanner: its axis, the depth (the line of sight without its part
    along the axis, away from the scanner) and the lateral direction across both.

    Parameters
    ----------
    start, end : array_like, (3,)
        Section axis ends, m.
    viewpoint : array_like, (3,)
        Scanner position, m.

    Returns
    -------
    tuple of ndarray or None
        ``(axis, depth, across)``; None for a section of zero length or an axis along the line of sight.
    """
    start, end = np.asarray(start, float), np.asarray(end, float)
    length = float(np.linalg.norm(end - start))
    if length == 0:
        return None
    axis = (end - start) / length
    view = 0.5 * (start + end) - np.asarray(viewpoint, float)
    depth = view - (view @ axis) * axis
    norm = float(np.linalg.norm(depth))
    if norm < 1e-6 * float(np.linalg.norm(view)):
        return None
    depth = depth / norm
    return axis, depth, np.cross(axis, depth)


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
    frame = section_frame(start, end, viewpoint)
    if frame is None:
        return float("inf")
    spread = float(np.sqrt(12.0 * np.var(points @ frame[2])))
    return max(0.0, 0.5 * (spread - footprint_m))


def lateral_radii(sections: list[tuple], points: np.ndarray, tree: cKDTree, viewpoint, footprint_m: float,
                  spacing_m: float | None = None) -> list:
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
    spacing_m : float, optional
        The cloud's point spacing, m: the bound is also at most :func:`silhouette_radius` of those points.

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
        beside = (t > 0) & (t < 1) & (distance <= reach)
        bound = lateral_radius(cand[beside], a, b, viewpoint, footprint_m)
        if spacing_m is not None and beside.sum() >= MIN_POINTS:
            length = float(np.linalg.norm(b - a))
            bound = min(bound, silhouette_radius(t[beside] * length, length, spacing_m, footprint_m))
        out.append(bound)
    return out


def silhouette_radius(along_m, length_m: float, spacing_m: float, footprint_m: float) -> float:
    """Radius bound of one section from how many points the stretches of its length hold.

    A pulse returns when its beam touches the branch (the widening of :func:`lateral_radius`), so the branch's
    silhouette across the line of sight, ``2 r + D`` wide, holds about ``(2 r + D) / s`` points per length ``s``
    along it at the scan's point spacing ``s``. Counted over stretches of :data:`SLICE_SPACINGS` spacings, the
    median count gives ``2 r + D = count s^2 / stretch`` and so ``r <= (count s^2 / stretch - D) / 2``. Unlike the
    points' spread, which spans the gaps between several twigs side by side (one section fitted across a cluster
    or a fork), the count adds up only the twigs' own widths. The cloud's nominal spacing (from the points'
    neighbour distances on the surfaces) is at least the spacing of the pulses across the line of sight (surfaces
    seen obliquely are sparser), so the bound errs wide. The count assumes the silhouette seen: a stretch without
    points (hidden behind a leaf or a branch, or beyond the branch's end) could have held any count and enters
    the median as unbounded, so that only a section whose stretches hold points over more than half its length
    is bounded at all. On a simulated leafy apple-like tree, a section fitted across a leaf in front of the
    2.3 cm stem at 1.3 m held points in 4 of its 9 stretches, 2 to 15; with the empty stretches left out of the
    median (as before), its 11.6 mm radius was cut to 0.44 mm. A stretch hidden across part of its width is
    still undercounted. Like the spread's bound, it applies to the sections the points do not resolve only
    (:func:`woody.cylinders.bound_by_footprint`).

    Parameters
    ----------
    along_m : array_like, (n,)
        Position of each point along the section's axis, from its start, m (within ``[0, length_m]``).
    length_m : float
        Section length, m.
    spacing_m : float
        The cloud's point spacing, m.
    footprint_m : float
        Beam footprint diameter at the section's range, m.

    Returns
    -------
    float
        The bound, m (at least 0); infinite for a section shorter than one stretch, or with half its stretches
        or more empty.

    Examples
    --------
    A 4 mm twig under a 5 mm footprint at 2 mm spacing: (4 + 5) / 2 = 4.5 points per 2 mm of length, 9 in each
    4 mm stretch; radius 2 mm.

    >>> along = np.repeat(np.arange(0.001, 0.1, 0.004), 9)
    >>> round(silhouette_radius(along, 0.1, 0.002, 0.005) * 1e3, 2)
    2.0
    """
    along_m = np.asarray(along_m, float)
    stretches = int(length_m // (SLICE_SPACINGS * spacing_m)) if spacing_m > 0 else 0
    if stretches < 1 or len(along_m) == 0:
        return float("inf")
    index = np.clip((along_m / length_m * stretches).astype(int), 0, stretches - 1)
    counts = np.bincount(index, minlength=stretches).astype(float)
    counts[counts == 0] = np.inf
    width = float(np.median(counts)) * spacing_m ** 2 / (length_m / stretches)
    return max(0.0, 0.5 * (width - footprint_m))


def facing_radius(points: np.ndarray, start, end, radius: float, viewpoint, footprint_m: float) -> float:
    """Radius of a section's circle from the points whose beam lay wholly on it.

    A pulse whose central ray passes within ``r - D / 2`` of the axis across the line of sight (``D`` the
    footprint) lies wholly on the branch and its point on the surface; nearer the silhouette the beam is partly
    off the branch and the point, placed on the central ray at the branch's range, lies outside the surface
    (by up to ``D / 2``). A circle fitted to all the points is pulled out by them: on a simulated leafless
    apple-like tree (FARO LS880 model, 4 m, footprint 4.9 mm) the stem's circles lay 0.7-2.2 mm behind its axis
    and 0.5-2.0 mm too wide while the points facing the scanner within 30 deg lay -0.2 to +0.5 mm from its surface.
    Here the circle is refitted to the points on the side facing the scanner whose lateral offset from the axis
    is at most ``r - D / 2``: with the axis' lateral position kept (the silhouettes widen it symmetrically),
    its depth and the radius by Gauss-Newton from the section's circle, fitted to the median point of each of
    :data:`ARC_BINS` equal bins of the lateral offset (a fit to the points themselves came out 0.2-2 mm too
    narrow on noisy synthetic arcs of 8-24 mm: the range noise on a short arc).

    Parameters
    ----------
    points : ndarray, (n, 3)
        The section's points (projecting inside it), m.
    start, end : array_like, (3,)
        Section axis ends, m.
    radius : float
        The section's fitted radius, m.
    viewpoint : array_like, (3,)
        Scanner position, m.
    footprint_m : float
        Beam footprint diameter at the section's range, m.

    Returns
    -------
    float
        The refitted radius, m; infinite where the kept arc is narrower than +-:data:`MIN_ARC_DEG` (a radius
        under ``D / (2 (1 - sin 45 deg))``, 1.7 D), a bin holds fewer than :data:`BIN_POINTS` points, the axis lies
        along the line of sight or the fit fails.

    Examples
    --------
    The facing half of a 20 mm circle widened by a 4 mm footprint (the points up to 2 mm beyond each silhouette
    at the silhouette's range), its circle fitted 1 mm too wide: the refit gives the true radius.

    >>> x = np.linspace(-0.022, 0.022, 89)
    >>> y = -np.sqrt(np.maximum(0.020 ** 2 - np.minimum(np.abs(x), 0.020) ** 2, 0.0))
    >>> pts = np.c_[4.0 + np.tile(y, 5), np.tile(x, 5), np.repeat(np.linspace(0.0, 0.1, 5), 89)]
    >>> round(facing_radius(pts, [4, 0, -0.01], [4, 0, 0.11], 0.021, [0, 0, 0.05], 0.004) * 1e3, 1)
    20.0
    """
    points = np.asarray(points, float)
    half = radius - 0.5 * footprint_m
    if len(points) < MIN_POINTS or not half >= radius * np.sin(np.radians(MIN_ARC_DEG)):
        return float("inf")
    frame = section_frame(start, end, viewpoint)
    if frame is None:
        return float("inf")
    _, depth, across = frame
    rel = points - np.asarray(start, float)
    x, y = rel @ across, rel @ depth
    keep = (np.abs(x) <= half) & (y < 0)
    edges = np.linspace(-half, half, ARC_BINS + 1)
    rows = [(np.median(x[inside]), np.median(y[inside])) for inside in
            (keep & (x >= lo) & (x <= hi) for lo, hi in zip(edges[:-1], edges[1:])) if inside.sum() >= BIN_POINTS]
    if len(rows) < ARC_BINS:
        return float("inf")
    x, y = np.array(rows).T
    y0, fitted = 0.0, float(radius)
    for _ in range(GN_STEPS):
        dy = y - y0
        dist = np.maximum(np.hypot(x, dy), 1e-12)
        step, *_ = np.linalg.lstsq(np.column_stack([dy / dist, np.ones_like(dist)]), dist - fitted, rcond=None)
        y0, fitted = y0 + float(step[0]), fitted + float(step[1])
    return fitted if np.isfinite(fitted) and fitted > 0 else float("inf")

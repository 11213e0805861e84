"""Radius of a stem seen from one side, from the part of its arc that faces the scanner, over a long band.

A single-return scanner places each point on its pulse's central ray; where the beam lies partly on a thin stem
(towards its silhouette) the point sits at the range of the part on the stem, outside the surface, and a circle
fitted to the whole arc comes out too wide (on the simulated one-sided 5 cm stems of ``tlsbench experiment
dbh-stems``, FARO LS880 model, 2-10 m: +2 to +9 %). The points facing the scanner are not biased: there the
simulated points' per-column medians lie within 0.5 mm of the true surface up to 60 deg from the line of sight
(docs/notebook/woody.md, "DBH of one-sided stems"). :func:`facing_radius` therefore refits the stem to those
points alone, without the scanner position:

1. the viewing direction is the mean direction of the section's points from its circle's centre (the middle of
   a one-sided arc);
2. the points kept are those on the facing side whose offset across that direction (their lateral coordinate,
   which the scanner's exact angles fix; its range noise lies along the line of sight) is within
   ``r sin(60 deg)`` of the centre. Selecting by the angle of each noisy point instead keeps the points whose
   noise brings them nearer the scanner near the limit, and pulled the radius out by up to 25 %;
3. the model is a tapered, leaning cylinder over :data:`BAND_M` either side of breast height (the centre and
   the radius linear in the height along the axis), fitted to the points' offsets along the line of sight
   (range residuals for parallel rays), not to their orthogonal distances: on a ±60 deg arc, orthogonal
   distances take the tangential part of the range noise for a narrower circle (an arc of 5 cm, 1.8 mm noise:
   −2.7 %, and −4.7 % on the simulated 2 m scan).

A short arc carries its radius in its sagitta, so the fit needs the arc sampled across: with fewer than
:data:`MIN_SPACINGS` point spacings across the kept arc (a 5 cm stem beyond about 7 m at 0.066 deg) it returns
None and the plain circle stands.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from woody.circles import INLIER_SIGMAS, robust_scale

#: Half the length of the band of stem fitted, m, either side of the measurement height (assumption: the taper
#: over a metre is linear; 87 scan rows at 11.5 mm spacing give the facing arc's few columns hundreds of points).
BAND_M = 0.5
#: Widest angle from the line of sight of the points fitted, deg: the beam of the FARO LS880 model (footprint
#: 3 mm + 0.49 mm/m) lies wholly on a 5 cm stem up to ``asin(1 - D / 2r)``, 57-67 deg at 10-2 m; the simulated
#: points' column medians at 60-62 deg lay within 0.4 mm of the surface at 2 and 7 m.
FACING_DEG = 60.0
#: Fewest point spacings across the kept arc (``2 r sin(FACING_DEG)``). Chosen on ``tlsbench experiment
#: dbh-stems`` seeds 0-3: with 3.8 and 5.3 spacings (5 cm at 10 and 7 m, 0.066 deg) the fit was off by -9 to
#: +38 % and -1.4 to -6.6 % (a few columns carry the sagitta), with 6.9 (10 m, 0.036 deg) by +1.3 to +2.7 %.
MIN_SPACINGS = 6.0
#: Widest arc coverage of a stem seen from one side, deg (assumption: one scan sees about 180-250 deg of a stem
#: with its silhouettes; a wider arc was seen from several sides and has no single line of sight).
ONE_SIDED_ARC_DEG = 270.0
#: Most points fitted (a deterministic random subset of larger bands: the fit's cost grows with them, its
#: precision no longer).
MAX_POINTS = 20000
#: Fewest points fitted.
MIN_POINTS = 30


def facing_radius(points, centre, axis, u, v, circle_centre, radius_m: float, band_m: float = BAND_M):
    """Radius and centre of a one-sided stem at a height, from its facing arc over a band (see the module).

    Parameters
    ----------
    points : ndarray, (n, 3)
        Points around the stem (others are left out by their distance to the axis), m.
    centre : ndarray, (3,)
        A point of the axis at the measurement height, m.
    axis : ndarray, (3,)
        Unit stem direction.
    u, v : ndarray, (3,)
        Unit vectors of the plane perpendicular to ``axis``.
    circle_centre : array_like, (2,)
        Centre of the section's circle in ``(u, v)`` coordinates from ``centre``, m.
    radius_m : float
        The section circle's radius, m.
    band_m : float
        Half the length of the band fitted along the axis, m.

    Returns
    -------
    tuple or None
        ``(radius_m, centre_uv)`` at the measurement height (``centre_uv`` in ``(u, v)`` coordinates from
        ``centre``, m); None where the kept arc spans fewer than :data:`MIN_SPACINGS` spacings of its points
        (:func:`nearest_spacing`), holds fewer than :data:`MIN_POINTS` points, or the fit fails.

    Examples
    --------
    A 5 cm upright stem whose facing points have 1.5 mm of range noise along x, and whose silhouette points are
    placed 2 mm beyond its surface: the plain circle is too wide, this one is not.

    >>> rng = np.random.default_rng(0)
    >>> y = np.repeat(np.arange(-0.0264, 0.0265, 0.0022), 200)
    >>> z = np.tile(np.linspace(0.8, 1.8, 200), len(y) // 200)
    >>> depth = -np.sqrt(np.maximum(0.025 ** 2 - np.minimum(np.abs(y), 0.025) ** 2, 0.0))
    >>> depth += np.where(np.abs(y) > 0.023, -0.002, rng.normal(0.0, 0.0015, len(y)))
    >>> pts = np.column_stack([5.0 + depth, y, z])
    >>> from woody.circles import fit_circle
    >>> plain = fit_circle(pts[:, :2])
    >>> u, v = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    >>> r, _ = facing_radius(pts, np.array([5.0, 0, 1.3]), np.array([0, 0, 1.0]), u, v, plain.centre - [5, 0],
    ...                      plain.radius_m)
    >>> plain.radius_m > 0.0255, round(r, 4)
    (True, 0.025)
    """
    rel = points - centre
    along = rel @ axis
    planar = np.column_stack([rel @ u, rel @ v]) - np.asarray(circle_centre, float)
    near = (np.abs(along) <= band_m) & (np.hypot(planar[:, 0], planar[:, 1]) <= 1.5 * radius_m + 0.05)
    points, planar, along = points[near], planar[near], along[near]
    if len(planar) < MIN_POINTS:
        return None
    mean = np.mean(planar / np.maximum(np.hypot(planar[:, 0], planar[:, 1]), 1e-12)[:, None], axis=0)
    if not np.linalg.norm(mean) > 0:
        return None
    view = mean / np.linalg.norm(mean)  # towards the scanner
    across, depth = planar @ np.array([-view[1], view[0]]), planar @ view
    half = radius_m * np.sin(np.radians(FACING_DEG))
    keep = (np.abs(across) <= half) & (depth > 0)
    if keep.sum() < MIN_POINTS or 2.0 * half < MIN_SPACINGS * nearest_spacing(points[keep]):
        return None
    x, y, h = across[keep], depth[keep], along[keep]
    if len(x) > MAX_POINTS:
        pick = np.sort(np.random.default_rng(0).choice(len(x), MAX_POINTS, replace=False))
        x, y, h = x[pick], y[pick], h[pick]
    scale = np.full(6, max(radius_m, 1e-3))
    params = np.array([0.0, 0.0, 0.0, 0.0, radius_m, 0.0])  # centre across, depth, their slopes, radius, taper
    residual = _range_residuals(params, x, y, h)
    params = least_squares(_range_residuals, params, args=(x, y, h), loss="soft_l1",
                           f_scale=robust_scale(residual), method="trf", x_scale=scale, max_nfev=200).x
    residual = _range_residuals(params, x, y, h)
    inliers = np.abs(residual) <= INLIER_SIGMAS * robust_scale(residual)
    if inliers.sum() < MIN_POINTS:
        return None
    params = least_squares(_range_residuals, params, args=(x[inliers], y[inliers], h[inliers]), method="trf",
                           x_scale=scale, max_nfev=200).x
    radius = float(params[4])
    if not (np.isfinite(params).all() and radius > 0):
        return None
    centre_uv = np.asarray(circle_centre, float) + params[0] * np.array([-view[1], view[0]]) + params[1] * view
    return radius, centre_uv


def _range_residuals(params: np.ndarray, x: np.ndarray, y: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Offsets along the line of sight of facing points ``(x across, y towards the scanner, h along the axis)``
    from a leaning, tapered cylinder's near surface, m (the surface's silhouette depth beyond its width)."""
    across = x - params[0] - params[2] * h
    radius = params[4] + params[5] * h
    return y - params[1] - params[3] * h - np.sqrt(np.maximum(radius ** 2 - across ** 2, 0.0))


def nearest_spacing(points: np.ndarray, sample: int = 5000) -> float:
    """Median distance of points to their nearest neighbour, m (on a deterministic sample of at most ``sample``).

    Unlike :func:`woody.density.point_spacing` (the square root of the area per point), this is the finer of a
    scan's row and column spacings, which is what resolves the arc across the stem.

    Parameters
    ----------
    points : ndarray, (n, 3)
        Points, m.
    sample : int
        Most points whose nearest neighbour is looked up.

    Returns
    -------
    float
        The spacing, m (0 for fewer than two points).
    """
    if len(points) < 2:
        return 0.0
    pick = np.random.default_rng(0).choice(len(points), min(len(points), sample), replace=False)
    distance, _ = cKDTree(points).query(points[pick], k=2)
    return float(np.median(distance[:, 1]))

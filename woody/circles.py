"""Robust circle fits on planar point sets, including partial arcs.

The fit is the usual forestry one (stem sections of terrestrial scans):

1. a start that tolerates up to half the points being outliers: of Kåsa's
   algebraic circle (the linear least-squares circle of
   ``x² + y² = 2ax + 2by + c``, biased towards small radii on short arcs)
   and the circles through random point triples, the one of least median
   squared residual (Rousseeuw's least median of squares);
2. a geometric fit (orthogonal distances, Gauss-Newton/trust region by
   ``scipy.optimize.least_squares``) with a robust loss scaled by the
   median absolute deviation of the residuals, which removes the bias and
   down-weights mixed pixels and bark or leaf outliers;
3. a last geometric fit on the inliers (residual within three robust
   standard deviations), whose root-mean-square residual is reported.

The arc coverage is the sector occupancy of the inliers around the fitted
centre (36 sectors of 10 degrees), as in forestry section fits: a stem seen
from one side covers about half a circle, a stem seen from all sides 360
degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from woody.errors import WoodyError

#: Sectors of the arc-coverage count (10 degrees each).
N_SECTORS = 36
#: Inliers lie within this many robust standard deviations of the circle.
INLIER_SIGMAS = 3.0
#: Floor of the robust residual scale, m (below any scanner's ranging noise).
SCALE_FLOOR_M = 1e-5
#: Point triples tried by the least-median-of-squares start (fixed seed: same points, same fit), and the
#: most points on which the candidates are compared (a random subset of larger sets).
N_TRIPLES, N_MEDIAN = 300, 2000


@dataclass(frozen=True)
class CircleFit:
    """A circle fitted to planar points.

    Attributes
    ----------
    centre : ndarray, (2,)
        Centre, m.
    radius_m : float
        Radius, m.
    residual_m : float
        Root-mean-square orthogonal residual of the inliers, m.
    arc_deg : float
        Arc coverage: degrees of the circle occupied by inliers (10 degree
        sectors).
    n_points, n_inliers : int
        Points given and points kept by the last fit.
    """

    centre: np.ndarray
    radius_m: float
    residual_m: float
    arc_deg: float
    n_points: int
    n_inliers: int


def algebraic_circle(xy) -> tuple[np.ndarray, float]:
    """Kåsa's algebraic circle through planar points (the start of :func:`fit_circle`).

    Parameters
    ----------
    xy : array_like, (n, 2)
        Points, m (n >= 3).

    Returns
    -------
    centre : ndarray, (2,)
        Centre, m.
    radius : float
        Radius, m.

    Raises
    ------
    WoodyError
        If the points are (nearly) collinear or coincident, so that no circle
        is defined.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.linspace(0, 1, 20)
    >>> centre, radius = algebraic_circle(np.column_stack([1 + 2 * np.cos(t), -1 + 2 * np.sin(t)]))
    >>> bool(np.allclose(centre, [1, -1]) and np.isclose(radius, 2))
    True
    """
    xy = _check_xy(xy)
    mean = xy.mean(axis=0)
    local = xy - mean
    scale = np.sqrt((local**2).sum(axis=1).mean())
    if not scale > 0:
        raise WoodyError("the points of a circle fit all coincide")
    u = local / scale
    design = np.column_stack([2.0 * u, np.ones(len(u))])
    (a, b, c), _, rank, singular = np.linalg.lstsq(design, (u**2).sum(axis=1), rcond=None)
    radius2 = c + a * a + b * b
    if rank < 3 or not np.isfinite(radius2) or radius2 <= 0 or singular[-1] < 1e-9 * singular[0]:
        raise WoodyError("the points of a circle fit are collinear: no circle through them")
    radius = np.sqrt(radius2)
    if radius > 1e4:  # a straight line in all but name
        raise WoodyError("the points of a circle fit are collinear: no circle through them")
    return mean + scale * np.array([a, b]), float(scale * radius)


def fit_circle(xy, scale_m: float | None = None) -> CircleFit:
    """Robust geometric circle fit that holds on partial arcs (40 degrees and more).

    Parameters
    ----------
    xy : array_like, (n, 2)
        Points of a section, m (n >= 3).
    scale_m : float, optional
        Residual scale of the robust loss, m (the expected noise of the
        points). By default the scale is estimated from the data (the
        least-median-of-squares scale of the start).

    Returns
    -------
    CircleFit

    Raises
    ------
    WoodyError
        If there are fewer than three points, or they are collinear.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.radians(np.linspace(5, 55, 50))
    >>> fit = fit_circle(np.column_stack([0.2 * np.cos(t), 0.2 * np.sin(t)]))
    >>> round(fit.radius_m, 6), fit.arc_deg
    (0.2, 60.0)
    """
    xy = _check_xy(xy)
    if scale_m is not None and not (np.isfinite(scale_m) and scale_m > 0):
        raise WoodyError(f"scale_m must be a positive length in metres, got {scale_m}")
    params, lmeds_scale = _lmeds_start(xy)
    if scale_m is None:
        scale_m = lmeds_scale
    params = _geometric(params, xy, loss="soft_l1", f_scale=scale_m)
    residual = _residuals(params, xy)
    inliers = np.abs(residual) <= INLIER_SIGMAS * _robust_scale(residual)
    if inliers.sum() >= 3 and not inliers.all():
        params = _geometric(params, xy[inliers], loss="linear", f_scale=1.0)
        inliers = np.abs(_residuals(params, xy)) <= INLIER_SIGMAS * _robust_scale(_residuals(params, xy[inliers]))
    if inliers.sum() < 3:
        inliers = np.ones(len(xy), bool)
    kept = xy[inliers]
    rms = float(np.sqrt(np.mean(_residuals(params, kept) ** 2)))
    return CircleFit(centre=params[:2].copy(), radius_m=float(abs(params[2])), residual_m=rms,
                     arc_deg=arc_coverage_deg(kept, params[:2]), n_points=len(xy), n_inliers=int(inliers.sum()))


def arc_coverage_deg(xy, centre, n_sectors: int = N_SECTORS) -> float:
    """Degrees of a circle around ``centre`` occupied by points (sector occupancy).

    Parameters
    ----------
    xy : array_like, (n, 2)
        Points, m.
    centre : array_like, (2,)
        Circle centre, m.
    n_sectors : int
        Number of equal sectors; the result is a multiple of ``360 / n_sectors``.

    Returns
    -------
    float
        Occupied sectors times the sector width, degrees.
    """
    d = np.asarray(xy, float) - np.asarray(centre, float)
    angle = np.mod(np.arctan2(d[:, 1], d[:, 0]), 2.0 * np.pi)
    sectors = np.minimum((angle / (2.0 * np.pi) * n_sectors).astype(int), n_sectors - 1)
    return float(len(np.unique(sectors)) * 360.0 / n_sectors)


def _lmeds_start(xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-median-of-squares start among Kåsa's circle and circles through random triples.

    Returns the parameters ``(cx, cy, r)`` and the robust residual scale of
    the best candidate (Rousseeuw & Leroy's ``1.4826 (1 + 5 / (n - p)) sqrt(median r²)``).
    """
    centre, radius = algebraic_circle(xy)
    candidates = [np.array([centre[0], centre[1], radius])]
    n = len(xy)
    rng = np.random.default_rng(0)
    if n > N_MEDIAN:
        xy = xy[rng.choice(n, N_MEDIAN, replace=False)]
    if n > 3:
        triples = rng.integers(0, len(xy), size=(N_TRIPLES, 3))
        a, b, c = xy[triples[:, 0]], xy[triples[:, 1]], xy[triples[:, 2]]
        d = 2.0 * (a[:, 0] * (b[:, 1] - c[:, 1]) + b[:, 0] * (c[:, 1] - a[:, 1]) + c[:, 0] * (a[:, 1] - b[:, 1]))
        ok = np.abs(d) > 1e-12 * max(np.ptp(xy), 1e-12) ** 2
        a, b, c, d = a[ok], b[ok], c[ok], d[ok]
        sa, sb, sc = (a**2).sum(axis=1), (b**2).sum(axis=1), (c**2).sum(axis=1)
        cx = (sa * (b[:, 1] - c[:, 1]) + sb * (c[:, 1] - a[:, 1]) + sc * (a[:, 1] - b[:, 1])) / d
        cy = (sa * (c[:, 0] - b[:, 0]) + sb * (a[:, 0] - c[:, 0]) + sc * (b[:, 0] - a[:, 0])) / d
        radius = np.hypot(a[:, 0] - cx, a[:, 1] - cy)
        candidates += list(np.column_stack([cx, cy, radius]))
    candidates = np.array(candidates)
    distance = np.hypot(xy[None, :, 0] - candidates[:, None, 0], xy[None, :, 1] - candidates[:, None, 1])
    median = np.median((distance - candidates[:, 2:3]) ** 2, axis=1)
    best = int(np.argmin(median))
    scale = 1.4826 * (1.0 + 5.0 / max(len(xy) - 3, 1)) * np.sqrt(median[best])
    return candidates[best], max(float(scale), SCALE_FLOOR_M)


def _check_xy(xy) -> np.ndarray:
    try:
        xy = np.asarray(xy, dtype=float)
    except (TypeError, ValueError):
        raise WoodyError("circle points must be a numeric (n, 2) array") from None
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise WoodyError(f"circle points must be an (n, 2) array, got shape {xy.shape}")
    if len(xy) < 3:
        raise WoodyError(f"a circle fit needs at least 3 points, got {len(xy)}")
    if not np.isfinite(xy).all():
        raise WoodyError("circle points hold NaN or infinite values")
    return xy


def _residuals(params: np.ndarray, xy: np.ndarray) -> np.ndarray:
    return np.hypot(xy[:, 0] - params[0], xy[:, 1] - params[1]) - params[2]


def _jacobian(params: np.ndarray, xy: np.ndarray) -> np.ndarray:
    dx, dy = xy[:, 0] - params[0], xy[:, 1] - params[1]
    distance = np.maximum(np.hypot(dx, dy), 1e-15)
    return np.column_stack([-dx / distance, -dy / distance, -np.ones(len(xy))])


def _geometric(params: np.ndarray, xy: np.ndarray, loss: str, f_scale: float) -> np.ndarray:
    result = least_squares(_residuals, params, jac=_jacobian, args=(xy,), loss=loss, f_scale=f_scale,
                           method="trf", x_scale="jac", max_nfev=200)
    return result.x if np.isfinite(result.x).all() else params


def _robust_scale(residual: np.ndarray) -> float:
    """1.4826 x the median absolute deviation from zero (a Gaussian's standard deviation), floored."""
    return max(1.4826 * float(np.median(np.abs(residual))), SCALE_FLOOR_M)

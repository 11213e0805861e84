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
    inliers = np.abs(residual) <= INLIER_SIGMAS * robust_scale(residual)
    if inliers.sum() >= 3 and not inliers.all():
        params = _geometric(params, xy[inliers], loss="linear", f_scale=1.0)
        inliers = np.abs(_residuals(params, xy)) <= INLIER_SIGMAS * robust_scale(_residuals(params, xy[inliers]))
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


def robust_scale(residual: np.ndarray) -> float:
    """1.4826 x the median absolute deviation from zero (a Gaussian's standard deviation), floored."""
    return max(1.4826 * float(np.median(np.abs(residual))), SCALE_FLOOR_M)


#: Gauss-Legendre nodes of the integral over the part of the beam that meets the circle in :func:`beam_ranges`,
#: and the beam's extent each side of its central ray in standard deviations (``footprint / 4``: the footprint is
#: the 1/e² diameter). Assumption: past 3 sigma a Gaussian beam holds 0.3 % of its power. 24 nodes gave the same
#: ranges as 96 to 2e-15 m on circles of 1-25 cm radius at 2-10 m with 4-8 mm footprints.
BEAM_NODES, BEAM_SIGMAS = 24, 3.0
#: A point whose central ray passes the circle farther than this many standard deviations of the beam (half the
#: footprint) cannot have come from it: the premise of :mod:`woody.footprint` (a pulse returns when its 1/e²
#: footprint touches the stem), whose spread measured on a simulated tree's twigs exceeded ``2 r + D`` by only
#: 0.3-0.6 mm.
EXTENT_SIGMAS = 2.0
#: The ranges :func:`fit_circle_beam` fits are those of the points whose central ray passes at least this many
#: standard deviations of the beam (a quarter footprint) inside the circle's silhouette: 84 % of the beam or more
#: on the stem (assumption: the weaker returns at the silhouette depend on the beam's exact profile and the
#: detection threshold). Chosen with a prototype of the fit among 0, 1 and 2 sigmas (and cuts on the modelled
#: cos-weighted signal, 0-0.95 of the beam, which did worse) on simulated 5 and 10 cm stems (the scan of
#: ``tlsbench experiment dbh-stems``) at 4, 7 and 10 m, 0.036 and 0.066 deg, seeds 0-3: 77, 81 and 83 % within
#: 3 %, |error| at the 90th percentile 5.1, 3.5 and 3.3 %, largest 26.6, 5.6 and 4.9 %; on 6 and 8 cm stems at
#: 3, 6 and 8.5 m, 0.018-0.066 deg, seeds 4-5, 1 sigma put 36 of 36 within 3 % (median 0.5 %), 2 sigmas 35.
FIT_SIGMAS = 1.0


def beam_ranges(params, xy, viewpoint, footprint_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Range a single-return scanner gives along each point's beam to a circle, and where its central ray passes.

    The beam of the pulse that returned point ``p`` is centred on the ray from ``viewpoint`` through ``p``;
    across the line of sight its power is Gaussian with a 1/e² diameter ``footprint_m`` (the Gaussian beam of
    :mod:`tlssim.scanner`'s preset; across a stem the beam is taken as parallel rays). Each lateral part of the
    beam that meets the circle returns from the near intersection with a power proportional to the beam's power
    there and to the cosine of the incidence (a Lambertian surface), and the scanner places the point on the
    central ray at the power-weighted mean of those ranges (phase-shift ranging of returns millimetres apart).
    Where the beam lies wholly on the circle this is about the central ray's own intersection (plus the beam's
    average over the curvature, ``sigma² / 2r`` at the front); where it lies partly on it the point sits on the
    central ray at about the silhouette's range, outside the circle, as the points of a thin stem's silhouette
    do. The mean is integrated over the part of the beam on the circle, ``s = r sin(phi)`` across it.

    Parameters
    ----------
    params : array_like, (3,)
        Circle centre x, y and radius, m.
    xy : ndarray, (n, 2)
        Points, m.
    viewpoint : array_like, (2,)
        Scanner position in the same plane, m.
    footprint_m : float
        Beam footprint (1/e² diameter) at the circle's range, m.

    Returns
    -------
    ranges : ndarray, (n,)
        Modelled range along each point's ray, m (the ray's closest approach to the centre where no part of the
        beam, out to :data:`BEAM_SIGMAS` standard deviations, meets the circle).
    lateral : ndarray, (n,)
        Distance of each central ray from the circle's centre, m.

    Examples
    --------
    A 10 cm stem 5 m away, footprint 5 mm: the central ray through its axis returns from its front, 5 cm before
    the axis; the ray grazing its side 1.1 cm before the widest point (the part of the beam on the stem lies
    nearer the scanner).

    >>> points = np.array([[5.0, 0.0], [5.0, 0.05]])
    >>> ranges, lateral = beam_ranges([5.0, 0.0, 0.05], points, [0, 0], 0.005)
    >>> np.round(ranges - np.hypot(*points.T), 3).tolist(), np.round(lateral, 3).tolist()
    ([-0.05, -0.011], [0.0, 0.05])
    """
    cx, cy, radius = float(params[0]), float(params[1]), max(abs(float(params[2])), 1e-12)
    rel = xy - np.asarray(viewpoint, float)
    ray = rel / np.maximum(np.hypot(rel[:, 0], rel[:, 1]), 1e-15)[:, None]
    to_centre = np.array([cx, cy]) - np.asarray(viewpoint, float)
    along = ray @ to_centre
    lateral = ray[:, 0] * to_centre[1] - ray[:, 1] * to_centre[0]
    sigma = max(0.25 * footprint_m, 1e-9)
    low = np.clip(lateral - BEAM_SIGMAS * sigma, -radius, radius)
    high = np.clip(lateral + BEAM_SIGMAS * sigma, -radius, radius)
    hit = high > low
    nodes, weights = np.polynomial.legendre.leggauss(BEAM_NODES)
    phi_low, phi_high = np.arcsin(low / radius), np.arcsin(high / radius)
    phi = 0.5 * (phi_low + phi_high)[:, None] + 0.5 * (phi_high - phi_low)[:, None] * nodes[None, :]
    cos_phi = np.cos(phi)
    # beam power x cos(incidence) x ds = exp(-(s - b)² / 2 sigma²) x cos(phi) x r cos(phi) dphi; range - along =
    # -r cos(phi)
    power = np.exp(-0.5 * ((radius * np.sin(phi) - lateral[:, None]) / sigma) ** 2) * cos_phi ** 2 * weights
    total = power.sum(axis=1)
    hit &= total > 0
    ranges = along.copy()
    ranges[hit] -= radius * (power[hit] * cos_phi[hit]).sum(axis=1) / total[hit]
    return ranges, np.abs(lateral)


def fit_circle_beam(xy, viewpoint, footprint_m: float, start: CircleFit | None = None) -> CircleFit:
    """Circle fit of a section seen from one scanner position, with the beam footprint's widening modelled.

    :func:`fit_circle` takes each point as a sample of the surface. Where the beam lies partly on a thin stem,
    a single-return scanner places the point on the central ray, which misses the stem, at about the range of
    the silhouette: those points lie outside the circle and pull the fitted radius out (on the simulated 5 cm
    stems of ``tlsbench experiment dbh-stems``, FARO LS880 model, 2-10 m: -1.6 to +8.8 %). Here the points'
    directions are kept (a scanner's angles are exact; its noise lies along the range) and the circle is the one
    whose modelled ranges (:func:`beam_ranges`) best match the measured ones, over the points whose central ray
    passes :data:`FIT_SIGMAS` standard deviations of the beam (a quarter footprint) inside its silhouette; every
    point adds how far its central ray passes beyond :data:`EXTENT_SIGMAS` of them (half a footprint) outside
    it (a point cannot come from farther), which keeps the circle as wide as the silhouette's points less half
    a footprint. The points in between (the beam partly off the stem) enter only the start. The fit starts
    from :func:`fit_circle` (``start``), minimises with a robust loss scaled by the residuals' median absolute
    deviation, then again on the inliers within three robust standard deviations.

    Parameters
    ----------
    xy : array_like, (n, 2)
        Points of the section, m (n >= 3).
    viewpoint : array_like, (2,)
        Scanner position in the section's plane, m.
    footprint_m : float
        Beam footprint (1/e² diameter) at the section's range, m (0: a thin beam, a range-residual fit).
    start : CircleFit, optional
        The plain fit of the same points (computed when not given).

    Returns
    -------
    CircleFit
        Its ``residual_m`` is the RMS range residual of the inliers whose range was fitted.

    Raises
    ------
    WoodyError
        If there are fewer than three points, they are collinear, or the footprint is negative.

    Examples
    --------
    A 5 cm circle seen from 4 m, each ray's point placed at the range the 6 mm footprint gives (the silhouette
    points up to half a footprint out): the plain fit is too wide, this one is not.

    >>> angle = np.radians(np.linspace(-0.4, 0.4, 81))
    >>> rays = np.column_stack([np.cos(angle), np.sin(angle)])
    >>> ranges, lateral = beam_ranges([4.0, 0.0, 0.025], 4.0 * rays, [0.0, 0.0], 0.006)
    >>> xy = (rays * ranges[:, None])[lateral <= 0.025 + 0.003]
    >>> round(fit_circle(xy).radius_m, 4), round(fit_circle_beam(xy, [0.0, 0.0], 0.006).radius_m, 4)
    (0.0256, 0.025)
    """
    xy = _check_xy(xy)
    viewpoint = np.asarray(viewpoint, float).reshape(2)
    if not (np.isfinite(footprint_m) and footprint_m >= 0):
        raise WoodyError(f"footprint_m must be a diameter >= 0 in metres, got {footprint_m}")
    if start is None:
        start = fit_circle(xy)
    distance = np.hypot(*(xy - viewpoint).T)
    origin = np.asarray(start.centre, float)  # the centre is solved as a shift from the start (xtol is relative)
    x_scale = np.full(3, max(start.radius_m, 1e-3))

    sigma = 0.25 * footprint_m

    def residuals(shift, pts, dist):
        ranges, lateral = beam_ranges([*(origin + shift[:2]), shift[2]], pts, viewpoint, footprint_m)
        beyond = lateral - abs(shift[2]) - EXTENT_SIGMAS * sigma
        inside = lateral <= abs(shift[2]) - FIT_SIGMAS * sigma
        return np.where(beyond > 0, np.hypot(dist - ranges, beyond), np.where(inside, dist - ranges, 0.0))

    shift = np.array([0.0, 0.0, start.radius_m])
    residual = residuals(shift, xy, distance)
    scale = robust_scale(residual[residual != 0])
    shift = least_squares(residuals, shift, args=(xy, distance), loss="soft_l1", f_scale=scale, method="trf",
                          x_scale=x_scale, max_nfev=200).x
    residual = residuals(shift, xy, distance)
    inliers = np.abs(residual) <= INLIER_SIGMAS * robust_scale(residual[residual != 0])
    if inliers.sum() >= 3 and not inliers.all():
        shift = least_squares(residuals, shift, args=(xy[inliers], distance[inliers]), method="trf",
                              x_scale=x_scale, max_nfev=200).x
        residual = residuals(shift, xy, distance)
    params = np.array([*(origin + shift[:2]), abs(shift[2])])
    fitted = inliers & (residual != 0)
    rms = float(np.sqrt(np.mean(residual[fitted] ** 2))) if fitted.any() else 0.0
    return CircleFit(centre=params[:2].copy(), radius_m=float(params[2]), residual_m=rms,
                     arc_deg=arc_coverage_deg(xy[inliers], params[:2]), n_points=len(xy),
                     n_inliers=int(inliers.sum()))

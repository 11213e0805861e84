"""Diameter at breast height (DBH) of the stems of a point cloud.

The forester's DBH is the stem diameter 1.3 m above the ground (on a slope,
measured from the ground at the stem). Here, for each stem crossing breast
height:

1. the ground is found from the lowest points (:mod:`woody.ground`) or
   given; under a stem it is the ground plane around it, or the lowest
   points at its foot where that plane floats more than 0.2 m above them
   (a tree cut out of its scan has no ground points: it stands on its
   lowest stem points);
2. the points of a thin horizontal slice at breast height are grouped into
   stems (connected within a few point spacings) and a circle is fitted to
   each group (:func:`woody.circles.fit_circle`);
3. the stem axis is the line through the centres of circles fitted to
   sub-slices from ``breast height - 0.3 m`` to ``+ 0.3 m`` (a leaning stem
   cut horizontally is an ellipse);
4. the final circle is fitted to the points of the slice around breast
   height (10 cm tall, grown up to 40 cm on sparse stems until it holds 300
   points), measured along that axis and projected on the plane
   perpendicular to it.

Each stem comes with a quality flag from its arc coverage (a stem scanned
from one side covers about half a circle) and its fit residual.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from woody.circles import CircleFit, fit_circle, fit_circle_beam
from woody.cloud import check_points
from woody.errors import WoodyError
from woody.facing import BAND_M, ONE_SIDED_ARC_DEG, facing_radius
from woody.geometry import cylinder_arrays, orthonormal_frame
from woody.ground import ENVELOPE_M, GROUND_RANK, ground_grid, local_ground_z

#: Breast height above the ground, m (the international convention; 1.37 m = 4.5 ft in the USA).
BREAST_HEIGHT_M = 1.3
#: Half the height of the band whose sub-slices give the stem axis, m.
AXIS_BAND_M = 0.3
#: Sub-slices of the axis band.
AXIS_SLICES = 6
#: Fewest inliers of a circle fit that is measured at all.
MIN_POINTS = 10
#: A slice with fewer points grows, up to four times its height, until it holds this many (a thin or distant
#: stem: the variance of the fit falls with the point count, the taper over a few decimetres is negligible).
SLICE_POINTS = 300
#: Arc coverage below which a DBH is unreliable, degrees (the issue's partial-arc goal: 40 degrees).
MIN_ARC_DEG = 40.0
#: Arc coverage from which a DBH is fully trusted, degrees (assumption: a quarter circle).
GOOD_ARC_DEG = 90.0
#: Largest RMS residual of a trusted fit: the larger of 5 mm and 5 % of the radius (assumption: ranging noise
#: and bark roughness of a few millimetres; more means leaves, branches or a non-circular stem in the slice).
MAX_RESIDUAL_M, MAX_RESIDUAL_REL = 0.005, 0.05


#: Margin around a stem's circle whose lowest points may be its ground, m (assumption: the root collar's flare).
FOOTPRINT_MARGIN_M = 0.1


@dataclass(frozen=True)
class StemDBH:
    """The DBH of one stem.

    Attributes
    ----------
    dbh_m : float
        Diameter at breast height, m.
    centre : ndarray, (3,)
        Stem centre at breast height, m.
    axis : ndarray, (3,)
        Unit stem direction at breast height (upwards).
    height_m : float
        Height above the ground of the measurement, m.
    ground_z_m : float
        Ground height at the stem, m.
    arc_deg : float
        Arc coverage of the fitted points, degrees.
    residual_m : float
        RMS orthogonal residual of the fit, m.
    n_points : int
        Points of the fitted slice (inliers of the fit).
    flag : str
        ``"ok"``; ``"partial-arc"`` (arc under 90 degrees); ``"high-residual"``
        (residual over 5 mm and 5 % of the radius: leaves, branches or an
        irregular stem in the slice); ``"unreliable"`` (arc under 40 degrees
        or fewer than 10 points).
    """

    dbh_m: float
    centre: np.ndarray
    axis: np.ndarray
    height_m: float
    ground_z_m: float
    arc_deg: float
    residual_m: float
    n_points: int
    flag: str

    def to_dict(self) -> dict:
        """The fields as JSON-ready values."""
        out = asdict(self)
        out["centre"], out["axis"] = self.centre.tolist(), self.axis.tolist()
        return out


def measure_dbh(points, ground_z: float | None = None, height_m: float = BREAST_HEIGHT_M,
                slice_m: float = 0.1, min_dbh_m: float = 0.02, max_dbh_m: float = 3.0, viewpoint=None,
                footprint: tuple[float, float] | None = None, facing: bool = True) -> list[StemDBH]:
    """DBH of every stem that crosses breast height in a point cloud.

    Parameters
    ----------
    points : array_like, (n, 3)
        Coordinates, m (z up). Ground, leaves and noise may be left in.
    ground_z : float, optional
        Ground height, m (a level ground). By default the ground is found
        from the lowest points (:func:`woody.ground.ground_grid`), and
        refined under each stem.
    height_m : float
        Measurement height above the ground, m.
    slice_m : float
        Height of the slice whose circle gives the diameter, m (grown up to
        four times on stems with fewer than 300 points in it).
    min_dbh_m, max_dbh_m : float
        Diameters outside this range are not stems, m.
    viewpoint : array_like, (3,), optional
        Position of the scanner of a single scan, m (a single scan's own
        origin). With ``footprint``, each stem's final circle models the
        widening of its silhouette by the beam
        (:func:`woody.circles.fit_circle_beam`).
    footprint : tuple of float, optional
        The scanner's beam: its 1/e² diameter at the exit, m, and its
        growth per metre of range, m/m (twice the tangent of the divergence
        half-angle); the footprint at a stem is ``footprint[0] + range x
        footprint[1]`` (e.g. the FARO LS880 preset of :mod:`tlssim.scanner`:
        0.003 m and 0.000489).
    facing : bool
        Without a beam, take a stem seen from one side from its facing arc
        over a 1 m band (:func:`woody.facing.facing_radius`), which the
        beam's widening of the silhouette does not bias; False: the slice's
        circle alone.

    Returns
    -------
    list of StemDBH
        Stems, the one with the most points first.

    Raises
    ------
    WoodyError
        If no stem with at least 10 points crosses the measurement height.
    """
    points = check_points(points)
    for name, value in (("height_m", height_m), ("slice_m", slice_m), ("min_dbh_m", min_dbh_m),
                        ("max_dbh_m", max_dbh_m)):
        if not (np.isfinite(value) and value > 0):
            raise WoodyError(f"{name} must be a positive length in metres, got {value}")
    if ground_z is not None and not np.isfinite(ground_z):
        raise WoodyError(f"ground_z must be a finite height in metres, got {ground_z}")
    beam = _check_beam(viewpoint, footprint)
    grid = None if ground_z is not None else ground_grid(points)
    heights = points[:, 2] - ground_z if grid is None else grid.heights(points)
    in_slice = np.abs(heights - height_m) <= slice_m / 2.0
    if in_slice.sum() < MIN_POINTS:
        raise WoodyError(f"no stem at {height_m} m above the ground: {int(in_slice.sum())} point(s) within "
                         f"{slice_m / 2} m of that height" + ("" if grid is None else
                                                              " (give the ground height with ground_z / --ground-z?)"))
    tree = cKDTree(points)
    stems = []
    for group in _groups(points[in_slice]):
        try:
            first = fit_circle(points[in_slice][group][:, :2])
        except WoodyError:
            continue
        if not (min_dbh_m <= 2 * first.radius_m <= max_dbh_m) or first.n_inliers < MIN_POINTS:
            continue
        ground = ground_z if grid is None else _stem_ground(points, grid, first)
        stem = _measure_stem(points, tree, first, ground, height_m, slice_m, beam, facing)
        if stem is not None and min_dbh_m <= stem.dbh_m <= max_dbh_m:
            stems.append(stem)
    if not stems:
        raise WoodyError(f"no stem found at {height_m} m above the ground (no group of points in the slice fits a "
                         f"circle of {min_dbh_m}-{max_dbh_m} m diameter)")
    stems = _distinct(stems)
    return sorted(stems, key=lambda s: -s.n_points)


def model_diameter_at(cylinders: list[dict], z: float) -> float | None:
    """Diameter of a cylinder model at height ``z``: the thickest frustum crossing that height.

    Parameters
    ----------
    cylinders : list of dict
        Cylinder list (``start``, ``end``, ``radius_m``, optional ``radius_end_m``).
    z : float
        Height, m.

    Returns
    -------
    float or None
        Diameter (radius interpolated along the frustum), m; ``None`` when no
        cylinder crosses ``z``.
    """
    if not cylinders:
        return None
    arr = cylinder_arrays(cylinders)
    z0, z1 = arr["start"][:, 2], arr["end"][:, 2]
    crossing = (np.minimum(z0, z1) <= z) & (np.maximum(z0, z1) >= z) & (z0 != z1)
    if not crossing.any():
        return None
    t = (z - z0[crossing]) / (z1[crossing] - z0[crossing])
    radius = arr["r0"][crossing] + t * (arr["r1"][crossing] - arr["r0"][crossing])
    return float(2.0 * radius.max())


def dbh_summary(points, cylinders: list[dict], ground_z: float | None = None) -> dict:
    """DBH for a reconstruction's outputs: the stems' slice fits and the model's diameter at breast height.

    Parameters
    ----------
    points : array_like, (n, 3)
        The reconstructed cloud, m.
    cylinders : list of dict
        The reconstruction's cylinder list.
    ground_z : float, optional
        Ground height, m (found from the points by default).

    Returns
    -------
    dict
        ``stems`` (:meth:`StemDBH.to_dict` of each stem, the main stem
        first) and ``model_dbh_m`` (the model's diameter at the main stem's
        breast height, or ``None``); ``error`` instead of ``stems`` when no
        stem is found.
    """
    try:
        stems = measure_dbh(points, ground_z=ground_z)
    except WoodyError as exc:
        return {"error": str(exc), "model_dbh_m": None}
    return {"stems": [s.to_dict() for s in stems], "model_dbh_m": model_diameter_at(cylinders, stems[0].centre[2])}


def quality_flag(fit: CircleFit) -> str:
    """Quality flag of a stem-section fit from its arc coverage, residual and inliers (see :class:`StemDBH`)."""
    if fit.arc_deg < MIN_ARC_DEG or fit.n_inliers < MIN_POINTS:
        return "unreliable"
    if fit.residual_m > max(MAX_RESIDUAL_M, MAX_RESIDUAL_REL * fit.radius_m):
        return "high-residual"
    return "ok" if fit.arc_deg >= GOOD_ARC_DEG else "partial-arc"


def _groups(xyz: np.ndarray) -> list[np.ndarray]:
    """Indices of the groups of slice points that touch in x, y.

    The points are rasterised on cells of twice the point spacing (at least
    1.5 cm) and the occupied cells joined with their eight neighbours, so
    points up to about four spacings apart fall in one group.
    """
    sample = xyz[np.random.default_rng(0).choice(len(xyz), min(len(xyz), 5000), replace=False)]
    cell = max(2.0 * _spacing(sample), 0.015)
    origin = xyz[:, :2].min(axis=0)
    index = np.floor((xyz[:, :2] - origin) / cell).astype(np.int64)
    shape = index.max(axis=0) + 1
    if shape.prod() > 5e7:
        raise WoodyError(f"the slice spans {shape[0] * cell:.0f} m x {shape[1] * cell:.0f} m at {cell * 100:.1f} cm "
                         "cells: too large; give the points of one plot")
    image = np.zeros(shape, bool)
    image[index[:, 0], index[:, 1]] = True
    labels, _ = ndimage.label(image, structure=np.ones((3, 3), bool))
    point_labels = labels[index[:, 0], index[:, 1]]
    order = np.argsort(point_labels, kind="stable")
    groups = np.split(order, np.flatnonzero(np.diff(point_labels[order])) + 1)
    return [g for g in groups if len(g) >= MIN_POINTS]


def _spacing(xyz: np.ndarray) -> float:
    """Median distance of points to their nearest neighbour, m."""
    if len(xyz) < 2:
        return 0.0
    distance, _ = cKDTree(xyz).query(xyz, k=2)
    return float(np.median(distance[:, 1]))


def _stem_ground(points: np.ndarray, grid, first: CircleFit) -> float:
    """Ground height at a stem, m: the ground plane around it, or its foot where that plane floats above it.

    The foot is the robust lowest height (the third-lowest point) within the stem's circle and 10 cm around
    it: a plane more than ``ENVELOPE_M`` above it saw no ground there (a tree cut out of its scan has no
    ground points, and the cells around its stem hold its crown).
    """
    plane = local_ground_z(grid, first.centre, radius_m=max(1.5, 3 * first.radius_m))
    near = np.hypot(*(points[:, :2] - first.centre).T) <= first.radius_m + FOOTPRINT_MARGIN_M
    heights = np.sort(points[near, 2])
    foot = float(heights[min(GROUND_RANK, len(heights) - 1)])
    return foot if plane - foot > ENVELOPE_M else plane


def _check_beam(viewpoint, footprint) -> tuple[np.ndarray, float, float] | None:
    """``(viewpoint, exit diameter, growth per metre)`` of :func:`measure_dbh`'s beam, or None when not both given."""
    if viewpoint is None or footprint is None:
        return None
    viewpoint = np.asarray(viewpoint, float)
    if viewpoint.shape != (3,) or not np.isfinite(viewpoint).all():
        raise WoodyError(f"viewpoint must be a finite (x, y, z) position in metres, got {viewpoint.tolist()}")
    try:
        exit_m, growth = (float(v) for v in footprint)
    except (TypeError, ValueError):
        raise WoodyError(f"footprint must be (exit diameter m, growth m/m), got {footprint!r}") from None
    if not (np.isfinite(exit_m) and exit_m >= 0 and np.isfinite(growth) and growth >= 0):
        raise WoodyError(f"footprint must be (exit diameter m, growth m/m), both >= 0, got {footprint!r}")
    return viewpoint, exit_m, growth


def _measure_stem(points, tree, first: CircleFit, ground: float, height_m: float, slice_m: float, beam=None,
                  facing: bool = True):
    """Axis from sub-slices, then the circle of the slice at breast height along that axis (with the beam's
    widening modelled when ``beam``, from :func:`_check_beam`, is given); without the beam and with ``facing``, a
    stem seen from one side takes its radius and centre from its facing arc over a band
    (:func:`woody.facing.facing_radius`)."""
    reach = 1.5 * first.radius_m + 0.05
    centre = np.array([first.centre[0], first.centre[1], ground + height_m])
    near = np.asarray(tree.query_ball_point(centre, np.hypot(reach, AXIS_BAND_M + slice_m)), dtype=np.int64)
    near = near[np.hypot(*(points[near, :2] - first.centre).T) <= reach]
    local = points[near]
    axis = _axis(local, ground + height_m, first)
    u, v = orthonormal_frame(axis)[:2]
    along = np.abs((local - centre) @ axis)
    for grow in (1.0, 2.0, 3.0, 4.0):
        section = local[along <= grow * slice_m / 2.0]
        if len(section) >= SLICE_POINTS:
            break
    if len(section) < MIN_POINTS:
        return None
    planar = np.column_stack([(section - centre) @ u, (section - centre) @ v])
    try:
        fit = fit_circle(planar)
        if beam is not None:
            viewpoint, exit_m, growth = beam
            seen = viewpoint - centre
            footprint_m = exit_m + growth * float(np.linalg.norm(seen))
            fit = fit_circle_beam(planar, [seen @ u, seen @ v], footprint_m, start=fit)
    except WoodyError:
        return None
    radius, centre_uv = fit.radius_m, fit.centre
    if facing and beam is None and fit.arc_deg <= ONE_SIDED_ARC_DEG:
        band = np.asarray(tree.query_ball_point(centre, np.hypot(reach, BAND_M)), dtype=np.int64)
        arc = facing_radius(points[band], centre, axis, u, v, fit.centre, fit.radius_m)
        if arc is not None:
            radius, centre_uv = arc
    on_axis = centre + centre_uv[0] * u + centre_uv[1] * v
    on_axis -= (on_axis[2] - centre[2]) / axis[2] * axis  # the axis point at breast height
    return StemDBH(dbh_m=2.0 * radius, centre=on_axis, axis=axis,
                   height_m=height_m, ground_z_m=float(ground), arc_deg=fit.arc_deg, residual_m=fit.residual_m,
                   n_points=fit.n_inliers, flag=quality_flag(fit))


def _axis(local: np.ndarray, z0: float, first: CircleFit) -> np.ndarray:
    """Stem direction from the centres of circles fitted to sub-slices around ``z0`` (vertical if too few)."""
    edges = np.linspace(z0 - AXIS_BAND_M, z0 + AXIS_BAND_M, AXIS_SLICES + 1)
    centres, levels, weights = [], [], []
    for low, high in zip(edges[:-1], edges[1:]):
        layer = local[(local[:, 2] >= low) & (local[:, 2] < high)]
        if len(layer) < MIN_POINTS:
            continue
        try:
            fit = fit_circle(layer[:, :2])
        except WoodyError:
            continue
        if quality_flag(fit) in ("ok", "partial-arc") and abs(fit.radius_m / first.radius_m - 1) < 0.3:
            centres.append(fit.centre)
            levels.append(0.5 * (low + high) - z0)
            weights.append(fit.n_inliers)
    if len(centres) < 3:
        return np.array([0.0, 0.0, 1.0])
    design = np.column_stack([np.ones(len(levels)), levels]) * np.sqrt(weights)[:, None]
    slope = np.linalg.lstsq(design, np.array(centres) * np.sqrt(weights)[:, None], rcond=None)[0][1]
    axis = np.array([slope[0], slope[1], 1.0])
    return axis / np.linalg.norm(axis)


def _distinct(stems: list[StemDBH]) -> list[StemDBH]:
    """Drop stems whose centre lies inside a stem with more points (a stem split into groups by a gap)."""
    kept: list[StemDBH] = []
    for stem in sorted(stems, key=lambda s: -s.n_points):
        if all(np.linalg.norm(stem.centre[:2] - k.centre[:2]) > k.dbh_m / 2 for k in kept):
            kept.append(stem)
    return kept

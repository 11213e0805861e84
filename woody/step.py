"""STEP: Snakes for Tuboid Extraction from Point clouds (Ravaglia et al. 2017, Computers & Graphics 66).

Pipeline: normals -> point–normal circle Hough transform (sparse 4-D) ->
local maxima as seeds (strongest first) -> one generalised open active
contour per seed -> conflict tests and selection -> tuboids, i.e. ordered
circles (centre, unit normal, radius). STEP gives no topology: the tuboids
are independent and do not intersect.

Acceptance rules (the paper names them but defines none; the spec's D-S9 /
A.10 recommendations): seeds whose centre lies inside an accepted tuboid are
skipped, as are seeds within one cell of a rejected contour (they would grow
the same contour); an end stops growing when its new sphere overlaps an
accepted tuboid's spheres (``|c_a - c_b| < r_a + r_b``); a snake is kept if
it has at least ``min_vertices`` vertices and a mean data energy below
``max_mean_energy``; ``max_tuboids`` caps the count (the paper used 10 for
its tree data set).

Circle refinement (optional, an addition to the paper): the Hough space
quantises radii to ``radius_step_m``; with ``refine=True`` each circle is
re-fitted by robust least squares to the points in its slab of the tube,
starting from the snake's circle, which brings the radius error well below
the radius cell. A re-fit is kept when its median residual is within one
radius cell or, with ``normal_levels`` > 0, the noise about the points'
local planes (:func:`woody.normals.multiscale_normals`) where that is larger.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from woody.cloud import check_normals, check_points, check_viewpoints
from woody.errors import WoodyError
from woody.geometry import cylinders_volume, frustum_volume, ring_frames, tube_mesh
from woody.hough import HoughGrid, HoughSpace, hough_transform
from woody.density import point_spacing, voxel_subsample
from woody.normals import multiscale_normals, orient_outward
from woody.snake import Snake, SnakeParams, data_energy, resample


@dataclass
class Tuboid:
    """An ordered series of circles whose centre, orientation and radius vary continuously.

    Attributes
    ----------
    centres : ndarray, (k, 3)
        Circle centres, m.
    normals : ndarray, (k, 3)
        Unit normals of the circle planes (tangent of the centreline).
    radii : ndarray, (k,)
        Circle radii, m.
    mean_energy : float
        Mean data energy ``E_d`` along the contour (in [-1, 0]; lower is a stronger ridge).
    """

    centres: np.ndarray
    normals: np.ndarray
    radii: np.ndarray
    mean_energy: float = 0.0

    @property
    def length(self) -> float:
        """Centreline length, m."""
        return float(np.linalg.norm(np.diff(self.centres, axis=0), axis=1).sum())

    @property
    def volume(self) -> float:
        """Volume of the frusta between consecutive circles, m^3."""
        h = np.linalg.norm(np.diff(self.centres, axis=0), axis=1)
        return float(frustum_volume(self.radii[:-1], self.radii[1:], h).sum())

    def diameter_at_height(self, z: float) -> float:
        """Diameter (m) where the centreline crosses height ``z`` (m); NaN if it does not.

        When the centreline crosses ``z`` several times, the lowest crossing
        along the tuboid is used.
        """
        heights = self.centres[:, 2]
        for i in range(len(heights) - 1):
            z0, z1 = heights[i], heights[i + 1]
            if min(z0, z1) <= z <= max(z0, z1):
                f = 0.5 if z1 == z0 else (z - z0) / (z1 - z0)
                return float(2.0 * (self.radii[i] + f * (self.radii[i + 1] - self.radii[i])))
        return float("nan")

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return {"centres": self.centres.tolist(), "normals": self.normals.tolist(), "radii": self.radii.tolist(),
                "mean_energy": self.mean_energy}


@dataclass
class StepResult:
    """Output of :func:`step`.

    Attributes
    ----------
    tuboids : list of Tuboid
        Accepted tuboids, in order of acceptance (strongest seed first).
    normals : ndarray, (n, 3)
        Normals used for voting (of the ``stats["points_used"]`` points
        kept when the cloud was subsampled).
    stats : dict
        Counts, Hough-space footprint (bytes), timings (s) and settings.
    """

    tuboids: list[Tuboid]
    normals: np.ndarray
    stats: dict = field(default_factory=dict)

    def cylinders(self) -> list[dict]:
        """Tuboids as a cylinder list (one frustum per pair of consecutive circles; ``order`` is None)."""
        out = []
        for branch, tube in enumerate(self.tuboids):
            for i in range(len(tube.radii) - 1):
                cid = len(out)
                out.append({"id": cid, "parent": -1 if i == 0 else cid - 1, "order": None, "branch": branch,
                            "start": tube.centres[i].tolist(), "end": tube.centres[i + 1].tolist(),
                            "radius_m": float(tube.radii[i]), "radius_end_m": float(tube.radii[i + 1])})
        return out

    @property
    def volume(self) -> float:
        """Total tuboid volume, m^3."""
        return cylinders_volume(self.cylinders())

    def mesh(self, sections: int = 16):
        """All tuboids as one triangle mesh (trimesh.Trimesh)."""
        import trimesh

        meshes = [tube_mesh(t.centres, t.normals, t.radii, sections) for t in self.tuboids]
        return trimesh.util.concatenate(meshes) if meshes else trimesh.Trimesh()

    def diameter_at_height(self, z: float) -> float:
        """Stem diameter at height ``z`` (m): the widest tuboid crossing that height; NaN if none does."""
        values = [t.diameter_at_height(z) for t in self.tuboids]
        values = [v for v in values if np.isfinite(v)]
        return max(values) if values else float("nan")

    def taper(self, heights) -> np.ndarray:
        """Stem diameters (m) at each of ``heights`` (m), NaN where no tuboid crosses."""
        return np.array([self.diameter_at_height(float(z)) for z in np.atleast_1d(heights)])


def step(points, normals=None, *, viewpoints=None, cell_m: float | None = None, radius_step_m: float | None = None,
         r_min_m: float | None = None, r_max_m: float = 0.30, oriented: bool | None = None, normal_k: int = 16,
         normal_levels: int = 0, samples_per_bin: int = 1, min_votes: int = 2, params: SnakeParams | None = None,
         max_tuboids: int | None = None, max_seeds: int | None = 5000, min_vertices: int = 3,
         min_length_radii: float = 1.0, max_mean_energy: float = -0.3, weak_energy: float = -0.4,
         min_weak_arc_deg: float = 72.0, refine: bool = True, subsample_m: float | None = None,
         progress: bool = False) -> StepResult:
    """Extract tuboids from a point cloud with STEP.

    Parameters
    ----------
    points : array_like, (n, 3)
        Coordinates, m.
    normals : array_like, (n, 3), optional
        Given normals (e.g. oracle normals from the scene truth). When
        omitted they are estimated by PCA (:func:`woody.normals.multiscale_normals`:
        of the ``normal_k`` nearest neighbours, or with ``normal_levels`` > 0
        at the scale of least surface variation).
    viewpoints : array_like, (3,) or (n, 3), optional
        Scanner position(s), m: estimated normals are flipped to face them.
    cell_m, radius_step_m : float, optional
        Hough cell sizes in x, y, z and in r, m (paper: 2 cm / 1 cm for
        single stems, up to 5 cm / 1 cm for sparse trees). Rules:
        ``cell_m >= 2 radius_step_m`` and ``radius_step_m < r_min_m``.
        By default they follow the cloud's point spacing
        (:func:`hough_cells`): 2 cm / 1 cm up to 1 cm spacing.
    r_min_m, r_max_m : float
        Radius range sought, m (``r_min_m`` by default from
        :func:`hough_cells`: 2 cm up to 1 cm spacing).
    oriented : bool, optional
        Whether normals point outwards (vote on one half-line, eq. 5) or
        have an arbitrary sign (both half-lines, eq. 6). Default True:
        given normals are taken as outward, PCA normals are flipped towards
        ``viewpoints`` when known, else away from the local centre of mass
        (:func:`woody.normals.orient_outward`). False votes on both
        half-lines: the outward votes put Hough maxima on rings around
        every stem, each grown as a snake and rejected (a 30 cm stem at 10
        pts/cm²: 5,589 maxima, 4,794 snakes, 89 s; oriented outward: 763
        maxima, 31 snakes, 10 s, the same diameter and volume).
    normal_k, normal_levels : int
        Neighbours of the finest PCA scale and number of coarser scales
        (see :func:`woody.normals.multiscale_normals`). With levels > 0
        they also measure the noise that the circle re-fit accepts, with
        given normals too: for noisy clouds (STEP DS1c: re-fitted circles
        within 1 cm up to 5 cm of noise). 0 (the default): PCA of the
        ``normal_k`` nearest neighbours and a re-fit tolerance of one radius
        cell (the quick suite's leafy tree at 0.08 deg: diameter error 0.99 cm
        against 1.22 cm with 4 levels, volume -25 % against -19 %; with 1 % of
        its points dropped at random, three draws: 0.92-1.14 cm and -9 to -39 %
        against 0.84-1.23 cm and -6 to -41 %, so the two differ by less than
        the spread of that one tree's scores).
    samples_per_bin, min_votes : int
        See :func:`woody.hough.hough_transform`.
    params : SnakeParams, optional
        Active-contour settings.
    max_tuboids : int, optional
        Stop after this many accepted tuboids.
    max_seeds : int, optional
        Stop after trying this many seeds (bounds run time on noisy clouds).
    min_vertices : int
        Shortest accepted snake, vertices.
    min_length_radii : float
        Shortest accepted tuboid, in units of its mean radius.
    max_mean_energy : float
        Snakes whose mean ``E_d`` is above this are rejected as noise.
    weak_energy, min_weak_arc_deg : float
        A snake whose mean ``E_d`` is above ``weak_energy`` (a weak ridge)
        is kept only if its circles have points on at least
        ``min_weak_arc_deg`` of their circumference (median over the
        circles, 10-deg sectors; :func:`arc_support`). Assumption of this
        project, not in the paper: in a tree crown, the votes of several thin
        twigs add up to weak ridges at radii far larger than any branch, and
        such circles have almost no points on them; a real stem gives a
        strong ridge even when only 10 deg of it are seen.
    refine : bool
        Re-fit each circle to its points (see the module docstring).
    subsample_m : float, optional
        Voxel edge of the subsampling applied before anything else, m
        (:func:`woody.density.voxel_subsample`); 0 keeps every point. By
        default a cloud whose point spacing is below a quarter of
        ``cell_m`` is subsampled to that spacing: a Hough cell then still
        receives the votes of about 16 points per cm of stem, and a 30
        pts/cm² scan costs what a 4 pts/cm² one does.
    progress : bool
        Show a progress bar over the seeds.

    Returns
    -------
    StepResult

    Raises
    ------
    WoodyError
        On an invalid cloud or parameter.

    Examples
    --------
    A vertical stem of radius 5 cm and 1 m length, sampled at 5000 points
    per m^2 with its exact (outward) normals:

    >>> from woody import step
    >>> from woody.synthetic import sample_cylinders, straight_cylinder
    >>> cloud = sample_cylinders(straight_cylinder(0.05, 1.0), 5e3, seed=0)
    >>> result = step(cloud.points, cloud.normals)
    >>> len(result.tuboids)
    1
    >>> round(result.diameter_at_height(0.5), 2), round(result.tuboids[0].length, 1)   # m
    (0.1, 1.0)
    """
    timings = {}
    clock = time.perf_counter()
    points = check_points(points)
    viewpoints = check_viewpoints(viewpoints, len(points))
    if min_vertices < 2:
        raise WoodyError(f"min_vertices must be at least 2, got {min_vertices}")
    if not -1 < max_mean_energy <= 0:
        raise WoodyError(f"max_mean_energy must be in (-1, 0], got {max_mean_energy}")
    if not 0 <= min_weak_arc_deg <= 360:
        raise WoodyError(f"min_weak_arc_deg must be in [0, 360], got {min_weak_arc_deg}")
    if max_tuboids is not None and max_tuboids < 1:
        raise WoodyError(f"max_tuboids must be at least 1, got {max_tuboids}")
    params = params or SnakeParams()
    if normals is not None:
        normals = check_normals(normals, len(points))
    count = len(points)
    _check_not_a_line(points)
    auto_cells = None in (cell_m, radius_step_m, r_min_m)
    spacing = point_spacing(points) if count >= 7 and (auto_cells or subsample_m is None) else 0.0
    if auto_cells:
        auto = hough_cells(spacing)
        cell_m, radius_step_m, r_min_m = (auto[i] if value is None else value
                                          for i, value in enumerate((cell_m, radius_step_m, r_min_m)))
    grid = HoughGrid.around(points, cell_m, radius_step_m, r_min_m, r_max_m)
    kept = _subsample(points, cell_m, subsample_m, spacing)
    if kept is not None:
        points = points[kept]
        normals = None if normals is None else normals[kept]
        viewpoints = None if viewpoints is None else viewpoints[kept]
        if len(points) < normal_k:
            raise WoodyError(f"the {count} points fill only {len(points)} voxels of {cell_m / 4} m: too few for "
                             f"STEP (at least {normal_k})")
    oriented = True if oriented is None else oriented
    noise = None  # the re-fit's tolerance beyond one radius cell: only with coarser scales
    if normals is None:
        normals, measured = multiscale_normals(points, normal_k, viewpoints, normal_levels)
        noise = measured if normal_levels > 0 else None
        if oriented and viewpoints is None:
            normals = orient_outward(points, normals)
    elif refine and normal_levels > 0:
        noise = multiscale_normals(points, normal_k, None, normal_levels)[1]
    timings["normals_s"] = time.perf_counter() - clock

    clock = time.perf_counter()
    hs = hough_transform(points, normals, grid, oriented, samples_per_bin, min_votes)
    timings["hough_s"] = time.perf_counter() - clock
    clock = time.perf_counter()
    is_max, h_min, h_max = hs.neighbourhood()
    energy = data_energy(hs, h_min, h_max, params.balance)
    seed_rows = np.flatnonzero(is_max)
    seed_rows = seed_rows[np.argsort(-hs.counts[seed_rows], kind="stable")]
    seeds = grid.unpack(hs.keys[seed_rows])
    timings["maxima_s"] = time.perf_counter() - clock

    clock = time.perf_counter()
    tree = cKDTree(points)

    def supported(metric: np.ndarray, e_d: np.ndarray) -> bool:
        return e_d.mean() <= weak_energy or \
            arc_support(metric[:, :3], metric[:, 3], points, tree, radius_step_m) >= min_weak_arc_deg / 360.0

    tuboids, tried, rejected = _run_snakes(hs, energy, seeds, params, max_tuboids, max_seeds, min_vertices,
                                           min_length_radii, max_mean_energy, supported, progress)
    timings["snakes_s"] = time.perf_counter() - clock
    clock = time.perf_counter()
    if refine:
        for _ in range(2):  # the second pass starts from straighter slabs
            tuboids = [refine_tuboid(t, points, tree, radius_step_m, noise) for t in tuboids]
    timings["refine_s"] = time.perf_counter() - clock
    stats = {"points": count, "points_used": len(points), "oriented": bool(oriented), "grid_shape": list(grid.shape),
             "dense_cells": float(np.prod(np.array(grid.shape, float))), "occupied_cells": len(hs.keys),
             "hough_bytes": hs.nbytes, "seeds": len(seeds), "seeds_tried": tried, "snakes_rejected": rejected,
             "tuboids": len(tuboids), **timings}
    return StepResult(tuboids, normals, stats)


def _check_not_a_line(points: np.ndarray) -> None:
    """Refuse points that all lie on one straight line (no circle, no tube through them)."""
    if len(points) < 3:
        return
    singular = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    if singular[0] == 0:
        raise WoodyError(f"all {len(points)} points coincide: no tube can be fitted to them")
    if singular[1] <= 1e-6 * singular[0]:
        raise WoodyError(f"the {len(points)} points lie on a straight line: no tube can be fitted to them")


#: Hough cells per point spacing: a cell of two spacings is crossed by the normal lines of several points of a
#: stem (assumption; the paper's 2 cm cells on clouds of about 1 cm spacing, and its "up to 5 cm for sparse
#: trees"). Chosen on the real cloud aRchi Tree_1 (69 mm spacing: 2 cm cells give no trunk; cells of 5 and 10 cm
#: give 2.2 and 4.0 m³ against TreeQSM's 3.9); rTwig's cloud (12.7 mm) was run after the choice.
CELLS_PER_SPACING = 2.0


def hough_cells(spacing_m: float) -> tuple[float, float, float]:
    """STEP's default Hough cell, radius cell and smallest radius for a cloud's point spacing, m.

    The cell is the larger of 2 cm (the paper's) and :data:`CELLS_PER_SPACING` spacings; the radius cell the
    larger of 1 cm and 0.4 cells (so that ``cell >= 2 radius cell``); the smallest radius the larger of 2 cm and
    1.5 radius cells (so that a radius cell is below it). Up to 1 cm spacing: the paper's 2 cm / 1 cm / 2 cm.

    Parameters
    ----------
    spacing_m : float
        Point spacing (:func:`woody.density.point_spacing`), m.

    Returns
    -------
    cell_m, radius_step_m, r_min_m : float

    Examples
    --------
    >>> hough_cells(0.005)
    (0.02, 0.01, 0.02)
    >>> [round(v, 3) for v in hough_cells(0.05)]
    [0.1, 0.04, 0.06]
    """
    cell = max(0.02, CELLS_PER_SPACING * spacing_m)
    radius_step = max(0.01, 0.4 * cell)
    return cell, radius_step, max(0.02, 1.5 * radius_step)


def _subsample(points: np.ndarray, cell_m: float, subsample_m: float | None,
               spacing_m: float) -> np.ndarray | None:
    """Indices of the points STEP uses (None: all of them); see ``subsample_m`` of :func:`step` (``spacing_m``: the
    cloud's point spacing, m)."""
    if subsample_m is not None and not (np.isfinite(subsample_m) and subsample_m >= 0):
        raise WoodyError(f"subsample_m must be a length >= 0 in metres, got {subsample_m}")
    if subsample_m == 0 or len(points) < 7:
        return None
    voxel = cell_m / 4.0 if subsample_m is None else subsample_m
    if subsample_m is None and spacing_m >= voxel:
        return None
    return voxel_subsample(points, voxel)


def _run_snakes(hs: HoughSpace, energy, seeds, params, max_tuboids, max_seeds, min_vertices, min_length_radii,
                max_mean_energy, supported, progress) -> tuple[list[Tuboid], int, int]:
    """Grow a snake from each live seed in turn; keep the significant, non-conflicting, supported ones."""
    from tqdm import tqdm

    grid = hs.grid
    snake = Snake(hs, energy, params)
    accepted: list[Tuboid] = []
    spheres = _SphereSet()
    alive = np.ones(len(seeds), bool)
    seed_index = cKDTree(seeds)
    seed_space = cKDTree(grid.to_metric(seeds.astype(float))[:, :3])
    tried = rejected = 0
    bar = tqdm(total=len(seeds), desc="STEP seeds", disable=not progress, leave=False)
    for row in range(len(seeds)):
        bar.update(1)
        if not alive[row]:
            continue
        if (max_tuboids is not None and len(accepted) >= max_tuboids) or (max_seeds is not None and tried >= max_seeds):
            break
        tried += 1
        vertices, _ = snake.grow(seeds[row], lambda v: spheres.overlaps(grid.to_metric(v)[None])[0])
        significant = _significant(grid.to_metric(vertices), hs.interpolate(energy, vertices), min_vertices,
                                   max_mean_energy, min_length_radii)
        if significant:  # the costly final minimisation only for contours that may be kept
            vertices = snake.minimise(resample(vertices, 1.0), params.final_iterations)
            metric = grid.to_metric(vertices)
            e_d = hs.interpolate(energy, vertices)
            keep = _trim_conflicts(metric, spheres)
            metric, e_d = metric[keep], e_d[keep]
            significant = _significant(metric, e_d, min_vertices, max_mean_energy, min_length_radii) and \
                supported(metric, e_d)
        if not significant:
            rejected += 1
            alive[_flatten(seed_index.query_ball_point(vertices, 1.0 + 1e-9))] = False
            continue
        tube = _to_tuboid(metric, float(e_d.mean()))
        accepted.append(tube)
        spheres.add(tube.centres, tube.radii)
        alive[_flatten(seed_space.query_ball_point(tube.centres, tube.radii))] = False
    bar.close()
    return accepted, tried, rejected


def _flatten(lists) -> np.ndarray:
    """Concatenation of the index lists returned by a ball query."""
    return np.fromiter((i for near in lists for i in near), dtype=np.int64)


def _significant(metric: np.ndarray, e_d: np.ndarray, min_vertices: int, max_mean_energy: float,
                 min_length_radii: float) -> bool:
    """Whether a contour is long enough, on a strong enough ridge, and of positive radius."""
    if len(metric) < min_vertices or (metric[:, 3] <= 0).any() or e_d.mean() > max_mean_energy:
        return False
    length = np.linalg.norm(np.diff(metric[:, :3], axis=0), axis=1).sum()
    return bool(length >= min_length_radii * metric[:, 3].mean())


class _SphereSet:
    """Spheres of the accepted tuboids, for the overlap test."""

    def __init__(self):
        self.centres = np.empty((0, 3))
        self.radii = np.empty(0)
        self.tree = None

    def add(self, centres, radii) -> None:
        self.centres = np.vstack([self.centres, centres])
        self.radii = np.concatenate([self.radii, radii])
        self.tree = cKDTree(self.centres)

    def overlaps(self, xyzr: np.ndarray) -> np.ndarray:
        """Whether each sphere ``(x, y, z, r)`` overlaps an accepted sphere (``|c_a - c_b| < r_a + r_b``)."""
        out = np.zeros(len(xyzr), bool)
        if self.tree is None:
            return out
        reach = np.maximum(xyzr[:, 3], 0.0)
        for i, near in enumerate(self.tree.query_ball_point(xyzr[:, :3], reach + self.radii.max())):
            if near:
                gap = np.linalg.norm(self.centres[near] - xyzr[i, :3], axis=1) - self.radii[near] - reach[i]
                out[i] = (gap < 0).any()
        return out


def _trim_conflicts(metric: np.ndarray, spheres: _SphereSet) -> np.ndarray:
    """Keep-mask that drops overlapping vertices at both ends (the contour relaxes after growth stopped);
    a snake overlapping in its interior keeps only its longest free run."""
    free = ~spheres.overlaps(metric)
    if free.all() or not free.any():
        return free
    edges = np.diff(np.concatenate([[0], free.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    longest = np.argmax(stops - starts)
    keep = np.zeros(len(metric), bool)
    keep[starts[longest]:stops[longest]] = True
    return keep


def _to_tuboid(metric: np.ndarray, mean_energy: float) -> Tuboid:
    """Circles of a metric snake: centre (x, y, z), radius r, normal = tangent of the centreline (D-S10)."""
    centres = metric[:, :3]
    tangents = np.gradient(centres, axis=0) if len(centres) > 1 else np.array([[0.0, 0.0, 1.0]])
    tangents /= np.maximum(np.linalg.norm(tangents, axis=1, keepdims=True), 1e-12)
    return Tuboid(centres.copy(), tangents, metric[:, 3].copy(), mean_energy)


def refine_tuboid(tube: Tuboid, points: np.ndarray, tree: cKDTree, radius_step_m: float,
                  noise_m: np.ndarray | None = None) -> Tuboid:
    """Re-fit every circle of a tuboid to the points of its slab by robust least squares.

    The slab of circle i spans half the distance to its neighbours along the
    normal; points farther than ``max(0.3 r, 2 radius_step_m)`` from the
    snake's circle are ignored. The fit (centre in the circle plane and
    radius, soft-L1 loss with scale ``radius_step_m``) replaces the circle
    when at least 6 points support it, the radius stays within that band
    and the median residual is at most the tolerance ``max(radius_step_m,
    s)``, ``s`` the median of ``noise_m`` over the fitted points; the centres
    are then smoothed along the tuboid and the normals re-derived. Points
    off a circle by noise of s.d. ``s`` have a median residual of 0.67 ``s``
    (Gaussian) to 0.87 ``s`` (uniform), so a fit to the circle they sample
    passes, and one a tolerance away from it does not.

    Parameters
    ----------
    tube : Tuboid
        The tuboid to refine (centres and radii in m).
    points : ndarray
        The point cloud, m, shape ``(n, 3)``.
    tree : cKDTree
        KD-tree built on ``points``.
    radius_step_m : float
        Radius cell size of the snake search, m; sets the band and the least tolerance.
    noise_m : ndarray, optional
        Noise about each point's local plane, m, shape ``(n,)``
        (:func:`woody.normals.multiscale_normals`); None: a tolerance of one radius cell.

    Returns
    -------
    Tuboid
        The refined tuboid (centres and radii in m, unit normals).
    """
    centres, radii = tube.centres.copy(), tube.radii.copy()
    spacing = np.linalg.norm(np.diff(tube.centres, axis=0), axis=1)
    half = 0.5 * np.maximum(np.concatenate([[spacing[0]], spacing]), np.concatenate([spacing, [spacing[-1]]]))
    normals = windowed_tangents(tube.centres, tube.radii)
    u, v = ring_frames(normals)
    for i, (c, n, r) in enumerate(zip(tube.centres, normals, tube.radii)):
        band = max(0.3 * r, 2 * radius_step_m)
        near = np.asarray(tree.query_ball_point(c, np.hypot(r + band, half[i])), dtype=np.int64)
        if len(near) < 6:
            continue
        rel = points[near] - c
        along = rel @ n
        plane = np.column_stack([rel @ u[i], rel @ v[i]])
        keep = (np.abs(along) <= half[i]) & (np.abs(np.linalg.norm(plane, axis=1) - r) <= band)
        if keep.sum() < 6:
            continue
        plane = plane[keep]
        tolerance = radius_step_m if noise_m is None else max(radius_step_m, float(np.median(noise_m[near[keep]])))
        fit = least_squares(lambda q: np.linalg.norm(plane - q[:2], axis=1) - q[2], x0=[0.0, 0.0, r],
                            loss="soft_l1", f_scale=tolerance)
        residual = np.abs(np.linalg.norm(plane - fit.x[:2], axis=1) - fit.x[2])
        if fit.success and 0 < fit.x[2] and abs(fit.x[2] - r) < band and np.median(residual) <= tolerance:
            centres[i] = c + fit.x[0] * u[i] + fit.x[1] * v[i]
            radii[i] = fit.x[2]
    if len(centres) >= 3:
        centres[1:-1] = 0.25 * centres[:-2] + 0.5 * centres[1:-1] + 0.25 * centres[2:]
    return _to_tuboid(np.column_stack([centres, radii]), tube.mean_energy)


def arc_support(centres: np.ndarray, radii: np.ndarray, points: np.ndarray, tree: cKDTree,
                radius_step_m: float) -> float:
    """Median over a tuboid's circles of the fraction of the circumference that has points on it.

    A point is on circle i when it lies within half the centre spacing of
    the circle plane and within ``max(0.1 r, radius_step_m)`` of the
    circle; the circumference is cut in 36 sectors of 10 deg.

    Parameters
    ----------
    centres : ndarray
        Circle centres along the tuboid, m, shape ``(k, 3)``.
    radii : ndarray
        Circle radii, m, shape ``(k,)``.
    points : ndarray
        The point cloud, m, shape ``(n, 3)``.
    tree : cKDTree
        KD-tree built on ``points``.
    radius_step_m : float
        Radius cell size, m; the least tolerance around a circle.

    Returns
    -------
    float
        Median covered fraction of the circumference, 0..1.
    """
    normals = windowed_tangents(centres, radii)
    u, v = ring_frames(normals)
    spacing = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    half = max(0.5 * float(np.median(spacing)) if len(spacing) else 0.0, radius_step_m)
    covered = []
    for i, (c, n, r) in enumerate(zip(centres, normals, radii)):
        band = max(0.1 * r, radius_step_m)
        near = np.asarray(tree.query_ball_point(c, np.hypot(r + band, half)), dtype=np.int64)
        rel = points[near] - c
        plane = np.column_stack([rel @ u[i], rel @ v[i]])
        on = (np.abs(rel @ n) <= half) & (np.abs(np.linalg.norm(plane, axis=1) - r) <= band)
        sectors = np.floor((np.arctan2(plane[on, 1], plane[on, 0]) + np.pi) / (2 * np.pi) * 36).astype(int) % 36
        covered.append(len(np.unique(sectors)) / 36.0)
    return float(np.median(covered))


def windowed_tangents(centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Unit tangents of a centreline, each the principal axis of the centres within one radius of it.

    A snake's vertices wander by up to a cell or so across the ridge; the
    tangent of neighbouring vertices then tilts the circle planes (by tens of
    degrees on a weakly constrained, partly visible stem), so that a circle
    fitted in that plane sees an ellipse. The centres within one local
    radius along the curve (at least the two neighbours) average the wander
    out; a tube bends on a scale of its radius or more.

    Parameters
    ----------
    centres : ndarray
        Centreline vertices, m, shape ``(k, 3)``.
    radii : ndarray
        Local radius at each vertex, m, shape ``(k,)``; the window half-length.

    Returns
    -------
    ndarray
        Unit tangents (dimensionless), shape ``(k, 3)`` (one vertical tangent for
        fewer than two vertices).
    """
    if len(centres) < 2:
        return np.array([[0.0, 0.0, 1.0]])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(centres, axis=0), axis=1))])
    tangents = np.empty_like(centres)
    for i in range(len(centres)):
        window = np.abs(arc - arc[i]) <= radii[i]
        window[max(i - 1, 0):i + 2] = True
        near = centres[window] - centres[window].mean(axis=0)
        axis = np.linalg.svd(near, full_matrices=False)[2][0]
        tangents[i] = axis if axis @ (centres[min(i + 1, len(centres) - 1)] - centres[max(i - 1, 0)]) >= 0 else -axis
    return tangents

"""Cylinder following: leafless tree reconstruction after Méndez et al.

(V. Méndez, J. R. Rosell-Polo, R. Sanz, A. Escolà, H. Catalán, "Deciduous tree
reconstruction algorithm based on cylinder fitting from mobile terrestrial
laser scanned point clouds", author manuscript; it follows Pfeifer et al. 2004.)

Each branch is a cylinder: an axis ``P1 -> P2`` (the extreme projections of
its points) and a radius. Growth starts from the lowest point and
repeatedly gives each active branch its closest unassigned point
(round-robin, one point per branch and visit: the paper's Table 1 loop read
as the spec's D-M2); a point goes to a branch only if no other branch is
closer (ties to the older branch). The first points of a branch are taken
without test ("free seeding", ``n_s`` by order, Table 7); afterwards a point
that lies farther from the refitted axis than ``k_r(t_d)`` times the
branch's radius, or than the radius of the branch's *significant* ancestor,
starts a child branch (D-M6: both the text's and the pseudocode's test).
Then: merge sibling branches whose angles to the parent differ by less than
4 deg, merge children within 11.5 deg of their parent, and move points
between parent and child where that lowers the total volume.

Two modes. ``FollowParams()`` (the default, "spec") makes the choices below
so that the method works on dense and on fully sampled stems;
``woody.experiments.PAPER_MODE`` reads the paper literally (covariance
axis through the centroid, radius = largest distance, running-maximum
test, merges as printed, one cylinder per branch).

Decisions where the paper is silent, contradicts itself or fails on our
test trees (spec Part D; each a documented departure in the default mode):

- axis direction (D-M3). Paper: a covariance eigenvector through the
  centroid, the one minimising the largest orthogonal distance
  (``direction="covariance"``; ``"iterative"`` is the polar-azimuth minimax
  search after Rabbani & van den Heuvel 2005). That fails on the first
  points of a wide stem, a patch or an arc along the rim, so by default
  (``"normals"``) the axis is the direction least aligned with the PCA
  normals when they clearly lie in one plane, else the long axis of an
  elongated cluster, else the normals' direction when merely decisive,
  else the paper's minimax eigenvector;
- axis position: by default (``axis="circle"``) the centre of a robust
  circle fitted to the points seen along the axis, once they curve around
  it (a one-sided scan sees half a stem, whose centroid is 0.64 r off the
  axis); ``"centroid"`` is the paper's;
- radius (D-M4) and the inclusion test: with the paper's reading (radius =
  largest orthogonal distance, a point "not aligned" when the radius would
  exceed ``k_r r``) a smooth fork never shows a 5-10 % jump between
  consecutive closest points, the radius creeps and one cylinder swallows
  the fork (seen on the Y-shaped test tree). By default
  (``inclusion="envelope"``) the test compares the new point's distance
  with ``k_r`` times the envelope radius of the branch's last exact fit,
  the median distance plus three robust standard deviations, which no
  minority of points can drag along; ``"max"`` is the paper's. The reported
  radius is ``radius="median"`` (default), ``"mean"`` or ``"max"`` (paper);
  the volume-balancing pass uses the largest distance, as the paper;
- free seeding ends after ``n_s`` points or, earlier, once the branch has
  6 points or more and an axis at least two diameters long (``n_s`` is
  meant to grow with density, and Table 7 was tuned for sparse mobile
  scans: at TLS densities 40-80 free points swallow whole forks);
- distance of a point to a branch (D-M5): ``max(0, d(P, P1P2) - r)`` with
  the largest distance as ``r``; candidates are the k nearest neighbours of
  the branch's points; the default ``Precision`` is 2.5 x the nominal
  spacing (from the median distance to the 6th neighbour);
- ``t_d`` normalised by ``|P2 - P1|`` (D-M7); ``ord_min1 = 2``,
  ``ord_min2 = 4``, ``n_min = 2 n_s(order)`` with AND semantics (D-M8);
  ``order <= threshold`` selects ``n_s`` (D-M9); axes point away from the
  branch base (D-M10);
- sibling merging (D-M11): ``mode="strict"`` (default) also requires
  the two children to be within 4 deg of each other and their union to fit
  one cylinder (95th-percentile distance within ``max(k_r)`` of the wider
  one's; the same holds for child-into-parent merges); ``"faithful"``
  compares only their angles to the parent, as printed;
- volume balancing (D-M12): axes fixed within a pass (a refit per
  candidate point would cost O(n)); strict mode keeps the child thinner
  than its parent, faithful mode applies the printed
  ``Tmp1.radius < Tmp2.radius``; at most ``max_balance_passes`` passes;
- clean-up (strict mode, additions): branches with fewer than
  ``min_branch_points`` points are given back to their parents (a stalled
  root to its largest child); a branch whose axis midpoint lies inside an
  older branch's cylinder is merged into it (a duplicate grown alongside);
- output: each branch is cut into pieces of ``section_radii`` radii, each
  refitted on its own points (0 gives the paper's one cylinder per
  branch); in strict mode the paper's radius hierarchy is applied to the
  output: no piece is wider than ``max(k_r)`` times the piece before it or
  than its significant ancestor where it starts;
- orders are recomputed from the trunk after the merges (D-M14).

Cost: a KD-tree and a k-nearest-neighbour graph (O(N log N)), then one heap
push per neighbour of each included point and amortised O(1) refits
(running sums of the points, their outer products and their normals'
outer products; the exact O(n) fit is redone each time a branch grows by
10 %), i.e. O(N log N) overall.
"""

from __future__ import annotations

import copy
import heapq
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from scenes.primitives import orthonormal_frame
from woody.cloud import check_points
from woody.errors import WoodyError
from woody.geometry import cylinders_mesh, cylinders_volume, segment_distance
from woody.normals import pca_normals

#: Table 7 of Méndez et al., apple tree: (order threshold, n_s) pairs, "order <= threshold".
APPLE_FREE_SEED = ((1, 80), (3, 60), (7, 40), (10, 30), (9999, 20))
#: Table 7, vine.
VINE_FREE_SEED = ((1, 80), (3, 50), (9999, 20))
#: Table 7, pear tree (sparser scan).
PEAR_FREE_SEED = ((1, 20), (7, 15), (9999, 10))


@dataclass(frozen=True)
class FollowParams:
    """Settings of :func:`follow_cylinders`.

    Attributes
    ----------
    free_seed : tuple of (int, int)
        ``(order threshold, n_s)`` pairs: a branch of order ``o`` takes its
        first ``n_s`` points freely, for the first threshold ``>= o`` (Table 7;
        default: apple tree).
    k_r : tuple of 2 float
        Radius factors for ``t_d < t_split`` and ``t_d >= t_split`` (Table 7: 1.05, 1.10).
    t_split : float
        Split of the normalised projection ``t_d`` (0.9 in the paper).
    ord_min1, ord_min2 : int
        Orders of the significant-ancestor rule (not reported; D-M8).
    n_min_factor : float
        ``n_min = n_min_factor * n_s(order)`` for orders in ``[ord_min1, ord_min2)``.
    precision_m : float or None
        Largest point-to-branch distance for inclusion, m; ``None``: 2.5 x the
        nominal point spacing (D-M5).
    neighbours : int
        Size of the k-nearest-neighbour graph that supplies candidate points.
    sibling_deg, parent_deg : float
        Merge angles (4 and 11.5 deg in the paper).
    direction : {"normals", "covariance", "iterative"}
        Axis estimator (see module docstring).
    axis : {"circle", "centroid"}
        Where the axis passes (see module docstring).
    inclusion : {"envelope", "max"}
        Radius of the inclusion test (see module docstring).
    radius : {"median", "mean", "max"}
        Reported radius (see module docstring).
    mode : {"strict", "faithful"}
        "strict": the spec's readings of the merge and balancing passes
        (D-M11, D-M12) with the early end of free seeding, the clean-ups and
        the output radius caps of the module docstring; "faithful": as
        printed in the paper.
    section_radii : float
        Length of the output cylinders in branch radii: each branch is cut
        into pieces refitted on their own points (an addition for taper and
        curvature; 0 gives one cylinder per branch, as the paper).
    min_branch_points : int
        Branches with fewer points are given back to their parents before
        the merge passes (an addition: the points that fail the inclusion
        test near a fork start branches that never grow; 1 disables it).
    max_balance_passes : int
        Cap on the volume-balancing passes.
    """

    free_seed: tuple = APPLE_FREE_SEED
    k_r: tuple = (1.05, 1.10)
    t_split: float = 0.9
    ord_min1: int = 2
    ord_min2: int = 4
    n_min_factor: float = 2.0
    precision_m: float | None = None
    neighbours: int = 12
    sibling_deg: float = 4.0
    parent_deg: float = 11.5
    direction: str = "normals"
    axis: str = "circle"
    inclusion: str = "envelope"
    radius: str = "median"
    mode: str = "strict"
    section_radii: float = 4.0
    min_branch_points: int = 10
    max_balance_passes: int = 50

    def __post_init__(self):
        problems = []
        seeds = list(self.free_seed)
        if not seeds or any(len(p) != 2 or p[1] < 1 for p in seeds) or \
                [p[0] for p in seeds] != sorted(p[0] for p in seeds):
            problems.append(f"free_seed={self.free_seed!r} (need increasing (order, n_s >= 1) pairs)")
        if len(self.k_r) != 2 or min(self.k_r) <= 1.0 or max(self.k_r) > 10:
            problems.append(f"k_r={self.k_r!r} (need two factors in (1, 10])")
        if not 0 < self.t_split <= 1.5:
            problems.append(f"t_split={self.t_split!r} (need (0, 1.5])")
        if not 1 <= self.ord_min1 <= self.ord_min2:
            problems.append(f"ord_min1={self.ord_min1}, ord_min2={self.ord_min2} (need 1 <= ord_min1 <= ord_min2)")
        if self.precision_m is not None and not (np.isfinite(self.precision_m) and self.precision_m > 0):
            problems.append(f"precision_m={self.precision_m!r} (need a positive length in m)")
        if not 2 <= self.neighbours <= 100:
            problems.append(f"neighbours={self.neighbours} (need 2..100)")
        if not (0 <= self.sibling_deg < 90 and 0 <= self.parent_deg < 90):
            problems.append(f"sibling_deg={self.sibling_deg}, parent_deg={self.parent_deg} (need [0, 90) deg)")
        for name, allowed in (("direction", ("normals", "covariance", "iterative")), ("axis", ("circle", "centroid")),
                              ("inclusion", ("envelope", "max")),
                              ("radius", ("median", "mean", "max")),
                              ("mode", ("strict", "faithful"))):
            if getattr(self, name) not in allowed:
                problems.append(f"{name}={getattr(self, name)!r} (allowed: {', '.join(allowed)})")
        if self.section_radii < 0:
            problems.append(f"section_radii={self.section_radii} (need >= 0)")
        if self.min_branch_points < 1:
            problems.append(f"min_branch_points={self.min_branch_points} (need >= 1)")
        if self.max_balance_passes < 0:
            problems.append(f"max_balance_passes={self.max_balance_passes} (need >= 0)")
        if problems:
            raise WoodyError("invalid cylinder-following parameter(s): " + "; ".join(problems))

    def n_s(self, order: int) -> int:
        """Free-seed count of a branch of this order."""
        for threshold, count in self.free_seed:
            if order <= threshold:
                return int(count)
        return int(self.free_seed[-1][1])


def fit_direction(points: np.ndarray, method: str = "covariance") -> np.ndarray:
    """Axis direction of a cluster of points on a cylinder (unit vector, sign arbitrary).

    Parameters
    ----------
    points : ndarray, (n, 3)
    method : {"covariance", "iterative"}
        ``"covariance"``: the eigenvector of the covariance matrix that
        minimises the largest orthogonal distance (Méndez et al., Sect. 2.3;
        spec D-M3). ``"iterative"``: coarse-to-fine search over polar angle
        and azimuth for that minimax direction (10 deg grid, refined by halves
        down to 0.1 deg).
    """
    centred = points - points.mean(axis=0)
    if method == "covariance":
        _, vectors = np.linalg.eigh(centred.T @ centred)
        candidates = vectors.T
    elif method == "iterative":
        candidates = _minimax_search(centred)[None]
    else:
        raise WoodyError(f"direction method must be 'covariance' or 'iterative', got {method!r}")
    spread = [_max_orthogonal(centred, d) for d in candidates]
    return candidates[int(np.argmin(spread))]


def _max_orthogonal(centred: np.ndarray, direction: np.ndarray) -> float:
    along = centred @ direction
    return float(np.sqrt(np.max(np.einsum("ij,ij->i", centred, centred) - along * along, initial=0.0)))


def _unit(polar: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    return np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)], axis=-1)


def _minimax_search(centred: np.ndarray) -> np.ndarray:
    """Direction minimising the largest orthogonal distance, by a refining polar/azimuth grid."""
    norms2 = np.einsum("ij,ij->i", centred, centred)
    step = np.radians(10.0)
    polar, azimuth = np.meshgrid(np.arange(0.0, np.pi / 2 + 1e-9, step), np.arange(0.0, 2 * np.pi, step))
    best = (0.0, 0.0)
    while True:
        dirs = _unit(polar.ravel(), azimuth.ravel())
        worst = (norms2[None, :] - (dirs @ centred.T) ** 2).max(axis=1)
        i = int(np.argmin(worst))
        best = (polar.ravel()[i], azimuth.ravel()[i])
        if step < np.radians(0.1):
            return dirs[i]
        grid = np.array([-1.0, -0.5, 0.0, 0.5, 1.0]) * step
        polar, azimuth = np.meshgrid(best[0] + grid, best[1] + grid)
        step /= 2.0


def fit_circle(xy: np.ndarray, iterations: int = 8) -> tuple[np.ndarray, float]:
    """Robust circle through 2-D points: algebraic (Kasa) start, then reweighted Gauss-Newton on the distances.

    The weights are Huber's with a scale of 1.5 x the median absolute
    residual, so that a few points of another branch do not drag the circle.
    Returns the centre (2,) and radius; the radius is NaN when the points
    are too few or collinear.
    """
    if len(xy) < 3:
        return np.zeros(2), float("nan")
    design = np.column_stack([xy, np.ones(len(xy))])
    (a, b, c), *_ = np.linalg.lstsq(design, np.einsum("ij,ij->i", xy, xy), rcond=None)
    centre = np.array([a, b]) / 2.0
    radius = np.sqrt(max(c + centre @ centre, 0.0))
    for _ in range(iterations):
        rel = xy - centre
        dist = np.maximum(np.linalg.norm(rel, axis=1), 1e-12)
        residual = dist - radius
        scale = max(1.5 * np.median(np.abs(residual)), 1e-9)
        weight = np.sqrt(np.minimum(1.0, scale / np.maximum(np.abs(residual), 1e-12)))
        jac = np.column_stack([-rel / dist[:, None], -np.ones(len(xy))])
        step, *_ = np.linalg.lstsq(jac * weight[:, None], -residual * weight, rcond=None)
        centre, radius = centre + step[:2], radius + step[2]
    return centre, float(radius) if np.isfinite(radius) and radius > 0 else float("nan")


class _Branch:
    """A growing cluster of points with its running sums and current cylinder.

    The cylinder is ``axis_point + t direction`` for ``t`` in ``[t0, t1]``,
    with the largest (``r_max``), summed (``d_sum``) and median (``r_median``)
    orthogonal distances of the points and the robust ``envelope`` of the
    last exact fit.
    """

    def __init__(self, bid: int, index: int, parent, order: int, cloud: tuple, params: FollowParams):
        self.id, self.parent, self.order, self.params = bid, parent, order, params
        self.coords, self.normals = cloud
        xyz = self.coords[index]
        self.children: list[_Branch] = []
        self.points = [index]
        self.base = xyz.copy()
        self.n, self.sum, self.outer = 1, xyz.copy(), np.outer(xyz, xyz)
        self.normal_outer = np.zeros((3, 3)) if self.normals is None else np.outer(self.normals[index], self.normals[index])
        self.axis_point, self.direction, self.fitted = xyz.copy(), None, False
        self.t0 = self.t1 = 0.0
        self.r_max = self.d_sum = self.r_median = self.envelope = 0.0
        self.exact_n = 0
        self.heap: list = []
        self.active = True

    def p1(self) -> np.ndarray:
        return self.axis_point if self.direction is None else self.axis_point + self.t0 * self.direction

    def p2(self) -> np.ndarray:
        return self.axis_point if self.direction is None else self.axis_point + self.t1 * self.direction

    @property
    def r_mean(self) -> float:
        """Mean orthogonal distance of the points to the axis, m."""
        return self.d_sum / self.n

    def reference_radius(self) -> float:
        """Radius of the inclusion test: the largest distance, or the robust envelope of the last exact fit."""
        return self.r_max if self.params.inclusion == "max" else self.envelope

    def distance(self, xyz: np.ndarray) -> np.ndarray:
        """``max(0, d(P, P1P2) - r)`` for points (m, 3), with ``r`` the largest distance."""
        dist, _ = segment_distance(xyz, self.p1(), self.p2())
        return np.maximum(dist - self.r_max, 0.0)

    def orient(self, direction: np.ndarray) -> np.ndarray:
        """``direction`` with the sign that points away from the branch base (upwards for a vertical trunk)."""
        lean = direction @ (self.sum / self.n - self.base)
        if abs(lean) < 1e-12:
            lean = direction[2]
        return direction if lean >= 0 else -direction

    def shape_direction(self, n: int, total: np.ndarray, outer: np.ndarray, normal_outer: np.ndarray):
        """Axis with ``direction="normals"``, or None; also returns the covariance eigenvectors.

        In order of trust: the direction least aligned with the normals when
        they clearly lie in one plane (a curved patch, ring or tube of a wide
        stem); the long axis of an elongated cluster (largest covariance
        eigenvalue at least 4x the next: a thin twig whose normals are
        noise); the normals' direction when merely decisive.
        """
        centroid = total / n
        values, vectors = np.linalg.eigh(outer / n - np.outer(centroid, centroid))
        strong = _normal_axis(normal_outer, max_flatness=0.1)
        if strong is not None:
            return strong, vectors
        if values[2] >= 4.0 * values[1]:
            return vectors[:, 2], vectors
        return _normal_axis(normal_outer), vectors

    def tracked_direction(self, n: int, total: np.ndarray, outer: np.ndarray, normal_outer: np.ndarray) -> np.ndarray | None:
        """Axis from running sums (None below 3 points): :meth:`shape_direction` in "normals" mode, else
        the covariance eigenvector closest to the current axis."""
        if n < 3:
            return None
        centroid = total / n
        if self.normals is not None:
            axis, vectors = self.shape_direction(n, total, outer, normal_outer)
            if axis is not None:
                return axis
        else:
            vectors = np.linalg.eigh(outer / n - np.outer(centroid, centroid))[1]
        if self.direction is None:
            return vectors[:, -1]
        return vectors[:, int(np.argmax(np.abs(self.direction @ vectors)))]

    def curved(self, min_ratio: float = 0.02) -> bool:
        """Whether the points curve around the axis, so that a circle fitted across it is meaningful.

        The covariance of the points across the axis has two eigenvalues; a
        flat patch has a near-zero small one, an arc of 70 deg or more of a
        circle has at least 2 % of the large one.
        """
        if self.direction is None:
            return False
        centroid = self.sum / self.n
        across = np.eye(3) - np.outer(self.direction, self.direction)
        values = np.linalg.eigvalsh(across @ (self.outer / self.n - np.outer(centroid, centroid)) @ across)
        return values[1] >= min_ratio * values[2]

    def seeded(self) -> bool:
        """Whether free seeding is over: ``n_s`` points or (strict mode) 6 points or more on an axis at least
        two diameters long."""
        if self.n >= self.params.n_s(self.order):
            return True
        return (self.params.mode == "strict" and self.n >= 6 and self.direction is not None
                and self.t1 - self.t0 >= 4.0 * self.reference_radius())

    def add(self, index: int) -> None:
        """Include a point and update the cylinder (exactly when the branch has grown by 10 %)."""
        xyz = self.coords[index]
        self.points.append(index)
        self.n += 1
        self.sum += xyz
        self.outer += np.outer(xyz, xyz)
        if self.normals is not None:
            self.normal_outer += np.outer(self.normals[index], self.normals[index])
        if self.n >= 1.1 * self.exact_n or self.n < 32:
            self.refit()
            return
        self.direction = self.orient(self.tracked_direction(self.n, self.sum, self.outer, self.normal_outer))
        if not self.fitted:
            self.axis_point = self.sum / self.n
        rel = xyz - self.axis_point
        t = rel @ self.direction
        orth = np.sqrt(max(rel @ rel - t * t, 0.0))
        self.t0, self.t1 = min(self.t0, t), max(self.t1, t)
        self.r_max = max(self.r_max, orth)
        self.d_sum += orth

    def refit(self, direction: np.ndarray | None = None) -> None:
        """Exact cylinder of the current points (O(n)); ``direction`` imposes the axis direction."""
        pts = self.coords[self.points]
        self.n = len(pts)
        self.sum = pts.sum(axis=0)
        self.outer = pts.T @ pts
        if self.normals is not None:
            normals = self.normals[self.points]
            self.normal_outer = normals.T @ normals
        self.exact_n = self.n
        self.axis_point, self.fitted = self.sum / self.n, False
        if self.n < 2:
            self.direction, self.t0, self.t1 = None, 0.0, 0.0
            self.r_max = self.d_sum = self.r_median = self.envelope = 0.0
            return
        if direction is not None:
            pass
        elif self.n == 2:
            direction = pts[1] - pts[0]
            direction = direction / max(np.linalg.norm(direction), 1e-12)
        else:
            if self.normals is not None:
                direction, _ = self.shape_direction(self.n, self.sum, self.outer, self.normal_outer)
            if direction is None:
                method = "covariance" if self.params.direction == "normals" else self.params.direction
                direction = fit_direction(pts, method)
        self.direction = self.orient(direction)
        if self.params.axis == "circle" and self.n >= 8 and self.curved():
            self._fit_axis_point(pts)
        rel = pts - self.axis_point
        t = rel @ self.direction
        orth = np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - t * t, 0.0))
        self.t0, self.t1 = float(t.min()), float(t.max())
        self.r_max, self.d_sum = float(orth.max()), float(orth.sum())
        self.r_median = float(np.median(orth))
        self.envelope = self.r_median + 3.0 * 1.4826 * float(np.median(np.abs(orth - self.r_median)))

    def _fit_axis_point(self, pts: np.ndarray) -> None:
        """Move the axis onto the centre of the circle fitted to the points seen along the axis."""
        u, v, _ = orthonormal_frame(self.direction)
        rel = pts - self.axis_point
        xy = np.column_stack([rel @ u, rel @ v])
        centre, radius = fit_circle(xy)
        extent = np.linalg.norm(xy, axis=1).max()
        if np.isfinite(radius) and radius < 1.5 * extent:
            self.axis_point = self.axis_point + centre[0] * u + centre[1] * v
            self.fitted = True

    def spread(self) -> float:
        """95th percentile of the points' orthogonal distances to the current axis, m."""
        if self.direction is None:
            return 0.0
        rel = self.coords[self.points] - self.axis_point
        t = rel @ self.direction
        return float(np.percentile(np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - t * t, 0.0)), 95))

    def tentative_distance(self, index: int) -> tuple[float, float]:
        """Orthogonal distance of point ``index`` to the axis refitted with it, and its normalised projection ``t_d``."""
        xyz = self.coords[index]
        span = self.t1 - self.t0
        t_d = 0.0 if self.direction is None or span <= 0 else float((xyz - self.p1()) @ self.direction / span)
        normal_outer = self.normal_outer
        if self.normals is not None:
            normal_outer = normal_outer + np.outer(self.normals[index], self.normals[index])
        direction = self.tracked_direction(self.n + 1, self.sum + xyz, self.outer + np.outer(xyz, xyz), normal_outer)
        if direction is None:
            return 0.0, t_d
        rel = xyz - (self.axis_point if self.fitted else (self.sum + xyz) / (self.n + 1))
        t = rel @ direction
        return float(np.sqrt(max(rel @ rel - t * t, 0.0))), t_d


def _normal_axis(normal_outer: np.ndarray, min_ratio: float = 0.02, max_flatness: float = 0.5) -> np.ndarray | None:
    """The direction least aligned with a set of normals (summed ``n n^T``), or None when not decisive.

    Normals of a cylinder are perpendicular to its axis, so the axis is the
    eigenvector of the smallest eigenvalue. It is decisive when the normals
    spread across the axis (the middle eigenvalue is at least ``min_ratio``
    of the largest; a flat patch fails) and the smallest is at most
    ``max_flatness`` of the middle one.
    """
    values, vectors = np.linalg.eigh(normal_outer)
    if values[1] < min_ratio * values[2] or values[0] > max_flatness * values[1]:
        return None
    return vectors[:, 0]


@dataclass
class FollowResult:
    """Output of :func:`follow_cylinders`.

    Attributes
    ----------
    branches : list of dict
        One per branch: ``id``, ``parent`` (-1 for the trunk), ``order``
        (trunk = 1), ``children``, ``start``/``end`` (P1, P2, m),
        ``direction``, ``radius_m`` (reported), ``radius_max_m``,
        ``n_points``.
    labels : ndarray, (n,)
        Branch id of every point (-1: never reached).
    stats : dict
        Counts, timings (s) and the settings used.
    """

    branches: list[dict]
    labels: np.ndarray
    stats: dict = field(default_factory=dict)

    def cylinders(self) -> list[dict]:
        """The reconstruction as a cylinder list (docs/contracts.md format).

        One cylinder per branch section (one per branch with
        ``section_radii=0``, as in the paper); a branch's first section is
        parented to the nearest section of its parent branch.
        """
        out, first, rows = [], {}, {}
        for b in self.branches:
            rows[b["id"]] = []
            for k, (start, end, radius) in enumerate(b["sections"]):
                cid = len(out)
                out.append({"id": cid, "parent": cid - 1 if k else -1, "order": b["order"], "branch": b["id"],
                            "start": list(start), "end": list(end), "radius_m": radius, "radius_end_m": radius})
                rows[b["id"]].append(cid)
            first[b["id"]] = rows[b["id"]][0]
        for b in self.branches:
            if b["parent"] >= 0:
                candidates = rows[b["parent"]]
                starts = np.array([out[c]["start"] for c in candidates])
                ends = np.array([out[c]["end"] for c in candidates])
                dist, _ = segment_distance(np.repeat(np.asarray(b["start"])[None], len(candidates), 0), starts, ends)
                out[first[b["id"]]]["parent"] = candidates[int(np.argmin(dist))]
        return out

    @property
    def volume(self) -> float:
        """Total woody volume (sum of the cylinders' ``h pi r^2``), m^3."""
        return cylinders_volume(self.cylinders())

    def skeleton(self) -> tuple[np.ndarray, np.ndarray]:
        """Skeleton graph: nodes (m, 3) and edges (e, 2).

        Each branch gives its axis P1 -> P2; each child is linked from its P1
        to the closest point of its parent's axis.
        """
        nodes, edges, ends = [], [], {}
        for b in self.branches:
            ends[b["id"]] = (np.asarray(b["start"]), np.asarray(b["end"]))
            nodes += [b["start"], b["end"]]
            edges.append((len(nodes) - 2, len(nodes) - 1))
        for b in self.branches:
            if b["parent"] >= 0:
                p1, p2 = ends[b["parent"]]
                _, t = segment_distance(np.asarray(b["start"])[None], p1, p2)
                nodes.append((p1 + t[0] * (p2 - p1)).tolist())
                child_start = [i for i, c in enumerate(self.branches) if c["id"] == b["id"]][0] * 2
                edges.append((len(nodes) - 1, child_start))
        return np.array(nodes, float).reshape(-1, 3), np.array(edges, np.int64).reshape(-1, 2)

    def mesh(self, sections: int = 16):
        """One closed cylinder mesh per branch (trimesh.Trimesh)."""
        return cylinders_mesh(self.cylinders(), sections)


def follow_cylinders(points, params: FollowParams | None = None, *, progress: bool = False, **overrides) -> FollowResult:
    """Reconstruct a leafless tree as a hierarchy of cylinders (Méndez et al.).

    Parameters
    ----------
    points : array_like, (n, 3)
        One cleaned tree (no ground, no leaves), m. The trunk is grown from
        the lowest point.
    params : FollowParams, optional
        Settings (default: the paper's apple-tree values and the spec's
        recommendations).
    progress : bool
        Show a progress bar over the included points.
    **overrides
        Fields of :class:`FollowParams` to override, e.g. ``k_r=(1.05, 1.05)``.

    Returns
    -------
    FollowResult

    Raises
    ------
    WoodyError
        On an invalid cloud or parameter.

    Examples
    --------
    >>> from woody.synthetic import sample_cylinders, straight_cylinder
    >>> cloud = sample_cylinders(straight_cylinder(0.05, 1.0), 2e4, seed=1)
    >>> result = follow_cylinders(cloud.points)
    >>> len(result.branches), round(result.branches[0]["radius_m"], 2)
    (1, 0.05)
    """
    points = check_points(points)
    try:
        params = FollowParams(**{**(params.__dict__ if params else {}), **overrides})
    except TypeError as exc:
        raise WoodyError(f"unknown cylinder-following parameter: {exc}") from None
    if len(points) < 3:
        raise WoodyError(f"cylinder following needs at least 3 points, got {len(points)}")
    timings = {}
    clock = time.perf_counter()
    tree = cKDTree(points)
    k = min(params.neighbours + 1, len(points))
    # Nominal spacing from the 6th-neighbour distance: on a surface with density lambda it is about
    # sqrt(6 / (pi lambda)) for random and for grid-like sampling alike, so spacing = d6 sqrt(pi / 6).
    sixth = min(6, len(points) - 1)
    spacing_d, _ = tree.query(points, k=sixth + 1)
    spacing = float(np.median(spacing_d[:, sixth]) * np.sqrt(np.pi / sixth))
    precision = params.precision_m if params.precision_m is not None else 2.5 * spacing
    if precision <= 0:
        raise WoodyError("the cloud has duplicate points only; cannot derive a point spacing")
    dist, graph = tree.query(points, k=k, distance_upper_bound=2.0 * precision)
    graph = np.where(np.isfinite(dist), graph, -1).astype(np.int32)[:, 1:]
    del dist
    timings["graph_s"] = time.perf_counter() - clock

    clock = time.perf_counter()
    normals = pca_normals(points, min(10, len(points))) if params.direction == "normals" else None
    branches, owner = _grow((points, normals), graph, params, precision, progress)
    timings["growth_s"] = time.perf_counter() - clock
    grown = len(branches)
    clock = time.perf_counter()
    branches = _dissolve_small(branches, params)
    branches = _merge_siblings(branches, params)
    branches = _merge_into_parents(branches, params)
    if params.mode == "strict":
        branches = _merge_contained(branches)
    passes = _balance_volume(branches, points, params)
    timings["merge_s"] = time.perf_counter() - clock

    records, labels = _records(branches, params, len(points))
    stats = {"points": len(points), "spacing_m": spacing, "precision_m": precision, "branches_grown": grown,
             "branches": len(records), "unassigned": int((labels < 0).sum()), "balance_passes": passes,
             "max_order": max(b["order"] for b in records), **timings}
    return FollowResult(records, labels, stats)


def _grow(cloud: tuple, graph: np.ndarray, params: FollowParams, precision: float,
          progress: bool) -> tuple[list[_Branch], np.ndarray]:
    """The round-robin growth loop (Table 1), with the closest-point search of Table 2.

    ``cloud`` is ``(points, normals or None)``.
    """
    from tqdm import tqdm

    points = cloud[0]
    owner = np.full(len(points), -1, np.int64)
    branches: list[_Branch] = []

    def new_branch(index: int, parent, order: int) -> _Branch:
        branch = _Branch(len(branches), index, parent, order, cloud, params)
        branches.append(branch)
        if parent is not None:
            parent.children.append(branch)
        owner[index] = branch.id
        push_neighbours(branch, index)
        return branch

    def push_neighbours(branch: _Branch, index: int) -> None:
        near = graph[index]
        near = near[near >= 0]
        near = near[owner[near] < 0]
        if len(near):
            for key, j in zip(branch.distance(points[near]).tolist(), near.tolist()):
                heapq.heappush(branch.heap, (key, j))

    def closer_elsewhere(branch: _Branch, index: int, d: float) -> bool:
        near = graph[index]
        others = {int(o) for o in owner[near[near >= 0]] if o >= 0 and o != branch.id}
        # Ties (e.g. a point inside two overlapping cylinders, distance 0) go to the older branch.
        return any(branches[o].distance(points[index][None])[0] < d + (1e-12 if o < branch.id else 0.0)
                   for o in others)

    def closest_point(branch: _Branch) -> int:
        """Index of the branch's closest admissible unassigned point, or -1."""
        heap = branch.heap
        while heap:
            key, j = heapq.heappop(heap)
            if owner[j] >= 0:
                continue
            d = float(branch.distance(points[j][None])[0])
            if heap and d > heap[0][0] + 1e-12:
                heapq.heappush(heap, (d, j))  # stale key: re-queue with the current distance
                continue
            if d >= precision:
                heapq.heappush(heap, (d, j))
                return -1
            if closer_elsewhere(branch, j, d):
                continue
            return j
        return -1

    def significant(branch):
        """The significant ancestor (Table 2, bottom), starting at ``branch``."""
        while branch is not None and not _is_significant(branch.order, branch.n, params):
            branch = branch.parent
        return branch

    # Root: the lowest point with three neighbours within Precision. The paper starts from the lowest
    # point; a lone stray return below the tree (a mixed pulse, a grazing edge) would then grow nothing.
    supported = (graph[:, min(2, graph.shape[1] - 1)] >= 0) & \
        (np.linalg.norm(points[np.maximum(graph[:, min(2, graph.shape[1] - 1)], 0)] - points, axis=1) < precision)
    candidates = np.flatnonzero(supported) if supported.any() else np.arange(len(points))
    root = int(candidates[np.argmin(points[candidates, 2])])
    new_branch(root, None, 1)
    bar = tqdm(total=len(points), desc="cylinder following", disable=not progress, leave=False)
    bar.update(1)
    active = [branches[0]]
    while active:
        born = len(branches)
        for branch in active:
            j = closest_point(branch)
            if j < 0:
                branch.active = False
                continue
            bar.update(1)
            owner[j] = branch.id
            if not branch.seeded():
                branch.add(j)
                push_neighbours(branch, j)
                continue
            distance, t_d = branch.tentative_distance(j)
            factor = params.k_r[0] if t_d < params.t_split else params.k_r[1]
            anchor = significant(branch.parent)
            if distance > factor * branch.reference_radius() or \
                    (anchor is not None and distance > anchor.reference_radius()):
                owner[j] = -1
                new_branch(j, branch, branch.order + 1)
            else:
                branch.add(j)
                push_neighbours(branch, j)
        active = [b for b in active if b.active] + branches[born:]
    bar.close()
    for branch in branches:
        branch.heap = []
        branch.refit()
    return branches, owner


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))


def _absorb(target: _Branch, source: _Branch, refit: bool = True) -> None:
    """Move all of ``source``'s points and children into ``target``; ``source`` is emptied.

    ``refit=False`` leaves ``target``'s cylinder stale (the caller refits it once after several moves).
    """
    target.points += source.points
    source.points = []
    for child in source.children:
        child.parent = target
        target.children.append(child)
    source.children = []
    if source.parent is not None:
        source.parent.children = [c for c in source.parent.children if c is not source]
    if refit:
        target.refit()


def _live(branches: list[_Branch]) -> list[_Branch]:
    return [b for b in branches if b.points]


def _one_cylinder(a: _Branch, b: _Branch, params: FollowParams) -> bool:
    """Whether two branches' points fit one cylinder (strict mode; always True in faithful mode).

    The 95th percentile of the union's orthogonal distances must stay within
    the larger ``k_r`` of the wider branch's: merging two parallel but
    separate twigs would otherwise make one fat cylinder around both. (A
    percentile, not the robust envelope: a thin twig is a minority of the
    union's points and would pass a median-based test.)
    """
    if params.mode == "faithful":
        return True
    union = copy.copy(a)
    union.points = a.points + b.points
    union.refit()
    return union.spread() <= max(params.k_r) * max(a.spread(), b.spread())


def _dissolve_small(branches: list[_Branch], params: FollowParams) -> list[_Branch]:
    """Give the points of branches smaller than ``min_branch_points`` back to their parents (deepest first).

    A root that small (the trunk stalled at the lowest points while a child
    took over the stem) is handed to its largest child, which becomes the root.
    """
    grown = set()
    for branch in reversed(branches):
        if branch.parent is not None and 0 < len(branch.points) < params.min_branch_points:
            grown.add(branch.parent.id)
            _absorb(branch.parent, branch, refit=False)
    for branch in branches:
        if branch.id in grown and branch.points:
            branch.refit()
    for root in [b for b in branches if b.parent is None and 0 < len(b.points) < params.min_branch_points]:
        if root.children:
            heir = max(root.children, key=lambda c: len(c.points))
            heir.parent = None
            root.children.remove(heir)
            _absorb(heir, root)
    return _live(branches)


def _merge_siblings(branches: list[_Branch], params: FollowParams) -> list[_Branch]:
    """AlignedChildrenBranches (Table 3): merge children whose angles to the parent differ by < sibling_deg."""
    for branch in branches:
        if len(branch.children) < 2 or branch.direction is None:
            continue
        changed = True
        while changed:
            changed = False
            kids = [c for c in branch.children if c.direction is not None]
            angles = [_angle_deg(branch.direction, c.direction) for c in kids]
            pairs = ((a, b) for a in range(len(kids)) for b in range(a + 1, len(kids)))
            for a, b in pairs:
                if abs(angles[a] - angles[b]) >= params.sibling_deg:
                    continue
                if params.mode == "strict" and (
                        _angle_deg(kids[a].direction, kids[b].direction) >= params.sibling_deg
                        or not _one_cylinder(kids[a], kids[b], params)):
                    continue
                _absorb(kids[a], kids[b])
                changed = True
                break
    return _live(branches)


def _merge_into_parents(branches: list[_Branch], params: FollowParams) -> list[_Branch]:
    """ConnectAlignedBranches (Table 4), repeated while anything merges."""
    changed = True
    while changed:
        changed = False
        for branch in branches:
            parent = branch.parent
            if not branch.points or parent is None or branch.direction is None or parent.direction is None:
                continue
            if _angle_deg(branch.direction, parent.direction) < params.parent_deg and \
                    _one_cylinder(parent, branch, params):
                _absorb(parent, branch)
                changed = True
        branches = _live(branches)
    return branches


def _merge_contained(branches: list[_Branch]) -> list[_Branch]:
    """Merge each branch whose axis midpoint lies inside an older branch's cylinder into that branch.

    A real child leaves its parent, so its axis midpoint is outside every
    other cylinder; one inside is a duplicate grown alongside an older
    branch (they share the points of one stem) or a stub at a junction.
    """
    for branch in branches:
        if not branch.points or branch.parent is None or branch.direction is None:
            continue
        middle = 0.5 * (branch.p1() + branch.p2())
        for older in branches:
            if older is branch:
                break
            if older.points and older.direction is not None and \
                    older.distance(middle[None])[0] == 0.0 and \
                    segment_distance(middle[None], older.p1(), older.p2())[0][0] < older.r_median:
                _absorb(older, branch)
                break
    return _live(branches)


def _balance_volume(branches: list[_Branch], points: np.ndarray, params: FollowParams) -> int:
    """Clustering (Table 5): move points between parent and child while the total volume drops.

    Within a pass the axes are fixed; the only points whose removal can
    shrink a cylinder are its widest point and its two extreme projections,
    so each step tries those three on both sides of every parent-child pair.
    Passes stop when one moves nothing, or lowers the total volume by less
    than 0.1 % (the refits after a pass turn the axes, so that later moves
    can undo earlier ones: the loop would otherwise run to the cap).
    Returns the number of passes run.
    """
    def total_volume() -> float:
        return sum(np.pi * b.r_max ** 2 * (b.t1 - b.t0) for b in branches if b.direction is not None)

    volume = total_volume()
    for passes in range(1, params.max_balance_passes + 1):
        moved = False
        for child in branches:
            parent = child.parent
            if parent is None or child.direction is None or parent.direction is None:
                continue
            pair_moved = False
            for source, target in ((child, parent), (parent, child)):
                pair_moved |= _balance_pair(source, target, child, parent, points, params)
            if pair_moved:
                child.refit()
                parent.refit()
                moved = True
        before, volume = volume, total_volume()
        if not moved or volume > (1.0 - 1e-3) * before:
            return passes
    return params.max_balance_passes


def _cylinder_stats(xyz: np.ndarray, centroid: np.ndarray, direction: np.ndarray):
    rel = xyz - centroid
    t = rel @ direction
    orth = np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - t * t, 0.0))
    return t, orth


def _balance_pair(source: _Branch, target: _Branch, child: _Branch, parent: _Branch, points: np.ndarray,
                  params: FollowParams) -> bool:
    """Greedy moves from ``source`` to ``target`` (fixed axes) while they lower the summed volume."""
    moved = False
    src = np.array(source.points)
    t_s, r_s = _cylinder_stats(points[src], source.axis_point, source.direction)
    tgt_t, tgt_r = _cylinder_stats(points[np.array(target.points)], target.axis_point, target.direction)
    t_lo, t_hi, r_tgt = tgt_t.min(), tgt_t.max(), tgt_r.max()
    keep = np.ones(len(src), bool)
    while keep.sum() > params.min_branch_points:
        rows = np.flatnonzero(keep)
        volume_src = np.pi * r_s[rows].max() ** 2 * (t_s[rows].max() - t_s[rows].min())
        volume_tgt = np.pi * r_tgt ** 2 * (t_hi - t_lo)
        best = None
        for row in {rows[np.argmax(r_s[rows])], rows[np.argmin(t_s[rows])], rows[np.argmax(t_s[rows])]}:
            rest = rows[rows != row]
            r_src_new = r_s[rest].max()
            v_src_new = np.pi * r_src_new ** 2 * (t_s[rest].max() - t_s[rest].min())
            (t_k,), (r_k,) = _cylinder_stats(points[src[row]][None], target.axis_point, target.direction)
            r_tgt_new = max(r_tgt, r_k)
            v_tgt_new = np.pi * r_tgt_new ** 2 * (max(t_hi, t_k) - min(t_lo, t_k))
            change = (v_src_new - volume_src) + (v_tgt_new - volume_tgt)
            if params.mode == "strict":
                r_child, r_parent = (r_src_new, r_tgt_new) if source is child else (r_tgt_new, r_src_new)
                allowed = r_child < r_parent
            else:
                allowed = r_src_new < r_tgt_new
            if change < 0 and allowed and (best is None or change < best[0]):
                best = (change, row, t_k, r_tgt_new)
        if best is None:
            break
        _, row, t_k, r_tgt = best
        t_lo, t_hi = min(t_lo, t_k), max(t_hi, t_k)
        keep[row] = False
        moved = True
    if moved:
        moving = set(src[~keep].tolist())
        source.points = [p for p in source.points if p not in moving]
        target.points += sorted(moving)
    return moved


def _records(branches: list[_Branch], params: FollowParams, count: int) -> tuple[list[dict], np.ndarray]:
    """Branch records with ids renumbered in breadth-first order from the trunk and orders recomputed (D-M14)."""
    roots = [b for b in branches if b.parent is None]
    order_of, queue = {}, [(r, 1) for r in roots]
    ranked = []
    while queue:
        branch, order = queue.pop(0)
        order_of[id(branch)] = order
        ranked.append(branch)
        queue += [(c, order + 1) for c in branch.children if c.points]
    new_id = {id(b): i for i, b in enumerate(ranked)}
    labels = np.full(count, -1, np.int64)
    records = []
    for b in ranked:
        labels[b.points] = new_id[id(b)]
        records.append({"id": new_id[id(b)], "parent": -1 if b.parent is None else new_id[id(b.parent)],
                        "order": order_of[id(b)], "children": [new_id[id(c)] for c in b.children if c.points],
                        "start": b.p1().tolist(), "end": b.p2().tolist(),
                        "direction": None if b.direction is None else b.direction.tolist(),
                        "radius_m": _radius(b, params), "radius_max_m": float(b.r_max), "n_points": len(b.points),
                        "sections": _sections(b, params)})
        anchor = _significant_record(records, records[-1]["parent"], params)
        if params.mode == "strict" and anchor is not None:
            _cap_radii(records[-1], anchor)
    return records, labels


def _is_significant(order: int, count: int, params: FollowParams) -> bool:
    """Méndez's significance: order below ``ord_min1``, or below ``ord_min2`` with more than ``n_min`` points."""
    return order < params.ord_min1 or (order < params.ord_min2 and count > params.n_min_factor * params.n_s(order))


def _significant_record(records: list[dict], row: int, params: FollowParams) -> dict | None:
    """The significant ancestor among final branch records, starting at ``row``."""
    while row >= 0 and not _is_significant(records[row]["order"], records[row]["n_points"], params):
        row = records[row]["parent"]
    return records[row] if row >= 0 else None


def _cap_radii(record: dict, parent: dict) -> None:
    """The paper's radius hierarchy applied to the output: no section of a branch is wider than the section of
    its significant ancestor nearest to its start (a cluster of several thin twigs fitted as one fat
    cylinder is the usual cause)."""
    starts = np.array([s[0] for s in parent["sections"]])
    ends = np.array([s[1] for s in parent["sections"]])
    dist, _ = segment_distance(np.repeat(np.asarray(record["start"])[None], len(starts), 0), starts, ends)
    limit = parent["sections"][int(np.argmin(dist))][2]
    record["sections"] = [(a, b, min(r, limit)) for a, b, r in record["sections"]]
    record["radius_m"] = min(record["radius_m"], limit)


def _radius(branch: _Branch, params: FollowParams) -> float:
    return float({"max": branch.r_max, "mean": branch.r_mean, "median": branch.r_median}[params.radius])


def _sections(branch: _Branch, params: FollowParams) -> list[tuple]:
    """Cylinders ``(start, end, radius)`` of a branch: the whole branch, or pieces of ``section_radii`` radii.

    Each piece is refitted on its own points (direction, axis, radius) so
    that the cylinders follow taper and curvature; a piece whose own axis is
    more than 30 deg off the branch's is refitted along the branch's axis,
    and one with fewer than 8 points keeps the branch's axis and radius. In
    strict mode no piece is wider than ``max(k_r)`` times the piece before
    it (the paper's radius hierarchy along the branch; a fork region fitted
    as one piece is the usual cause).
    """
    whole = [(branch.p1().tolist(), branch.p2().tolist(), _radius(branch, params))]
    if params.section_radii <= 0 or branch.direction is None:
        return whole
    piece = params.section_radii * max(branch.r_median, 1e-9)
    count = int((branch.t1 - branch.t0) // piece)
    if count < 2:
        return whole
    indices = np.asarray(branch.points)
    t = (branch.coords[indices] - branch.axis_point) @ branch.direction
    edges = np.linspace(branch.t0, branch.t1, count + 1)
    out = []
    for k, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        members = indices[(t >= lo) & ((t < hi) if k < count - 1 else (t <= hi))]
        part = copy.copy(branch)
        part.points = members.tolist()
        if len(members) >= 8:
            part.refit()
            if part.direction is not None and _angle_deg(part.direction, branch.direction) > 30.0:
                part.refit(branch.direction)  # a piece bends little: an axis far off the branch's is a misfit
        if len(members) < 8 or part.direction is None:
            out.append(((branch.axis_point + lo * branch.direction).tolist(),
                        (branch.axis_point + hi * branch.direction).tolist(), _radius(branch, params)))
        else:
            out.append((part.p1().tolist(), part.p2().tolist(), _radius(part, params)))
    if params.mode == "strict":  # radii do not grow away from the root (beyond the k_r tolerance)
        for k in range(1, len(out)):
            out[k] = (out[k][0], out[k][1], min(out[k][2], max(params.k_r) * out[k - 1][2]))
    return out

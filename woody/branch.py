"""A branch of cylinder following (:mod:`woody.cylinders`): a growing cluster of points and its cylinder.

The running sums that make a refit O(1), the axis estimators chosen by
:class:`woody.cylinders.FollowParams`, the inclusion test's reference radius,
the end of free seeding and Méndez's significance of a branch. Lengths in m.
"""

from __future__ import annotations

import numpy as np

from woody.cylfit import fit_circle, fit_direction, median, normal_axis
from woody.geometry import axis_distance, orthonormal_frame, segment_axis


#: The circle that places a branch's axis is also fitted to the points within this factor times their median
#: distance from their centroid across the axis (points on a half circle of radius ``r`` lie at most about 1.5
#: times their median distance from it; a point of a side twig or a stray return lies farther) ...
CIRCLE_TRIM = 2.5
#: ... and that circle is taken when the circle of all the points is accepted but over this factor wider: a few
#: side-twig points drew circles 3-10 cm wide, whose centres lay 3-10 cm off the 1-2.5 cm leaders of a simulated
#: leafy pear (tree seed 1, simulation seed 3; the leaders' radii then fell to 0.25x). Only then: taking the
#: trimmed circle always, or wherever the full one was refused, cut the volume of the real Tree_1 of ``tlsbench
#: experiment woody-real`` from -10.6 to -58.7 / -43.4 % (its sparse sides). Assumption, chosen on those two.
CIRCLE_WIDE = 2.0


class Branch:
    """A growing cluster of points with its running sums and current cylinder.

    The cylinder is ``axis_point + t direction`` for ``t`` in ``[t0, t1]``,
    with the largest (``r_max``), summed (``d_sum``) and median (``r_median``)
    orthogonal distances of the points and the robust ``envelope`` of the
    last exact fit. Lengths in m.

    Parameters
    ----------
    bid : int
        Branch id (its index in the growth's branch list).
    index : int
        Index of the branch's first point in the cloud.
    parent : Branch or None
        The branch it grew from (None for the trunk).
    order : int
        Branch order (trunk = 1).
    cloud : tuple
        ``(points (n, 3) in m, unit normals (n, 3) or None)``.
    params : woody.cylinders.FollowParams
        Settings of :func:`woody.cylinders.follow_cylinders`.
    """

    def __init__(self, bid: int, index: int, parent, order: int, cloud: tuple, params):
        self.id, self.parent, self.order, self.params = bid, parent, order, params
        self.coords, self.normals = cloud
        xyz = self.coords[index]
        self.children: list[Branch] = []
        self.points = [index]
        self.base = xyz.copy()
        self.n, self.sum, self.outer = 1, xyz.copy(), xyz[:, None] * xyz
        normal = None if self.normals is None else self.normals[index]
        self.normal_outer = np.zeros((3, 3)) if normal is None else normal[:, None] * normal
        self.axis_point, self.direction, self.fitted = xyz.copy(), None, False
        self.t0 = self.t1 = 0.0
        self.r_max = self.d_sum = self.r_median = self.envelope = 0.0
        self.exact_n = 0
        self.segment = None  # segment_axis(p1, p2), kept until the axis or its ends move
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
        if self.segment is None:
            self.segment = segment_axis(self.p1(), self.p2())
        dist, _ = axis_distance(xyz, *self.segment)
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

        Parameters
        ----------
        n : int
            Number of points.
        total : ndarray, (3,)
            Sum of the points, m.
        outer : ndarray, (3, 3)
            Sum of the points' outer products, m^2.
        normal_outer : ndarray, (3, 3)
            Sum of the unit normals' outer products.

        Returns
        -------
        axis : ndarray, (3,) or None
            Unit axis direction, or None when neither test is decisive.
        vectors : ndarray, (3, 3) or None
            Eigenvectors of the points' covariance (columns, ascending eigenvalues); None when the normals
            decided the axis (the covariance is then not needed).
        """
        normal_eig = np.linalg.eigh(normal_outer)
        strong = normal_axis(normal_outer, max_flatness=0.1, eig=normal_eig)
        if strong is not None:
            return strong, None
        centroid = total / n
        values, vectors = np.linalg.eigh(outer / n - np.outer(centroid, centroid))
        if values[2] >= 4.0 * values[1]:
            return vectors[:, 2], vectors
        return normal_axis(normal_outer, eig=normal_eig), vectors

    def tracked_direction(self, n: int, total: np.ndarray, outer: np.ndarray, normal_outer: np.ndarray) -> np.ndarray | None:
        """Axis from running sums (None below 3 points): :meth:`shape_direction` in "normals" mode, else
        the covariance eigenvector closest to the current axis.

        Parameters
        ----------
        n : int
            Number of points.
        total : ndarray, (3,)
            Sum of the points, m.
        outer : ndarray, (3, 3)
            Sum of the points' outer products, m^2.
        normal_outer : ndarray, (3, 3)
            Sum of the unit normals' outer products (used in "normals" mode).

        Returns
        -------
        ndarray, (3,) or None
            Unit axis direction.
        """
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
        self.outer += xyz[:, None] * xyz
        if self.normals is not None:
            self.normal_outer += self.normals[index][:, None] * self.normals[index]
        if self.n >= 1.1 * self.exact_n or self.n < 32:
            self.refit()
            return
        self.direction = self.orient(self.tracked_direction(self.n, self.sum, self.outer, self.normal_outer))
        self.segment = None
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
        self.segment = None
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
        self.r_median = median(orth)
        self.envelope = self.r_median + 3.0 * 1.4826 * median(np.abs(orth - self.r_median))

    def _fit_axis_point(self, pts: np.ndarray) -> None:
        """Move the axis onto the centre of the circle fitted to the points seen along the axis (in strict mode that
        of the points within :data:`CIRCLE_TRIM` median distances of the centroid where it is :data:`CIRCLE_WIDE`
        times narrower; the paper's faithful mode fits all the points)."""
        u, v, _ = orthonormal_frame(self.direction)
        rel = pts - self.axis_point
        xy = np.column_stack([rel @ u, rel @ v])
        distance = np.linalg.norm(xy, axis=1)
        near = distance <= CIRCLE_TRIM * np.median(distance)
        fits = [fit_circle(part) + (np.linalg.norm(part, axis=1).max(),)
                for part in ((xy, xy[near]) if 8 <= near.sum() < len(xy) and self.params.mode == "strict" else (xy,))]
        accepted = [np.isfinite(radius) and radius < 1.5 * extent for _, radius, extent in fits]
        if accepted[0]:
            trimmed = len(fits) == 2 and accepted[1] and fits[1][1] < fits[0][1] / CIRCLE_WIDE
            centre = fits[1][0] if trimmed else fits[0][0]
            self.axis_point = self.axis_point + centre[0] * u + centre[1] * v
            self.fitted = True

    def spread(self) -> float:
        """95th percentile of the points' orthogonal distances to the current axis, m."""
        if self.direction is None:
            return 0.0
        rel = self.coords[self.points] - self.axis_point
        t = rel @ self.direction
        return float(np.percentile(np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - t * t, 0.0)), 95))

    def spread_radius(self) -> float:
        """Radius of the circle whose points spread as the branch's do across its axis, ``sqrt(2 lambda)``, m.

        ``lambda`` is the larger eigenvalue of the points' covariance across
        the axis; points spread evenly over a half or a full circle of radius
        ``r`` give ``r``, a shorter arc less, a line of points along a thin
        twig about the noise.
        """
        if self.direction is None or self.n < 3:
            return 0.0
        pts = self.coords[self.points]
        rel = pts - pts.mean(axis=0)
        rel -= np.outer(rel @ self.direction, self.direction)
        return float(np.sqrt(2.0 * max(np.linalg.eigvalsh(rel.T @ rel / len(pts))[-1], 0.0)))

    def tentative_distance(self, index: int) -> tuple[float, float]:
        """Orthogonal distance of point ``index`` to the axis refitted with it, and its normalised projection ``t_d``."""
        xyz = self.coords[index]
        span = self.t1 - self.t0
        t_d = 0.0 if self.direction is None or span <= 0 else float((xyz - self.p1()) @ self.direction / span)
        normal_outer = self.normal_outer
        if self.normals is not None:
            normal_outer = normal_outer + self.normals[index][:, None] * self.normals[index]
        direction = self.tracked_direction(self.n + 1, self.sum + xyz, self.outer + xyz[:, None] * xyz, normal_outer)
        if direction is None:
            return 0.0, t_d
        rel = xyz - (self.axis_point if self.fitted else (self.sum + xyz) / (self.n + 1))
        t = rel @ direction
        return float(np.sqrt(max(rel @ rel - t * t, 0.0))), t_d


def is_significant(order: int, count: int, params) -> bool:
    """Méndez's significance: order below ``ord_min1``, or below ``ord_min2`` with more than ``n_min`` points.

    Parameters
    ----------
    order : int
        Branch order (trunk = 1).
    count : int
        Number of points of the branch.
    params : woody.cylinders.FollowParams
        Settings (``ord_min1``, ``ord_min2``, ``n_min_factor``, free-seed counts).

    Returns
    -------
    bool
    """
    return order < params.ord_min1 or (order < params.ord_min2 and count > params.n_min_factor * params.n_s(order))

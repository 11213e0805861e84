"""Cylinder and circle fitting for cylinder following (:mod:`woody.cylinders`): axis directions and circles.

The axis estimators of the cylinder-following module docstring: the paper's
minimax covariance eigenvector or polar/azimuth search (Méndez et al.,
Sect. 2.3; spec D-M3), the axis least aligned with a set of surface normals,
and a robust circle for the axis position. Lengths in m, angles in rad
unless named ``*_deg``.
"""

from __future__ import annotations

import numpy as np

from woody.errors import WoodyError


def fit_direction(points: np.ndarray, method: str = "covariance") -> np.ndarray:
    """Axis direction of a cluster of points on a cylinder (unit vector, sign arbitrary).

    Parameters
    ----------
    points : ndarray, (n, 3)
        The points, m.
    method : {"covariance", "iterative"}
        ``"covariance"``: the eigenvector of the covariance matrix that
        minimises the largest orthogonal distance (Méndez et al., Sect. 2.3;
        spec D-M3). ``"iterative"``: coarse-to-fine search over polar angle
        and azimuth for that minimax direction (10 deg grid, refined by halves
        down to 0.1 deg).

    Returns
    -------
    ndarray, (3,)
        Unit axis direction.

    Raises
    ------
    WoodyError
        For an unknown ``method``.
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
    """Largest distance of centred points (m) from the line through the origin along unit ``direction``, m."""
    along = centred @ direction
    return float(np.sqrt(np.max(np.einsum("ij,ij->i", centred, centred) - along * along, initial=0.0)))


def _unit(polar: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Unit vectors of polar angles and azimuths (rad), ``(..., 3)``."""
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

    Parameters
    ----------
    xy : ndarray, (n, 2)
        The points, m.
    iterations : int
        Gauss-Newton steps.

    Returns
    -------
    centre : ndarray, (2,)
        Centre, m.
    radius : float
        Radius, m; NaN when the points are too few or collinear.
    """
    if len(xy) < 3:
        return np.zeros(2), float("nan")
    design = np.column_stack([xy, np.ones(len(xy))])
    (a, b, c), *_ = np.linalg.lstsq(design, np.einsum("ij,ij->i", xy, xy), rcond=None)
    centre = np.array([a, b]) / 2.0
    radius = np.sqrt(max(c + centre @ centre, 0.0))
    x, y = xy[:, 0], xy[:, 1]
    jac = np.empty((len(xy), 3))
    for _ in range(iterations):
        # Element by element the same arithmetic as norm, column_stack and median (same result bits, less overhead).
        dx, dy = x - centre[0], y - centre[1]
        dist = np.maximum(np.sqrt(dx * dx + dy * dy), 1e-12)
        residual = dist - radius
        scale = max(1.5 * median(np.abs(residual)), 1e-9)
        weight = np.sqrt(np.minimum(1.0, scale / np.maximum(np.abs(residual), 1e-12)))
        np.multiply(-dx / dist, weight, out=jac[:, 0])
        np.multiply(-dy / dist, weight, out=jac[:, 1])
        np.negative(weight, out=jac[:, 2])
        step, *_ = np.linalg.lstsq(jac, -residual * weight, rcond=None)
        centre, radius = centre + step[:2], radius + step[2]
    return centre, float(radius) if np.isfinite(radius) and radius > 0 else float("nan")


def median(values: np.ndarray) -> float:
    """Median of a 1-D array, as ``np.median`` computes it (same bits, NaN if any value is NaN) at a third of its
    overhead on short arrays.

    Parameters
    ----------
    values : ndarray, (n,)
        Values, n >= 1.

    Returns
    -------
    float
    """
    n = len(values)
    half = n // 2
    part = np.partition(values, [half - 1, half, n - 1] if n % 2 == 0 else [half, n - 1])
    if np.isnan(part[-1]):
        return float("nan")
    return float(part[half]) if n % 2 else float((part[half - 1] + part[half]) / 2.0)


def normal_axis(normal_outer: np.ndarray, min_ratio: float = 0.02, max_flatness: float = 0.5,
                eig: tuple | None = None) -> np.ndarray | None:
    """The direction least aligned with a set of normals (summed ``n n^T``), or None when not decisive.

    Normals of a cylinder are perpendicular to its axis, so the axis is the
    eigenvector of the smallest eigenvalue. It is decisive when the normals
    spread across the axis (the middle eigenvalue is at least ``min_ratio``
    of the largest; a flat patch fails) and the smallest is at most
    ``max_flatness`` of the middle one.

    Parameters
    ----------
    normal_outer : ndarray, (3, 3)
        Sum of the outer products ``n n^T`` of unit normals.
    min_ratio : float
        Smallest ratio of the middle to the largest eigenvalue.
    max_flatness : float
        Largest ratio of the smallest to the middle eigenvalue.
    eig : tuple, optional
        ``np.linalg.eigh(normal_outer)`` when already computed.

    Returns
    -------
    ndarray, (3,) or None
        Unit axis direction (sign arbitrary), or None when not decisive.
    """
    values, vectors = np.linalg.eigh(normal_outer) if eig is None else eig
    if values[1] < min_ratio * values[2] or values[0] > max_flatness * values[1]:
        return None
    return vectors[:, 0]


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two unit vectors, degrees.

    Parameters
    ----------
    a, b : ndarray, (3,)
        Unit vectors.

    Returns
    -------
    float
        Angle in [0, 180], degrees.
    """
    return float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))

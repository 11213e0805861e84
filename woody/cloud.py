"""Point clouds for woody: validation, and reading any file through :mod:`tlssim.formats.points`.

A :class:`Cloud` holds the points and, where the file says so, the position
of the scanner that saw each point (used to orient normals) and given
normals. :func:`read_cloud` reads every format that
:func:`tlssim.formats.points.read_points` reads (NPZ, PLY, LAS/LAZ, E57,
PTX, and ASCII ``.xyz``/``.txt``/``.csv``/``.pts``/``.asc``) and checks the
result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from woody.errors import WoodyError


@dataclass
class Cloud:
    """Points with what is known about how they were seen.

    Attributes
    ----------
    points : ndarray, (n, 3), float64
        Coordinates, m.
    viewpoints : ndarray, (n, 3), float64, or None
        Position of the scanner that measured each point, m; ``None`` when
        unknown.
    normals : ndarray, (n, 3), float64, or None
        Unit normals given with the cloud (e.g. a simulated scan's truth
        normals); ``None`` when the file has none.
    """

    points: np.ndarray
    viewpoints: np.ndarray | None = None
    normals: np.ndarray | None = None


def single_viewpoint(cloud: Cloud) -> np.ndarray | None:
    """The scanner position of a cloud seen from one position, m (``(3,)``), or None (unknown or several scans)."""
    if cloud.viewpoints is None or not np.all(cloud.viewpoints == cloud.viewpoints[0]):
        return None
    return cloud.viewpoints[0]


def check_points(points, name: str = "points") -> np.ndarray:
    """Validate a point array and return it as ``(n, 3)`` float64.

    Parameters
    ----------
    points : array_like
        Point coordinates x, y, z, m, shape ``(n, 3)``.
    name : str
        Name of the argument in error messages.

    Returns
    -------
    ndarray
        The points, m, float64 of shape ``(n, 3)``.

    Raises
    ------
    WoodyError
        If the array is not ``(n, 3)``, is empty, or holds NaN or infinite values.
    """
    try:
        array = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        raise WoodyError(f"{name} must be a numeric (n, 3) array") from None
    if array.ndim != 2 or array.shape[1] != 3:
        raise WoodyError(f"{name} must be an (n, 3) array of x, y, z in metres, got shape {array.shape}")
    if len(array) == 0:
        raise WoodyError(f"{name} is empty: at least one point is needed")
    bad = ~np.isfinite(array).all(axis=1)
    if bad.any():
        raise WoodyError(f"{name} holds {int(bad.sum())} point(s) with NaN or infinite coordinates "
                         f"(first at index {int(np.argmax(bad))}); drop them first")
    return array


def check_normals(normals, count: int) -> np.ndarray:
    """Validate normals for ``count`` points and return them as unit ``(n, 3)`` float64.

    Parameters
    ----------
    normals : array_like
        One normal per point, shape ``(count, 3)``, any non-zero length.
    count : int
        Number of points the normals belong to.

    Returns
    -------
    ndarray
        Unit normals (dimensionless), float64 of shape ``(count, 3)``.

    Raises
    ------
    WoodyError
        If the shape does not match, or a normal is NaN, infinite or zero.
    """
    array = check_points(normals, "normals")
    if len(array) != count:
        raise WoodyError(f"normals has {len(array)} rows but there are {count} points")
    length = np.linalg.norm(array, axis=1)
    if (length < 1e-12).any():
        raise WoodyError(f"normals holds {int((length < 1e-12).sum())} zero vector(s)")
    return array / length[:, None]


def check_viewpoints(viewpoints, count: int) -> np.ndarray | None:
    """Scanner positions as ``(n, 3)`` float64 (a single ``(3,)`` position is broadcast), or ``None``.

    Parameters
    ----------
    viewpoints : array_like or None
        Scanner position per point, m, shape ``(count, 3)``, one position of shape
        ``(3,)`` for all points, or ``None`` when unknown.
    count : int
        Number of points.

    Returns
    -------
    ndarray or None
        Viewpoints, m, float64 of shape ``(count, 3)``, or ``None``.

    Raises
    ------
    WoodyError
        If the shape does not match or a coordinate is NaN or infinite.
    """
    if viewpoints is None:
        return None
    array = np.asarray(viewpoints, dtype=float)
    if array.shape == (3,):
        array = np.broadcast_to(array, (count, 3))
    if array.shape != (count, 3) or not np.isfinite(array).all():
        raise WoodyError(f"scanner_position must be a finite (3,) or ({count}, 3) array, got shape {array.shape}")
    return np.ascontiguousarray(array)


def read_cloud(path) -> Cloud:
    """Read a point cloud file (format by extension, see :func:`tlssim.formats.points.read_points`).

    Raises
    ------
    WoodyError
        If the file is missing, has an unknown extension, or cannot be read
        (the message names the file and the problem).
    """
    from tlssim.errors import ScanError
    from tlssim.formats.points import read_points

    try:
        cloud = read_points(path)
    except ScanError as exc:
        raise WoodyError(str(exc)) from None
    try:
        points = check_points(cloud.points)
        return Cloud(points, check_viewpoints(cloud.viewpoints, len(points)),
                     None if cloud.normals is None else check_normals(cloud.normals, len(points)))
    except WoodyError as exc:
        raise WoodyError(f"{path}: {exc}") from None

"""Flat and solid primitives as triangle meshes (world coordinates, metres)."""

from __future__ import annotations

import math

import numpy as np

from scenes.errors import SceneError


def cross(a, b) -> np.ndarray:
    """Cross product of 3-vectors along the last axis (``np.cross`` without its per-call overhead).

    Parameters
    ----------
    a, b : array_like, shape (..., 3)
        Vectors (broadcast against each other).

    Returns
    -------
    ndarray, shape (..., 3), float
        ``a × b``, in the product of the inputs' units.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def orthonormal_frame(normal, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Right-handed frame ``(u, v, n)`` with ``n`` along ``normal`` and ``v`` as close to ``up`` as possible.

    Parameters
    ----------
    normal : array_like, shape (3,)
        Direction of the frame's third axis (need not be unit length).
    up : array_like, shape (3,), optional
        Preferred direction of the second axis; replaced by +x when it is
        parallel to ``normal`` (+y when ``normal`` is along x too).

    Returns
    -------
    u, v, n : ndarray, shape (3,)
        Unit vectors with ``u × v = n``.
    """
    n = np.asarray(normal, dtype=float)
    length = np.linalg.norm(n)
    if not np.isfinite(length) or length == 0:
        raise SceneError(f"normal must be a finite non-zero vector, got {normal!r}")
    n = n / length
    up = np.asarray(up, dtype=float)
    v = up - np.dot(up, n) * n
    if np.linalg.norm(v) < 1e-9:
        v = np.array([1.0, 0.0, 0.0]) - n[0] * n
    if np.linalg.norm(v) < 1e-9:  # normal and up both along x
        v = np.array([0.0, 1.0, 0.0]) - n[1] * n
    v /= np.linalg.norm(v)
    return np.cross(v, n), v, n


def rectangle(center, normal, size, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """A flat rectangle as two triangles.

    Parameters
    ----------
    center : array_like, shape (3,)
        Centre of the rectangle, m.
    normal : array_like, shape (3,)
        Normal of the rectangle.
    size : (float, float)
        Width along the in-plane horizontal axis and height along the axis
        closest to ``up``, m.
    up : array_like, shape (3,), optional
        Preferred "up" direction in the plane.

    Returns
    -------
    vertices : ndarray, shape (4, 3)
    faces : ndarray, shape (2, 3)
    """
    width, height = (float(s) for s in size)
    if not (width > 0 and height > 0 and np.isfinite(width) and np.isfinite(height)):
        raise SceneError(f"rectangle size must be two positive numbers (m), got {size!r}")
    u, v, _ = orthonormal_frame(normal, up)
    c = np.asarray(center, dtype=float)
    corners = [(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)]
    vertices = np.array([c + a * width * u + b * height * v for a, b in corners])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    return vertices, faces


def grid_faces(n_rows: int, n_cols: int) -> np.ndarray:
    """Triangles of a structured grid of ``n_rows x n_cols`` vertices stored row by row.

    Each grid cell gives two triangles, counter-clockwise when the column
    index grows along the first parameter axis and the row index along the
    second (so a grid laid out in an ``(x, y)`` plane gets normals along +z).

    Parameters
    ----------
    n_rows, n_cols : int
        Vertices per column and per row, each >= 2.

    Returns
    -------
    faces : ndarray, shape (2 (n_rows - 1)(n_cols - 1), 3), int64
    """
    if n_rows < 2 or n_cols < 2:
        raise SceneError(f"a grid needs at least 2 x 2 vertices, got {n_rows} x {n_cols}")
    index = np.arange(n_rows * n_cols, dtype=np.int64).reshape(n_rows, n_cols)
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, :-1].ravel(), index[1:, 1:].ravel()
    return np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def square_to_disk(u, v) -> tuple[np.ndarray, np.ndarray]:
    """Map the square ``[-1, 1]²`` onto the closed unit disk, border onto circle.

    Uses the elliptical grid mapping ``x = u sqrt(1 - v²/2)``,
    ``y = v sqrt(1 - u²/2)``, which is smooth, orientation-preserving and
    sends the square's border onto the unit circle (so meshes built on it end
    exactly at a round rim).

    Parameters
    ----------
    u, v : array_like
        Coordinates in ``[-1, 1]`` (dimensionless, broadcast against each other).

    Returns
    -------
    x, y : ndarray
        Coordinates in the unit disk.
    """
    u, v = np.asarray(u, dtype=float), np.asarray(v, dtype=float)
    return u * np.sqrt(1.0 - 0.5 * v**2), v * np.sqrt(1.0 - 0.5 * u**2)


#: Largest facet, as a fraction of the beam footprint diameter, that the scanner cannot resolve.
FACET_FRACTION = 0.25
#: The beam that facets are sized for when a scene's scanner section names none: 1/e² waist radius (m) and
#: half-angle divergence (deg) of the ``faro-ls880`` preset (:mod:`tlssim.scanner`; a test checks they agree).
DEFAULT_BEAM_WAIST_RADIUS_M, DEFAULT_DIVERGENCE_DEG = 0.0015, 0.014


def section_beam(scanner: dict | None) -> tuple[float, float]:
    """Beam waist radius (m) and divergence (deg) of a scene's scanner section, defaults where it gives none.

    Parameters
    ----------
    scanner : dict or None
        The scene's scanner section; its ``beam_waist_radius_m`` and
        ``divergence_deg`` entries are used when present.
    """
    scanner = scanner or {}
    return (scanner.get("beam_waist_radius_m", DEFAULT_BEAM_WAIST_RADIUS_M),
            scanner.get("divergence_deg", DEFAULT_DIVERGENCE_DEG))


def facet_size_m(distance_m, beam_waist_radius_m: float = DEFAULT_BEAM_WAIST_RADIUS_M,
                 divergence_deg: float = DEFAULT_DIVERGENCE_DEG, fraction: float = FACET_FRACTION):
    """Facet (triangle edge) size that the scanner cannot see at ``distance_m``.

    The rule: facets no larger than ``fraction`` (default 1/4) of the 1/e²
    beam footprint diameter ``2 (w0 + d tan(divergence))`` of the scene's
    scanner at that distance, so that every footprint averages over many
    facets and the mesh's piecewise-flat shape does not show in range or
    intensity. For the FARO LS880 beam (the default) this is 0.87 mm at 1 m,
    0.93 mm at 1.5 m, 1.1 mm at 3 m and 1.4 mm at 5 m.

    Parameters
    ----------
    distance_m : float or ndarray
        Distance from the scanner, m.
    beam_waist_radius_m : float
        1/e² beam radius at the exit aperture, m (see :func:`section_beam`).
    divergence_deg : float
        Half-angle divergence of the 1/e² radius, degrees.
    fraction : float
        Facet size as a fraction of the footprint diameter.

    Returns
    -------
    float or ndarray
        Facet size, m (shape of ``distance_m``; negative distances count as 0).
    """
    radius = beam_waist_radius_m + np.maximum(np.asarray(distance_m, dtype=float), 0.0) * math.tan(
        math.radians(divergence_deg))
    return fraction * 2.0 * radius

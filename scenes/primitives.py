"""Flat and solid primitives as triangle meshes (world coordinates, metres)."""

from __future__ import annotations

import numpy as np

from scenes.errors import SceneError


def orthonormal_frame(normal, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Right-handed frame ``(u, v, n)`` with ``n`` along ``normal`` and ``v`` as close to ``up`` as possible.

    Parameters
    ----------
    normal : array_like, shape (3,)
        Direction of the frame's third axis (need not be unit length).
    up : array_like, shape (3,), optional
        Preferred direction of the second axis; replaced by +x when it is
        parallel to ``normal``.

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

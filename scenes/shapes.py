"""Solid primitives as triangle meshes in their local frames (metres).

Curved solids follow one tessellation rule: the polygon's sagitta (largest
gap between a facet and the true surface) stays below :data:`SAGITTA_M`,
0.2 mm, well under the scanner's range noise (about 0.5-2 mm for the FARO
LS880 at 1-5 m, spec tls-physics A.3), so facets do not show in scans.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from scenes.errors import SceneError

#: Largest allowed gap between a facet and the curved surface it stands for, m.
SAGITTA_M = 2e-4


def polygon_sides(radius_m, sagitta_m: float = SAGITTA_M, minimum: int = 6, maximum: int = 512):
    """Sides of a regular polygon approximating a circle of ``radius_m`` within ``sagitta_m``.

    Works element-wise on arrays; ``r (1 - cos(π / n)) <= sagitta``.

    Parameters
    ----------
    radius_m : float or array_like
        Circle radius, m.
    sagitta_m : float
        Largest allowed gap between a polygon side and the circle, m.
    minimum, maximum : int
        Bounds on the number of sides.

    Returns
    -------
    int or ndarray of int
        Number of sides, same shape as ``radius_m``.
    """
    radius = np.asarray(radius_m, dtype=float)
    ratio = np.clip(1.0 - sagitta_m / np.maximum(radius, 1e-12), -1.0, 1.0)
    sides = np.ceil(np.pi / np.maximum(np.arccos(ratio), 1e-12))
    return np.clip(sides, minimum, maximum).astype(int)


def _perpendicular_frames(axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to each unit axis ``(M, 3)`` (and to each other)."""
    helper = np.where(np.abs(axes[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(axes, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(axes, e1)


def frusta(starts, ends, radii_start, radii_end, sides: int) -> tuple[np.ndarray, np.ndarray]:
    """Open tapered tubes (frusta) between ``starts`` and ``ends``, all with ``sides`` sides (vectorised).

    Parameters
    ----------
    starts, ends : array_like, shape (M, 3)
        Axis end points, m.
    radii_start, radii_end : array_like, shape (M,)
        Radii at the two ends, m (``radii_end`` may be 0: a cone).
    sides : int
        Polygon sides.

    Returns
    -------
    vertices : ndarray, shape (2 M sides, 3)
    faces : ndarray, shape (2 M sides, 3)
        Outward-facing triangles.
    """
    starts, ends = np.atleast_2d(np.asarray(starts, float)), np.atleast_2d(np.asarray(ends, float))
    r0 = np.broadcast_to(np.asarray(radii_start, float), (len(starts),))
    r1 = np.broadcast_to(np.asarray(radii_end, float), (len(starts),))
    axis = ends - starts
    length = np.linalg.norm(axis, axis=1, keepdims=True)
    if np.any(length <= 0):
        raise SceneError("every tube segment needs distinct start and end points")
    e1, e2 = _perpendicular_frames(axis / length)
    angle = 2 * np.pi * np.arange(sides) / sides
    ring = np.cos(angle)[None, :, None] * e1[:, None] + np.sin(angle)[None, :, None] * e2[:, None]  # (M, S, 3)
    vertices = np.concatenate([starts[:, None] + r0[:, None, None] * ring,
                               ends[:, None] + r1[:, None, None] * ring], axis=1)  # (M, 2S, 3)
    j = np.arange(sides)
    k = (j + 1) % sides
    quad = np.concatenate([np.stack([j, k, sides + k], 1), np.stack([j, sides + k, sides + j], 1)])
    offsets = (2 * sides * np.arange(len(starts)))[:, None, None]
    return vertices.reshape(-1, 3), (quad[None] + offsets).reshape(-1, 3)


def frustum_volume(length, radius_start, radius_end):
    """Exact volume of frusta, ``π h (r0² + r0 r1 + r1²) / 3`` (element-wise).

    Parameters
    ----------
    length : float or array_like
        Axis length ``h``, m.
    radius_start, radius_end : float or array_like
        Radii ``r0`` and ``r1`` at the two ends, m.

    Returns
    -------
    float or ndarray
        Volume, m³ (broadcast shape of the inputs).
    """
    r0, r1 = np.asarray(radius_start, float), np.asarray(radius_end, float)
    return np.pi * np.asarray(length, float) * (r0 * r0 + r0 * r1 + r1 * r1) / 3.0


def disk_mesh(radius: float, segments: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Flat disk in the local x-y plane, centred at the origin, normal +z, as a triangle fan.

    Parameters
    ----------
    radius : float
        Disk radius, m.
    segments : int, optional
        Number of rim segments; default :func:`polygon_sides` of ``radius``.

    Returns
    -------
    vertices : ndarray, shape (segments + 1, 3)
        Centre first, then the rim, m.
    faces : ndarray, shape (segments, 3)
    """
    n = int(segments or polygon_sides(radius))
    angle = 2 * np.pi * np.arange(n) / n
    vertices = np.concatenate([[[0.0, 0.0, 0.0]], np.stack([radius * np.cos(angle), radius * np.sin(angle),
                                                             np.zeros(n)], 1)])
    j = np.arange(n)
    return vertices, np.stack([np.zeros(n, dtype=int), 1 + j, 1 + (j + 1) % n], 1)


def tube_mesh(radius: float, length: float, radius_end: float | None = None, caps: bool = True,
              sides: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Straight (tapered) tube along local +z from ``-length/2`` to ``+length/2``, optionally capped.

    Parameters
    ----------
    radius : float
        Radius at ``z = -length/2``, m.
    length : float
        Length along z, m.
    radius_end : float, optional
        Radius at ``z = +length/2``, m (0 gives a cone); default ``radius``.
    caps : bool
        Close both ends with outward-facing disks (an end of radius 0 gets none).
    sides : int, optional
        Polygon sides; default :func:`polygon_sides` of the larger radius.

    Returns
    -------
    vertices : ndarray, shape (V, 3)
        Local coordinates, m.
    faces : ndarray, shape (F, 3)
    """
    radius_end = radius if radius_end is None else radius_end
    n = int(sides or polygon_sides(max(radius, radius_end)))
    vertices, faces = frusta([[0, 0, -length / 2]], [[0, 0, length / 2]], [radius], [radius_end], n)
    parts_v, parts_f = [vertices], [faces]
    if caps:
        for z, r, flip in ((-length / 2, radius, True), (length / 2, radius_end, False)):
            if r > 0:
                v, f = disk_mesh(r, n)
                parts_f.append((f[:, ::-1] if flip else f) + sum(len(p) for p in parts_v))
                parts_v.append(v + [0.0, 0.0, z])
    return np.concatenate(parts_v), np.concatenate(parts_f)


def ellipsoid_mesh(radii, sagitta_m: float = SAGITTA_M) -> tuple[np.ndarray, np.ndarray]:
    """Ellipsoid with semi-axes ``radii`` along local x, y, z (a scaled icosphere), centred at the origin.

    Parameters
    ----------
    radii : array_like, shape (3,)
        Semi-axes, m.
    sagitta_m : float
        Largest allowed facet-to-surface gap on the sphere of the largest semi-axis, m
        (sets the subdivision level, at most 7).

    Returns
    -------
    vertices : ndarray, shape (V, 3)
        Local coordinates, m.
    faces : ndarray, shape (F, 3), int64
    """
    radii = np.asarray(radii, dtype=float)
    r = radii.max()
    # Icosphere edge ≈ 1.05 r / 2^k; sagitta ≈ edge² / (8 r).
    level = math.ceil(math.log2(max(1.05 * r / math.sqrt(8 * r * sagitta_m), 1.0)))
    sphere = trimesh.creation.icosphere(subdivisions=min(level, 7), radius=1.0)
    return np.asarray(sphere.vertices) * radii, np.asarray(sphere.faces, dtype=np.int64)


def box_mesh(size) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box of ``size`` (x, y, z) centred at the origin."""
    box = trimesh.creation.box(extents=np.asarray(size, dtype=float))
    return np.asarray(box.vertices), np.asarray(box.faces, dtype=np.int64)

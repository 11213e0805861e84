"""Preview pictures of a scene seen from the scanner (Mitsuba ray casting, hot-spot shading).

A pinhole camera sits at the scanner position and looks along the centre of
the scan window; its field of view covers the window (at most
:data:`MAX_FOV_DEG` across). Camera rays are cast with Mitsuba on the
scene's merged mesh; each hit is shaded like the scanner sees it, with the
light at the camera: ``colour(object) · (0.15 + 0.85 |cos incidence|)``,
tinted by object type (leaves green, wood brown, ground earthy, others grey
by reflectance). Misses are pale sky.
"""

from __future__ import annotations

import math

import numpy as np

from scenes.scene import Scene
from tlssim.backend import select_backend
from tlssim.errors import ScanError
from tlssim.pattern import grid_directions
from tlssim.simulate import ScanSetup

#: Widest field of view of the preview camera, degrees.
MAX_FOV_DEG = 150.0

_TINTS = {"leaf": (0.45, 1.0, 0.35), "wood": (1.0, 0.72, 0.45), "ground": (1.0, 0.85, 0.65)}
_SKY = np.array([0.86, 0.91, 0.97])


def _camera(setup: ScanSetup):
    """Camera frame (forward, right, up) and image-plane half-extents covering the scan window."""
    rotation = setup.pose.rotation
    theta, psi = (np.radians(np.asarray(r)) for r in (setup.window.theta_deg, setup.window.psi_deg))
    centre = grid_directions(np.array([theta.mean()]), np.array([psi.mean()]), rotation).reshape(3)
    up_world = rotation @ np.array([0.0, 0.0, 1.0])
    right = np.cross(centre, up_world)
    if np.linalg.norm(right) < 1e-6:  # looking straight up or down
        right = rotation @ np.array([0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, centre)
    edge_t, edge_p = np.linspace(*theta, 9), np.linspace(*psi, 9)
    border = np.concatenate([grid_directions(edge_t, psi, rotation).reshape(-1, 3),
                             grid_directions(theta, edge_p, rotation).reshape(-1, 3)])
    forward = border @ centre
    limit = math.tan(math.radians(MAX_FOV_DEG / 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(forward > 0, np.abs(border @ right) / forward, limit)
        y = np.where(forward > 0, np.abs(border @ up) / forward, limit)
    half_x = float(np.clip(x.max(), 1e-3, limit))
    half_y = float(np.clip(y.max(), 1e-3, limit))
    return centre, right, up, half_x, half_y


def render_preview(scene: Scene, setup: ScanSetup, width: int = 800, backend: str = "auto",
                   supersample: int = 2) -> np.ndarray:
    """Render ``scene`` from the scanner of ``setup``.

    Parameters
    ----------
    scene : Scene
        What to show.
    setup : ScanSetup
        Scanner pose and window (the camera looks along the window centre).
    width : int
        Image width in pixels (the height follows the window's aspect).
    backend : {"auto", "llvm", "cuda"}
        Mitsuba variant (see :func:`tlssim.backend.select_backend`).
    supersample : int
        Rays per pixel along each axis (anti-aliasing).

    Returns
    -------
    ndarray, shape (H, W, 3)
        RGB image in [0, 1].
    """
    import drjit as dr
    import mitsuba as mi

    if width < 16 or supersample < 1:
        raise ScanError(f"preview width must be >= 16 pixels and supersample >= 1, got {width}, {supersample}")
    select_backend(backend)
    vertices, faces, face_object = scene.merged_mesh()
    origin = setup.pose.position
    mesh = mi.Mesh("preview", len(vertices), len(faces), has_vertex_normals=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float((vertices - origin).astype(np.float32).ravel())
    params["faces"] = mi.UInt32(faces.astype(np.uint32).ravel())
    params.update()
    traced = mi.load_dict({"type": "scene", "mesh": mesh})

    forward, right, up, half_x, half_y = _camera(setup)
    height = max(16, round(width * half_y / half_x))
    nx, ny = width * supersample, height * supersample
    x = (2 * (np.arange(nx) + 0.5) / nx - 1) * half_x
    y = (1 - 2 * (np.arange(ny) + 0.5) / ny) * half_y
    direction = forward + x[None, :, None] * right + y[:, None, None] * up
    direction = (direction / np.linalg.norm(direction, axis=-1, keepdims=True)).reshape(-1, 3)
    ray = mi.Ray3f(mi.Point3f(0.0, 0.0, 0.0), mi.Vector3f(*(mi.Float(c.astype(np.float32)) for c in direction.T)))
    hit = traced.ray_intersect_preliminary(ray)
    valid = np.array(hit.is_valid(), dtype=bool)
    prim = np.array(hit.prim_index, dtype=np.int64)
    dr.sync_thread()

    tri = vertices[faces[prim[valid]]]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-30)
    cosine = np.abs(np.sum(normal * direction[valid], axis=1))
    colours = np.array([_colour(o.type, o.material.reflectance) for o in scene.objects])
    image = np.tile(_SKY, (len(direction), 1))
    image[valid] = colours[face_object[prim[valid]]] * (0.15 + 0.85 * cosine)[:, None]
    image = image.reshape(ny, nx, 3).reshape(height, supersample, width, supersample, 3).mean(axis=(1, 3))
    return np.clip(image, 0.0, 1.0)


def _colour(kind: str, reflectance: float) -> np.ndarray:
    level = 0.35 + 0.65 * min(1.0, reflectance / 0.6)
    return level * np.asarray(_TINTS.get(kind, (1.0, 1.0, 1.0)))

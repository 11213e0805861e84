"""Import the shapes of a Mitsuba 3 scene XML as triangle meshes.

Triangle meshes (``obj``, ``ply``, ``serialized``, ``cube``, ``rectangle``,
...) are taken as they are (world coordinates). The analytic ``sphere``,
``disk`` and ``cylinder`` are tessellated with this package's primitives
and mapped through their ``to_world`` transform. Other shape types are
rejected with the list of supported ones.

Material: a ``diffuse`` BSDF with a uniform reflectance gives the mean of its
RGB value (an assumption standing in for the 785 nm reflectance, which an
RGB scene does not hold); anything else gets 0.5. A scene entry's
``material`` field overrides it for every shape.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scenes.errors import SceneError
from scenes.scene import Material
from scenes.shapes import disk_mesh, ellipsoid_mesh, tube_mesh

ANALYTIC_SHAPES = ("sphere", "disk", "cylinder")


def _unit_shape(kind: str, world_radius: float):
    """Mitsuba's unit analytic shapes, tessellated for a world radius of ``world_radius``."""
    if kind == "sphere":
        v, f = ellipsoid_mesh([world_radius] * 3)
    elif kind == "disk":
        v, f = disk_mesh(world_radius)
    else:  # unit cylinder: radius 1, z from 0 to 1, open
        v, f = tube_mesh(world_radius, world_radius, caps=False)
        v = v + [0.0, 0.0, world_radius / 2]
    return v / world_radius, f


def _reflectance(shape, mi) -> tuple[str, float]:
    bsdf = shape.bsdf()
    params = mi.traverse(bsdf)
    if "reflectance.value" in params and "diffuse" in str(bsdf).lower():
        value = float(np.mean(np.array(params["reflectance.value"], dtype=float)))
        if 0.0 <= value <= 1.0:
            return f"lambert-{value:.3g}", value
    return "lambert-0.5", 0.5


def load_mitsuba_shapes(path: Path, where: str) -> list[tuple[str, np.ndarray, np.ndarray, Material]]:
    """Shapes of the Mitsuba scene at ``path`` as ``(id, vertices, faces, material)`` in world coordinates.

    Parameters
    ----------
    path : Path
        Mitsuba 3 scene XML file (its lengths are taken as metres).
    where : str
        Location used in error messages.

    Returns
    -------
    list of (str, ndarray, ndarray, Material)
        Per shape: its id (``shape-<k>`` when it has none), vertices ``(V, 3)`` in m, faces ``(F, 3)``
        and a Lambertian material from a diffuse BSDF's mean reflectance (0.5 otherwise).

    Raises
    ------
    SceneError
        If the file cannot be parsed by Mitsuba, holds an unsupported shape
        type, or has no shapes.
    """
    import mitsuba as mi

    if mi.variant() is None:
        mi.set_variant("scalar_rgb")
    try:
        scene = mi.load_file(str(path))
    except Exception as exc:  # Mitsuba reports parse errors as RuntimeError with a long message
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise SceneError(f"{where}: field 'file': Mitsuba cannot load {path.name}: {first}") from None
    out = []
    for k, shape in enumerate(scene.shapes()):
        name = shape.id() or f"shape-{k + 1}"
        if shape.is_mesh():
            vertices = np.array(shape.vertex_positions_buffer(), dtype=float).reshape(-1, 3)
            faces = np.array(shape.faces_buffer(), dtype=np.int64).reshape(-1, 3)
        else:
            kind = str(shape).split("[", 1)[0].strip().lower()
            if kind not in ANALYTIC_SHAPES:
                raise SceneError(f"{where}: field 'file': shape {name!r} in {path.name} is not a triangle mesh "
                                 f"and not one of {', '.join(ANALYTIC_SHAPES)}")
            matrix = np.array(mi.traverse(shape)["to_world"].matrix, dtype=float).reshape(4, 4)
            radius = float(np.linalg.norm(matrix[:3, :2], axis=0).max())
            local, faces = _unit_shape(kind, radius)
            vertices = local @ matrix[:3, :3].T + matrix[:3, 3]
        label, reflectance = _reflectance(shape, mi)
        out.append((name, vertices, faces, Material(label, reflectance)))
    if not out:
        raise SceneError(f"{where}: field 'file': {path.name} contains no shapes")
    return out

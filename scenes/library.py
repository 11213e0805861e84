"""The library of built-in scenes, registered by name.

Each entry is a function that builds a :class:`~scenes.scene.Scene` (with the
scanner section that goes with it). Register new scenes with
:func:`register`; list them with :func:`names` and :func:`describe`; build one
with :func:`build`.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from scenes.errors import SceneError
from scenes.primitives import rectangle
from scenes.scene import Material, Scene, SceneObject

_REGISTRY: dict[str, tuple[str, Callable[[], Scene]]] = {}


def register(name: str, description: str):
    """Decorator registering a scene builder under ``name`` with a one-line description.

    Parameters
    ----------
    name : str
        Name of the built-in scene (registering a name twice raises :class:`SceneError`).
    description : str
        One-line description shown by :func:`describe`.

    Returns
    -------
    callable
        Decorator that registers a function ``() -> Scene`` and returns it unchanged.
    """

    def decorator(builder: Callable[[], Scene]):
        if name in _REGISTRY:
            raise SceneError(f"built-in scene {name!r} is registered twice")
        _REGISTRY[name] = (description, builder)
        return builder

    return decorator


def names() -> list[str]:
    """Names of the built-in scenes, sorted."""
    return sorted(_REGISTRY)


def describe() -> dict[str, str]:
    """One-line description of every built-in scene, by name."""
    return {name: _REGISTRY[name][0] for name in names()}


def build(name: str) -> Scene:
    """Build the built-in scene ``name``.

    Raises
    ------
    SceneError
        If no built-in scene has that name (the message lists them).
    """
    if name not in _REGISTRY:
        raise SceneError(f"unknown built-in scene {name!r}; available: {', '.join(names())}")
    scene = _REGISTRY[name][1]()
    scene.name = name
    return scene


def _plate(name, center, normal, size, reflectance) -> SceneObject:
    vertices, faces = rectangle(center, normal, size)
    return SceneObject(
        name=name,
        type="plane",
        vertices=vertices,
        faces=faces,
        material=Material(f"lambert-{reflectance:g}", reflectance),
        truth={"normal": list(np.asarray(normal, float) / np.linalg.norm(normal))},
    )


@register("knife-edge", "20 x 20 cm plate (rho 0.5) at 1.5 m whose vertical edge halves the window, wall (rho 0.5) at 2 m")
def knife_edge() -> Scene:
    # The scanner looks along +x. The plate covers y in [-0.2, 0] so its edge
    # lies on the x-z plane, which the window's middle column (theta = 0) hits.
    plate = _plate("plate", (1.5, -0.1, 0.0), (-1, 0, 0), (0.2, 0.2), 0.5)
    wall = _plate("wall", (2.0, 0.0, 0.0), (-1, 0, 0), (1.0, 1.0), 0.5)
    return Scene(
        objects=[plate, wall],
        scanner={
            "preset": "faro-ls880",
            "position": [0.0, 0.0, 0.0],
            "window": {"theta_deg": [-0.5, 0.5], "psi_deg": [89.75, 90.25]},
        },
    )


@register("tilted-plane", "plane 2 m from the scanner; the window sweeps incidence from 0 to 85 deg")
def tilted_plane() -> Scene:
    # Plane x = 2 m facing the scanner: along the horizontal scan line the
    # incidence angle equals the azimuth theta, so theta in [0, 85] deg spans
    # incidence 0-85 deg (the far end lies 2 / cos 85 deg = 23 m away).
    half_width = 2.0 * np.tan(np.radians(87.0))
    plane = _plate("plane", (2.0, half_width / 2 - 0.5, 0.0), (-1, 0, 0), (half_width + 1.0, 1.0), 0.5)
    return Scene(
        objects=[plane],
        scanner={
            "preset": "faro-ls880",
            "position": [0.0, 0.0, 0.0],
            "window": {"theta_deg": [0.0, 85.0], "psi_deg": [89.91, 90.09]},
        },
    )


@register("wavy-sheet", "4 x 4 m wavy height field (318k triangles, rho 0.5) 3 m in front of the scanner; perf scene")
def wavy_sheet() -> Scene:
    n = 400
    y, z = np.meshgrid(np.linspace(-2, 2, n), np.linspace(-2, 2, n))
    x = 3.0 + 0.05 * np.sin(7 * y) * np.cos(7 * z)
    vertices = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    index = np.arange(n * n).reshape(n, n)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])
    sheet = SceneObject("sheet", "height-field", vertices, faces, Material("lambert-0.5", 0.5))
    return Scene(objects=[sheet], scanner={"preset": "faro-ls880", "position": [0.0, 0.0, 0.0],
                                           "window": {"theta_deg": [-2, 2], "psi_deg": [88, 92]}})

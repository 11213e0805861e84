"""Scenes: everything that can be scanned, with its ground truth."""

from scenes.errors import SceneError
from scenes.library import build, describe, names, register
from scenes.scene import Material, Scene, SceneObject


def load(spec: str) -> Scene:
    """A scene from a built-in name (see :func:`names`).

    Raises
    ------
    SceneError
        If ``spec`` names no built-in scene.
    """
    return build(spec)

__all__ = ["Material", "Scene", "SceneError", "SceneObject", "build", "describe", "load", "names", "register"]

# Modules that register further built-in scenes (imported for their side effect).
BUILTIN_MODULES: tuple[str, ...] = ("scenes.calibration_scenes",)
for _module in BUILTIN_MODULES:
    __import__(_module)

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

"""Scenes: everything that can be scanned, with its ground truth."""

from pathlib import Path

from scenes.errors import SceneError
from scenes.library import build, describe, names, register
from scenes.scene import Material, Scene, SceneObject
from scenes.scenefile import load_scene_file, save_scene, scene_from_spec


def load(spec: str | Path) -> Scene:
    """A scene from a built-in name (see :func:`names`) or a YAML scene file.

    A string that names a built-in scene builds it; anything else is read as
    a scene file path (YAML).

    Raises
    ------
    SceneError
        If ``spec`` is neither a built-in name nor an existing scene file, or
        the scene is invalid.
    """
    if isinstance(spec, str) and spec in names():
        return build(spec)
    path = Path(spec)
    if not path.is_file() and path.suffix.lower() not in (".yaml", ".yml") and len(path.parts) == 1:
        raise SceneError(f"unknown built-in scene {str(spec)!r}; available: {', '.join(names())} "
                         "(or give a scene file path)")
    return load_scene_file(path)


__all__ = ["Material", "Scene", "SceneError", "SceneObject", "build", "describe", "load", "load_scene_file",
           "names", "register", "save_scene", "scene_from_spec"]

# Modules that register further built-in scenes (imported for their side effect).
BUILTIN_MODULES: tuple[str, ...] = ("scenes.builtin", "scenes.calibration_scenes")
for _module in BUILTIN_MODULES:
    __import__(_module)

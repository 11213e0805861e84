"""The scene description: YAML files and the same vocabulary from Python.

A description is a mapping with an optional ``name``, a ``scanner`` section
(plain data passed to the simulator: ``preset``, ``position``,
``orientation``, ``window``, ``step_deg`` and scanner-model overrides) and a
list of ``objects``, each with a ``type`` (:data:`~scenes.builders.OBJECT_TYPES`),
a ``name``, usually a ``material`` and a ``pose``. ``docs/scene-format.md``
lists every field.

- :func:`scene_from_spec` builds a :class:`~scenes.scene.Scene` from such a
  mapping (from Python);
- :func:`load_scene_file` reads a YAML file (``yaml.safe_load``);
- :func:`save_scene` writes a scene's description back to YAML (file paths
  rewritten relative to the new location), so that loading it again gives
  the same meshes and truth.

Every mistake raises :class:`~scenes.errors.SceneError` naming the file, the
object, the field and what is allowed.
"""

from __future__ import annotations

import copy
import os
from pathlib import Path

import numpy as np
import yaml

from scenes.builders import BUILDERS, OBJECT_TYPES, Context
from scenes.errors import SceneError
from scenes.fields import Fields, vector
from scenes.scene import Scene

_FILE_TYPES = ("mesh", "mitsuba")


def plain(value):
    """``value`` with numpy arrays and scalars turned into lists and Python numbers (YAML/JSON-ready)."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value


def scene_from_spec(spec: dict, base_dir: str | Path = ".", source: str = "scene") -> Scene:
    """Build a scene from a description mapping.

    Parameters
    ----------
    spec : dict
        ``{name?, scanner?, objects: [...]}`` (see the module docstring).
    base_dir : str or Path
        Directory that relative ``file`` paths are resolved against.
    source : str
        Name used at the start of error messages (e.g. the file name).

    Returns
    -------
    Scene
        With ``scene.spec`` holding the description (file paths absolute).

    Examples
    --------
    >>> scene = scene_from_spec({"objects": [
    ...     {"name": "wall", "type": "plane", "size": [4, 4], "material": {"reflectance": 0.5},
    ...      "pose": {"center": [2.5, 0, 0], "facing": "scanner"}}]})
    >>> scene.object_names
    ['wall']
    """
    top = Fields(plain(spec), source)
    name = top.raw("name", "")
    if not isinstance(name, str):
        raise top.error("name", f"must be a string, got {name!r}")
    top.raw("description", "")
    scanner = top.sub("scanner", {}).data
    position = vector(scanner.get("position", [0.0, 0.0, 0.0]), 3,
                      lambda msg: SceneError(f"{source}, scanner: field 'position': {msg}"))
    entries = top.raw("objects")
    if not isinstance(entries, list) or not entries:
        raise top.error("objects", f"must be a non-empty list of object entries, got {entries!r}")
    top.finish()
    ctx = Context(scanner=scanner, scanner_position=position, base_dir=Path(base_dir))
    objects, seen = [], {}
    stored = copy.deepcopy(top.data)
    for i, entry in enumerate(entries):
        label = entry.get("name") if isinstance(entry, dict) else None
        kind = entry.get("type") if isinstance(entry, dict) else None
        where = f"{source}: object #{i + 1}" + (f" {label!r}" if label else "") + (f" ({kind})" if kind else "")
        f = Fields(entry, where)
        kind = f.choice("type", OBJECT_TYPES)
        label = f.text("name")
        if label in seen:
            raise f.error("name", f"{label!r} is already used by object #{seen[label]}; names must be unique")
        seen[label] = i + 1
        built = BUILDERS[kind](f, label, ctx)
        f.finish()
        objects.extend(built)
        if kind in _FILE_TYPES:
            stored["objects"][i]["file"] = str((ctx.base_dir / entry["file"]).resolve())
    return Scene(objects=objects, scanner=scanner, name=name, spec=stored)


def load_scene_file(path: str | Path) -> Scene:
    """Read a YAML scene file (``yaml.safe_load``) and build it.

    Raises
    ------
    SceneError
        If the file is missing, is not valid YAML, or describes an invalid scene.
    """
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"scene file {str(path)!r} not found")
    try:
        spec = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise SceneError(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from None
    except UnicodeDecodeError:
        raise SceneError(f"{path}: not a text (UTF-8) file") from None
    if not isinstance(spec, dict):
        raise SceneError(f"{path}: a scene file must be a mapping with 'objects' (and 'scanner'), "
                         f"got {type(spec).__name__}")
    scene = scene_from_spec(spec, base_dir=path.parent, source=str(path))
    if not scene.name:
        scene.name = path.stem
        scene.spec["name"] = path.stem
    return scene


def save_scene(scene: Scene, path: str | Path) -> Path:
    """Write the description of ``scene`` as a YAML scene file.

    Relative ``file`` paths of mesh and Mitsuba entries are rewritten
    relative to ``path``'s directory.

    Parameters
    ----------
    scene : Scene
        A scene built from a description (file, dict or built-in spec).
    path : str or Path
        File to write (overwritten).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    SceneError
        If the scene was built from meshes rather than a description.
    """
    if scene.spec is None:
        raise SceneError(f"scene {scene.name!r} was built from meshes, not from a description; "
                         "only scenes built from a description (file, dict or built-in spec) can be saved")
    path = Path(path)
    spec = copy.deepcopy(scene.spec)
    if scene.name:
        spec["name"] = scene.name
    for entry in spec["objects"]:
        if entry.get("type") in _FILE_TYPES:
            entry["file"] = os.path.relpath(entry["file"], path.parent.resolve())
    path.write_text(yaml.safe_dump(plain(spec), sort_keys=False))
    return path

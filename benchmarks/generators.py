"""Parametric scenes for benchmark cases, built in Python.

A case names its scene with a small JSON-ready description (see
:func:`build_scene`): a built-in scene of the :mod:`scenes` library
(``{"builtin": "knife-edge"}``), one of the generators registered here with
its parameters (``{"generator": "plate-leaf", "distance_m": 3,
"incidence_deg": 60}``), or a scene file of the user's
(``{"file": "/abs/path/scene.yaml", "sha256": "..."}``: suites resolve the
path relative to the suite file and record the file's digest, so that a
changed file is refused rather than mixed into a resumed run). Scenes are rebuilt from that description wherever
they are needed (the simulation and the scoring), so every generator must be
deterministic in its parameters (random layouts take a ``seed``).

Generators place their targets in front of the scanner at the origin, which
looks along +x, and return a scanner section whose window covers every
target with a margin, so that no edge outlier falls outside the scan.

Generators: ``single-leaf`` (a procedural pear leaf of :mod:`scenes`),
``tree`` (a procedural tree of :mod:`scenes` with its leaves: seed,
distance, leaf count, optional wall),
``plate-leaf`` (a flat elliptic leaf, an exactly known shape for controlled
tests; it carries the leaf truth fields of the data contract),
``analytic-surface`` (the thesis' test surfaces at leaf size) and ``branch``
(a cylinder with truth cylinders, for the woody methods); all but the
branch stand in front of a background wall that the edge pulses mix with.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import math
from pathlib import Path
from typing import Callable

import numpy as np

import scenes
from benchmarks.errors import BenchError
from scenes.primitives import orthonormal_frame, rectangle
from scenes.scene import Material, Scene, SceneObject

_GENERATORS: dict[str, tuple[str, Callable[..., Scene]]] = {}

#: Pear (Conference) blade: length 6.5 cm, half-width 2.2 cm (scenes issue, from the thesis' orchard).
PEAR_LENGTH_M = 0.065
PEAR_WIDTH_RATIO = 2 * 0.022 / 0.065
#: Leaf reflectance at 785 nm (tls-physics digest §7.12 recommendation).
LEAF_REFLECTANCE = 0.48


def generator(name: str, description: str):
    """Decorator registering a scene generator under ``name``.

    Parameters
    ----------
    name : str
        Generator name, unique.
    description : str
        One line shown in the list of generators.

    Returns
    -------
    callable
        Decorator that registers a function returning a :class:`Scene` and
        returns it unchanged.
    """

    def decorator(func: Callable[..., Scene]):
        if name in _GENERATORS:
            raise BenchError(f"scene generator {name!r} is registered twice")
        _GENERATORS[name] = (description, func)
        return func

    return decorator


def generator_names() -> list[str]:
    """Names of the registered scene generators, sorted."""
    return sorted(_GENERATORS)


def describe_generators() -> dict[str, str]:
    """One-line description of every generator, by name."""
    return {name: _GENERATORS[name][0] for name in generator_names()}


def check_scene(spec: dict) -> None:
    """Validate a case's scene description without building it.

    Parameters
    ----------
    spec : dict
        The case's ``scene`` entry (see :func:`build_scene`).

    Raises
    ------
    BenchError
        On an unknown scene or generator, parameters the generator does not
        accept (the message lists what is allowed), or a length (``*_m``)
        that is not a positive number or an angle (``*_deg``) that is not a
        finite one.
    """
    from benchmarks.heightfields import check_heightfield, is_heightfield

    if not isinstance(spec, dict):
        raise BenchError(f"a case scene must be a mapping with 'builtin', 'generator', 'file' or 'heightfield', "
                         f"got {spec!r}")
    if is_heightfield(spec):
        check_heightfield(spec)
        return
    if "file" in spec:
        check_scene_file(spec)
        return
    if "builtin" in spec:
        if set(spec) != {"builtin"}:
            raise BenchError(f"a built-in scene takes no parameters, got {sorted(set(spec) - {'builtin'})}")
        if spec["builtin"] not in scenes.names():
            raise BenchError(f"unknown built-in scene {spec['builtin']!r}; available: {', '.join(scenes.names())}")
        return
    if "generator" not in spec:
        raise BenchError(f"a case scene needs 'builtin', 'generator', 'file' or 'heightfield', got keys {sorted(spec)}")
    name = spec["generator"]
    if name not in _GENERATORS:
        raise BenchError(f"unknown scene generator {name!r}; available: {', '.join(generator_names())}")
    allowed = list(inspect.signature(_GENERATORS[name][1]).parameters)
    unknown = sorted(set(spec) - {"generator"} - set(allowed))
    if unknown:
        raise BenchError(f"scene generator {name!r} has no parameter(s) {unknown}; allowed: {allowed}")
    for key, value in spec.items():
        if key.endswith(("_m", "_deg")) and not (isinstance(value, (int, float)) and math.isfinite(value)):
            raise BenchError(f"scene generator {name!r}: {key} must be a finite number, got {value!r}")
        if key.endswith("_m") and value <= 0:
            raise BenchError(f"scene generator {name!r}: {key} is a length or distance in metres and must be "
                             f"positive, got {value!r}")


def build_scene(spec: dict) -> Scene:
    """Build the scene a case describes.

    Parameters
    ----------
    spec : dict
        ``{"builtin": NAME}`` for a scene of the :mod:`scenes` library, or
        ``{"generator": NAME, **params}`` for a generator of this module.

    Returns
    -------
    Scene
        With its scanner section.

    Raises
    ------
    BenchError
        As :func:`check_scene`, or when the generator rejects a value.
    """
    check_scene(spec)
    if "heightfield" in spec:
        raise BenchError("a height-field case has no scene to scan (see benchmarks.heightfields)")
    if "builtin" in spec:
        return scenes.build(spec["builtin"])
    if "file" in spec:
        try:
            return scenes.load_scene_file(spec["file"])
        except scenes.SceneError as exc:
            raise BenchError(f"scene file: {exc}") from None
    try:
        scene = _GENERATORS[spec["generator"]][1](**{k: v for k, v in spec.items() if k != "generator"})
    except (scenes.SceneError, TypeError) as exc:
        raise BenchError(f"scene generator {spec['generator']!r}: {exc}") from None
    scene.name = spec["generator"]
    return scene


def file_digest(path) -> str:
    """SHA-256 of a file's bytes (hex)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def check_scene_file(spec: dict) -> None:
    """Validate a scene-file description ``{"file": absolute path, "sha256": digest}`` (see :func:`resolve_scene_file`).

    Raises
    ------
    BenchError
        On other keys, a missing file, or a file whose bytes no longer match the digest.
    """
    unknown = sorted(set(spec) - {"file", "sha256"})
    if unknown:
        raise BenchError(f"a scene file entry takes only 'file', got {unknown}")
    path = spec["file"]
    if not isinstance(path, str) or not Path(path).is_file():
        raise BenchError(f"scene file {path!r} not found")
    if "sha256" in spec and file_digest(path) != spec["sha256"]:
        raise BenchError(f"scene file {path!r} changed since its suite was read: start a new run")


def resolve_scene_file(spec: dict, base_dir) -> dict:
    """A case's ``{"file": PATH}`` made absolute (relative to ``base_dir``, the suite file's directory), with the
    file's digest; the scene is built once to check it.

    Parameters
    ----------
    spec : dict
        The case's scene entry, ``{"file": PATH}``.
    base_dir : str or Path
        Directory relative paths are resolved against.

    Raises
    ------
    BenchError
        If the path is not a string, the file is missing or it is not a valid scene file (the message says why).
    """
    unknown = sorted(set(spec) - {"file"})
    if unknown:
        raise BenchError(f"a scene file entry takes only 'file' (the path, relative to the suite file), got {unknown}")
    if not isinstance(spec["file"], str) or not spec["file"]:
        raise BenchError(f"scene 'file' must be a path (relative to the suite file), got {spec['file']!r}")
    path = (Path(base_dir) / spec["file"]).resolve()
    if not path.is_file():
        raise BenchError(f"scene file {spec['file']!r} not found (looked for {path})")
    _load_checked(str(path), path.stat().st_mtime_ns)
    return {"file": str(path), "sha256": file_digest(path)}


@functools.lru_cache(maxsize=16)
def _load_checked(path: str, mtime_ns: int) -> None:
    """Build a scene file once per version (cases that share a file are checked once)."""
    try:
        scenes.load_scene_file(path)
    except scenes.SceneError as exc:
        raise BenchError(f"scene file {path!r} is not a valid scene: {exc}") from None


def elliptic_leaf(name: str, center, normal, midrib, length_m: float, width_m: float,
                  reflectance: float = LEAF_REFLECTANCE, segments: int = 96, rings: int = 8,
                  group: str = "") -> SceneObject:
    """A flat elliptic leaf blade with the leaf truth fields of the data contract.

    Parameters
    ----------
    name : str
        Object name.
    center : array_like, shape (3,)
        Blade centre, m.
    normal : array_like, shape (3,)
        Normal of the adaxial side.
    midrib : array_like, shape (3,)
        Direction from base to apex (projected into the blade plane).
    length_m, width_m : float
        Blade length (along the midrib) and full width, m.
    reflectance : float
        Lambertian reflectance at 785 nm.
    segments : int
        Outline vertices.
    rings : int
        Concentric rings of vertices between the centre and the outline.
    group : str, optional
        Group name of the object.

    Returns
    -------
    SceneObject
        Type ``leaf``; truth ``area_m2`` (of the mesh), ``normal``,
        ``elevation_deg`` and ``azimuth_deg`` of the midrib, ``outline``,
        ``length_m``, ``half_width_m``.
    """
    if not (length_m > 0 and width_m > 0):
        raise BenchError(f"leaf {name!r}: length_m and width_m must be positive, got {length_m}, {width_m}")
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    m = np.asarray(midrib, float)
    m = m - np.dot(m, n) * n
    m /= np.linalg.norm(m)
    across = np.cross(n, m)
    # Concentric rings of the outline, so that triangles stay small (about
    # length / (2 rings)) and the mesh is exactly the polygon of the outline.
    angle = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    fraction = np.arange(1, rings + 1) / rings
    local = np.vstack([np.zeros(2)] + [np.stack([0.5 * length_m * f * np.cos(angle),
                                                 0.5 * width_m * f * np.sin(angle)], axis=1) for f in fraction])
    c = np.asarray(center, float)
    vertices = c + np.outer(local[:, 0], m) + np.outer(local[:, 1], across)
    i = np.arange(segments)
    j = (i + 1) % segments

    def ring(k, index):  # vertex ids of ring k
        return 1 + k * segments + index

    # Counter-clockwise seen from the normal side, so face normals equal n.
    faces = [np.stack([np.zeros(segments, dtype=int), ring(0, i), ring(0, j)], axis=1)]
    for k in range(rings - 1):
        faces += [np.stack([ring(k, i), ring(k + 1, i), ring(k + 1, j)], axis=1),
                  np.stack([ring(k, i), ring(k + 1, j), ring(k, j)], axis=1)]
    faces = np.concatenate(faces)
    outline = vertices[ring(rings - 1, 0):]
    tri = vertices[faces]
    area = 0.5 * float(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())
    elevation, azimuth = direction_angles_deg(m)
    truth = {"area_m2": area, "normal": n.tolist(), "elevation_deg": elevation, "azimuth_deg": azimuth,
             "outline": outline.tolist(), "length_m": float(length_m), "half_width_m": 0.5 * float(width_m)}
    return SceneObject(name, "leaf", vertices, faces, Material("leaf", float(reflectance)), truth, group)


def direction_angles_deg(direction) -> tuple[float, float]:
    """Elevation above the horizontal ([-90, 90]) and azimuth from +x counter-clockwise ([0, 360)), degrees."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    elevation = math.degrees(math.asin(float(np.clip(d[2], -1.0, 1.0))))
    azimuth = math.degrees(math.atan2(d[1], d[0])) % 360.0
    return elevation, azimuth


def rotate(vector, axis, angle_rad: float) -> np.ndarray:
    """``vector`` rotated by ``angle_rad`` about the unit ``axis`` (Rodrigues).

    Parameters
    ----------
    vector : array_like
        Vector to rotate, shape ``(3,)`` (any unit).
    axis : array_like
        Rotation axis, shape ``(3,)``; normalised here.
    angle_rad : float
        Rotation angle, rad (right-handed about ``axis``).

    Returns
    -------
    ndarray
        The rotated vector, in the unit of ``vector``.
    """
    v, k = np.asarray(vector, float), np.asarray(axis, float) / np.linalg.norm(axis)
    return v * math.cos(angle_rad) + np.cross(k, v) * math.sin(angle_rad) + k * np.dot(k, v) * (1 - math.cos(angle_rad))


def scanner_window(objects: list[SceneObject], margin_deg: float = 0.4) -> dict:
    """Scanner section (scanner at the origin) whose window covers ``objects`` with a margin.

    The margin must exceed the beam footprint radius plus a few angular
    steps, so that every pulse touching an object lies in the window (0.4 deg
    covers the FARO LS880 footprint at 0.6 m and five 0.072 deg steps).

    Parameters
    ----------
    objects : list of SceneObject
        Objects the window must cover (vertices in m, scanner at the origin).
    margin_deg : float
        Margin on every side of the window, degrees.

    Returns
    -------
    dict
        Scanner section: ``preset``, ``position`` (m) and ``window`` with
        ``theta_deg`` and ``psi_deg`` ranges, degrees.
    """
    points = np.vstack([o.vertices for o in objects])
    theta = np.degrees(np.arctan2(points[:, 1], points[:, 0]))
    psi = np.degrees(np.arccos(points[:, 2] / np.linalg.norm(points, axis=1)))
    return {"preset": "faro-ls880", "position": [0.0, 0.0, 0.0],
            "window": {"theta_deg": [float(theta.min() - margin_deg), float(theta.max() + margin_deg)],
                       "psi_deg": [float(psi.min() - margin_deg), float(psi.max() + margin_deg)]}}


def background_wall(objects: list[SceneObject], distance_m: float, reflectance: float,
                    margin_deg: float = 1.0) -> SceneObject:
    """A wall facing the scanner at ``distance_m`` along +x, wide enough to fill the window behind ``objects``.

    Parameters
    ----------
    objects : list of SceneObject
        Objects the wall stands behind (vertices in m, scanner at the origin).
    distance_m : float
        Distance of the wall from the scanner along +x, m.
    reflectance : float
        Diffuse reflectance of the wall, 0..1.
    margin_deg : float
        Angular margin beyond the objects, degrees.

    Returns
    -------
    SceneObject
        A square plane named ``background`` facing -x.
    """
    points = np.vstack([o.vertices for o in objects])
    half_angle = math.radians(margin_deg) + np.max(np.arccos(points[:, 0] / np.linalg.norm(points, axis=1)))
    half = distance_m * math.tan(min(half_angle, math.radians(80.0))) + 0.05
    vertices, faces = rectangle((distance_m, 0.0, 0.0), (-1.0, 0.0, 0.0), (2 * half, 2 * half))
    return SceneObject("background", "plane", vertices, faces, Material("background", float(reflectance)),
                       {"normal": [-1.0, 0.0, 0.0]})


@generator("plate-leaf", "one flat elliptic leaf (pear size by default) in front of a background wall; "
                         "distance, incidence, size, reflectance and scanner settings are parameters")
def plate_leaf(distance_m: float = 1.5, incidence_deg: float = 0.0, axis: str = "vertical",
               length_m: float = PEAR_LENGTH_M, width_m: float | None = None, roll_deg: float = 60.0,
               reflectance: float = LEAF_REFLECTANCE, background_gap_m: float | None = 0.5,
               background_reflectance: float = 0.3) -> Scene:
    """One flat elliptic leaf facing the scanner, tilted by the incidence angle.

    Parameters
    ----------
    distance_m : float
        Scanner-to-leaf-centre distance along +x, m.
    incidence_deg : float
        Angle between the leaf normal and the direction to the scanner, degrees.
    axis : {"vertical", "horizontal"}
        Axis the leaf is tilted about.
    length_m : float
        Blade length, m (the thesis' ROP protocol used leaves of about 9 cm).
    width_m : float, optional
        Blade width, m (default: the pear ratio, 0.68 of the length).
    roll_deg : float
        Angle of the midrib from the blade's "up" direction, degrees; 60 gives
        a midrib 30 deg above the horizontal on an untilted leaf, so that both
        its elevation and azimuth are defined.
    reflectance : float
        Leaf reflectance (0.48: digest §7.12).
    background_gap_m : float or None
        Distance from the leaf to a wall behind it, m; ``None`` for no
        background (edge pulses then keep the leaf distance and lose power).
    background_reflectance : float
        Reflectance of the wall (default 0.3, a canopy-like background: assumption).
    """
    if axis not in ("vertical", "horizontal"):
        raise BenchError(f"plate-leaf axis must be 'vertical' or 'horizontal', got {axis!r}")
    if not 0.0 <= incidence_deg < 90.0:
        raise BenchError(f"plate-leaf incidence_deg must lie in [0, 90), got {incidence_deg}")
    if not distance_m > 0.6:
        raise BenchError(f"plate-leaf distance_m must exceed the 0.6 m minimum range, got {distance_m}")
    width_m = PEAR_WIDTH_RATIO * length_m if width_m is None else width_m
    center = np.array([distance_m, 0.0, 0.0])
    to_scanner = -center / distance_m
    tilt_axis = (0.0, 0.0, 1.0) if axis == "vertical" else np.cross(to_scanner, (0.0, 0.0, 1.0))
    normal = rotate(to_scanner, tilt_axis, math.radians(incidence_deg))
    u, v, _ = orthonormal_frame(normal)
    midrib = math.cos(math.radians(roll_deg)) * v + math.sin(math.radians(roll_deg)) * u
    leaf = elliptic_leaf("leaf", center, normal, midrib, length_m, width_m, reflectance)
    objects = [leaf]
    if background_gap_m is not None:
        objects.append(background_wall(objects, distance_m + background_gap_m, background_reflectance))
    return Scene(objects, scanner_window([leaf]))


@generator("analytic-surface", "an analytic test surface of the PROP-SFS thesis (scenes.surfaces: hemisphere, "
                               "ellipsoid, cone, saddles, ...) facing the scanner, in front of a background wall")
def analytic_surface(surface: str = "hemisphere", distance_m: float = 1.5, size_m: float = 0.08,
                     surface_params: dict | None = None, resolution: int = 101,
                     reflectance: float = LEAF_REFLECTANCE, background_gap_m: float | None = 0.5,
                     background_reflectance: float = 0.3) -> Scene:
    """One analytic surface of :mod:`scenes.surfaces`, its +z axis towards the scanner.

    Parameters
    ----------
    surface : str
        Surface name (``scenes.surfaces.SURFACE_NAMES``).
    distance_m : float
        Distance from the scanner to the surface's base point, m.
    size_m : float
        World size of the longest side of the surface's domain, m (8 cm: leaf size).
    surface_params : dict, optional
        Parameters of the surface (radians for angles).
    resolution : int
        Mesh vertices per axis (101 keeps facets under a quarter of the
        footprint for an 8 cm surface beyond 1 m).
    reflectance : float
        Lambertian reflectance of the surface.
    background_gap_m, background_reflectance : float
        Wall behind the surface (``None``: no wall).
    """
    from scenes.surfaces import surface_object

    obj = surface_object(surface, distance_m, size_m, params=surface_params, resolution=resolution,
                         material=Material("leaf", float(reflectance)))
    objects = [obj]
    if background_gap_m is not None:
        objects.append(background_wall(objects, distance_m + background_gap_m, background_reflectance))
    return Scene(objects, scanner_window([obj]))


@generator("single-leaf", "one procedural pear leaf (scenes package: outline, petiole, bending, roll, wrinkles) in "
                          "front of a background wall; distance, incidence, size, shape seed and reflectance")
def single_leaf(distance_m: float = 1.5, incidence_deg: float = 0.0, axis: str = "vertical",
                length_m: float = PEAR_LENGTH_M, seed: int = 0, spin_deg: float = 30.0,
                reflectance: float | None = None, background_gap_m: float | None = 0.5,
                background_reflectance: float = 0.3) -> Scene:
    """One procedural pear leaf of :mod:`scenes` facing the scanner, tilted by the incidence angle.

    Parameters
    ----------
    distance_m : float
        Scanner-to-blade-centroid distance along +x, m.
    incidence_deg : float
        Angle between the blade's mean normal direction (its local +z) and
        the direction to the scanner, degrees.
    axis : {"vertical", "horizontal"}
        Axis the leaf is tilted about.
    length_m : float
        Blade length, m (pear default 6.5 cm; the thesis' ROP protocol used about 9 cm).
    seed : int
        Seed of the leaf's shape (outline, bending, roll, wrinkles).
    spin_deg : float
        Rotation of the midrib about the blade normal before the tilt,
        degrees (from the horizontal; 30 gives a midrib elevation and
        azimuth that are both defined).
    reflectance : float, optional
        Leaf reflectance (default: the ``pear-leaf`` library material).
    background_gap_m, background_reflectance : float
        Wall behind the leaf (``None``: no wall).
    """
    if axis not in ("vertical", "horizontal"):
        raise BenchError(f"single-leaf axis must be 'vertical' or 'horizontal', got {axis!r}")
    leaf = {"name": "leaf", "type": "leaf", "preset": "pear", "seed": seed, "length": length_m,
            "material": "pear-leaf" if reflectance is None else {"reflectance": reflectance},
            "pose": {"center": [distance_m, 0.0, 0.0], "facing": "scanner", "spin_deg": spin_deg,
                     "incidence_deg": incidence_deg, "rotation_axis": axis}}
    blade = scenes.scene_from_spec({"objects": [leaf]}, source="single-leaf").objects[0]
    objects = [blade]
    if background_gap_m is not None:
        objects.append(background_wall(objects, distance_m + background_gap_m, background_reflectance))
    return Scene(objects, scanner_window([blade]))


@generator("branch", "one straight woody branch (a closed cylinder of the scenes package, truth cylinders for "
                     "woody scoring) standing upright in front of the scanner")
def branch(distance_m: float = 3.0, radius_m: float = 0.05, length_m: float = 0.6, tilt_deg: float = 0.0) -> Scene:
    """A cylinder standing at ``distance_m`` along +x, tilted by ``tilt_deg`` towards the scanner.

    Parameters
    ----------
    distance_m : float
        Distance from the scanner to the axis, m.
    radius_m, length_m : float
        Cylinder radius and length, m.
    tilt_deg : float
        Rotation of the axis about +y, degrees (0: vertical).
    """
    spec = {"objects": [{"name": "branch", "type": "cylinder", "radius": radius_m, "length": length_m,
                         "material": "bark", "pose": {"translate": [distance_m, 0.0, 0.0],
                                                      "rotate": {"axis": [0, 1, 0], "angle_deg": tilt_deg}}}]}
    wood = scenes.scene_from_spec(spec, source="branch").objects[0]
    return Scene([wood], scanner_window([wood]))


@generator("tree", "a procedural tree of the scenes package with its leaves (preset, seed, leaf count), standing "
                   "distance_m in front of the scanner, turned heading_deg about its trunk, optionally before a wall; the "
                   "window covers the whole tree")
def tree(preset: str = "conference-pear", seed: int = 1, distance_m: float = 4.0, base_below_m: float = 1.3,
         leaf_count: int | None = None, heading_deg: float = 0.0, background_gap_m: float | None = None,
         background_reflectance: float = 0.3) -> Scene:
    """A tree grown by :func:`scenes.tree.grow_tree` from a preset and a seed (``leafy-tree`` is preset
    ``conference-pear``, seed 1, 4 m, base 1.3 m below the scanner, no wall).

    Parameters
    ----------
    preset : str
        Tree preset of :mod:`scenes.tree` (``conference-pear``, ``apple``, ...).
    seed : int
        Seed of the tree's growth and leaves.
    distance_m : float
        Distance from the scanner to the trunk's base along +x, m.
    base_below_m : float
        Height of the scanner above the trunk's base, m.
    leaf_count : int, optional
        Number of leaves (default: the preset's).
    heading_deg : float
        Turn of the tree about the vertical through its trunk's base, deg (counter-clockwise seen from above;
        0: as grown, e.g. a vine's cordons along the line of sight, 90: across it as seen from an inter-row).
    background_gap_m, background_reflectance : float
        Wall behind the trunk (``None``: no wall, the tree against the sky).
    """
    entry = {"name": "tree", "type": "tree", "preset": preset, "seed": seed,
             "pose": {"translate": [distance_m, 0.0, -base_below_m]}}
    if heading_deg:
        entry["pose"]["rotate"] = {"axis": [0.0, 0.0, 1.0], "angle_deg": heading_deg}
    if leaf_count is not None:
        entry["leaf_count"] = leaf_count
    objects = scenes.scene_from_spec({"scanner": {"preset": "faro-ls880", "position": [0, 0, 0]},
                                      "objects": [entry]}, source="tree").objects
    window = scanner_window(objects, margin_deg=1.0)
    if background_gap_m is not None:
        objects = objects + [background_wall(objects, distance_m + background_gap_m, background_reflectance)]
    return Scene(objects, window)

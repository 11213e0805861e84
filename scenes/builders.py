"""Object types of the scene description: one builder per ``type``.

Each builder reads its entry's fields (through :class:`~scenes.fields.Fields`,
so mistakes are reported with the file, object, field and allowed values)
and returns the entry's :class:`~scenes.scene.SceneObject` list. Lengths are
metres, angles ``*_deg`` degrees. See ``docs/scene-format.md`` for the
fields of every type.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenes.errors import SceneError
from scenes.fields import Fields
from scenes.leaf import PEAR, leaf_objects, sample_pear_leaf
from scenes.materials import material_from_spec
from scenes.pose import Pose, pose_from_spec
from scenes.primitives import cross, facet_size_m, rectangle
from scenes.scene import Material, SceneObject
from scenes.shapes import box_mesh, disk_mesh, ellipsoid_mesh, frustum_volume, tube_mesh
from scenes.surfaces import SURFACE_NAMES, get_surface, surface_mesh, surface_parameters, surface_truth
from scenes.tree import (LEAF_ANGLE_DISTRIBUTIONS, PRESETS, LeafBatch, grow_tree, tree_objects, v_trellis_leaders,
                         wood_object)

#: Default material of geometric objects.
DEFAULT_MATERIAL = Material("lambert-0.5", 0.5)


@dataclass(frozen=True)
class Context:
    """What builders need to know about the scene around an entry."""

    scanner: dict
    scanner_position: np.ndarray
    base_dir: Path


def _material(f: Fields, key: str = "material", default=DEFAULT_MATERIAL) -> Material:
    value = f.raw(key, None)
    return default if value is None else material_from_spec(value, f"{f.where}: field {key!r}")


def _population_material(f: Fields, key: str, default: str):
    """A library name (drawn per object later) or a fixed Material."""
    value = f.raw(key, default)
    if isinstance(value, str):
        material_from_spec(value, f"{f.where}: field {key!r}")  # validates the name
        return value
    return material_from_spec(value, f"{f.where}: field {key!r}")


def _pose(f: Fields, ctx: Context) -> Pose:
    return pose_from_spec(f.raw("pose", None), ctx.scanner_position, f.where)


def _rigid_pose(f: Fields, ctx: Context) -> Pose:
    pose = _pose(f, ctx)
    if not math.isclose(pose.scale, 1.0):
        raise SceneError(f"{f.where}, pose: field 'scale': this type cannot be scaled (got {pose.scale}); "
                         "change its size fields instead")
    return pose


def _distance(ctx: Context, pose: Pose) -> float:
    return float(np.linalg.norm(pose.translation - ctx.scanner_position))


def _single(f: Fields, name: str, kind: str, vertices, faces, pose: Pose, truth: dict | None = None):
    return [SceneObject(name, kind, pose.apply(vertices), faces, _material(f), truth=truth or {})]


def build_plane(f: Fields, name: str, ctx: Context):
    """A flat rectangle centred on its pose, normal along the pose's +z.

    Parameters
    ----------
    f : Fields
        The entry's fields: ``size`` [width, height] (m), ``pose``, ``material``.
    name : str
        Name of the entry.
    ctx : Context
        Scanner description, scanner position and base directory of the scene file.

    Returns
    -------
    list of SceneObject
        One object in world coordinates (m), with its ground truth (``center``, ``normal``, ``area_m2``).
    """
    width, height = f.vector("size", 2, positive=True, unit="m")
    vertices, faces = rectangle((0, 0, 0), (0, 0, 1), (width, height))
    pose = _pose(f, ctx)
    return _single(f, name, "plane", vertices, faces, pose, _flat_truth(pose, width * height))


def build_disk(f: Fields, name: str, ctx: Context):
    """A flat round disk centred on its pose, normal along the pose's +z.

    Parameters
    ----------
    f : Fields
        The entry's fields: ``radius`` (m), ``segments``, ``pose``, ``material``.
    name : str
        Name of the entry.
    ctx : Context
        Scanner description, scanner position and base directory of the scene file.

    Returns
    -------
    list of SceneObject
        One object in world coordinates (m), with its ground truth (``center``, ``normal``, ``area_m2``).
    """
    radius = f.number("radius", positive=True, unit="m")
    vertices, faces = disk_mesh(radius, f.number("segments", None, integer=True, low=3))
    pose = _pose(f, ctx)
    return _single(f, name, "disk", vertices, faces, pose, _flat_truth(pose, math.pi * radius**2))


def _flat_truth(pose: Pose, area: float) -> dict:
    return {"center": pose.translation.tolist(), "normal": pose.rotate([0.0, 0.0, 1.0]).tolist(),
            "area_m2": float(area * pose.scale**2)}


def build_box(f: Fields, name: str, ctx: Context):
    """An axis-aligned box (in its pose's frame) centred on its pose.

    Parameters
    ----------
    f : Fields
        The entry's fields: ``size`` [x, y, z] (m), ``pose``, ``material``.
    name : str
        Name of the entry.
    ctx : Context
        Scanner description, scanner position and base directory of the scene file.

    Returns
    -------
    list of SceneObject
        One object in world coordinates (m), with its ground truth (``center``, ``size_m``).
    """
    size = f.vector("size", 3, positive=True, unit="m")
    vertices, faces = box_mesh(size)
    pose = _pose(f, ctx)
    return _single(f, name, "box", vertices, faces, pose,
                   {"center": pose.translation.tolist(), "size_m": (size * pose.scale).tolist()})


def build_sphere(f: Fields, name: str, ctx: Context):
    """A sphere centred on its pose.

    Parameters
    ----------
    f : Fields
        The entry's fields: ``radius`` (m), ``pose``, ``material``.
    name : str
        Name of the entry.
    ctx : Context
        Scanner description, scanner position and base directory of the scene file.

    Returns
    -------
    list of SceneObject
        One object in world coordinates (m), with its ground truth (``center``, ``radius_m``).
    """
    radius = f.number("radius", positive=True, unit="m")
    vertices, faces = ellipsoid_mesh([radius] * 3)
    pose = _pose(f, ctx)
    return _single(f, name, "sphere", vertices, faces, pose,
                   {"center": pose.translation.tolist(), "radius_m": radius * pose.scale})


def build_ellipsoid(f: Fields, name: str, ctx: Context):
    """An ellipsoid with semi-axes along its pose's x, y, z.

    Parameters
    ----------
    f : Fields
        The entry's fields: ``radii`` [a, b, c] (m), ``pose``, ``material``.
    name : str
        Name of the entry.
    ctx : Context
        Scanner description, scanner position and base directory of the scene file.

    Returns
    -------
    list of SceneObject
        One object in world coordinates (m), with its ground truth (``center``, ``radii_m``).
    """
    radii = f.vector("radii", 3, positive=True, unit="m")
    vertices, faces = ellipsoid_mesh(radii)
    pose = _pose(f, ctx)
    return _single(f, name, "ellipsoid", vertices, faces, pose,
                   {"center": pose.translation.tolist(), "radii_m": (radii * pose.scale).tolist()})


def _build_tube(f: Fields, name: str, ctx: Context, kind: str, caps_default: bool, cone: bool = False):
    radius = f.number("radius", positive=True, unit="m")
    length = f.number("length", positive=True, unit="m")
    radius_end = 0.0 if cone else f.number("radius_end", radius, low=0.0, unit="m")
    caps = f.flag("caps", caps_default)
    vertices, faces = tube_mesh(radius, length, radius_end, caps, f.number("sides", None, integer=True, low=3))
    pose = _pose(f, ctx)
    start, end = pose.apply([[0.0, 0.0, -length / 2], [0.0, 0.0, length / 2]])
    cylinder = {"id": 0, "parent": -1, "order": 0, "branch": 0, "start": start.tolist(), "end": end.tolist(),
                "radius_m": radius * pose.scale, "radius_end_m": radius_end * pose.scale}
    volume = float(frustum_volume(length, radius, radius_end)) * pose.scale**3
    return _single(f, name, kind, vertices, faces, pose, {"cylinders": [cylinder], "volume_m3": volume})


def build_cylinder(f: Fields, name: str, ctx: Context):
    """A closed (capped by default) cylinder along its pose's z, centred on the pose.

    Parameters
    ----------
    f : Fields
        The entry's fields: ``radius``, ``length``, ``radius_end`` (m), ``caps``, ``sides``, ``pose``, ``material``.
    name : str
        Name of the entry.
    ctx : Context
        Scanner description, scanner position and base directory of the scene file.

    Returns
    -------
    list of SceneObject
        One object in world coordinates (m), with its ground truth (one ``cylinders`` record, ``volume_m3``).
    """
    return _build_tube(f, name, ctx, "cylinder", caps_default=True)


def build_tube(f: Fields, name: str, ctx: Context):
    """An open (uncapped by default) cylinder along its pose's z, centred on the pose.

    Parameters
    ----------
    f : Fields
        The entry's fields: ``radius``, ``length``, ``radius_end`` (m), ``caps``, ``sides``, ``pose``, ``material``.
    name : str
        Name of the entry.
    ctx : Context
        Scanner description, scanner position and base directory of the scene file.

    Returns
    -------
    list of SceneObject
        One object in world coordinates (m), with its ground truth (one ``cylinders`` record, ``volume_m3``).
    """
    return _build_tube(f, name, ctx, "tube", caps_default=False)


def build_cone(f: Fields, name: str, ctx: Context):
    """A cone along its pose's z (apex at +z), centred on the pose, capped by default.

    Parameters
    ----------
    f : Fields
        The entry's fields: ``radius``, ``length`` (m), ``caps``, ``sides``, ``pose``, ``material``.
    name : str
        Name of the entry.
    ctx : Context
        Scanner description, scanner position and base directory of the scene file.

    Returns
    -------
    list of SceneObject
        One object in world coordinates (m), with its ground truth (one ``cylinders`` record, ``volume_m3``).
    """
    return _build_tube(f, name, ctx, "cone", caps_default=True, cone=True)


def build_surface(f: Fields, name: str, ctx: Context):
    """An analytic height field (:mod:`scenes.surfaces`) meshed finer than the scanner resolves.

    Angle parameters are given as ``<name>_deg`` and converted to radians; the default grid
    resolution follows :func:`~scenes.primitives.facet_size_m` at the surface's distance.

    Parameters
    ----------
    f : Fields
        The entry's fields: ``surface``, ``params``, ``size`` (m), ``resolution``, ``pose``, ``material``.
    name : str
        Name of the entry.
    ctx : Context
        Scanner description, scanner position and base directory of the scene file.

    Returns
    -------
    list of SceneObject
        One object in world coordinates (m), with its ground truth from :func:`~scenes.surfaces.surface_truth`.
    """
    surface_name = f.choice("surface", SURFACE_NAMES)
    params = dict(f.sub("params", {}).data)
    for key in [k for k in params if isinstance(k, str) and k.endswith("_deg")]:
        value = params.pop(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise f.error("params", f"{key} must be a number of degrees, got {value!r}")
        params[key[:-4]] = math.radians(value)
    allowed = surface_parameters(surface_name)
    if set(params) - set(allowed):
        raise f.error("params", f"unknown parameter(s) {sorted(set(params) - set(allowed))} for surface "
                                f"{surface_name!r}; allowed: {sorted(allowed) or 'none'} (angles as <name>_deg)")
    try:
        surface = get_surface(surface_name, **params)
    except SceneError as exc:
        raise f.error("params", str(exc)) from None
    size = f.number("size", positive=True, unit="m")
    pose = _pose(f, ctx)
    facet = facet_size_m(_distance(ctx, pose), ctx.scanner)
    resolution = f.number("resolution", min(1001, math.ceil(size / facet) + 1), integer=True, low=2)
    local, faces, scale, center = surface_mesh(surface, size, resolution)
    return _single(f, name, "surface", local, faces, pose, surface_truth(surface, pose, scale, center))


#: Mesh file formats read through trimesh.
MESH_FORMATS = (".obj", ".ply", ".stl")


def _resolve(f: Fields, ctx: Context, allowed: tuple[str, ...]) -> Path:
    raw = f.text("file")
    path = Path(raw).expanduser()
    path = path if path.is_absolute() else ctx.base_dir / path
    if path.suffix.lower() not in allowed:
        raise f.error("file", f"{raw!r} has an unsupported extension; allowed: {', '.join(allowed)}")
    if not path.is_file():
        raise f.error("file", f"{raw!r} not found (looked for {path})")
    return path


def build_mesh(f: Fields, name: str, ctx: Context):
    """A triangle mesh read from an OBJ, PLY or STL file; zero-area triangles are dropped.

    Parameters
    ----------
    f : Fields
        The entry's fields: ``file`` (relative to the scene file), ``pose``, ``material``.
    name : str
        Name of the entry.
    ctx : Context
        Scanner description, scanner position and base directory of the scene file.

    Returns
    -------
    list of SceneObject
        One object in world coordinates (m), with its ground truth (``file``, ``area_m2``).
    """
    import trimesh

    path = _resolve(f, ctx, MESH_FORMATS)
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for malformed files
        raise f.error("file", f"cannot read {path.name} as a triangle mesh ({exc})") from None
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=float)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(faces) == 0:
        raise f.error("file", f"{path.name} contains no triangles")
    if not np.all(np.isfinite(vertices)):
        raise f.error("file", f"{path.name} has NaN or infinite vertex coordinates")
    tri = vertices[faces]
    good = np.linalg.norm(cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1) > 0
    if not good.any():
        raise f.error("file", f"{path.name} is degenerate: all {len(faces)} triangles have zero area")
    pose = _pose(f, ctx)
    obj = _single(f, name, "mesh", vertices, faces[good], pose, {"file": path.name})
    obj[0].truth["area_m2"] = float(obj[0].face_areas().sum())
    return obj


def _leaf_shape(f: Fields):
    """A leaf shape from the entry's preset, seed and explicit overrides."""
    f.choice("preset", ("pear",), "pear")
    seed = f.number("seed", None, integer=True, low=0)
    shape = PEAR if seed is None else sample_pear_leaf(np.random.default_rng(seed))
    changes = {}
    for key, field_name, unit in (("length", "length_m", "m"), ("half_width", "half_width_m", "m"),
                                  ("petiole_length", "petiole_length_m", "m"),
                                  ("petiole_radius", "petiole_radius_m", "m"),
                                  ("wrinkle_amplitude", "wrinkle_amplitude_m", "m"),
                                  ("wrinkle_wavelength", "wrinkle_wavelength_m", "m"),
                                  ("base_exponent", "base_exponent", ""), ("apex_exponent", "apex_exponent", ""),
                                  ("serration_depth", "serration_depth", "")):
        if key in f:
            changes[field_name] = f.number(key, unit=unit)
    if "serration_teeth" in f:
        changes["serration_teeth"] = f.number("serration_teeth", integer=True, low=1)
    for key in ("bend", "roll", "twist"):
        if f"{key}_deg" in f:
            changes[key] = math.radians(f.number(f"{key}_deg", unit="deg"))
    if "length_m" in changes and "half_width_m" not in changes:  # keep the drawn proportions
        ratio = changes["length_m"] / shape.length_m
        changes["half_width_m"] = shape.half_width_m * ratio
        changes.setdefault("petiole_length_m", shape.petiole_length_m * ratio)
    try:
        return shape.replace(**changes), seed
    except SceneError as exc:
        raise SceneError(f"{f.where}: {exc}") from None


def build_leaf(f: Fields, name: str, ctx: Context):
    """One pear leaf (preset shape, or drawn from ``seed``, with per-field overrides).

    Parameters
    ----------
    f : Fields
        The entry's fields: ``preset``, ``seed``, shape overrides (m, ``*_deg``), ``facet`` (m), ``pose``, ``material``.
    name : str
        Name of the entry.
    ctx : Context
        Scanner description, scanner position and base directory of the scene file.

    Returns
    -------
    list of SceneObject
        One object: the leaf (blade and petiole in one mesh, world coordinates, m) with its ground truth.
    """
    shape, seed = _leaf_shape(f)
    pose = _rigid_pose(f, ctx)
    facet = f.number("facet", facet_size_m(_distance(ctx, pose), ctx.scanner), positive=True, unit="m")
    material = _material(f, default=material_from_spec("pear-leaf"))
    extra = {"preset": "pear", "seed": seed}
    return leaf_objects([shape], pose.rotation[None], pose.translation[None], [name], [material], facet,
                        extra_truth=[extra])


def _leaf_options(f: Fields, default_detail: float):
    leafless = f.flag("leafless", False)
    count = f.number("leaf_count", None, integer=True, low=0)
    lad = f.choice("leaf_angle_distribution", tuple(LEAF_ANGLE_DISTRIBUTIONS), None) \
        if "leaf_angle_distribution" in f else None
    detail = f.number("leaf_detail", default_detail, positive=True)
    return (0 if leafless else count), lad, detail


def _leaf_facet(ctx: Context, detail: float):
    """Facet of population leaves: ``detail`` x the footprint diameter at each leaf's distance."""

    def facet(anchors):
        return facet_size_m(np.linalg.norm(anchors - ctx.scanner_position, axis=1), ctx.scanner, fraction=detail)

    return facet


def build_tree(f: Fields, name: str, ctx: Context):
    """One grown tree (:func:`~scenes.tree.grow_tree`) placed at its pose.

    Parameters
    ----------
    f : Fields
        The entry's fields: ``preset``, ``seed``, ``leaf_count``, ``leafless``, ``leaf_angle_distribution``,
        ``leaf_detail``, ``overrides``, ``pose``, ``material``, ``leaf_material``.
    name : str
        Name of the entry; its objects are grouped under it.
    ctx : Context
        Scanner description, scanner position and base directory of the scene file.

    Returns
    -------
    list of SceneObject
        The woody object and one object per leaf, in world coordinates (m).
    """
    preset = f.choice("preset", tuple(PRESETS))
    seed = f.number("seed", 0, integer=True, low=0)
    count, lad, detail = _leaf_options(f, 1.0)
    overrides = dict(f.sub("overrides", {}).data)
    pose = _rigid_pose(f, ctx)
    try:
        model = grow_tree(preset, seed, leaf_count=count, leaf_angle_distribution=lad, **overrides)
    except (SceneError, TypeError) as exc:
        raise SceneError(f"{f.where}: {exc}") from None
    return tree_objects(model, pose, name, bark=_population_material(f, "material", "bark"),
                        leaf_material=_population_material(f, "leaf_material", "pear-leaf"),
                        leaf_facet_m=_leaf_facet(ctx, detail), seed=seed,
                        extra_truth={"preset": preset, "seed": seed})


#: Height of the new shoots above the leaders of a Conference tree, m (thesis ch.7: 2.43 m without the
#: new shoots, 2.95 m with them; our shoots reach about 0.4 m above the leader tips).
SHOOT_ALLOWANCE_M = 0.4


def build_orchard_row(f: Fields, name: str, ctx: Context):
    """Rows of V-trellised Conference pear trees with (optional) soil beneath.

    Trees stand ``tree_spacing`` apart along the pose's x, rows ``row_spacing`` apart along y;
    each tree's height is drawn uniformly from ``height`` [min, max] (m).

    Parameters
    ----------
    f : Fields
        The entry's fields: ``seed``, ``trees``, ``tree_spacing``, ``rows``, ``row_spacing``, ``height`` (m),
        ``v_aperture_deg``, ``leaders_per_side``, leaf options, ``ground``, materials, ``pose``.
    name : str
        Name of the entry; trees are grouped as ``<name>/tree-NN``.
    ctx : Context
        Scanner description, scanner position and base directory of the scene file.

    Returns
    -------
    list of SceneObject
        Per tree a woody object and its leaves, then the ground, in world coordinates (m).
    """
    f.choice("preset", ("conference-pear",), "conference-pear")
    seed = f.number("seed", 0, integer=True, low=0)
    n_trees = f.number("trees", 19, integer=True, low=1)
    spacing = f.number("tree_spacing", 1.05, positive=True, unit="m")
    rows = f.number("rows", 1, integer=True, low=1)
    row_spacing = f.number("row_spacing", 3.4, positive=True, unit="m")
    low, high = f.vector("height", 2, default=[2.4, 3.0], positive=True, unit="m")
    if high < low:
        raise f.error("height", f"must be [min, max] with min <= max, got {[low, high]}")
    aperture = f.number("v_aperture_deg", 40.0, low=0.0, high=120.0, unit="deg")
    per_side = f.number("leaders_per_side", 2, integer=True, low=1)
    count, lad, detail = _leaf_options(f, 2.0)
    ground = f.flag("ground", True)
    ground_material = _material(f, "ground_material", material_from_spec("soil"))
    bark = _population_material(f, "material", "bark")
    leaf_material = _population_material(f, "leaf_material", "pear-leaf")
    pose = _rigid_pose(f, ctx)

    trunk = PRESETS["conference-pear"].orders[0].length_m
    leaders = v_trellis_leaders(aperture, per_side)
    rng = np.random.default_rng([seed, 2])
    heights = rng.uniform(low, high, (rows, n_trees))
    objects, leaves = [], LeafBatch()
    for r in range(rows):
        for t in range(n_trees):
            tree_seed = int(rng.integers(2**31))
            # The leaders stop SHOOT_ALLOWANCE_M below the tree top; the new shoots make up the rest.
            leader = (heights[r, t] - SHOOT_ALLOWANCE_M - trunk) / min(d[2] for d in leaders)
            model = grow_tree("conference-pear", tree_seed, leaf_count=count, leaf_angle_distribution=lad,
                              order1_length_m=leader, order1_directions=leaders, order0_children=len(leaders),
                              order0_whorl=len(leaders))
            x = (t - (n_trees - 1) / 2) * spacing
            local = Pose(translation=np.array([x, r * row_spacing, 0.0]))
            group = f"{name}/tree-{r * n_trees + t + 1:02d}"
            tree_rng = np.random.default_rng([tree_seed, 1])
            objects.append(wood_object(model, local.then(pose), group, bark, tree_rng,
                                       {"preset": "conference-pear", "seed": tree_seed,
                                        "height_m": float(heights[r, t]), "row": r, "position": t}))
            leaves.add_tree(model, local.then(pose), group, leaf_material, tree_rng)
    objects += leaves.objects(_leaf_facet(ctx, detail))
    if ground:
        # Soil under the rows and the inter-rows on either side, 1 m beyond the end trees.
        length, width = n_trees * spacing + 2.0, (rows + 1) * row_spacing
        vertices, faces = rectangle((0.0, (rows - 1) * row_spacing / 2, 0.0), (0, 0, 1), (length, width),
                                    up=(0, 1, 0))
        objects.append(SceneObject(f"{name}/ground", "ground", pose.apply(vertices), faces, ground_material,
                                   truth=_flat_truth(pose, length * width), group=name))
    return objects


def build_mitsuba(f: Fields, name: str, ctx: Context):
    """The shapes of a Mitsuba 3 scene XML file, one object per shape.

    Parameters
    ----------
    f : Fields
        The entry's fields: ``file`` (relative to the scene file), ``pose``, ``material`` (overrides the file's).
    name : str
        Name of the entry; objects are named ``<name>/<shape id>``.
    ctx : Context
        Scanner description, scanner position and base directory of the scene file.

    Returns
    -------
    list of SceneObject
        One mesh object per shape, in world coordinates (m).
    """
    from scenes.mitsuba_xml import load_mitsuba_shapes

    path = _resolve(f, ctx, (".xml",))
    override = _material(f, default=None)
    pose = _pose(f, ctx)
    objects = []
    for shape_name, vertices, faces, material in load_mitsuba_shapes(path, f.where):
        objects.append(SceneObject(f"{name}/{shape_name}", "mesh", pose.apply(vertices), faces, override or material,
                                   truth={"file": path.name, "shape": shape_name}, group=name))
    return objects


#: Builders by object type (``tube`` is an open cylinder, ``height-field`` another name for ``surface``).
BUILDERS = {
    "plane": build_plane,
    "disk": build_disk,
    "box": build_box,
    "sphere": build_sphere,
    "ellipsoid": build_ellipsoid,
    "cylinder": build_cylinder,
    "tube": build_tube,
    "cone": build_cone,
    "surface": build_surface,
    "height-field": build_surface,
    "mesh": build_mesh,
    "leaf": build_leaf,
    "tree": build_tree,
    "orchard-row": build_orchard_row,
    "mitsuba": build_mitsuba,
}

#: Object types of the scene description.
OBJECT_TYPES: tuple[str, ...] = tuple(BUILDERS)


"""Procedural trees: tapered-tube skeletons with exact cylinder truth, plus leaves.

A tree grows from a :class:`TreePreset`: one :class:`OrderParams` per
branching order (0 = trunk). Every branch is a chain of straight, tapered
segments (frusta); each segment is one truth cylinder in the
``docs/contracts.md`` format. A branch of order ``k`` carries
``OrderParams.children`` branches of order ``k + 1``, inserted at evenly
spaced nodes over a span of its length (``whorl`` per node, turning by the
divergence angle from node to node), at the insertion angle from the parent
direction; lengths, angles and wandering are drawn from seeded normal
distributions. A child starts on its parent's axis (the usual QSM
convention); its base radius is a fraction of the parent's radius there.

Azimuths around a parent are measured from the parent's "upper side" (the
projection of world up on the plane perpendicular to the parent; +x for a
vertical parent), so ``azimuth 0`` is up and ±90 deg is sideways.

Leaves hang on the branches of order ``>= leaf_min_order``: nodes evenly
spaced over that wood so that the tree gets ``leaf_count`` leaves, turning by
144 deg (2/5 phyllotaxis); each petiole starts on the branch surface. Leaf
normals follow a leaf-angle distribution (:data:`LEAF_ANGLE_DISTRIBUTIONS`,
de Wit 1965) with uniform azimuth; the midrib points away from the branch
(projected into the leaf plane). Leaf sizes are pear draws
(:func:`~scenes.leaf.sample_pear_leaves`) times a log-normal size factor.
Leaves may touch each other or the wood; no collision test is made.

Presets (:data:`PRESETS`): ``apple`` (leafless apple-like tree, orders 0-4,
about 3 dm³ of wood, after Méndez et al.'s simulated apple: spec woody C.4),
``vine`` (trunk, two cordons, upright canes with laterals), ``conifer``
(16 m stem, 30 cm at the base, with whorls of 15 cm branch stubs: STEP DS3 /
woody C.3 S3), ``conference-pear`` (V-trellised Conference pear, leaders at
±20 deg from vertical, for orchard rows), ``shoot`` (a 30 cm leafy twig
growing sideways with eight planophile leaves) and ``cylinder`` (one cylinder,
radius 0.5 m, length 2 m: STEP DS1 / woody C.3 S1). Their numbers are
assumptions chosen to look like those set-ups, not measurements.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from scenes.errors import SceneError
from scenes.leaf import LeafShape, leaf_frame, leaf_objects, sample_pear_leaves
from scenes.materials import sample_material
from scenes.pose import Pose
from scenes.scene import Material, SceneObject
from scenes.shapes import frusta, frustum_volume, polygon_sides

#: Leaf-angle distributions: density g(θ) of the leaf normal's inclination θ from the zenith (de Wit 1965).
LEAF_ANGLE_DISTRIBUTIONS = {
    "spherical": lambda t: np.sin(t),
    "planophile": lambda t: 2 / np.pi * (1 + np.cos(2 * t)),
    "erectophile": lambda t: 2 / np.pi * (1 - np.cos(2 * t)),
    "plagiophile": lambda t: 2 / np.pi * (1 - np.cos(4 * t)),
    "extremophile": lambda t: 2 / np.pi * (1 + np.cos(4 * t)),
    "uniform": lambda t: np.full_like(t, 2 / np.pi),
}


def sample_leaf_inclination(distribution: str, rng: np.random.Generator, size: int) -> np.ndarray:
    """Draw leaf-normal inclinations from the zenith by inverse transform sampling.

    Parameters
    ----------
    distribution : str
        Key of :data:`LEAF_ANGLE_DISTRIBUTIONS`.
    rng : numpy.random.Generator
        Source of randomness.
    size : int
        Number of draws.

    Returns
    -------
    ndarray, shape (size,)
        Inclinations, rad in [0, π/2].
    """
    if distribution not in LEAF_ANGLE_DISTRIBUTIONS:
        raise SceneError(f"unknown leaf-angle distribution {distribution!r}; "
                         f"allowed: {', '.join(LEAF_ANGLE_DISTRIBUTIONS)}")
    grid = np.linspace(0.0, np.pi / 2, 2049)
    density = LEAF_ANGLE_DISTRIBUTIONS[distribution](grid)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(grid))])
    return np.interp(rng.uniform(0.0, cdf[-1], size), cdf, grid)


@dataclass(frozen=True)
class OrderParams:
    """Growth parameters of the branches of one order.

    Parameters
    ----------
    length_m : float
        Mean branch length, m.
    length_sd : float
        Relative standard deviation of the length.
    radius : float
        Order 0: base radius of the trunk, m. Higher orders: base radius as a
        fraction of the parent's radius at the insertion point.
    tip_ratio : float
        Tip radius / base radius (linear taper along the branch).
    angle_deg, angle_sd_deg : float
        Insertion angle from the parent direction, mean and sd, degrees.
    segments : int
        Segments (truth cylinders) per branch.
    wander_deg : float
        Sd of the random turn of the direction at each segment, degrees.
    tropism_deg : float
        Turn towards world up (negative: down) at each segment, degrees.
    children : int
        Number of child branches (of the next order) per branch.
    span : (float, float)
        Fractions of the branch length between which children are inserted.
    whorl : int
        Children per insertion node.
    divergence_deg : float
        Azimuth turn from one node to the next, degrees.
    azimuth_deg : float
        Azimuth of the first node (from the parent's upper side), degrees.
    directions : tuple of (x, y, z), optional
        Fixed tree-frame directions of this order's branches (overrides the
        angles), e.g. the leaders of a V trellis; for order 0 the trunk
        direction (default +z).
    from_surface : bool
        Measure the length from the parent's surface rather than its axis.
    """

    length_m: float
    radius: float
    tip_ratio: float = 0.3
    length_sd: float = 0.2
    angle_deg: float = 45.0
    angle_sd_deg: float = 8.0
    segments: int = 4
    wander_deg: float = 5.0
    tropism_deg: float = 0.0
    children: int = 0
    span: tuple[float, float] = (0.2, 0.95)
    whorl: int = 1
    divergence_deg: float = 137.5
    azimuth_deg: float = 0.0
    directions: tuple = ()
    from_surface: bool = False

    def __post_init__(self):
        checks = {"length_m": self.length_m > 0, "radius": self.radius > 0, "tip_ratio": 0 <= self.tip_ratio <= 1,
                  "length_sd": self.length_sd >= 0, "angle_sd_deg": self.angle_sd_deg >= 0,
                  "segments": self.segments >= 1, "children": self.children >= 0, "whorl": self.whorl >= 1,
                  "span": len(self.span) == 2 and 0 <= self.span[0] <= self.span[1] <= 1,
                  "directions": all(len(d) == 3 and np.linalg.norm(d) > 0 for d in self.directions)}
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise SceneError(f"invalid tree growth parameter(s) {bad}: lengths and radii must be positive, "
                             f"tip_ratio in [0, 1], counts >= 1 (children >= 0), span within [0, 1], "
                             f"directions non-zero 3-vectors; got {self}")


@dataclass(frozen=True)
class TreePreset:
    """A tree recipe: one :class:`OrderParams` per order, plus its leaves.

    Parameters
    ----------
    orders : tuple of OrderParams
        Index = branching order (0 = trunk).
    leaf_count : int
        Default number of leaves.
    leaf_min_order : int
        Lowest order that bears leaves.
    leaf_angle_distribution : str
        Key of :data:`LEAF_ANGLE_DISTRIBUTIONS`.
    leaf_size_median, leaf_size_sigma : float
        Log-normal size factor applied to the pear leaf draws (median and
        sigma of its logarithm).
    """

    orders: tuple[OrderParams, ...]
    leaf_count: int = 0
    leaf_min_order: int = 2
    leaf_angle_distribution: str = "spherical"
    leaf_size_median: float = 1.0
    leaf_size_sigma: float = 0.15


def v_trellis_leaders(aperture_deg: float = 40.0, per_side: int = 2, splay_deg: float = 12.0) -> tuple:
    """Directions of V-trellis leaders: ``per_side`` on each side of the row, leaning off vertical.

    Seen along the row (x), a leader leans ``aperture_deg / 2`` from vertical towards +y or -y;
    the leaders of one side fan out along x over ``[-splay_deg, +splay_deg]``.

    Parameters
    ----------
    aperture_deg : float
        Opening angle of the V between the two sides, degrees.
    per_side : int
        Leaders on each side.
    splay_deg : float
        Largest tilt along the row of a side's outer leaders, degrees (unused for one per side).

    Returns
    -------
    tuple of (float, float, float)
        ``2 per_side`` unit directions in the tree frame (z up): the +y side first.
    """
    lean = math.radians(aperture_deg / 2)
    splays = np.radians(np.linspace(-splay_deg, splay_deg, per_side)) if per_side > 1 else np.zeros(1)
    out = []
    for side in (1.0, -1.0):
        for s in splays:
            d = np.array([math.tan(s), side * math.tan(lean), 1.0])
            out.append(tuple(d / np.linalg.norm(d)))
    return tuple(out)


#: Named tree recipes (see the module docstring).
PRESETS: dict[str, TreePreset] = {
    "apple": TreePreset(orders=(
        OrderParams(1.6, 0.03, tip_ratio=0.25, length_sd=0.0, segments=8, wander_deg=2.0, children=8,
                    span=(0.35, 0.95)),
        OrderParams(0.8, 0.5, tip_ratio=0.2, length_sd=0.25, angle_deg=55, angle_sd_deg=10, segments=6,
                    wander_deg=6.0, tropism_deg=-1.0, children=6),
        OrderParams(0.35, 0.55, length_sd=0.3, angle_deg=45, angle_sd_deg=10, wander_deg=8.0, children=4),
        OrderParams(0.15, 0.6, length_sd=0.3, angle_deg=40, segments=3, wander_deg=8.0, children=2),
        OrderParams(0.07, 0.6, length_sd=0.3, angle_deg=40, segments=2, wander_deg=8.0),
    ), leaf_count=800),
    "vine": TreePreset(orders=(
        OrderParams(1.0, 0.03, tip_ratio=0.8, length_sd=0.0, segments=4, wander_deg=1.0, children=2,
                    span=(1.0, 1.0), whorl=2),
        OrderParams(1.0, 0.8, tip_ratio=0.5, length_sd=0.05, segments=8, wander_deg=2.0, children=7,
                    span=(0.1, 0.95), directions=((1.0, 0.0, 0.0), (-1.0, 0.0, 0.0)), divergence_deg=0.0),
        OrderParams(1.2, 0.35, tip_ratio=0.4, length_sd=0.15, angle_deg=80, angle_sd_deg=5, segments=6,
                    wander_deg=5.0, tropism_deg=2.0, children=4, span=(0.2, 0.8), divergence_deg=180.0,
                    azimuth_deg=90.0),
        OrderParams(0.25, 0.5, length_sd=0.3, angle_deg=50, segments=3, wander_deg=8.0, children=2),
        OrderParams(0.08, 0.6, length_sd=0.3, angle_deg=45, segments=2, wander_deg=8.0),
    ), leaf_count=600),
    "conifer": TreePreset(orders=(
        OrderParams(16.0, 0.15, tip_ratio=0.05, length_sd=0.0, segments=32, wander_deg=0.5, children=115,
                    span=(0.12, 0.97), whorl=5, divergence_deg=36.0),
        OrderParams(0.15, 0.12, tip_ratio=0.8, length_sd=0.0, angle_deg=80, angle_sd_deg=5, segments=1,
                    wander_deg=0.0, from_surface=True),
    )),
    "conference-pear": TreePreset(orders=(
        OrderParams(0.5, 0.05, tip_ratio=0.85, length_sd=0.0, segments=2, wander_deg=1.0, children=4,
                    span=(1.0, 1.0), whorl=4),
        OrderParams(2.3, 0.6, tip_ratio=0.15, length_sd=0.0, segments=10, wander_deg=1.5, children=10,
                    span=(0.08, 0.95), divergence_deg=180.0, azimuth_deg=90.0, directions=v_trellis_leaders()),
        OrderParams(0.45, 0.4, length_sd=0.3, angle_deg=60, angle_sd_deg=15, segments=4, wander_deg=8.0,
                    tropism_deg=-2.0, children=4, span=(0.15, 1.0)),
        OrderParams(0.25, 0.5, length_sd=0.3, angle_deg=45, angle_sd_deg=10, segments=3, wander_deg=10.0,
                    tropism_deg=4.0),
    ), leaf_count=300, leaf_size_median=1.3, leaf_size_sigma=0.17),
    "shoot": TreePreset(orders=(
        OrderParams(0.3, 0.003, tip_ratio=0.6, length_sd=0.0, segments=4, wander_deg=4.0,
                    directions=((0.0, 1.0, 0.15),)),
    ), leaf_count=8, leaf_min_order=0, leaf_angle_distribution="planophile"),
    "cylinder": TreePreset(orders=(
        OrderParams(2.0, 0.5, tip_ratio=1.0, length_sd=0.0, segments=1, wander_deg=0.0),
    )),
}


@dataclass
class TreeModel:
    """A grown tree in its own frame (base of the trunk at the origin, +z up).

    Attributes
    ----------
    cylinders : list of dict
        Truth cylinders (``id, parent, order, branch, start, end, radius_m,
        radius_end_m``), m.
    leaf_shapes : list of LeafShape
    leaf_rotations : ndarray, shape (L, 3, 3)
        Canonical-to-tree rotation of every leaf.
    leaf_anchors : ndarray, shape (L, 3)
        Tree-frame position of every petiole's free end (on the branch surface), m.
    leaf_cylinders : ndarray, shape (L,), int
        Id of the cylinder each leaf hangs on.
    """

    cylinders: list[dict]
    leaf_shapes: list[LeafShape] = field(default_factory=list)
    leaf_rotations: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    leaf_anchors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    leaf_cylinders: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    def arrays(self) -> dict[str, np.ndarray]:
        """Cylinder fields as arrays: ``start``, ``end`` (C, 3), ``radius_m``, ``radius_end_m``, ``order``, ..."""
        keys = ("id", "parent", "order", "branch", "start", "end", "radius_m", "radius_end_m")
        return {k: np.array([c[k] for c in self.cylinders]) for k in keys}


def _turn(direction, angle: float, azimuth: float) -> np.ndarray:
    """Unit ``direction`` turned by ``angle`` towards the azimuth ``azimuth`` (from its upper side), rad.

    The upper side is world up projected on the plane perpendicular to
    ``direction`` (+x for a vertical direction). Plain floats: this runs once
    per segment and per leaf, where numpy's per-call overhead would dominate.
    """
    dx, dy, dz = (float(c) for c in direction)
    rx, ry, rz = -dz * dx, -dz * dy, 1.0 - dz * dz
    norm = math.sqrt(rx * rx + ry * ry + rz * rz)
    if norm < 1e-6:
        rx, ry, rz = 1.0 - dx * dx, -dx * dy, -dx * dz
        norm = math.sqrt(rx * rx + ry * ry + rz * rz)
    rx, ry, rz = rx / norm, ry / norm, rz / norm
    ca, sa, c, s = math.cos(azimuth), math.sin(azimuth), math.cos(angle), math.sin(angle)
    side = (ca * rx + sa * (dy * rz - dz * ry), ca * ry + sa * (dz * rx - dx * rz), ca * rz + sa * (dx * ry - dy * rx))
    out = np.array([c * dx + s * side[0], c * dy + s * side[1], c * dz + s * side[2]])
    return out / math.sqrt(out @ out)


def _tropism(direction: np.ndarray, angle: float) -> np.ndarray:
    """``direction`` turned by ``angle`` towards world up (negative: down), without overshooting."""
    if angle == 0:
        return direction
    elevation = math.asin(np.clip(direction[2], -1, 1))
    target = math.copysign(math.pi / 2, angle)
    step = min(abs(angle), abs(target - elevation))
    return _turn(direction, math.copysign(step, angle), 0.0)


def grow_tree(preset: TreePreset | str, seed: int, leaf_count: int | None = None,
              leaf_angle_distribution: str | None = None, **order_overrides) -> TreeModel:
    """Grow a tree from a preset (same seed, same tree).

    Parameters
    ----------
    preset : TreePreset or str
        A recipe or a key of :data:`PRESETS`.
    seed : int
        Seed of every random draw.
    leaf_count : int, optional
        Number of leaves (default: the preset's; 0: leafless).
    leaf_angle_distribution : str, optional
        Override of the preset's leaf-angle distribution.
    **order_overrides
        ``order<k>_<field>=value`` replaces a field of order ``k`` (e.g.
        ``order1_length_m=2.0``).

    Returns
    -------
    TreeModel
        Truth cylinders and placed leaves in the tree's own frame (m, z up).
    """
    preset = get_tree_preset(preset) if isinstance(preset, str) else preset
    orders = list(preset.orders)
    for key, value in order_overrides.items():
        head, _, name = key.partition("_")
        if not (head.startswith("order") and head[5:].isdigit() and int(head[5:]) < len(orders)
                and name in {f.name for f in dataclasses.fields(OrderParams)}):
            raise SceneError(f"unknown tree override {key!r}; use order<k>_<field> with k < {len(orders)} and a "
                             f"field of OrderParams")
        k = int(head[5:])
        orders[k] = dataclasses.replace(orders[k], **{name: _checked_override(key, getattr(orders[k], name), value)})
    rng = np.random.default_rng(seed)
    cylinders: list[dict] = []
    trunk = np.asarray(orders[0].directions[0] if orders[0].directions else (0.0, 0.0, 1.0), dtype=float)
    _grow(orders, rng, cylinders, order=0, parent=-1, start=np.zeros(3), direction=trunk / np.linalg.norm(trunk),
          radius=orders[0].radius, length=orders[0].length_m, branch_counter=[0])
    model = TreeModel(cylinders)
    count = preset.leaf_count if leaf_count is None else int(leaf_count)
    if count > 0:
        _add_leaves(model, preset, count, leaf_angle_distribution or preset.leaf_angle_distribution, rng)
    return model


def _checked_override(key: str, default, value):
    """``value`` if it has the type of the field's ``default`` (lists become tuples)."""
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if isinstance(default, bool):
        ok, what = isinstance(value, bool), "true or false"
    elif isinstance(default, int):
        ok, what = number and float(value) == int(value), "an integer"
        value = int(value) if ok else value
    elif isinstance(default, float):
        ok, what = number, "a number"
    else:
        ok, what = isinstance(value, (list, tuple)), "a list"
        value = tuple(value) if ok else value
    if not ok:
        raise SceneError(f"tree override {key!r} must be {what}, got {value!r}")
    return value


def get_tree_preset(name: str) -> TreePreset:
    """The tree preset ``name``."""
    if name not in PRESETS:
        raise SceneError(f"unknown tree preset {name!r}; allowed: {', '.join(PRESETS)}")
    return PRESETS[name]


def _grow(orders, rng, cylinders, order, parent, start, direction, radius, length, branch_counter):
    p = orders[order]
    branch = branch_counter[0]
    branch_counter[0] += 1
    n = p.segments
    points, d = [start], direction
    for _ in range(n):
        if p.wander_deg:
            d = _turn(d, abs(rng.normal(0.0, math.radians(p.wander_deg))), rng.uniform(0, 2 * np.pi))
        d = _tropism(d, math.radians(p.tropism_deg))
        points.append(points[-1] + (length / n) * d)
    radii = radius * (1.0 + (p.tip_ratio - 1.0) * np.linspace(0.0, 1.0, n + 1))
    ids = []
    for i in range(n):
        ids.append(len(cylinders))
        cylinders.append({"id": ids[-1], "parent": parent if i == 0 else ids[-2], "order": order, "branch": branch,
                          "start": points[i].tolist(), "end": points[i + 1].tolist(),
                          "radius_m": float(radii[i]), "radius_end_m": float(radii[i + 1])})
    if order + 1 >= len(orders) or p.children == 0:
        return
    child = orders[order + 1]
    nodes = max(1, math.ceil(p.children / p.whorl))
    fractions = np.linspace(*p.span, nodes) if nodes > 1 else np.array([p.span[1]])
    azimuth = math.radians(p.azimuth_deg)
    made = 0
    for f in fractions:
        seg = min(int(f * n), n - 1)
        local = f * n - seg
        where = points[seg] + local * (points[seg + 1] - points[seg])
        axis = (points[seg + 1] - points[seg]) / np.linalg.norm(points[seg + 1] - points[seg])
        parent_radius = radii[seg] + local * (radii[seg + 1] - radii[seg])
        for w in range(p.whorl):
            if made == p.children:
                break
            if child.directions:
                d_child = np.asarray(child.directions[made % len(child.directions)], dtype=float)
                d_child = d_child / np.linalg.norm(d_child)
            else:
                angle = math.radians(max(1.0, rng.normal(child.angle_deg, child.angle_sd_deg)))
                d_child = _turn(axis, angle, azimuth + 2 * np.pi * w / p.whorl + rng.normal(0.0, 0.1))
            length = child.length_m * max(0.2, rng.normal(1.0, child.length_sd))
            if child.from_surface:
                length += parent_radius
            _grow(orders, rng, cylinders, order + 1, ids[seg], where, d_child,
                  min(child.radius * parent_radius, 0.95 * parent_radius), length, branch_counter)
            made += 1
        azimuth += math.radians(p.divergence_deg)


def _add_leaves(model: TreeModel, preset: TreePreset, count: int, distribution: str, rng) -> None:
    arrays = model.arrays()
    bearing = np.nonzero(arrays["order"] >= preset.leaf_min_order)[0]
    if len(bearing) == 0:
        raise SceneError(f"this tree has no branches of order >= {preset.leaf_min_order} to carry leaves")
    start, end = arrays["start"][bearing], arrays["end"][bearing]
    seg_len = np.linalg.norm(end - start, axis=1)
    cumulative = np.concatenate([[0.0], np.cumsum(seg_len)])
    # Evenly spaced nodes over all leaf-bearing wood, with a random offset.
    positions = (rng.uniform() + np.arange(count)) * cumulative[-1] / count
    which = np.clip(np.searchsorted(cumulative, positions, side="right") - 1, 0, len(bearing) - 1)
    local = ((positions - cumulative[which]) / seg_len[which])[:, None]
    axis = (end - start)[which] / seg_len[which, None]
    r0, r1 = arrays["radius_m"][bearing][which], arrays["radius_end_m"][bearing][which]
    radius = r0 + local[:, 0] * (r1 - r0)
    on_axis = start[which] + local * (end - start)[which]

    inclination = sample_leaf_inclination(distribution, rng, count)
    normal_azimuth = rng.uniform(0.0, 2 * np.pi, count)
    normals = np.stack([np.sin(inclination) * np.cos(normal_azimuth), np.sin(inclination) * np.sin(normal_azimuth),
                        np.cos(inclination)], axis=1)
    size = np.exp(rng.normal(math.log(preset.leaf_size_median), preset.leaf_size_sigma, count))
    phyllotaxis = math.radians(144.0)  # 2/5
    outward = np.array([_turn(axis[i], np.pi / 2, i * phyllotaxis) for i in range(count)])
    midrib = outward - np.sum(outward * normals, axis=1, keepdims=True) * normals
    # A normal along the outward direction leaves no in-plane outward part: use the branch axis instead.
    midrib = np.where(np.linalg.norm(midrib, axis=1, keepdims=True) < 1e-3, axis, midrib)
    model.leaf_shapes = sample_pear_leaves(rng, size)
    model.leaf_rotations = leaf_frame(normals, midrib)
    model.leaf_anchors = on_axis + radius[:, None] * outward
    model.leaf_cylinders = arrays["id"][bearing][which]


def wood_mesh(cylinders: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Open frusta of all truth cylinders (arrays from :meth:`TreeModel.arrays`), sides by the sagitta rule."""
    sides = polygon_sides(np.maximum(cylinders["radius_m"], cylinders["radius_end_m"]))
    parts_v, parts_f, offset = [], [], 0
    for n in np.unique(sides):
        members = sides == n
        v, f = frusta(cylinders["start"][members], cylinders["end"][members], cylinders["radius_m"][members],
                      cylinders["radius_end_m"][members], int(n))
        parts_v.append(v)
        parts_f.append(f + offset)
        offset += len(v)
    return np.concatenate(parts_v), np.concatenate(parts_f)


def wood_object(model: TreeModel, pose: Pose, group: str, bark: str | Material, rng: np.random.Generator,
                extra_truth: dict | None = None) -> SceneObject:
    """The ``<group>/wood`` object of a tree: all its frusta, with the cylinder truth in world coordinates.

    Parameters
    ----------
    model : TreeModel
        The tree in its own frame.
    pose : Pose
        Tree frame to world (rigid: scale must be 1).
    group : str
        Group and name prefix.
    bark : str or Material
        A library name (one material drawn for the tree with ``rng``) or a fixed material.
    rng : numpy.random.Generator
        Source of the material draw.
    extra_truth : dict, optional
        Added to the object's truth.

    Returns
    -------
    SceneObject
        Type ``"wood"``, with truth ``cylinders`` (world coordinates, m) and ``volume_m3``.
    """
    if not math.isclose(pose.scale, 1.0):
        raise SceneError(f"{group}: trees cannot be scaled (got scale {pose.scale}); change the preset instead")
    arrays = model.arrays()
    world = dict(arrays, start=pose.apply(arrays["start"]), end=pose.apply(arrays["end"]))
    vertices, faces = wood_mesh(world)
    cylinders = [dict(c, start=s.tolist(), end=e.tolist()) for c, s, e in zip(model.cylinders, world["start"],
                                                                                world["end"])]
    volume = float(frustum_volume(np.linalg.norm(world["end"] - world["start"], axis=1), world["radius_m"],
                                  world["radius_end_m"]).sum())
    material = bark if isinstance(bark, Material) else sample_material(bark, rng)
    return SceneObject(f"{group}/wood", "wood", vertices, faces, material, group=group,
                       truth={"cylinders": cylinders, "volume_m3": volume, **(extra_truth or {})})


@dataclass
class LeafBatch:
    """Placed leaves waiting to be meshed together (possibly from several trees)."""

    shapes: list = field(default_factory=list)
    rotations: list = field(default_factory=list)
    anchors: list = field(default_factory=list)
    names: list = field(default_factory=list)
    groups: list = field(default_factory=list)
    materials: list = field(default_factory=list)
    truth: list = field(default_factory=list)

    def add_tree(self, model: TreeModel, pose: Pose, group: str, leaf_material: str | Material,
                 rng: np.random.Generator) -> None:
        """Queue the leaves of ``model`` placed by ``pose`` as ``<group>/leaf-0001`` ...

        Parameters
        ----------
        model : TreeModel
            The tree in its own frame.
        pose : Pose
            Tree frame to world (rigid).
        group : str
            Group and name prefix.
        leaf_material : str or Material
            A library name (one material drawn per leaf with ``rng``) or a fixed material.
        rng : numpy.random.Generator
            Source of the material draws.
        """
        count = len(model.leaf_shapes)
        self.shapes += model.leaf_shapes
        self.rotations.append(np.einsum("ij,njk->nik", pose.rotation, model.leaf_rotations))
        self.anchors.append(pose.apply(model.leaf_anchors))
        self.names += [f"{group}/leaf-{i + 1:04d}" for i in range(count)]
        self.groups += [group] * count
        self.materials += [leaf_material if isinstance(leaf_material, Material)
                           else sample_material(leaf_material, rng) for _ in range(count)]
        self.truth += [{"cylinder": int(c)} for c in model.leaf_cylinders]

    def objects(self, facet_m) -> list[SceneObject]:
        """Mesh all queued leaves; ``facet_m`` is a size (m) or a function of the anchors ``(L, 3)``."""
        if not self.shapes:
            return []
        anchors = np.concatenate(self.anchors)
        facet = facet_m(anchors) if callable(facet_m) else facet_m
        return leaf_objects(self.shapes, np.concatenate(self.rotations), anchors, self.names, self.materials,
                            facet, group=self.groups, extra_truth=self.truth, anchor="petiole")


def tree_objects(model: TreeModel, pose: Pose, group: str, *, bark: str | Material = "bark",
                 leaf_material: str | Material = "pear-leaf", leaf_facet_m=0.004, seed: int = 0,
                 extra_truth: dict | None = None) -> list[SceneObject]:
    """Scene objects of a grown tree: ``<group>/wood`` plus ``<group>/leaf-0001`` ...

    Parameters
    ----------
    model : TreeModel
        The tree in its own frame.
    pose : Pose
        Tree frame to world (rigid: scale must be 1).
    group : str
        Group and name prefix.
    bark, leaf_material : str or Material
        Library names are drawn per tree (bark) and per leaf (leaves) with
        :func:`~scenes.materials.sample_material`; a Material is used as is.
    leaf_facet_m : float or callable
        Facet size of the leaves, m, or a function of their world anchor
        positions ``(L, 3)`` returning it.
    seed : int
        Seed of the material draws.
    extra_truth : dict, optional
        Added to the truth of the wood object.

    Returns
    -------
    list of SceneObject
        The wood object first, then one object per leaf (world coordinates, m).
    """
    rng = np.random.default_rng([seed, 1])
    wood = wood_object(model, pose, group, bark, rng, extra_truth)
    leaves = LeafBatch()
    leaves.add_tree(model, pose, group, leaf_material, rng)
    return [wood] + leaves.objects(leaf_facet_m)


def centreline(cylinders: list[dict], spacing_m: float = 0.01) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense samples along the axes of truth cylinders (woody spec C.1: every 1 cm, with the local radius).

    Parameters
    ----------
    cylinders : list of dict
        Truth cylinders (``docs/contracts.md`` format).
    spacing_m : float
        Largest distance between consecutive samples along a cylinder, m;
        both ends of every cylinder are sampled.

    Returns
    -------
    points : ndarray, shape (K, 3)
        Axis points, m.
    radius : ndarray, shape (K,)
        Radius at each point (linear taper), m.
    cylinder_id : ndarray, shape (K,)
        Id of the cylinder each point belongs to.
    """
    if not spacing_m > 0:
        raise SceneError(f"centreline spacing_m must be positive, got {spacing_m!r}")
    points, radius, ids = [], [], []
    for c in cylinders:
        start, end = np.asarray(c["start"], float), np.asarray(c["end"], float)
        t = np.linspace(0.0, 1.0, max(2, math.ceil(np.linalg.norm(end - start) / spacing_m) + 1))
        points.append(start + t[:, None] * (end - start))
        radius.append(c["radius_m"] + t * (c["radius_end_m"] - c["radius_m"]))
        ids.append(np.full(len(t), c["id"]))
    return np.concatenate(points), np.concatenate(radius), np.concatenate(ids)

"""Synthetic woody geometry and point clouds sampled on it (for tests and experiments).

Geometry is a cylinder list in the truth format of ``docs/contracts.md``
(frusta with parent links). Clouds are drawn uniformly on the lateral
surfaces at a given density, with analytic outward normals, so that the
methods can be run without a scanner simulation and with oracle normals.

The procedural trees here (apple-like, vine-like, conifer stem, curved tube)
are stand-ins sized after the designs in the woody spec (Méndez et al.: a
leafless apple tree of about 2.8 dm^3 and order 7, a vine of about 6.8 dm^3;
Ravaglia et al. 2017: a 0.5 m x 2 m cylinder, a winding tapering tube, a
conifer stem with 15 cm branch stubs). Their sizes are assumptions, not
published values; the scenes package owns the trees that the simulator scans.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from woody.errors import WoodyError
from woody.geometry import cylinder_arrays, cylinders_volume, orthonormal_frame, segment_distance


@dataclass
class SyntheticCloud:
    """Points sampled on known geometry.

    Attributes
    ----------
    points, normals : ndarray, (n, 3)
        Coordinates (m) and outward unit normals (oracle normals).
    labels : ndarray, (n,)
        Row of the cylinder each point was drawn on.
    cylinders : list of dict
        The truth cylinder list.
    """

    points: np.ndarray
    normals: np.ndarray
    labels: np.ndarray
    cylinders: list[dict]

    @property
    def truth(self) -> dict:
        """Truth of the woody object as in the scene contract (``cylinders``, ``volume_m3``)."""
        return {"cylinders": self.cylinders, "volume_m3": cylinders_volume(self.cylinders)}


def sample_cylinders(cylinders: list[dict], density_per_m2: float, seed=0, arc_deg: float = 360.0,
                     view=None, drop_inside: bool = True) -> SyntheticCloud:
    """Draw points uniformly on the lateral surfaces of a cylinder list.

    Parameters
    ----------
    cylinders : list of dict
        Frusta in the truth format.
    density_per_m2 : float
        Points per square metre of surface (1 pt/cm^2 = 1e4 pts/m^2).
    seed : int or numpy.random.Generator
        Randomness.
    arc_deg : float
        Visible sector about each axis, degrees, centred on the frame's first
        axis (+x for a vertical cylinder); 360 keeps the whole surface (the
        occlusion model of the spec's D-S14).
    view : array_like, (3,), optional
        Direction towards a distant scanner: only points whose normal faces
        it are kept (a one-sided view such as a monolateral mobile scan;
        branches do not shadow each other).
    drop_inside : bool
        Drop points that lie inside another cylinder (the buried base of a
        child branch).

    Returns
    -------
    SyntheticCloud
        Points (m), their outward unit normals, the row of the cylinder each lies on, and the cylinders.
    """
    if not density_per_m2 > 0:
        raise WoodyError(f"density_per_m2 must be positive, got {density_per_m2}")
    if not 0 < arc_deg <= 360:
        raise WoodyError(f"arc_deg must be in (0, 360], got {arc_deg}")
    rng = np.random.default_rng(seed)
    arr = cylinder_arrays(cylinders)
    half_arc = np.radians(arc_deg) / 2
    points, normals, labels = [], [], []
    for row, (start, end, r0, r1) in enumerate(zip(arr["start"], arr["end"], arr["r0"], arr["r1"])):
        axis = end - start
        height = np.linalg.norm(axis)
        area = np.pi * (r0 + r1) * np.hypot(height, r1 - r0) * arc_deg / 360.0
        count = rng.poisson(area * density_per_m2)
        d = axis / height
        u, v = _axis_frame(d)
        uniform = rng.random(count)
        # Axial position with density proportional to the local radius (inverse CDF of a linear pdf).
        if abs(r1 - r0) > 1e-12:
            t = (np.sqrt(r0 * r0 + (r1 * r1 - r0 * r0) * uniform) - r0) / (r1 - r0)
        else:
            t = uniform
        phi = rng.uniform(-half_arc, half_arc, count)
        radial = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
        radius = r0 + (r1 - r0) * t
        points.append(start + (t * height)[:, None] * d + radius[:, None] * radial)
        normal = height * radial - (r1 - r0) * d
        normals.append(normal / np.linalg.norm(normal, axis=1, keepdims=True))
        labels.append(np.full(count, row))
    points, normals, labels = np.concatenate(points), np.concatenate(normals), np.concatenate(labels)
    keep = np.ones(len(points), bool)
    if view is not None:
        keep &= normals @ np.asarray(view, float) > 0
    if drop_inside and len(cylinders) > 1:
        keep &= ~_inside_other(points, labels, arr)
    points, normals, labels = points[keep], normals[keep], labels[keep]
    return SyntheticCloud(points, normals, labels, cylinders)


def _axis_frame(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to ``direction``; the first is +x for a vertical axis."""
    u, v, _ = orthonormal_frame(direction, up=(1.0, 0.0, 0.0))
    return v, -u


def _inside_other(points: np.ndarray, labels: np.ndarray, arr: dict) -> np.ndarray:
    """Whether each point lies strictly inside a cylinder other than its own."""
    inside = np.zeros(len(points), bool)
    tree = cKDTree(points)
    for row, (start, end, r0, r1) in enumerate(zip(arr["start"], arr["end"], arr["r0"], arr["r1"])):
        reach = 0.5 * np.linalg.norm(end - start) + max(r0, r1)
        near = np.array(tree.query_ball_point(0.5 * (start + end), reach), dtype=np.int64)
        near = near[labels[near] != row]
        if len(near):
            dist, t = segment_distance(points[near], start, end)
            inside[near[(dist < r0 + (r1 - r0) * t - 1e-9) & (t > 0) & (t < 1)]] = True
    return inside


def add_noise(points: np.ndarray, amplitude_m: float, seed=0, kind: str = "uniform") -> np.ndarray:
    """Points with isotropic coordinate noise (spec D-S13).

    ``kind="uniform"``: each coordinate shifted by U(-A, A); ``"gaussian"``: by N(0, A^2).

    Parameters
    ----------
    points : ndarray, (n, 3)
        Coordinates, m.
    amplitude_m : float
        ``A``, m (>= 0): half-width of the uniform noise or standard deviation of the Gaussian.
    seed : int
        Seed of the noise generator.
    kind : {"uniform", "gaussian"}
        Noise distribution.

    Returns
    -------
    ndarray, (n, 3)
        Noisy coordinates, m.
    """
    rng = np.random.default_rng(seed)
    if amplitude_m < 0:
        raise WoodyError(f"noise amplitude must be >= 0 m, got {amplitude_m}")
    if kind == "uniform":
        return points + rng.uniform(-amplitude_m, amplitude_m, points.shape)
    if kind == "gaussian":
        return points + rng.normal(0.0, amplitude_m, points.shape)
    raise WoodyError(f"noise kind must be 'uniform' or 'gaussian', got {kind!r}")


def _cylinder(cid, parent, order, branch, start, end, r0, r1) -> dict:
    return {"id": int(cid), "parent": int(parent), "order": int(order), "branch": int(branch),
            "start": [float(x) for x in start], "end": [float(x) for x in end],
            "radius_m": float(r0), "radius_end_m": float(r1)}


def straight_cylinder(radius_m: float = 0.5, length_m: float = 2.0) -> list[dict]:
    """One vertical cylinder standing on the origin (STEP's DS1: 0.5 m x 2 m).

    Parameters
    ----------
    radius_m : float
        Radius, m.
    length_m : float
        Length along +z, m.

    Returns
    -------
    list of dict
        One cylinder record (:mod:`woody.geometry`).
    """
    return [_cylinder(0, -1, 1, 0, (0, 0, 0), (0, 0, length_m), radius_m, radius_m)]


def polyline_cylinders(centres: np.ndarray, radii: np.ndarray, first_id: int = 0, parent: int = -1,
                       order: int = 1, branch: int = 0) -> list[dict]:
    """A chain of frusta through centreline vertices (one branch, each piece parented to the previous).

    Parameters
    ----------
    centres : ndarray, (k, 3)
        Centreline vertices, m.
    radii : ndarray, (k,)
        Radius at each vertex, m.
    first_id : int
        Id of the first frustum (the others follow).
    parent : int
        Parent id of the first frustum (-1: none).
    order : int
        Branching order of the chain (1: stem).
    branch : int
        Branch id of every frustum.

    Returns
    -------
    list of dict
        ``k - 1`` cylinder records (:mod:`woody.geometry`).
    """
    out = []
    for i in range(len(centres) - 1):
        cid = first_id + i
        out.append(_cylinder(cid, parent if i == 0 else cid - 1, order, branch, centres[i], centres[i + 1],
                             radii[i], radii[i + 1]))
    return out


def curved_tube(pieces: int = 60) -> list[dict]:
    """A winding, tapering tube with strong radius changes (after STEP's DS2 design).

    Assumed sizes: a 3 m long S-shaped centreline rising from the origin,
    radius going 0.30 m -> 0.10 m -> 0.20 m -> 0.06 m along it.
    """
    s = np.linspace(0.0, 1.0, pieces + 1)
    centres = np.column_stack([0.6 * np.sin(2.0 * np.pi * s), 0.3 * np.sin(np.pi * s), 3.0 * s])
    radii = np.interp(s, [0.0, 0.35, 0.6, 1.0], [0.30, 0.10, 0.20, 0.06])
    return polyline_cylinders(centres, radii)


def conifer_stem(height_m: float = 15.0, dbh_m: float = 0.30, whorl_step_m: float = 0.8,
                 first_whorl_m: float = 3.0, stub_m: float = 0.15, seed=0) -> list[dict]:
    """A tapered conifer stem with whorls of short branch stubs (after STEP's DS3 design).

    The stem is a chain of 0.5 m frusta whose diameter falls linearly from
    ``dbh_m`` at 1.3 m to 2 cm at the top (sizes are assumptions: the paper
    gives none). Each whorl has 4-5 stubs of ``stub_m`` beyond the bark,
    radius 0.15 x the local stem radius, rising 30 deg above horizontal.

    Parameters
    ----------
    height_m : float
        Stem height, m (above 1.3 m).
    dbh_m : float
        Stem diameter at 1.3 m, m.
    whorl_step_m : float
        Vertical distance between whorls, m.
    first_whorl_m : float
        Height of the lowest whorl, m.
    stub_m : float
        Length of a stub beyond the bark, m.
    seed : int
        Seed of the whorl azimuths and stub counts.

    Returns
    -------
    list of dict
        Cylinder records (:mod:`woody.geometry`): the stem, then the stubs.
    """
    rng = np.random.default_rng(seed)
    z = np.linspace(0.0, height_m, int(round(height_m / 0.5)) + 1)
    radius = np.maximum(0.5 * dbh_m * (height_m - z) / (height_m - 1.3), 0.01)
    stem = polyline_cylinders(np.column_stack([np.zeros_like(z), np.zeros_like(z), z]), radius)
    out = list(stem)
    branch = 1
    for zw in np.arange(first_whorl_m, height_m - 1.0, whorl_step_m):
        r_stem = float(np.interp(zw, z, radius))
        parent = int(min(zw // 0.5, len(stem) - 1))
        for az in rng.uniform(0, 2 * np.pi) + np.arange(rng.integers(4, 6)) * 2 * np.pi / 5:
            d = np.array([np.cos(az) * np.cos(np.pi / 6), np.sin(az) * np.cos(np.pi / 6), np.sin(np.pi / 6)])
            start = np.array([0.0, 0.0, zw])
            r_b = 0.15 * r_stem
            out.append(_cylinder(len(out), parent, 2, branch, start, start + (r_stem + stub_m) * d, r_b, r_b))
            branch += 1
    return out


def _grow_branch(out: list, rng, start, direction, length, radius, order, parent, branch, spec) -> None:
    """Append one curved, tapering branch (2-4 frusta) and, recursively, its children."""
    pieces = int(rng.integers(2, 5))
    r_end = radius * spec["taper"]
    centres = [np.asarray(start, float)]
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    for _ in range(pieces):
        bend = rng.normal(0.0, spec["bend"], 3)
        d = d + bend - np.dot(bend, d) * d
        d[2] += spec["gravitropism"]
        d /= np.linalg.norm(d)
        centres.append(centres[-1] + d * length / pieces)
    centres = np.array(centres)
    radii = np.linspace(radius, r_end, pieces + 1)
    first = len(out)
    out.extend(polyline_cylinders(centres, radii, first_id=first, parent=parent, order=order, branch=branch))
    if order >= spec["max_order"]:
        return
    n_children = int(rng.integers(*spec["children"]))
    for _ in range(n_children):
        where = rng.uniform(0.25, 0.9)
        piece = min(int(where * pieces), pieces - 1)
        frac = where * pieces - piece
        attach = centres[piece] + frac * (centres[piece + 1] - centres[piece])
        r_here = radii[piece] + frac * (radii[piece + 1] - radii[piece])
        r_child = r_here * rng.uniform(*spec["radius_ratio"])
        if r_child < spec["min_radius"]:
            continue
        axis = centres[piece + 1] - centres[piece]
        axis /= np.linalg.norm(axis)
        u, v = _axis_frame(axis)
        az = rng.uniform(0, 2 * np.pi)
        angle = np.radians(rng.uniform(*spec["branch_angle_deg"]))
        child_dir = np.cos(angle) * axis + np.sin(angle) * (np.cos(az) * u + np.sin(az) * v)
        child_len = length * rng.uniform(*spec["length_ratio"])
        branch_id = 1 + max(c["branch"] for c in out)
        _grow_branch(out, rng, attach, child_dir, child_len, r_child, order + 1, first + piece, branch_id, spec)


#: Shape parameters of the procedural apple-like tree (assumptions sized to about 2-3 dm^3; the 3 mm smallest radius
#: ends the branching at order 4 on seeds 0-7, before ``max_order``, where the paper's tree reaches order 7).
APPLE_SPEC = {"taper": 0.6, "bend": 0.12, "gravitropism": 0.05, "max_order": 6, "children": (2, 4),
              "radius_ratio": (0.45, 0.7), "min_radius": 0.003, "branch_angle_deg": (35, 65),
              "length_ratio": (0.45, 0.7)}

#: Shape parameters of the vine-like shoots (assumptions).
VINE_SHOOT_SPEC = {"taper": 0.5, "bend": 0.08, "gravitropism": 0.08, "max_order": 5, "children": (1, 3),
                   "radius_ratio": (0.45, 0.7), "min_radius": 0.002, "branch_angle_deg": (30, 60),
                   "length_ratio": (0.3, 0.5)}


def apple_like_tree(seed=0) -> list[dict]:
    """A leafless apple-like tree: a 0.7 m trunk of 3 cm radius with recursive, tapering scaffolds.

    Sizes are assumptions chosen to land near the Méndez apple model
    (order up to 6-7, a few dm^3); see :data:`APPLE_SPEC`.
    """
    rng = np.random.default_rng(seed)
    out: list[dict] = []
    _grow_branch(out, rng, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 1.2, 0.03, 1, -1, 0, APPLE_SPEC)
    return out


def vine_like(seed=0, shoots_per_arm: int = 5) -> list[dict]:
    """A cordon-trained vine: a 0.8 m trunk, two horizontal arms of 0.9 m, upright shoots with laterals.

    Sizes are assumptions (trunk radius 2.5 cm, arms 1.8 cm tapering to 1
    cm, shoots 7 mm at the base and 0.8-1.1 m long); see
    :data:`VINE_SHOOT_SPEC`.

    Parameters
    ----------
    seed : int
        Seed of the shoot shapes.
    shoots_per_arm : int
        Upright shoots along each arm.

    Returns
    -------
    list of dict
        Cylinder records (:mod:`woody.geometry`).
    """
    rng = np.random.default_rng(seed)
    trunk_top = np.array([0.0, 0.0, 0.8])
    out = polyline_cylinders(np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.4], trunk_top]), np.array([0.025, 0.024, 0.022]))
    branch = 1
    for side in (-1.0, 1.0):
        arm = trunk_top + np.column_stack([np.zeros(4), side * np.linspace(0.0, 0.9, 4), np.linspace(0, 0.05, 4)])
        arm_first = len(out)
        out.extend(polyline_cylinders(arm, np.linspace(0.018, 0.010, 4), first_id=arm_first, parent=1, order=2,
                                      branch=branch))
        branch += 1
        for y in np.linspace(0.15, 0.85, shoots_per_arm):
            piece = min(int(y / 0.3), 2)
            attach = trunk_top + np.array([0.0, side * y, 0.05 * y / 0.9])
            direction = np.array([rng.normal(0, 0.15), side * rng.normal(0.1, 0.1), 1.0])
            _grow_branch(out, rng, attach, direction, rng.uniform(0.8, 1.1), 0.007, 3, arm_first + piece,
                         branch, VINE_SHOOT_SPEC)
            branch = 1 + max(c["branch"] for c in out)
    return out

"""The trunk of a tree followed from the ground up by stacked circle fits (robust on stems seen from one side).

Starting from the main stem at breast height (:func:`woody.dbh.measure_dbh`;
at 0.9 or 0.5 m when no stem fits well there: a tree forking lower),
slabs of the stem perpendicular to its axis are fitted with circles
(:func:`woody.circles.fit_circle`), stepping down to the ground and up
until a fit fails twice in a row (a fork, the crown, the top of the stem).
A fit fails when its quality flag is ``unreliable`` or ``high-residual``,
its radius or centre jumps from the previous slab's, or, above breast
height, its radius exceeds the breast-height radius by a quarter; a slab
whose fit fails is fitted once more on its points within the radius jump
of the previous circle (the stem's own surface, without the bases of a
whorl's branches or the root flare beside it). The axis follows
the centres of the last slabs, so a leaning or curved stem is followed.

The trunk is returned as a cylinder list (frusta between consecutive
circles) with the points it explains, so that a branch-following method can
reconstruct the rest of the tree from the remaining points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from woody.circles import fit_circle
from woody.cloud import check_points
from woody.dbh import measure_dbh, quality_flag
from woody.errors import WoodyError
from woody.geometry import orthonormal_frame, segment_distance

#: Largest change of radius (relative) and of centre (in radii) between consecutive slabs.
MAX_RADIUS_JUMP, MAX_CENTRE_JUMP = 0.25, 0.5
#: Slabs whose fits may fail in a row before the trunk ends.
MAX_MISSES = 2
#: Centres of this many last slabs give the axis.
AXIS_SLABS = 5
#: Heights above the ground where the trunk is looked for, in turn, m (breast height first; lower for a tree
#: that forks below it).
START_HEIGHTS_M = (1.3, 0.9, 0.5)
#: Largest RMS residual of a rough trunk section seen over half a circle or more, relative to its radius
#: (assumption: real trunks are not circular to better than this; crossing branches give more).
TRUNK_RESIDUAL_REL = 0.1
#: Smallest part of the cloud left by the trunk that cylinder following reconstructs.
MIN_COMPONENT_POINTS = 10
#: A trunk of fewer circles is no trunk (a short piece of a leader): cylinder following alone is used.
MIN_TRUNK_CIRCLES = 4
#: Spacing of the trunk points the rest's bridging measures its gaps from, m (assumption: fine next to the 1 m
#: bridge, coarse enough to keep a dense trunk's query cheap).
ANCHOR_SPACING_M = 0.02


@dataclass
class Trunk:
    """A trunk followed by stacked circles.

    Attributes
    ----------
    centres : ndarray, (k, 3)
        Circle centres from the ground up, m.
    radii : ndarray, (k,)
        Circle radii, m.
    members : ndarray of bool, (n,)
        Points explained by the trunk.
    ground_z_m : float
        Ground height at the trunk, m.
    """

    centres: np.ndarray
    radii: np.ndarray
    members: np.ndarray
    ground_z_m: float

    def cylinders(self, first_id: int = 0, branch: int = 0) -> list[dict]:
        """The trunk as a cylinder list (order 0, each piece parented to the one below).

        Parameters
        ----------
        first_id : int
            Id of the lowest piece (the others follow).
        branch : int
            Branch id of every piece.

        Returns
        -------
        list of dict
        """
        out = []
        for i in range(len(self.radii) - 1):
            cid = first_id + i
            out.append({"id": cid, "parent": -1 if i == 0 else cid - 1, "order": 0, "branch": branch,
                        "start": self.centres[i].tolist(), "end": self.centres[i + 1].tolist(),
                        "radius_m": float(self.radii[i]), "radius_end_m": float(self.radii[i + 1])})
        return out


def follow_trunk(points, ground_z: float | None = None, slab_m: float | None = None,
                 member_tolerance_m: float = 0.01) -> Trunk:
    """Follow the main stem of a cloud from the ground up with circle fits on slabs.

    Parameters
    ----------
    points : array_like, (n, 3)
        Coordinates, m (z up).
    ground_z : float, optional
        Ground height, m (found from the points by default).
    slab_m : float, optional
        Slab thickness and step along the stem, m (default: the stem's
        radius at breast height, between 5 and 30 cm).
    member_tolerance_m : float
        Points within this distance of a slab's circle (plus three times
        its residual) belong to the trunk, m; so do points inside it.

    Returns
    -------
    Trunk

    Raises
    ------
    WoodyError
        If no stem crosses 1.3, 0.9 or 0.5 m above the ground with a fit
        flagged ``ok`` or ``partial-arc``.
    """
    points = check_points(points)
    stem = _start(points, ground_z)
    radius = stem.dbh_m / 2
    slab = float(np.clip(radius, 0.05, 0.3)) if slab_m is None else float(slab_m)
    if not (np.isfinite(slab) and slab > 0):
        raise WoodyError(f"slab_m must be a positive length in metres, got {slab_m}")
    tree = cKDTree(points)
    members = np.zeros(len(points), bool)
    start = {"centre": stem.centre, "axis": stem.axis, "radius": radius, "breast_radius": radius}
    down = _walk(points, tree, start, -slab, stem.ground_z_m, members, member_tolerance_m)
    up = _walk(points, tree, start, slab, None, members, member_tolerance_m)
    rings = down[::-1] + [(stem.centre, radius)] + up
    centres = np.array([c for c, _ in rings])
    radii = np.array([r for _, r in rings])
    if 0 < centres[0, 2] - stem.ground_z_m <= 1.5 * slab:  # the lowest circle down to the ground, along the axis
        axis = stem.axis if len(centres) < 2 else centres[1] - centres[0]
        axis = axis / np.linalg.norm(axis)
        base = centres[0] - (centres[0, 2] - stem.ground_z_m) / axis[2] * axis
        centres, radii = np.vstack([base, centres]), np.concatenate([[radii[0]], radii])
    _claim(points, tree, centres, radii, members, member_tolerance_m, residual=0.0)
    if len(centres) >= 2 and members.any():  # the top circle at the highest trunk point, not past it
        axis = centres[-1] - centres[-2]
        length = np.linalg.norm(axis)
        reach = float(((points[members] - centres[-2]) @ axis).max()) / length
        if 0 < reach < length:
            centres[-1] = centres[-2] + reach / length * axis
    return Trunk(centres=centres, radii=radii, members=members, ground_z_m=stem.ground_z_m)


def _start(points: np.ndarray, ground_z: float | None):
    """The main stem at breast height, or lower on a tree that forks below it (the best-fitted, most points).

    The walk starts from the slice's circle, not the facing arc's (``facing=False``): with the facing arc's
    radius, the quick suite's leafy tree (`cylinders-trunk`) went from +1.3 to +21.2 % volume (round 34)."""
    for height in START_HEIGHTS_M:
        try:
            stems = [s for s in measure_dbh(points, ground_z=ground_z, height_m=height, facing=False)
                     if _trunk_like(s.flag, s.arc_deg, s.residual_m, s.dbh_m / 2)]
        except WoodyError:
            continue
        if stems:
            return stems[0]
    raise WoodyError(f"no stem fits a circle well at {', '.join(map(str, START_HEIGHTS_M))} m above the ground "
                     "(arcs under 40 deg or residuals too high)")


def _trunk_like(flag: str, arc_deg: float, residual_m: float, radius_m: float) -> bool:
    """Whether a section fit can be trunk: flagged ok or partial-arc, or rough (bark, a non-circular trunk) with
    a residual within 10 % of the radius over at least half a circle."""
    if flag in ("ok", "partial-arc"):
        return True
    return flag == "high-residual" and arc_deg >= 180.0 and residual_m <= TRUNK_RESIDUAL_REL * radius_m


def _walk(points, tree, start: dict, step: float, floor: float | None, members, tolerance) -> list:
    """Circles from ``start`` in steps of ``step`` along the axis (down to ``floor``), until the fits fail."""
    centre, axis, radius = start["centre"], start["axis"], start["radius"]
    history = [centre]
    rings, misses = [], 0
    while misses < MAX_MISSES:
        target = centre + step * axis
        if floor is not None and target[2] - abs(step) / 2 < floor:
            break
        fit = _slab_fit(points, tree, target, axis, radius, abs(step))
        if fit is not None and step > 0 and fit[1] > (1.0 + MAX_RADIUS_JUMP) * start["breast_radius"]:
            fit = None  # a trunk does not thicken upwards: two branches side by side
        if fit is None:
            misses += 1
            centre = target
            continue
        new_centre, new_radius, residual = fit
        misses = 0
        rings.append((new_centre, new_radius))
        _claim(points, tree, np.array([target - axis * abs(step) / 2, target + axis * abs(step) / 2]),
               np.array([new_radius, new_radius]), members, tolerance, residual)
        history.append(new_centre)
        centre, radius = new_centre, new_radius
        if len(history) >= 3:
            recent = np.array(history[-AXIS_SLABS:])
            direction = recent[-1] - recent[0]
            if np.linalg.norm(direction) > 0:
                direction = direction / np.linalg.norm(direction)
                axis = direction if direction[2] > 0 else -direction
    return rings


def _slab_fit(points, tree, target, axis, radius, thickness):
    """Circle of the slab of the stem around ``target`` (perpendicular to ``axis``), or None if it fails."""
    reach = 1.5 * radius + 0.05
    near = np.asarray(tree.query_ball_point(target, np.hypot(reach, thickness)), dtype=np.int64)
    if len(near) < 10:
        return None
    local = points[near] - target
    along = local @ axis
    u, v = orthonormal_frame(axis)[:2]
    planar = np.column_stack([local @ u, local @ v])
    keep = (np.abs(along) <= thickness / 2) & (np.hypot(*planar.T) <= reach)
    band = keep & (np.abs(np.hypot(*planar.T) - radius) <= MAX_RADIUS_JUMP * radius)
    for chosen in (keep, band):  # the slab, then only its points near the expected circle (a whorl's branch bases)
        if chosen.sum() < 10:
            return None
        try:
            fit = fit_circle(planar[chosen])
        except WoodyError:
            continue
        if _trunk_like(quality_flag(fit), fit.arc_deg, fit.residual_m, fit.radius_m) \
                and abs(fit.radius_m / radius - 1) <= MAX_RADIUS_JUMP \
                and np.hypot(*fit.centre) <= MAX_CENTRE_JUMP * radius:
            return target + fit.centre[0] * u + fit.centre[1] * v, fit.radius_m, fit.residual_m
    return None


def _claim(points, tree, centres, radii, members, tolerance, residual):
    """Mark the points within a trunk piece (or near its surface) as members."""
    for (a, b), (ra, rb) in zip(zip(centres[:-1], centres[1:]), zip(radii[:-1], radii[1:])):
        axis = b - a
        length = np.linalg.norm(axis)
        if length == 0:
            continue
        limit = max(ra, rb) + tolerance + 3 * residual
        near = np.asarray(tree.query_ball_point(0.5 * (a + b), np.hypot(length / 2, limit)), dtype=np.int64)
        if not len(near):
            continue
        rel = points[near] - a
        t = rel @ axis / length**2
        inside = (t >= 0) & (t <= 1)
        distance = np.linalg.norm(rel - t[:, None] * axis, axis=1)
        members[near[inside & (distance <= ra + (rb - ra) * np.clip(t, 0, 1) + tolerance + 3 * residual)]] = True


def follow_tree(points, ground_z: float | None = None, ground_clearance_m: float = 0.1, progress: bool = False,
                all_parts: bool = False, separate: bool = False, **follow):
    """Cylinder following with the trunk followed first, from the ground up, by stacked circle fits.

    The trunk (:func:`follow_trunk`) is branch 0; cylinder following
    (:func:`woody.cylinders.follow_cylinders`) reconstructs the points the
    trunk does not explain, less the ground (points within
    ``ground_clearance_m`` of it), as one cloud (its unconnected parts
    bridged from what grew and from the trunk's points, see
    ``FollowParams.bridge_m``: a crown above a trunk that ended below it is
    reached from the trunk's top), and each of its root branches
    that starts within two trunk radii of the trunk's surface becomes a
    child of the trunk. A cloud without a stem (fitted over at least four slabs, from
    1.3, 0.9 or 0.5 m above the ground) is reconstructed by cylinder
    following alone, from its lowest point, which reaches only the part of
    the cloud connected to it; with ``all_parts`` each connected part is
    followed from its own lowest point (ground left in), each a root branch.

    Parameters
    ----------
    points : array_like, (n, 3)
        One tree, m (z up); ground points may be left in.
    ground_z : float, optional
        Ground height, m (found from the points by default).
    ground_clearance_m : float
        Points this close above the ground are ground, m.
    progress : bool
        Show cylinder following's progress bar.
    all_parts : bool
        Without a stem, follow every connected part of the cloud, not only
        the lowest (occlusion cuts a single scan of a leafless tree into
        many parts; on a leafy crown the parts' first cylinders swallow
        leaves and twigs, see docs/notebook/woody.md, the
        ``all_parts`` paragraph).
    separate : bool
        Reconstruct only the points :func:`woody.leafwood.separate_wood`
        finds are wood (leaves, needles and strays left out); the other
        points are labelled -1.
    **follow
        Settings of :func:`woody.cylinders.follow_cylinders` (e.g.
        ``precision_m``, ``section_radii``).

    Returns
    -------
    woody.cylinders.FollowResult
        Branch 0 is the trunk (one section per pair of circles);
        ``stats["trunk"]`` gives its circles' count, height and the ground,
        ``stats["parts"]`` the number of connected parts followed (with a
        trunk or ``all_parts``); with ``separate``, ``stats["wood_points"]``
        counts the points kept.
    """
    from woody.cylinders import FollowResult, apply_pipe_model, follow_cylinders
    from woody.ground import ground_grid

    points = check_points(points)
    if separate:
        from woody.leafwood import REACH_M, separate_wood

        wood = separate_wood(points)
        if wood.sum() < 3:
            raise WoodyError(f"the leaf/wood separation found {int(wood.sum())} wood points of {len(points)} (no path "
                             f"from the base runs on for {REACH_M} m); reconstruct without --separate")
        result = follow_tree(points[wood], ground_z, ground_clearance_m, progress, all_parts, **follow)
        labels = np.full(len(points), -1, np.int64)
        labels[wood] = result.labels
        return FollowResult(result.branches, labels, {**result.stats, "wood_points": int(wood.sum())})
    try:
        trunk = follow_trunk(points, ground_z=ground_z)
    except WoodyError:
        trunk = None
    labels = np.full(len(points), -1, np.int64)
    if trunk is None or len(trunk.radii) < MIN_TRUNK_CIRCLES:
        if not all_parts:
            return follow_cylinders(points, progress=progress, **follow)
        branches, stats = _follow_parts(points, _components(points) if len(points) >= MIN_COMPONENT_POINTS else [],
                                        None, labels, [], progress, follow)
        if not branches:  # every part below MIN_COMPONENT_POINTS: the cloud as one
            return follow_cylinders(points, progress=progress, **follow)
        return FollowResult(branches, labels, stats)
    heights = points[:, 2] - ground_z if ground_z is not None else ground_grid(points).heights(points)
    rest = np.flatnonzero(~trunk.members & (heights > ground_clearance_m))
    sections = [(a.tolist(), b.tolist(), float(0.5 * (ra + rb))) for a, b, ra, rb in
                zip(trunk.centres[:-1], trunk.centres[1:], trunk.radii[:-1], trunk.radii[1:])]
    base, top = trunk.centres[0], trunk.centres[-1]
    axis = (top - base) / np.linalg.norm(top - base)
    trunk_record = {"id": 0, "parent": -1, "order": 1, "children": [], "start": base.tolist(), "end": top.tolist(),
                    "direction": axis.tolist(), "radius_m": float(np.median(trunk.radii)),
                    "radius_max_m": float(trunk.radii.max()), "n_points": int(trunk.members.sum()),
                    "sections": sections}
    labels[trunk.members] = 0
    # The rest is followed as one cloud: cylinder following bridges its unconnected parts (a part followed on its
    # own grows its first cylinder as a trunk that swallows twigs and leaves: the quick suite's leafy tree +380 %
    # volume that way, +60 % as one cloud).
    branches, stats = _follow_parts(points, [rest] if len(rest) >= MIN_COMPONENT_POINTS else [], trunk, labels,
                                    [trunk_record], progress, follow)
    stats = {**stats, "trunk": {"circles": len(trunk.radii), "base": base.tolist(), "top": top.tolist(),
                                "ground_z_m": trunk.ground_z_m, "points": int(trunk.members.sum())}}
    if follow.get("pipe_model", True) and follow.get("mode", "strict") == "strict":  # the trunk's circles anchor it
        apply_pipe_model(branches)
    return FollowResult(branches, labels, stats)


def _follow_parts(points, parts, trunk, labels, branches, progress, follow):
    """Cylinder following on each of ``parts`` (index arrays into ``points``) from its own lowest point; a part's
    root branch that starts within two trunk radii of the trunk's surface becomes a child of the trunk (branch 0).
    Fills ``labels`` and returns the branch records (``branches`` first) and the first part's statistics with the
    number of parts."""
    from woody.cylinders import follow_cylinders

    stats = {}
    anchors = None if trunk is None else _surface_samples(points, trunk)
    for chosen in parts:
        result = follow_cylinders(points[chosen], progress=progress, anchors=anchors, **follow)
        stats = result.stats if not stats else stats
        offset = len(branches)
        labels[chosen] = np.where(result.labels >= 0, result.labels + offset, -1)
        depth = {}
        for b in result.branches:  # parents come before their children
            record = {**b, "id": b["id"] + offset, "children": [c + offset for c in b["children"]]}
            if b["parent"] >= 0:
                record["parent"] = b["parent"] + offset
                record["order"] = depth[b["parent"]] + 1
            else:
                attached = trunk is not None and \
                    _distance_to_trunk(np.asarray(b["start"]), trunk) <= 2.0 * float(np.median(trunk.radii))
                record["parent"] = 0 if attached else -1
                record["order"] = 2 if attached else 1
                if attached:
                    branches[0]["children"].append(record["id"])
            depth[b["id"]] = record["order"]
            branches.append(record)
    return branches, {**stats, "parts": len(parts)}


def _surface_samples(points: np.ndarray, trunk: Trunk) -> np.ndarray:
    """The trunk's points thinned to ``ANCHOR_SPACING_M``: where the rest's bridging may reach the trunk, m."""
    from woody.density import thin_to_spacing

    members = points[trunk.members]
    return members[thin_to_spacing(members, ANCHOR_SPACING_M)] if len(members) >= 7 else members


def _components(points: np.ndarray) -> list[np.ndarray]:
    """Indices of the connected parts of a cloud (voxels of twice the point spacing, 26-connected), largest first;
    parts of fewer than ``MIN_COMPONENT_POINTS`` points are left out."""
    from scipy import ndimage

    from woody.density import point_spacing

    voxel = 2.0 * max(point_spacing(points), 1e-4) if len(points) >= 7 else 1.0
    index = np.floor((points - points.min(axis=0)) / voxel).astype(np.int64)
    shape = index.max(axis=0) + 1
    if float(np.prod(shape.astype(float))) > 2e8:  # too fine a grid: one part
        return [np.arange(len(points))]
    occupied = np.zeros(shape, bool)
    occupied[tuple(index.T)] = True
    grid_labels, _ = ndimage.label(occupied, structure=np.ones((3, 3, 3), bool))
    labels = grid_labels[tuple(index.T)]
    order = np.argsort(labels, kind="stable")
    parts = np.split(order, np.flatnonzero(np.diff(labels[order])) + 1)
    return sorted((p for p in parts if len(p) >= MIN_COMPONENT_POINTS), key=len, reverse=True)


def _distance_to_trunk(point: np.ndarray, trunk: Trunk) -> float:
    """Distance of a point to the trunk's surface (0 inside), m."""
    starts, ends = trunk.centres[:-1], trunk.centres[1:]
    distance, t = segment_distance(np.repeat(point[None], len(starts), 0), starts, ends)
    radius = trunk.radii[:-1] + t * (trunk.radii[1:] - trunk.radii[:-1])
    return float(max(0.0, (distance - radius).min()))

"""The merge passes of cylinder following (:mod:`woody.cylinders`): small, aligned and duplicate branches.

After growth: small branches are given back to their parents, aligned
siblings (Table 3) and children aligned with their parent (Table 4) merge,
and in strict mode a branch grown inside an older one's cylinder joins it
(spec D-M11 and the additions of the cylinder-following module docstring);
at the end, the sections that lie mostly inside another branch's are dropped
(:func:`drop_doubled`).
Angles in degrees where named ``*_deg``, lengths in m.
"""

from __future__ import annotations

import copy

import numpy as np
from scipy.spatial import cKDTree

from woody.branch import Branch
from woody.cylfit import angle_deg
from woody.geometry import orthonormal_frame, section_arrays, segment_distance

#: Margin of the screening of :func:`merge_contained`, m (far above rounding, far below any radius).
SCREEN_M = 1e-6


def dissolve_small(branches: list[Branch], params) -> list[Branch]:
    """Give the points of branches smaller than ``min_branch_points`` back to their parents (deepest first).

    A root that small (the trunk stalled at the lowest points while a child
    took over the stem) is handed to its largest child, which becomes the root.

    Parameters
    ----------
    branches : list of Branch
        The branches, oldest first.
    params : woody.cylinders.FollowParams
        Settings (``min_branch_points``).

    Returns
    -------
    list of Branch
        The branches that still hold points.
    """
    grown = set()
    for branch in reversed(branches):
        if branch.parent is not None and 0 < len(branch.points) < params.min_branch_points:
            grown.add(branch.parent.id)
            _absorb(branch.parent, branch, refit=False)
    for branch in branches:
        if branch.id in grown and branch.points:
            branch.refit()
    for root in [b for b in branches if b.parent is None and 0 < len(b.points) < params.min_branch_points]:
        if root.children:
            heir = max(root.children, key=lambda c: len(c.points))
            heir.parent = None
            root.children.remove(heir)
            _absorb(heir, root)
    return _live(branches)


def merge_siblings(branches: list[Branch], params) -> list[Branch]:
    """AlignedChildrenBranches (Table 3): merge children whose angles to the parent differ by < sibling_deg (deg).

    Parameters
    ----------
    branches : list of Branch
        The branches, oldest first.
    params : woody.cylinders.FollowParams
        Settings (``sibling_deg`` in degrees, ``mode``, ``k_r``).

    Returns
    -------
    list of Branch
        The branches that still hold points.
    """
    for branch in branches:
        if len(branch.children) < 2 or branch.direction is None:
            continue
        changed = True
        while changed:
            changed = False
            kids = [c for c in branch.children if c.direction is not None]
            angles = [angle_deg(branch.direction, c.direction) for c in kids]
            pairs = ((a, b) for a in range(len(kids)) for b in range(a + 1, len(kids)))
            for a, b in pairs:
                if abs(angles[a] - angles[b]) >= params.sibling_deg:
                    continue
                if params.mode == "strict" and (
                        angle_deg(kids[a].direction, kids[b].direction) >= params.sibling_deg
                        or not _one_cylinder(kids[a], kids[b], params)):
                    continue
                _absorb(kids[a], kids[b])
                changed = True
                break
    return _live(branches)


def merge_into_parents(branches: list[Branch], params) -> list[Branch]:
    """ConnectAlignedBranches (Table 4), repeated while anything merges: a child within ``parent_deg``
    (deg) of its parent's axis joins it.

    Parameters
    ----------
    branches : list of Branch
        The branches, oldest first.
    params : woody.cylinders.FollowParams
        Settings (``parent_deg`` in degrees, ``mode``, ``k_r``).

    Returns
    -------
    list of Branch
        The branches that still hold points.
    """
    changed = True
    while changed:
        changed = False
        for branch in branches:
            parent = branch.parent
            if not branch.points or parent is None or branch.direction is None or parent.direction is None:
                continue
            if angle_deg(branch.direction, parent.direction) < params.parent_deg and \
                    _one_cylinder(parent, branch, params):
                _absorb(parent, branch)
                changed = True
        branches = _live(branches)
    return branches


def merge_contained(branches: list[Branch]) -> list[Branch]:
    """Merge each branch whose axis midpoint lies inside an older branch's cylinder into that branch.

    A real child leaves its parent, so its axis midpoint is outside every
    other cylinder; one inside is a duplicate grown alongside an older
    branch (they share the points of one stem) or a stub at a junction.

    Parameters
    ----------
    branches : list of Branch
        The branches, oldest first.

    Returns
    -------
    list of Branch
        The branches that still hold points.
    """
    # All older cylinders are screened at once (slightly generous, so that rounding cannot drop one); only those
    # passing are tested one by one, oldest first, with the exact test.
    ends = np.array([[b.p1(), b.p2()] for b in branches]).reshape(len(branches), 2, 3)
    reach = np.array([b.r_max for b in branches])
    usable = np.array([bool(b.points) and b.direction is not None for b in branches])
    for i, branch in enumerate(branches):
        if not branch.points or branch.parent is None or branch.direction is None:
            continue
        middle = 0.5 * (branch.p1() + branch.p2())
        gap, _ = segment_distance(middle[None], ends[:i, 0], ends[:i, 1])
        for k in np.flatnonzero(usable[:i] & (gap <= reach[:i] + SCREEN_M)).tolist():
            older = branches[k]
            if older.points and older.direction is not None and \
                    older.distance(middle[None])[0] == 0.0 and \
                    segment_distance(middle[None], older.p1(), older.p2())[0][0] < older.r_median:
                _absorb(older, branch)
                ends[k], reach[k], usable[i] = (older.p1(), older.p2()), older.r_max, False
                usable[k] = bool(older.points) and older.direction is not None
                break
    return _live(branches)


def _absorb(target: Branch, source: Branch, refit: bool = True) -> None:
    """Move all of ``source``'s points and children into ``target``; ``source`` is emptied.

    Parameters
    ----------
    target, source : Branch
        The branch that takes the points and the one that gives them.
    refit : bool
        ``False`` leaves ``target``'s cylinder stale (the caller refits it once after several moves).
    """
    target.points += source.points
    source.points = []
    for child in source.children:
        child.parent = target
        target.children.append(child)
    source.children = []
    if source.parent is not None:
        source.parent.children = [c for c in source.parent.children if c is not source]
    if refit:
        target.refit()


def _live(branches: list[Branch]) -> list[Branch]:
    """The branches that still hold points."""
    return [b for b in branches if b.points]


def _one_cylinder(a: Branch, b: Branch, params) -> bool:
    """Whether two branches' points fit one cylinder (strict mode; always True in faithful mode).

    The 95th percentile of the union's orthogonal distances must stay within
    the larger ``k_r`` of the wider branch's: merging two parallel but
    separate twigs would otherwise make one fat cylinder around both. (A
    percentile, not the robust envelope: a thin twig is a minority of the
    union's points and would pass a median-based test.)

    Parameters
    ----------
    a, b : Branch
        The two branches.
    params : woody.cylinders.FollowParams
        Settings (``mode``, ``k_r``).
    """
    if params.mode == "faithful":
        return True
    union = copy.copy(a)
    union.points = a.points + b.points
    union.refit()
    return union.spread() <= max(params.k_r) * max(a.spread(), b.spread())


def drop_doubled(records: list[dict], labels: np.ndarray) -> int:
    """Drop the sections that lie mostly inside another branch's sections, in place: wood counted twice.

    Cylinder following can follow one stem twice: on aRchi's Tree_1 (``tlsbench experiment woody-real``) a
    leader fitted at 0.10-0.13 m inside another branch's 0.16 m sections, sibling branches along one 0.1 m limb,
    pieces of the stem below a fork grown down beside each other: 368 dm3 of its 4,891 dm3 (7.5 %) lay in two
    branches at once (round 36). The records are taken youngest first (the breadth-first order reversed), each
    section against the sections of the other branches still kept; a section with at least
    :data:`DOUBLED_SHARE` of its volume inside them (:func:`_inside_share`) is dropped. A narrow cylinder inside a
    wider one goes and the wider one stays, whichever is older. A record left without sections is removed: its
    children and points go to its parent, and the ids are renumbered in the same order. A root's first section stays
    (the root with it).

    Parameters
    ----------
    records : list of dict
        Branch records of :func:`woody.cylinders.follow_cylinders` (``id`` 0..n-1 in list order, ``parent``,
        ``children``, ``start``, ``end``, ``sections`` as ``(start, end, radius)`` in m, ``reliable`` per
        section), parents first.
    labels : ndarray of int, (n,)
        Branch id of each point (-1: none); relabelled in place.

    Returns
    -------
    int
        Number of sections dropped.
    """
    starts, ends, radii, owner, _ = section_arrays(records)
    if len(np.unique(owner)) < 2:
        return 0
    middle = (starts + ends) / 2
    reach = np.linalg.norm(ends - starts, axis=1) / 2 + radii
    tree, widest = cKDTree(middle), float(reach.max())
    first = np.r_[True, owner[1:] != owner[:-1]]
    kept = np.ones(len(radii), bool)
    for k in range(len(radii) - 1, -1, -1):
        if (first[k] and records[owner[k]]["parent"] < 0) or radii[k] <= 0:
            continue
        near = np.asarray(tree.query_ball_point(middle[k], reach[k] + widest), np.int64)
        others = near[kept[near] & (owner[near] != owner[k]) &
                      (np.linalg.norm(middle[near] - middle[k], axis=1) <= reach[near] + reach[k])]
        if len(others) and _inside_share(starts[k], ends[k], radii[k], starts[others], ends[others], radii[others]) \
                >= DOUBLED_SHARE:
            kept[k] = False
    if kept.all():
        return 0
    for i, record in enumerate(records):
        mine = kept[owner == i]
        if not mine.all():
            reliable = record.get("reliable")
            record["sections"] = [s for s, ok in zip(record["sections"], mine) if ok]
            if reliable is not None:
                record["reliable"] = [r for r, ok in zip(reliable, mine) if ok]
            if record["sections"]:
                record["start"], record["end"] = list(record["sections"][0][0]), list(record["sections"][-1][1])
    _remove_empty(records, labels)
    return int((~kept).sum())


#: Share of a section's volume inside other branches' sections from which it is wood counted twice and is
#: dropped (:func:`drop_doubled`). Assumption: at three quarters it adds at most a quarter of its volume; a
#: child's first section that starts on its parent's surface has none of it inside, and one that starts on
#: its parent's axis reaches the share only when the parent is more than three times as wide.
DOUBLED_SHARE = 0.75
#: Where a section's volume is sampled (:func:`_inside_share`): fractions of its length, and rings as (fraction
#: of its radius, points on the ring, share of the volume). The rings' radii split the disc into three annuli of
#: 10, 45 and 45 % of its area (0-0.32, 0.32-0.74, 0.74-1 of the radius), each ring at the annulus' median radius
#: (the square root of the mean of its ends' squares).
SAMPLE_ALONG = (0.1, 0.3, 0.5, 0.7, 0.9)
SAMPLE_RINGS = ((0.0, 1, 0.10), (0.57, 8, 0.45), (0.88, 8, 0.45))


def _inside_share(start: np.ndarray, end: np.ndarray, radius: float, starts: np.ndarray, ends: np.ndarray,
                  radii: np.ndarray) -> float:
    """Share of the volume of the cylinder ``start -> end`` of ``radius`` (m) that lies inside any of the
    cylinders ``starts -> ends`` of ``radii`` (m; flat ends), from the fixed samples :data:`SAMPLE_ALONG` x
    :data:`SAMPLE_RINGS`."""
    axis = end - start
    if radius <= 0 or not np.any(axis):
        return 0.0
    u, v, _ = orthonormal_frame(axis)
    samples, weights = [], []
    for fraction, count, share in SAMPLE_RINGS:
        angle = 2 * np.pi * np.arange(count) / count
        ring = radius * fraction * (np.cos(angle)[:, None] * u + np.sin(angle)[:, None] * v)
        for t in SAMPLE_ALONG:
            samples.append(start + t * axis + ring)
            weights.append(np.full(count, share / count / len(SAMPLE_ALONG)))
    samples, weights = np.concatenate(samples), np.concatenate(weights)
    along = ends - starts
    t = np.einsum("cpk,ck->cp", samples[None] - starts[:, None], along) / \
        np.maximum((along * along).sum(1), 1e-300)[:, None]
    off = np.linalg.norm(samples[None] - starts[:, None] - t[..., None] * along[:, None], axis=2)
    inside = ((t >= 0) & (t <= 1) & (off <= radii[:, None])).any(axis=0)
    return float(weights[inside].sum())


def _remove_empty(records: list[dict], labels: np.ndarray) -> None:
    """Remove the records without sections, in place: children and points go to the parent; ids renumbered
    0..n-1 in list order (parents still first), ``labels`` with them."""
    index = [r["id"] for r in records]
    gone = {r["id"] for r in records if not r["sections"]}
    if not gone:
        return
    heir = {}
    for record in records:  # parents first: a removed parent's heir is known before its children
        if record["id"] in gone:
            parent = record["parent"]
            heir[record["id"]] = heir.get(parent, parent)
    for record in records:
        if record["id"] not in gone and record["parent"] in heir:
            record["parent"] = heir[record["parent"]]
    alive = [r for r in records if r["id"] not in gone]
    new_id = {r["id"]: k for k, r in enumerate(alive)}
    children = {k: [] for k in range(len(alive))}
    for r in alive:
        if r["parent"] >= 0:
            children[new_id[r["parent"]]].append(new_id[r["id"]])
    mapping = np.full(len(records), -1, np.int64)
    for old in index:
        alive_as = heir[old] if old in gone else old
        mapping[old] = new_id[alive_as] if alive_as >= 0 else -1
    valid = labels >= 0
    labels[valid] = mapping[labels[valid]]
    for r in alive:
        r["id"], r["parent"] = new_id[r["id"]], new_id[r["parent"]] if r["parent"] >= 0 else -1
        r["children"] = children[r["id"]]
    records[:] = alive

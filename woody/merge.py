"""The merge passes of cylinder following (:mod:`woody.cylinders`): small, aligned and duplicate branches.

After growth: small branches are given back to their parents, aligned
siblings (Table 3) and children aligned with their parent (Table 4) merge,
and in strict mode a branch grown inside an older one's cylinder joins it
(spec D-M11 and the additions of the cylinder-following module docstring).
Angles in degrees where named ``*_deg``, lengths in m.
"""

from __future__ import annotations

import copy

import numpy as np

from woody.branch import Branch
from woody.cylfit import angle_deg
from woody.geometry import segment_distance

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

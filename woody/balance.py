"""Volume balancing of cylinder following (:mod:`woody.cylinders`): Méndez's clustering step (Table 5).

Points move between a parent and a child branch while that lowers the
summed cylinder volume (m^3), with the axes fixed within a pass (spec
D-M12). Lengths in m.
"""

from __future__ import annotations

import numpy as np

from woody.branch import Branch


def balance_volume(branches: list[Branch], points: np.ndarray, params) -> int:
    """Clustering (Table 5): move points between parent and child while the total volume drops.

    Within a pass the axes are fixed; the only points whose removal can
    shrink a cylinder are its widest point and its two extreme projections,
    so each step tries those three on both sides of every parent-child pair.
    Passes stop when one moves nothing, or lowers the total volume by less
    than 0.1 % (the refits after a pass turn the axes, so that later moves
    can undo earlier ones: the loop would otherwise run to the cap).

    Parameters
    ----------
    branches : list of Branch
        The branches (changed in place: points move, cylinders are refitted).
    points : ndarray, (n, 3)
        The cloud, m.
    params : woody.cylinders.FollowParams
        Settings (``max_balance_passes``, ``mode``, ``min_branch_points``).

    Returns
    -------
    int
        The number of passes run.
    """
    def total_volume() -> float:
        return sum(np.pi * b.r_max ** 2 * (b.t1 - b.t0) for b in branches if b.direction is not None)

    volume = total_volume()
    for passes in range(1, params.max_balance_passes + 1):
        moved = False
        for child in branches:
            parent = child.parent
            if parent is None or child.direction is None or parent.direction is None:
                continue
            pair_moved = False
            for source, target in ((child, parent), (parent, child)):
                pair_moved |= _balance_pair(source, target, child, parent, points, params)
            if pair_moved:
                child.refit()
                parent.refit()
                moved = True
        before, volume = volume, total_volume()
        if not moved or volume > (1.0 - 1e-3) * before:
            return passes
    return params.max_balance_passes


def _balance_pair(source: Branch, target: Branch, child: Branch, parent: Branch, points: np.ndarray,
                  params) -> bool:
    """Greedy moves from ``source`` to ``target`` (fixed axes) while they lower the summed volume (m^3).

    Parameters
    ----------
    source, target : Branch
        The branch that gives points and the one that takes them.
    child, parent : Branch
        The pair, as child and parent (one of them is ``source``).
    points : ndarray, (n, 3)
        The cloud, m.
    params : woody.cylinders.FollowParams
        Settings (``mode``, ``min_branch_points``).

    Returns
    -------
    bool
        Whether any point moved.
    """
    moved = False
    src = np.array(source.points)
    t_s, r_s = _cylinder_stats(points[src], source.axis_point, source.direction)
    tgt_t, tgt_r = _cylinder_stats(points[np.array(target.points)], target.axis_point, target.direction)
    t_lo, t_hi, r_tgt = tgt_t.min(), tgt_t.max(), tgt_r.max()
    # Strict mode: a point moves only where the target's inclusion test would take it (within max(k_r) times its
    # envelope radius). With the paper's largest distance, every point within a trunk's one stray point's distance
    # costs the trunk nothing: on a simulated leafless apple-like tree (seed 5, simulation seed 8) the trunk took in
    # 1,500 points of the crown's base and its median radius went from 26 to 84 mm.
    reach = max(params.k_r) * target.reference_radius()
    keep = np.ones(len(src), bool)
    while keep.sum() > params.min_branch_points:
        rows = np.flatnonzero(keep)
        volume_src = np.pi * r_s[rows].max() ** 2 * (t_s[rows].max() - t_s[rows].min())
        volume_tgt = np.pi * r_tgt ** 2 * (t_hi - t_lo)
        best = None
        for row in {rows[np.argmax(r_s[rows])], rows[np.argmin(t_s[rows])], rows[np.argmax(t_s[rows])]}:
            rest = rows[rows != row]
            r_src_new = r_s[rest].max()
            v_src_new = np.pi * r_src_new ** 2 * (t_s[rest].max() - t_s[rest].min())
            (t_k,), (r_k,) = _cylinder_stats(points[src[row]][None], target.axis_point, target.direction)
            r_tgt_new = max(r_tgt, r_k)
            v_tgt_new = np.pi * r_tgt_new ** 2 * (max(t_hi, t_k) - min(t_lo, t_k))
            change = (v_src_new - volume_src) + (v_tgt_new - volume_tgt)
            if params.mode == "strict":
                r_child, r_parent = (r_src_new, r_tgt_new) if source is child else (r_tgt_new, r_src_new)
                allowed = r_child < r_parent and r_k <= reach
            else:
                allowed = r_src_new < r_tgt_new
            if change < 0 and allowed and (best is None or change < best[0]):
                best = (change, row, t_k, r_tgt_new)
        if best is None:
            break
        _, row, t_k, r_tgt = best
        t_lo, t_hi = min(t_lo, t_k), max(t_hi, t_k)
        keep[row] = False
        moved = True
    if moved:
        moving = set(src[~keep].tolist())
        source.points = [p for p in source.points if p not in moving]
        target.points += sorted(moving)
    return moved


def _cylinder_stats(xyz: np.ndarray, centroid: np.ndarray, direction: np.ndarray):
    """Projections ``t`` on the axis and orthogonal distances of points (m) to the axis through ``centroid``, m."""
    rel = xyz - centroid
    t = rel @ direction
    orth = np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - t * t, 0.0))
    return t, orth

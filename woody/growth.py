"""The growth of cylinder following (:mod:`woody.cylinders`): the round-robin loop of Méndez et al.

Table 1's loop (as the spec's D-M2 reads it) gives each active branch its
closest unassigned point in turn, with Table 2's closest-point search and
the inclusion test that starts a child branch (D-M6). The state of the loop
(which branch owns which point, the branches grown so far) lives in one
:class:`_Growth`. Lengths in m.
"""

from __future__ import annotations

import heapq

import numpy as np
from scipy.spatial import cKDTree

from woody.branch import Branch, is_significant


def grow(cloud: tuple, graph: np.ndarray, params, precision: float,
         progress: bool, anchors: np.ndarray | None = None) -> tuple[list[Branch], np.ndarray]:
    """The round-robin growth loop (Table 1), with the closest-point search of Table 2.

    Parameters
    ----------
    cloud : tuple
        ``(points (n, 3) in m, unit normals (n, 3) or None)``.
    graph : ndarray of int32, (n, k)
        Indices of each point's nearest neighbours within twice ``precision``
        (-1: none), the point itself excluded.
    params : woody.cylinders.FollowParams
        Settings.
    precision : float
        Largest point-to-branch distance for inclusion, m.
    progress : bool
        Show a progress bar over the included points.
    anchors : ndarray, (m, 3), optional
        Points of the tree reconstructed beforehand (a trunk's surface), m:
        strict mode's bridging counts them as grown, and a part bridged from
        one starts as a root branch.

    Returns
    -------
    branches : list of Branch
        The branches grown, refitted exactly, in the order they were started.
    owner : ndarray of int64, (n,)
        Branch id of every point (-1: never reached).
    """
    from tqdm import tqdm

    points = cloud[0]
    state = _Growth(cloud, graph, params, precision, anchors)
    branches = state.branches
    for index in _root_points(points, graph, params, precision):
        if not branches:
            state.new_branch(index, None, 1)
        else:
            state.owner[index] = 0
            branches[0].add(index)
            state.push_neighbours(branches[0], index)
    bar = tqdm(total=len(points), desc="cylinder following", disable=not progress, leave=False)
    bar.update(len(branches[0].points))
    active = [branches[0]]
    while active:
        while active:
            born = len(branches)
            for branch in active:
                j = state.closest_point(branch)
                if j < 0:
                    branch.active = False
                    continue
                bar.update(1)
                state.owner[j] = branch.id
                if not branch.seeded():
                    branch.add(j)
                    state.push_neighbours(branch, j)
                    continue
                distance, t_d = branch.tentative_distance(j)
                factor = params.k_r[0] if t_d < params.t_split else params.k_r[1]
                anchor = state.significant(branch.parent)
                if distance > factor * branch.reference_radius() or \
                        (anchor is not None and distance > anchor.reference_radius()):
                    state.owner[j] = -1
                    state.new_branch(j, branch, branch.order + 1)
                else:
                    branch.add(j)
                    state.push_neighbours(branch, j)
            active = [b for b in active if b.active] + branches[born:]
        if params.mode == "strict" and params.bridge_m > 0:
            active = state.bridge()
    bar.close()
    for branch in branches:
        branch.heap = []
        if branch.exact_n != branch.n:  # a branch refitted at its last point is exact already
            branch.refit()
    return branches, state.owner


def _root_points(points: np.ndarray, graph: np.ndarray, params, precision: float) -> list[int]:
    """The points the trunk starts from, lowest first.

    The paper starts from the lowest point. A lone stray return below the
    tree (a mixed pulse, a grazing edge) would then grow nothing, so the
    lowest point with three neighbours within ``precision`` is taken; in
    strict mode the trunk starts from all the points connected to it
    (through the neighbour graph) within four ``precision`` above it: the
    base of the stem, whatever pulse happens to be lowest, from which a
    first axis is fitted (a single point's first neighbours on a one-sided
    stem are a patch, whose axis can lie anywhere).

    Parameters
    ----------
    points : ndarray, (n, 3)
        The cloud, m.
    graph : ndarray of int32, (n, k)
        Neighbour indices (-1: none).
    params : woody.cylinders.FollowParams
        Settings (``mode``).
    precision : float
        Largest point-to-branch distance for inclusion, m.

    Returns
    -------
    list of int
        Indices into ``points``.
    """
    third = graph[:, min(2, graph.shape[1] - 1)]
    supported = (third >= 0) & (np.linalg.norm(points[np.maximum(third, 0)] - points, axis=1) < precision)
    candidates = np.flatnonzero(supported) if supported.any() else np.arange(len(points))
    root = int(candidates[np.argmin(points[candidates, 2])])
    if params.mode != "strict":
        return [root]
    top = points[root, 2] + 4.0 * precision
    seen, queue = {root}, [root]
    while queue:
        near = graph[queue.pop()]
        for j in near[near >= 0].tolist():
            if j not in seen and points[j, 2] <= top:
                seen.add(j)
                queue.append(j)
    return sorted(seen, key=lambda j: (points[j, 2], j))


class _Growth:
    """State of the growth loop: the cloud, its neighbour graph, the owner of every point and the branches.

    Parameters
    ----------
    cloud : tuple
        ``(points (n, 3) in m, unit normals (n, 3) or None)``.
    graph : ndarray of int32, (n, k)
        Neighbour indices (-1: none).
    params : woody.cylinders.FollowParams
        Settings.
    precision : float
        Largest point-to-branch distance for inclusion, m.
    anchors : ndarray, (m, 3), optional
        Points reconstructed beforehand that bridging counts as grown, m.
    """

    def __init__(self, cloud: tuple, graph: np.ndarray, params, precision: float, anchors: np.ndarray | None = None):
        self.cloud, self.points, self.graph = cloud, cloud[0], graph
        self.params, self.precision = params, precision
        self.anchors = np.empty((0, 3)) if anchors is None else np.asarray(anchors, float).reshape(-1, 3)
        self.owner = np.full(len(self.points), -1, np.int64)
        self.branches: list[Branch] = []

    def new_branch(self, index: int, parent, order: int) -> Branch:
        """Start a branch at point ``index`` (a child of ``parent``, None for the trunk) of the given order."""
        branch = Branch(len(self.branches), index, parent, order, self.cloud, self.params)
        self.branches.append(branch)
        if parent is not None:
            parent.children.append(branch)
        self.owner[index] = branch.id
        self.push_neighbours(branch, index)
        return branch

    def push_neighbours(self, branch: Branch, index: int) -> None:
        """Queue the unassigned neighbours of point ``index`` on ``branch``'s heap, keyed by their distance (m)."""
        near = self.graph[index]
        near = near[near >= 0]
        near = near[self.owner[near] < 0]
        if len(near):
            for key, j in zip(branch.distance(self.points[near]).tolist(), near.tolist()):
                heapq.heappush(branch.heap, (key, j))

    def closer_elsewhere(self, branch: Branch, index: int, d: float) -> bool:
        """Whether a branch owning a neighbour of point ``index`` is closer to it than ``d`` (m)."""
        near = self.graph[index]
        others = {int(o) for o in self.owner[near[near >= 0]] if o >= 0 and o != branch.id}
        # Ties (e.g. a point inside two overlapping cylinders, distance 0) go to the older branch.
        return any(self.branches[o].distance(self.points[index][None])[0] < d + (1e-12 if o < branch.id else 0.0)
                   for o in others)

    def closest_point(self, branch: Branch) -> int:
        """Index of the branch's closest admissible unassigned point, or -1."""
        heap = branch.heap
        while heap:
            key, j = heapq.heappop(heap)
            if self.owner[j] >= 0:
                continue
            d = float(branch.distance(self.points[j][None])[0])
            if heap and d > heap[0][0] + 1e-12:
                heapq.heappush(heap, (d, j))  # stale key: re-queue with the current distance
                continue
            if d >= self.precision:
                heapq.heappush(heap, (d, j))
                return -1
            if self.closer_elsewhere(branch, j, d):
                continue
            return j
        return -1

    def significant(self, branch):
        """The significant ancestor (Table 2, bottom), starting at ``branch``."""
        while branch is not None and not is_significant(branch.order, branch.n, self.params):
            branch = branch.parent
        return branch

    def bridge(self) -> list[Branch]:
        """Start a branch on each part of the cloud that growth could not reach, nearest parts first.

        A single scan falls apart where leaves, other branches or the stem
        itself hide a branch. Each unreached part (connected through the
        neighbour graph, at least ``min_branch_points`` points) whose gap to
        the grown points is at most ``bridge_m`` and at most twice the
        smallest such gap plus ``precision`` is started at its point nearest
        to the grown points, as a child of the branch that owns the grown
        point across the gap (a root of its own when what lies across the
        gap is one of the ``anchors``): it grows away from the tree, with the
        free-seed count of its order and under its significant ancestor's
        radius, instead of as a trunk of its own. Parts farther off wait for
        the next round, when the parts attached now may have brought the
        tree closer to them.

        Returns
        -------
        list of Branch
            The branches started (empty when no part is within reach).
        """
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        free = np.flatnonzero(self.owner < 0)
        grown = np.flatnonzero(self.owner >= 0)
        if not len(free) or not len(grown):
            return []
        local = np.full(len(self.points), -1, np.int64)
        local[free] = np.arange(len(free))
        rows = np.repeat(np.arange(len(free)), self.graph.shape[1])
        cols = self.graph[free].ravel()
        cols = np.where(cols >= 0, local[np.maximum(cols, 0)], -1)
        keep = cols >= 0
        adjacency = coo_matrix((np.ones(int(keep.sum()), np.int8), (rows[keep], cols[keep])),
                               shape=(len(free), len(free)))
        _, part = connected_components(adjacency, directed=False)
        sizes = np.bincount(part)
        large = sizes[part] >= self.params.min_branch_points
        if not large.any():
            return []
        gap, nearest = cKDTree(np.vstack([self.points[grown], self.anchors])).query(
            self.points[free[large]], distance_upper_bound=self.params.bridge_m)
        parts = part[large]
        order = np.lexsort((gap, parts))  # within each part, its nearest point first
        first = order[np.r_[True, np.diff(parts[order]) != 0]]
        first = first[np.isfinite(gap[first])]
        if not len(first):
            return []
        first = first[gap[first] <= 2.0 * gap[first].min() + self.precision]
        started = []
        for row in first[np.argsort(gap[first], kind="stable")]:
            index = int(free[large][row])
            if nearest[row] >= len(grown):  # across the gap lies an anchor: a root of its own
                started.append(self.new_branch(index, None, 1))
                continue
            parent = self.branches[int(self.owner[grown[nearest[row]]])]
            started.append(self.new_branch(index, parent, parent.order + 1))
        return started

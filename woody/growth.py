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

from woody.branch import Branch, is_significant


def grow(cloud: tuple, graph: np.ndarray, params, precision: float,
         progress: bool) -> tuple[list[Branch], np.ndarray]:
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

    Returns
    -------
    branches : list of Branch
        The branches grown, refitted exactly, in the order they were started.
    owner : ndarray of int64, (n,)
        Branch id of every point (-1: never reached).
    """
    from tqdm import tqdm

    points = cloud[0]
    state = _Growth(cloud, graph, params, precision)
    branches = state.branches
    # Root: the lowest point with three neighbours within Precision. The paper starts from the lowest
    # point; a lone stray return below the tree (a mixed pulse, a grazing edge) would then grow nothing.
    supported = (graph[:, min(2, graph.shape[1] - 1)] >= 0) & \
        (np.linalg.norm(points[np.maximum(graph[:, min(2, graph.shape[1] - 1)], 0)] - points, axis=1) < precision)
    candidates = np.flatnonzero(supported) if supported.any() else np.arange(len(points))
    root = int(candidates[np.argmin(points[candidates, 2])])
    state.new_branch(root, None, 1)
    bar = tqdm(total=len(points), desc="cylinder following", disable=not progress, leave=False)
    bar.update(1)
    active = [branches[0]]
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
    bar.close()
    for branch in branches:
        branch.heap = []
        branch.refit()
    return branches, state.owner


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
    """

    def __init__(self, cloud: tuple, graph: np.ndarray, params, precision: float):
        self.cloud, self.points, self.graph = cloud, cloud[0], graph
        self.params, self.precision = params, precision
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

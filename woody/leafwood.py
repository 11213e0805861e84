"""Leaf/wood separation of a tree's point cloud from its geometry alone (no intensity, no scanner position).

Wood is what the tree's paths run through: leaves and needles hang at the
ends of them. The cloud is thinned to one point per voxel (``VOXEL_M``, or
the point spacing of a sparser cloud) and linked into a graph of each
point's ``NEIGHBOURS`` nearest neighbours, weighted by their distance. The
shortest paths (Dijkstra) from the base of each connected part (its points
within ``BASE_M`` of its lowest) form a tree; a point's *reach* is how far
the paths through it go on beyond it (the largest path length of its
descendants less its own). A leaf, a needle tuft or a stray point is a dead
end: its points reach no farther than its own size. A point of the trunk or
of a branch carries the paths to everything above it and reaches on to the
tips. Points that reach ``REACH_M`` or more are the wood's core. The paths
run up a stem along a few lines of its surface; the surface between them is
given back: a point off the core is wood when nothing the paths reach
through it lies farther than ``MARGIN_VOXELS`` from the core (a dead end
that leads into a leaf or a tuft does not), and so are the base's points
within ``REACH_M`` of the core (the stem's foot all round).

The idea of tracing the paths from the base and keeping the points they run
through is TLSeparation's path retracing (Vicari et al. 2019, Methods in
Ecology and Evolution 10: 680-694); LeWoS (Wang 2020, Methods in Ecology and
Evolution 11: 376-389) segments the graph and keeps linear segments
instead. Per-point eigenvalue features (linearity, planarity, scattering
of neighbourhoods of 2-16 cm; Demantké et al. 2011) were tried first and
told the synthetic pear's wood from its leaves poorly (woody notebook,
round 30).

Assumptions: the wood of a tree is connected from its base (occluded wood
seen as a detached piece is kept only if the paths run on through it for
``REACH_M``); no leaf or needle cluster reaches more than ``REACH_M``
beyond where its path leaves the wood; so the last ``REACH_M`` of every
twig and twigs shorter than that go with the leaves: on a leafless cloud
that is the cost of the separation (rTwig's tree: 14 % of its points,
woody notebook, round 30). Leaves that touch one another can carry a path
beyond ``REACH_M``: such chains stay in. The cost is a k-d tree, a sparse
graph of ``NEIGHBOURS`` edges per point, one Dijkstra run and two passes
over the path tree: O(n log n) in the voxel count.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from woody.cloud import check_points
from woody.density import point_spacing, voxel_centroids
from woody.errors import WoodyError

#: Voxel edge of the graph's points, m (assumption: finer than a leaf's width and than the 2 cm branches cylinder
#: following resolves, coarse enough that a needle tuft is a blob, not single needles; clouds sparser than it use
#: their own point spacing).
VOXEL_M = 0.01
#: Nearest neighbours each graph point is linked to (assumption: enough to link a surface's points across scan
#: lines, few enough that an edge stays within a few voxels).
NEIGHBOURS = 10
#: Smallest reach of the wood's core, m (assumption: about the blade of the conference-pear leaves of scenes.tree,
#: 6.5 cm times the preset's median size 1.3, and the 7-10 cm needles of a pine; 0.10 rather than 0.15 chosen on
#: rTwig's leafless tree, whose twigs 0.15 took 3.3 points of volume from, and the synthetic pear seed 1; woody
#: notebook, round 30).
REACH_M = 0.10
#: A cloud whose voxel (its point spacing) is coarser than ``REACH_M`` over this is left whole, all wood: a leaf or
#: a needle tuft spans too few of its points to be told from a twig's end (assumption; aRchi's Tree_1, 6.9 cm
#: apart, lost 2.6 % of its points, the ends of its crown's twigs, and 26 points of volume error otherwise).
MIN_VOXELS_PER_REACH = 3.0
#: The paths start from every point this close above the lowest point of its connected part, m (assumption: a
#: stem's foot all round, so that the paths run up along its whole surface, not fanned out from one point).
BASE_M = 0.05
#: A point off the core is wood when nothing the paths reach through it lies farther than this many voxels from the
#: core: the surface of a stem between the paths that run along it (assumption: leaves and needles, 6 cm and
#: longer, stick out farther).
MARGIN_VOXELS = 3.0


def separate_wood(points, voxel_m: float = VOXEL_M, reach_m: float = REACH_M, neighbours: int = NEIGHBOURS) -> np.ndarray:
    """Which points of a tree's cloud are wood, from the geometry alone (see the module docstring).

    Parameters
    ----------
    points : array_like, (n, 3)
        One tree, m (z up); leaves, needles, noise and ground may be left in.
    voxel_m : float
        Voxel edge of the graph, m (the cloud's point spacing when larger).
    reach_m : float
        Smallest reach of the wood's core, m.
    neighbours : int
        Nearest neighbours each graph point is linked to.

    Returns
    -------
    ndarray of bool, (n,)
        True for wood (every point of a cloud sparser than ``reach_m / MIN_VOXELS_PER_REACH``).

    Raises
    ------
    WoodyError
        If a setting is not positive, or the cloud has fewer than ``neighbours + 1`` voxels.

    Examples
    --------
    A 1 m pole (points 5 mm apart) with a 5 cm blob of points 8 cm beside its top: the pole is wood, the blob is
    not.

    >>> import numpy as np
    >>> z = np.arange(0.0, 1.0, 0.005)
    >>> pole = np.column_stack([0.01 * np.cos(z * 900), 0.01 * np.sin(z * 900), z])
    >>> blob = np.array([0.08, 0.0, 0.9]) + np.random.default_rng(0).uniform(-0.025, 0.025, (200, 3))
    >>> wood = separate_wood(np.vstack([pole, blob]))
    >>> bool(wood[:len(pole)][z < 0.8].all()), int(wood[len(pole):].sum())
    (True, 0)
    """
    points = check_points(points)
    if not (np.isfinite(voxel_m) and voxel_m > 0 and np.isfinite(reach_m) and reach_m > 0):
        raise WoodyError(f"voxel_m and reach_m must be positive lengths in metres, got {voxel_m}, {reach_m}")
    if int(neighbours) < 1:
        raise WoodyError(f"neighbours must be at least 1, got {neighbours}")
    voxel = max(float(voxel_m), point_spacing(points)) if len(points) >= 7 else float(voxel_m)
    if voxel > reach_m / MIN_VOXELS_PER_REACH:  # too sparse to see a leaf as a dead end of several points
        return np.ones(len(points), bool)
    cell, centres = voxel_centroids(points, voxel)
    if len(centres) <= neighbours:
        raise WoodyError(f"{len(centres)} voxels of {voxel:.3f} m are too few for {neighbours} neighbours each")
    tree = cKDTree(centres)
    reach, parent, part = path_reach(centres, tree, int(neighbours))
    core = reach >= reach_m
    if not core.any():
        return np.zeros(len(points), bool)
    # a point off the core is wood when nothing the paths reach through it lies farther than the margin from the core
    away, _ = cKDTree(centres[core]).query(centres)
    wood = core | (_subtree_max(away, parent, reach) <= MARGIN_VOXELS * voxel)
    # a stem's foot all round (the paths start from all of it): the base of a part with a core
    wood |= (parent < 0) & (np.bincount(part, weights=core)[part] > 0) & (away <= reach_m)
    return wood[cell]


def path_reach(centres: np.ndarray, tree: cKDTree, neighbours: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How far the shortest paths from each connected part's base (``BASE_M``) go on beyond each point, m.

    Parameters
    ----------
    centres : ndarray, (m, 3)
        The graph's points, m.
    tree : scipy.spatial.cKDTree
        Their k-d tree.
    neighbours : int
        Nearest neighbours each point is linked to (edges weighted by their length, both ways).

    Returns
    -------
    reach : ndarray, (m,)
        The largest path length of the point's descendants in the shortest-path tree less its own, m (0 for a
        dead end).
    parent : ndarray of int, (m,)
        Each point's predecessor in the shortest-path tree (negative for a base point).
    part : ndarray of int, (m,)
        The connected part of the graph each point belongs to.
    """
    count = len(centres)
    distance, index = tree.query(centres, k=neighbours + 1)
    rows = np.repeat(np.arange(count), neighbours)
    # coincident points get a tiny weight: a zero would drop the edge from the sparse graph
    graph = coo_matrix((np.maximum(distance[:, 1:].ravel(), 1e-9), (rows, index[:, 1:].ravel())),
                       shape=(count, count)).tocsr()
    graph = graph.maximum(graph.T)
    parts, part = connected_components(graph, directed=False)
    lowest = np.full(parts, np.inf)
    np.minimum.at(lowest, part, centres[:, 2])
    base = np.flatnonzero(centres[:, 2] <= lowest[part] + BASE_M)
    length, parent = dijkstra(graph, directed=False, indices=base, min_only=True, return_predecessors=True)[:2]
    farthest = length.copy()
    for node in np.argsort(-length, kind="stable"):  # descendants before their parents
        up = parent[node]
        if up >= 0 and farthest[node] > farthest[up]:
            farthest[up] = farthest[node]
    return farthest - length, parent, part


def _subtree_max(values: np.ndarray, parent: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """The largest of ``values`` over each point and its descendants in the shortest-path tree."""
    out = values.copy()
    for node in np.argsort(reach, kind="stable"):  # descendants before their ancestors: reach grows towards the base
        up = parent[node]
        if up >= 0 and out[node] > out[up]:
            out[up] = out[node]
    return out

"""Leaf/wood separation of a tree's point cloud from its geometry alone (no intensity, no scanner position).

Wood is what the tree's paths run through: leaves and needles hang at the
ends of them. The cloud is thinned to one point per voxel (``VOXEL_M``, or
the point spacing of a sparser cloud) and linked into a graph of each
point's ``NEIGHBOURS`` nearest neighbours, weighted by their distance. The
shortest paths from the lowest point of each connected part (Dijkstra) form
a tree; a point's *reach* is how far the paths through it go on beyond it
(the largest path length of its descendants less its own). A leaf, a needle
tuft or a stray point is a dead end: its points reach no farther than its
own size. A point of the trunk or of a branch carries the paths to
everything above it and reaches on to the tips. Points that reach
``REACH_M`` or more are the wood's core; every point within two voxels of
the core is wood (the paths run along a few lines of a stem's surface: the
margin gives the surface between them back). The idea of tracing the paths
from the base and keeping the points many paths cross is the path
retracing of TLSeparation (Vicari et al. 2019, Methods in Ecology and
Evolution 10: 680-694; also Wang et al. 2020's LeWoS, which segments the
graph instead); this is a plain version of it on a k-nearest-neighbour
graph.

Assumptions: the tree's wood is one connected structure from its base
(occluded wood seen as a detached piece is kept only if that piece is
longer than ``REACH_M``); no leaf or needle cluster reaches more than
``REACH_M`` beyond where its path leaves the wood; the last ``REACH_M`` of
every twig is lost with the leaves (on a leafless cloud that is the cost of
the separation: a small volume, see the README's measurements). Leaves that
touch one another can carry a path beyond ``REACH_M``: such chains stay in.
The cost is a k-d tree, a sparse graph of ``NEIGHBOURS`` edges per point
and one Dijkstra run: O(n log n) in the voxel count.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from woody.cloud import check_points
from woody.density import point_spacing
from woody.errors import WoodyError

#: Voxel edge of the graph's points, m (assumption: finer than a leaf's width and than the 2 cm branches cylinder
#: following resolves, coarse enough that a needle tuft is a blob, not single needles; clouds sparser than it use
#: their own point spacing).
VOXEL_M = 0.01
#: Nearest neighbours each graph point is linked to (assumption: enough to link a surface's points across scan
#: lines, few enough that an edge stays within a few voxels).
NEIGHBOURS = 10
#: Smallest reach of the wood's core, m (assumption: longer than the pear leaves of scenes.tree, 6-10 cm, and the
#: 7-10 cm needles of a pine; chosen on the synthetic conference pear, seed 1, and checked on others: see the
#: woody notebook, round 30).
REACH_M = 0.15
#: The wood grows on beyond the core into a point whose dead end (the point and all it leads to) spreads less than
#: this many voxels across its own axis (standard deviation): a twig's tip (assumption: a twig thinner than a
#: voxel is a line of voxels, spread near 0; a leaf 4 cm wide spreads 1.2 cm, a needle tuft more).
TIP_SPREAD_VOXELS = 0.5
#: The paths start from every point this close above the lowest point of its connected part, m (assumption: a
#: stem's foot all round, so that the paths run up along its whole surface, not fanned out from one point).
BASE_M = 0.05
#: A dead end that hangs off the core is wood when none of its points lies farther than this many voxels from the
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
        True for wood.

    Raises
    ------
    WoodyError
        If a setting is not positive, or the cloud has fewer than ``neighbours + 1`` voxels.

    Examples
    --------
    A 1 m pole (points 5 mm apart) with a 5 cm blob of points beside its top: the pole is wood, the blob is not.

    >>> import numpy as np
    >>> z = np.arange(0.0, 1.0, 0.005)
    >>> pole = np.column_stack([0.01 * np.cos(z * 900), 0.01 * np.sin(z * 900), z])
    >>> blob = np.array([0.05, 0.0, 0.9]) + np.random.default_rng(0).uniform(-0.025, 0.025, (200, 3))
    >>> wood = separate_wood(np.vstack([pole, blob]))
    >>> bool(wood[z < 0.8].all()), int(wood[len(pole):].sum())
    (True, 0)
    """
    points = check_points(points)
    if not (np.isfinite(voxel_m) and voxel_m > 0 and np.isfinite(reach_m) and reach_m > 0):
        raise WoodyError(f"voxel_m and reach_m must be positive lengths in metres, got {voxel_m}, {reach_m}")
    if int(neighbours) < 1:
        raise WoodyError(f"neighbours must be at least 1, got {neighbours}")
    voxel = max(float(voxel_m), point_spacing(points)) if len(points) >= 7 else float(voxel_m)
    cell, centres = _voxels(points, voxel)
    if len(centres) <= neighbours:
        raise WoodyError(f"{len(centres)} voxels of {voxel:.3f} m are too few for {neighbours} neighbours each")
    tree = cKDTree(centres)
    reach, parent = path_reach(centres, tree, int(neighbours))
    core = reach >= reach_m
    if not core.any():
        return np.zeros(len(points), bool)
    # a point off the core is wood when nothing the paths reach through it lies farther than the margin from the core
    away, _ = cKDTree(centres[core]).query(centres)
    wood = core | (_subtree_max(away, parent, reach) <= MARGIN_VOXELS * voxel)
    wood |= (parent < 0) & (away <= reach_m)  # a stem's foot all round: the paths start from all of it
    # a twig's tip: the wood grows on along the paths into every point whose dead end is a thin line
    thin = _subtree_spread(centres, parent, reach, ~core) <= TIP_SPREAD_VOXELS * voxel
    return _extend(wood, parent, reach, thin)[cell]


def path_reach(centres: np.ndarray, tree: cKDTree, neighbours: int) -> np.ndarray:
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
    return farthest - length, parent


def _subtree_max(values: np.ndarray, parent: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """The largest of ``values`` over each point and its descendants in the shortest-path tree."""
    out = values.copy()
    for node in np.argsort(reach, kind="stable"):  # descendants before their ancestors: reach grows towards the base
        up = parent[node]
        if up >= 0 and out[node] > out[up]:
            out[up] = out[node]
    return out


def _extend(wood: np.ndarray, parent: np.ndarray, reach: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """``wood`` grown along the shortest-path tree into the ``allowed`` children of wood points, and on."""
    wood = wood.copy()
    for node in np.argsort(-reach, kind="stable"):  # ancestors before their descendants
        up = parent[node]
        if not wood[node] and allowed[node] and up >= 0 and wood[up]:
            wood[node] = True
    return wood


def _subtree_spread(centres: np.ndarray, parent: np.ndarray, reach: np.ndarray, counted: np.ndarray) -> np.ndarray:
    """The spread of each ``counted`` point's subtree across its principal axis: the square root of the second
    eigenvalue of the covariance of the point and its descendants, m (the sums are passed up the shortest-path
    tree; points not ``counted`` pass nothing up and get infinity)."""
    x, y, z = centres.T
    sums = np.column_stack([np.ones(len(centres)), x, y, z, x * x, x * y, x * z, y * y, y * z, z * z])
    sums[~counted] = 0.0
    for node in np.argsort(reach, kind="stable"):  # descendants before their ancestors
        up = parent[node]
        if up >= 0 and counted[node] and counted[up]:
            sums[up] += sums[node]
    n = np.maximum(sums[:, 0], 1.0)
    mean = sums[:, 1:4] / n[:, None]
    second = sums[:, [4, 5, 6, 5, 7, 8, 6, 8, 9]].reshape(-1, 3, 3) / n[:, None, None]
    cov = second - mean[:, :, None] * mean[:, None, :]
    spread = np.sqrt(np.maximum(np.linalg.eigvalsh(cov)[:, 1], 0.0))
    return np.where(counted, spread, np.inf)


def _voxels(points: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Each point's voxel (index into the centres) and the centroid of each occupied voxel, m."""
    index = np.floor((points - points.min(axis=0)) / voxel).astype(np.int64)
    shape = index.max(axis=0) + 1
    if float(np.prod(shape.astype(float))) >= 2.0**62:
        raise WoodyError(f"voxels of {voxel} m over a cloud this large overflow the voxel index; use larger voxels")
    key = (index[:, 0] * shape[1] + index[:, 1]) * shape[2] + index[:, 2]
    _, cell, counts = np.unique(key, return_inverse=True, return_counts=True)
    cell = cell.reshape(-1)
    centres = np.zeros((len(counts), 3))
    np.add.at(centres, cell, points)
    return cell, centres / counts[:, None]

"""Cylinder following: leafless tree reconstruction after Méndez et al.

(V. Méndez, J. R. Rosell-Polo, R. Sanz, A. Escolà, H. Catalán, "Deciduous tree
reconstruction algorithm based on cylinder fitting from mobile terrestrial
laser scanned point clouds", author manuscript; it follows Pfeifer et al. 2004.)

Each branch is a cylinder: an axis ``P1 -> P2`` (the extreme projections of
its points) and a radius. Growth starts from the lowest point (in strict
mode: from the base of the stem around it) and
repeatedly gives each active branch its closest unassigned point
(round-robin, one point per branch and visit: the paper's Table 1 loop read
as the spec's D-M2); a point goes to a branch only if no other branch is
closer (ties to the older branch). The first points of a branch are taken
without test ("free seeding", ``n_s`` by order, Table 7); afterwards a point
that lies farther from the refitted axis than ``k_r(t_d)`` times the
branch's radius, or than the radius of the branch's *significant* ancestor,
starts a child branch (D-M6: both the text's and the pseudocode's test).
Then: merge sibling branches whose angles to the parent differ by less than
4 deg, merge children within 11.5 deg of their parent, and move points
between parent and child where that lowers the total volume.

Two modes. ``FollowParams()`` (the default, "spec") makes the choices below
so that the method works on dense and on fully sampled stems;
``benchmarks.experiments.woody_experiments.PAPER_MODE`` reads the paper literally (covariance
axis through the centroid, radius = largest distance, running-maximum
test, merges as printed, one cylinder per branch).

Decisions where the paper is silent, contradicts itself or fails on our
test trees (spec Part D; each a documented departure in the default mode):

- axis direction (D-M3). Paper: a covariance eigenvector through the
  centroid, the one minimising the largest orthogonal distance
  (``direction="covariance"``; ``"iterative"`` is the polar-azimuth minimax
  search after Rabbani & van den Heuvel 2005). That fails on the first
  points of a wide stem, a patch or an arc along the rim, so by default
  (``"normals"``) the axis is the direction least aligned with the PCA
  normals when they clearly lie in one plane, else the long axis of an
  elongated cluster, else the normals' direction when merely decisive,
  else the paper's minimax eigenvector;
- axis position: by default (``axis="circle"``) the centre of a robust
  circle fitted to the points seen along the axis, once they curve around
  it (a one-sided scan sees half a stem, whose centroid is 0.64 r off the
  axis); ``"centroid"`` is the paper's;
- radius (D-M4) and the inclusion test: with the paper's reading (radius =
  largest orthogonal distance, a point "not aligned" when the radius would
  exceed ``k_r r``) a smooth fork never shows a 5-10 % jump between
  consecutive closest points, the radius creeps and one cylinder swallows
  the fork (seen on the Y-shaped test tree). By default
  (``inclusion="envelope"``) the test compares the new point's distance
  with ``k_r`` times the envelope radius of the branch's last exact fit,
  the median distance plus three robust standard deviations, which no
  minority of points can drag along; ``"max"`` is the paper's. The reported
  radius is ``radius="median"`` (default), ``"mean"`` or ``"max"`` (paper);
  the volume-balancing pass uses the largest distance, as the paper;
- free seeding ends after ``n_s`` points or, earlier, once the branch has
  6 points or more and an axis at least two diameters long (``n_s`` is
  meant to grow with density, and Table 7 was tuned for sparse mobile
  scans: at TLS densities 40-80 free points swallow whole forks);
- distance of a point to a branch (D-M5): ``max(0, d(P, P1P2) - r)`` with
  the largest distance as ``r``; candidates are the k nearest neighbours of
  the branch's points; the default ``Precision`` is 2.5 x the nominal
  spacing (from the median distance to the 6th neighbour);
- ``t_d`` normalised by ``|P2 - P1|`` (D-M7); ``ord_min1 = 2``,
  ``ord_min2 = 4``, ``n_min = 2 n_s(order)`` with AND semantics (D-M8);
  ``order <= threshold`` selects ``n_s`` (D-M9); axes point away from the
  branch base (D-M10);
- sibling merging (D-M11): ``mode="strict"`` (default) also requires
  the two children to be within 4 deg of each other and their union to fit
  one cylinder (95th-percentile distance within ``max(k_r)`` of the wider
  one's; the same holds for child-into-parent merges); ``"faithful"``
  compares only their angles to the parent, as printed;
- volume balancing (D-M12): axes fixed within a pass (a refit per
  candidate point would cost O(n)); strict mode keeps the child thinner
  than its parent and moves a point only where the inclusion test would
  take it (within ``max(k_r)`` times the robust envelope radius of the
  taking branch: with the paper's largest distance a trunk's one stray
  point let it take in the crown's base), faithful mode applies the
  printed ``Tmp1.radius < Tmp2.radius``; at most ``max_balance_passes`` passes;
- start and gaps (strict mode, additions): the trunk starts from every
  point connected to the lowest one within four ``Precision`` above it,
  not from one point: which pulse at the stem base is lowest decided how
  far growth reached (a simulated leafy pear, four noise realisations:
  -96 to -48 % volume). When growth ends, each part of the cloud it did
  not reach (a single scan falls apart behind leaves and branches; 80-95
  parts on that pear) is started, nearest first, as a child of the branch
  across the gap (up to ``bridge_m``), so it grows under its ancestors'
  radii instead of as a trunk of its own;
- forks (strict mode, addition, :mod:`woody.fork`): a root stem whose
  slice falls apart into two limbs, each fitting its own circle of 1/3 to
  1/sqrt(2) of the stem's radius (the pipe model), ends there and its
  points past the fork go to the leaders (the quick suite's leafy tree
  with the trunk fitted first: the stem ran 48 cm past its four-way fork,
  now 26 cm; volume error +16.8 -> +1.3 %);
- hidden stretches (strict mode, addition, :mod:`woody.gaps`): a branch
  whose first section the points resolve and whose axis, extended back,
  runs through no resolved wood as wide as itself for more than four of
  its radii before it meets such wood within ``bridge_m`` gets cylinders
  along that line, radii from the pipe model, when it carries at least
  the stretch's length and a point lies on the line's surface (the gap's wood was missing: leaves hid 0.1-1.1 m
  of a 51 mm leader of a simulated leafy pear; the trees suite's leafy
  pears went from -26.2 / -18.1 / -28.3 to -21.8 / -15.4 / -25.7 % volume);
- wood counted twice (strict mode, addition, :func:`woody.merge.drop_doubled`):
  last, a section with three quarters of its volume inside other branches'
  sections is dropped, youngest first (on aRchi's real Tree_1 a leader
  followed twice, at 0.10-0.13 and at 0.16 m, and sibling branches along
  one limb: 7.5 % of its volume in two branches at once);
- radii (strict mode, additions): a reported radius is at most 1.3 times
  the radius the points' spread across the axis gives (``sqrt(2 lambda)``),
  and no branch is wider than its parent (the paper's inclusion test uses
  the significant ancestor only); a section clamped at its parent's radius
  whose points cover less than half of its fitted circle's visible half
  (a circle drawn across several twigs) takes the pipe model's radius
  below, not the parent's (such clamped sections held 6.1 of the 11.2 dm3
  reconstructed on a simulated leafless apple-like tree of 2.8 dm3), and
  one whose points cover its circle and lie on it keeps its own radius
  (the clamp was the parent's error: a limb grown as the child of a thin
  piece across a gap or under a parent piece fitted too thin), also
  through the pipe model below, which judges the radius it keeps (judged
  on the clamped radius, the leaders of a simulated leafy pear found as
  children of 2.9 mm twigs came out at 0.37 of their 1-2.5 cm radii);
  under a parent section the points do not resolve (its radius a clamp's
  or the pipe model's guess, no evidence against the child's circle) a
  clamped section also keeps its own radius when its points lie on one
  circle its radius was cut from by the spread cap (``_on_arc``: an arc
  narrower than 120 deg, a limb half hidden by leaves, that bulges by at
  least half a point spacing however narrow it is): the leaders of
  the leafy pears of ``benchmarks/suites/trees.yaml`` were followed as
  chains of fragments under 1-4 mm pieces, and sections fitted at 18-36 mm
  on 20-40 mm leaders were held at 1.7-3.8 mm (under resolved parents too,
  the test moved the suite's pear seed 4 from -21.9 to -23.2 % volume and
  apple seed 2 from +2.8 to +4.1 %: there the clamp is evidence);
  and a section the points resolve is no wider than the radius at which
  they would still cover half of its visible half surface
  (``covered_radii``): circles fitted to a dozen stray points beside a
  stem were 17-20 mm wide where no wood was (0.30 of the 0.72 dm3 of
  false volume on a simulated leafless apple-like tree of 2.7 dm3, 0.65
  of 1.58 dm3 on a leafy pear);
- unresolved radii (strict mode, addition, ``pipe_model=True``, the
  default): a section whose radius is under one point spacing, or whose
  branch's points beside it scatter about its surface by more than a
  quarter of its radius, takes at most its nearest resolved ancestor
  section's radius times the square root of their growth lengths' ratio
  (the pipe model, :mod:`woody.pipe`): circles fitted to the noise of
  twigs thinner than the spacing, or to clusters of twigs, were 5-10
  times the twigs' radii;
- radii thinner than the beam (strict mode, addition, with ``viewpoint``
  and ``footprint_m``): an unresolved section is at most half as wide as
  its points spread across the line of sight less the beam's footprint
  (:mod:`woody.footprint`): the pipe model gave the twigs of a simulated
  leafless apple-like tree, 0.01-3 mm against a 4.9 mm footprint, about
  three times their radius, also from the true tree's own resolved limbs;
  and at most half the width its points' count gives the silhouette
  (``count spacing^2 / length``, median over its stretches, those without
  points unbounded) less the footprint
  (:func:`woody.footprint.silhouette_radius`): the spread spans the gaps of
  a section fitted across several twigs side by side, the count does not;
  and a section the points resolve takes, where narrower, the circle of
  its points whose beam lay wholly on it (the facing side, within
  ``r - D / 2`` of the axis across the line of sight;
  :func:`woody.footprint.facing_radius`): the points near a silhouette lie
  outside the surface and widened a simulated apple-like tree's stem
  circles by 0.5-1.9 mm;
- clean-up (strict mode, additions): branches with fewer than
  ``min_branch_points`` points are given back to their parents (a stalled
  root to its largest child); a branch whose axis midpoint lies inside an
  older branch's cylinder is merged into it (a duplicate grown alongside);
- output: each branch is cut into pieces of ``section_radii`` radii, each
  refitted on its own points (0 gives the paper's one cylinder per
  branch); in strict mode the radius hierarchy is applied to the
  output: no piece is wider than ``max(k_r)`` times the piece before it or
  than its parent where it starts;
- orders are recomputed from the trunk after the merges (D-M14).

Cost: a KD-tree and a k-nearest-neighbour graph (O(N log N)), then one heap
push per neighbour of each included point and amortised O(1) refits
(running sums of the points, their outer products and their normals'
outer products; the exact O(n) fit is redone each time a branch grows by
10 %), i.e. O(N log N) overall.

Modules: :mod:`woody.cylfit` (axis directions and circles),
:mod:`woody.branch` (a growing branch and its cylinder),
:mod:`woody.growth` (the round-robin loop), :mod:`woody.merge` (the
merge passes), :mod:`woody.balance` (volume balancing); this one holds
the settings, the entry point and the output records.
"""

from __future__ import annotations

import copy
import math
import numbers
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from woody.balance import balance_volume
from woody.branch import Branch
from woody.cloud import check_points
from woody.cylfit import angle_deg
from woody.density import thin_to_spacing
from woody.errors import WoodyError
from woody.footprint import facing_radius, lateral_radii
from woody.fork import cut_forks
from woody.gaps import extend_over_strips, fill_gaps
from woody.geometry import cylinders_mesh, cylinders_volume, orthonormal_frame, segment_distance
from woody.growth import grow
from woody.merge import dissolve_small, drop_doubled, merge_contained, merge_into_parents, merge_siblings
from woody.normals import pca_normals
from woody.pipe import pipe_radii

#: Table 7 of Méndez et al., apple tree: (order threshold, n_s) pairs, "order <= threshold".
APPLE_FREE_SEED = ((1, 80), (3, 60), (7, 40), (10, 30), (9999, 20))
#: Table 7, vine.
VINE_FREE_SEED = ((1, 80), (3, 50), (9999, 20))
#: Table 7, pear tree (sparser scan).
PEAR_FREE_SEED = ((1, 20), (7, 15), (9999, 10))


#: Points along the visible half circle of the thinnest branch to resolve when a dense cloud is thinned
#: (assumption: six points over 180 deg, twice the three a circle needs, hold a circle fit against range noise).
ARC_POINTS = 6

#: The reported radius is at most this factor times the radius from the points' spread across the axis: an
#: arc of 120 deg of a circle spreads as 0.77 of its radius, 150 deg as 0.9 (assumption: a one-sided scan sees
#: at least 120 deg of a stem's circle).
SPREAD_FACTOR = 1.3


@dataclass(frozen=True)
class FollowParams:
    """Settings of :func:`follow_cylinders`.

    Attributes
    ----------
    free_seed : tuple of (int, int)
        ``(order threshold, n_s)`` pairs: a branch of order ``o`` takes its
        first ``n_s`` points freely, for the first threshold ``>= o`` (Table 7;
        default: apple tree).
    k_r : tuple of 2 float
        Radius factors for ``t_d < t_split`` and ``t_d >= t_split`` (Table 7: 1.05, 1.10).
    t_split : float
        Split of the normalised projection ``t_d`` (0.9 in the paper).
    ord_min1, ord_min2 : int
        Orders of the significant-ancestor rule (not reported; D-M8).
    n_min_factor : float
        ``n_min = n_min_factor * n_s(order)`` for orders in ``[ord_min1, ord_min2)``.
    precision_m : float or None
        Largest point-to-branch distance for inclusion, m; ``None``: 2.5 x the
        nominal point spacing (D-M5).
    neighbours : int
        Size of the k-nearest-neighbour graph that supplies candidate points.
    sibling_deg, parent_deg : float
        Merge angles (4 and 11.5 deg in the paper).
    direction : {"normals", "covariance", "iterative"}
        Axis estimator (see module docstring).
    axis : {"circle", "centroid"}
        Where the axis passes (see module docstring).
    inclusion : {"envelope", "max"}
        Radius of the inclusion test (see module docstring).
    radius : {"median", "mean", "max"}
        Reported radius (see module docstring).
    mode : {"strict", "faithful"}
        "strict": the spec's readings of the merge and balancing passes
        (D-M11, D-M12) with the early end of free seeding, the clean-ups and
        the output radius caps of the module docstring; "faithful": as
        printed in the paper.
    section_radii : float
        Length of the output cylinders in branch radii: each branch is cut
        into pieces refitted on their own points (an addition for taper and
        curvature; 0 gives one cylinder per branch, as the paper).
    min_branch_points : int
        Branches with fewer points are given back to their parents before
        the merge passes (an addition: the points that fail the inclusion
        test near a fork start branches that never grow; 1 disables it).
    max_balance_passes : int
        Cap on the volume-balancing passes.
    bridge_m : float
        Strict mode: parts of the cloud that growth does not reach (a single
        scan falls apart behind leaves and other branches) are started as
        child branches of the tree across gaps up to this length, m (an
        addition; assumption: the cloud is one tree, whose hidden pieces are
        shorter than this; 0 disables it). It is also the longest hidden
        stretch of a limb that is filled with cylinders (:mod:`woody.gaps`).
    pipe_model : bool
        Strict mode: the radii the points do not resolve (under one point
        spacing, or scattered about) follow the pipe model from their
        nearest resolved ancestor (an addition, on by default since round
        11: paired with the covered-clamp rule it halves the leafless
        trees' and the real clouds' volume errors; see
        docs/notebook/woody.md, round 11).
        Sections clamped at their parent's radius whose points do not cover
        their fitted circle follow it in strict mode whatever this says.
    resolve_radius_m : float
        Radius of the thinnest branch the fit should resolve, m: a cloud
        denser than needed for it is first thinned at random to a point
        spacing of ``pi * resolve_radius_m / 6`` (:data:`ARC_POINTS`
        points along the visible half of that branch's circle;
        :func:`woody.density.thin_to_spacing`), the branches are followed
        on the subset and every point takes the label of its nearest
        kept point, so that results and cost stop depending on the scan
        density above it; 0 keeps every point. The default, 1 cm, is an
        assumption of this project: its 5.2 mm spacing is about 4 pts/cm²,
        near the density the point counts of Table 7 (free seeds) and the
        inclusion distance (2.5 spacings) work at; on denser clouds a
        trunk's free seeds cover a small patch and the branches fragment
        (the apple-like tree, seed 0: -6.4 / -1.5 / -27 % volume at 0.75 /
        3 / 30 pts/cm² without thinning, -1.8 % at 30 pts/cm² with it).
        A random subset, not one point per voxel: voxels keep every stray
        point of a scan (mixed pulses, 18 % of a simulated vine's wood
        points lie over 5 mm off its surface) while they thin the surface.
    viewpoint : tuple of 3 float or None
        Position of the scanner the cloud was taken from, m (a single
        scan); with ``footprint_m`` it bounds the radii (below).
    footprint_m : float
        Diameter of the scanner's beam footprint at the cloud's range, m
        (e.g. ``tlssim.beam.footprint_axes_m``; 0: unknown, no bound).
        Strict mode, with ``viewpoint``: the radius of a section the points
        do not resolve is at most half the spread of the points near its
        axis across the line of sight less the footprint
        (:mod:`woody.footprint`), a bound that holds at any point spacing
        and needs no assumption about the tree's form, where the pipe
        model gives twigs thinner than the beam about 3 times their radius,
        and at most half the silhouette width their count gives less the
        footprint where they fill more than half its stretches
        (:func:`woody.footprint.silhouette_radius`);
        and a resolved section is at most as wide as the circle of its
        points whose beam lay wholly on it
        (:func:`woody.footprint.facing_radius`). With these bounds, a
        branch one of whose sections shows it wider than its parent
        releases its other sections from the parent's radius
        (:func:`released_clamps`): the only rule here that can widen.
    """

    free_seed: tuple = APPLE_FREE_SEED
    k_r: tuple = (1.05, 1.10)
    t_split: float = 0.9
    ord_min1: int = 2
    ord_min2: int = 4
    n_min_factor: float = 2.0
    precision_m: float | None = None
    neighbours: int = 12
    sibling_deg: float = 4.0
    parent_deg: float = 11.5
    direction: str = "normals"
    axis: str = "circle"
    inclusion: str = "envelope"
    radius: str = "median"
    mode: str = "strict"
    section_radii: float = 4.0
    min_branch_points: int = 10
    max_balance_passes: int = 50
    bridge_m: float = 1.0
    pipe_model: bool = True
    resolve_radius_m: float = 0.01
    viewpoint: tuple | None = None
    footprint_m: float = 0.0

    def __post_init__(self):
        problems = []
        seeds = list(self.free_seed)
        if not seeds or any(len(p) != 2 or p[1] < 1 for p in seeds) or \
                [p[0] for p in seeds] != sorted(p[0] for p in seeds):
            problems.append(f"free_seed={self.free_seed!r} (need increasing (order, n_s >= 1) pairs)")
        if len(self.k_r) != 2 or min(self.k_r) <= 1.0 or max(self.k_r) > 10:
            problems.append(f"k_r={self.k_r!r} (need two factors in (1, 10])")
        if not 0 < self.t_split <= 1.5:
            problems.append(f"t_split={self.t_split!r} (need (0, 1.5])")
        if not 1 <= self.ord_min1 <= self.ord_min2:
            problems.append(f"ord_min1={self.ord_min1}, ord_min2={self.ord_min2} (need 1 <= ord_min1 <= ord_min2)")
        if self.precision_m is not None and not (np.isfinite(self.precision_m) and self.precision_m > 0):
            problems.append(f"precision_m={self.precision_m!r} (need a positive length in m)")
        if not 2 <= self.neighbours <= 100:
            problems.append(f"neighbours={self.neighbours} (need 2..100)")
        if not (0 <= self.sibling_deg < 90 and 0 <= self.parent_deg < 90):
            problems.append(f"sibling_deg={self.sibling_deg}, parent_deg={self.parent_deg} (need [0, 90) deg)")
        for name, allowed in (("direction", ("normals", "covariance", "iterative")), ("axis", ("circle", "centroid")),
                              ("inclusion", ("envelope", "max")),
                              ("radius", ("median", "mean", "max")),
                              ("mode", ("strict", "faithful"))):
            if getattr(self, name) not in allowed:
                problems.append(f"{name}={getattr(self, name)!r} (allowed: {', '.join(allowed)})")
        if self.section_radii < 0:
            problems.append(f"section_radii={self.section_radii} (need >= 0)")
        if self.min_branch_points < 1:
            problems.append(f"min_branch_points={self.min_branch_points} (need >= 1)")
        if not _non_negative(self.bridge_m):
            problems.append(f"bridge_m={self.bridge_m!r} (need a length >= 0 in m)")
        if not _non_negative(self.resolve_radius_m):
            problems.append(f"resolve_radius_m={self.resolve_radius_m!r} (need a radius >= 0 in m)")
        if not _non_negative(self.footprint_m):
            problems.append(f"footprint_m={self.footprint_m!r} (need a diameter >= 0 in m)")
        if self.viewpoint is not None and (np.shape(self.viewpoint) != (3,) or
                                           not np.all(np.isfinite(np.asarray(self.viewpoint, float)))):
            problems.append(f"viewpoint={self.viewpoint!r} (need a position (x, y, z) in m)")
        if self.max_balance_passes < 0:
            problems.append(f"max_balance_passes={self.max_balance_passes} (need >= 0)")
        if problems:
            raise WoodyError("invalid cylinder-following parameter(s): " + "; ".join(problems))

    def n_s(self, order: int) -> int:
        """Free-seed count of a branch of this order."""
        for threshold, count in self.free_seed:
            if order <= threshold:
                return int(count)
        return int(self.free_seed[-1][1])


def _non_negative(value) -> bool:
    """Whether a parameter is a finite real number >= 0 (``None`` or a string is not)."""
    return isinstance(value, numbers.Real) and math.isfinite(value) and value >= 0


@dataclass
class FollowResult:
    """Output of :func:`follow_cylinders`.

    Attributes
    ----------
    branches : list of dict
        One per branch: ``id``, ``parent`` (-1 for the trunk), ``order``
        (trunk = 1), ``children``, ``start``/``end`` (P1, P2, m),
        ``direction``, ``radius_m`` (reported), ``radius_max_m``,
        ``n_points``, ``sections`` (``(start, end, radius)`` of its
        cylinders, m) and, in strict mode, ``reliable`` (whether the points
        resolve each section's radius; the others follow the pipe model).
    labels : ndarray, (n,)
        Branch id of every point (-1: never reached).
    stats : dict
        Counts, timings (s) and the settings used.
    """

    branches: list[dict]
    labels: np.ndarray
    stats: dict = field(default_factory=dict)

    def cylinders(self) -> list[dict]:
        """The reconstruction as a cylinder list (docs/contracts.md format).

        One cylinder per branch section (one per branch with
        ``section_radii=0``, as in the paper); a branch's first section is
        parented to the nearest section of its parent branch.
        """
        out, first, rows = [], {}, {}
        for b in self.branches:
            rows[b["id"]] = []
            for k, (start, end, radius) in enumerate(b["sections"]):
                cid = len(out)
                out.append({"id": cid, "parent": cid - 1 if k else -1, "order": b["order"], "branch": b["id"],
                            "start": list(start), "end": list(end), "radius_m": radius, "radius_end_m": radius})
                rows[b["id"]].append(cid)
            first[b["id"]] = rows[b["id"]][0]
        for b in self.branches:
            if b["parent"] >= 0:
                candidates = rows[b["parent"]]
                starts = np.array([out[c]["start"] for c in candidates])
                ends = np.array([out[c]["end"] for c in candidates])
                dist, _ = segment_distance(np.repeat(np.asarray(b["start"])[None], len(candidates), 0), starts, ends)
                out[first[b["id"]]]["parent"] = candidates[int(np.argmin(dist))]
        return out

    @property
    def volume(self) -> float:
        """Total woody volume (sum of the cylinders' ``h pi r^2``), m^3."""
        return cylinders_volume(self.cylinders())

    def skeleton(self) -> tuple[np.ndarray, np.ndarray]:
        """Skeleton graph: nodes (m, 3) and edges (e, 2).

        Each branch gives its axis P1 -> P2; each child is linked from its P1
        to the closest point of its parent's axis.
        """
        nodes, edges, ends = [], [], {}
        for b in self.branches:
            ends[b["id"]] = (np.asarray(b["start"]), np.asarray(b["end"]))
            nodes += [b["start"], b["end"]]
            edges.append((len(nodes) - 2, len(nodes) - 1))
        for b in self.branches:
            if b["parent"] >= 0:
                p1, p2 = ends[b["parent"]]
                _, t = segment_distance(np.asarray(b["start"])[None], p1, p2)
                nodes.append((p1 + t[0] * (p2 - p1)).tolist())
                child_start = [i for i, c in enumerate(self.branches) if c["id"] == b["id"]][0] * 2
                edges.append((len(nodes) - 1, child_start))
        return np.array(nodes, float).reshape(-1, 3), np.array(edges, np.int64).reshape(-1, 2)

    def mesh(self, sections: int = 16):
        """One closed cylinder mesh per branch (trimesh.Trimesh)."""
        return cylinders_mesh(self.cylinders(), sections)


def follow_cylinders(points, params: FollowParams | None = None, *, progress: bool = False, anchors=None,
                     **overrides) -> FollowResult:
    """Reconstruct a leafless tree as a hierarchy of cylinders (Méndez et al.).

    Parameters
    ----------
    points : array_like, (n, 3)
        One cleaned tree (no ground, no leaves), m. The trunk is grown from
        the lowest point (strict mode: from the stem base around it), parts
        of the cloud out of reach are bridged (``bridge_m``). A cloud denser
        than the thinnest branch to resolve needs is thinned first
        (``resolve_radius_m``).
    params : FollowParams, optional
        Settings (default: the paper's apple-tree values and the spec's
        recommendations).
    progress : bool
        Show a progress bar over the included points.
    anchors : array_like, (m, 3), optional
        Points of the tree reconstructed beforehand and not in ``points``
        (a trunk's surface), m: strict mode bridges the parts of the cloud
        that growth does not reach from them too, each started as a root
        branch.
    **overrides
        Fields of :class:`FollowParams` to override, e.g. ``k_r=(1.05, 1.05)``.

    Returns
    -------
    FollowResult

    Raises
    ------
    WoodyError
        On an invalid cloud or parameter.

    Examples
    --------
    A stem (radius 5 cm, 1 m) with one branch (radius 2 cm, 0.5 m, leaving
    it at 0.6 m height at 45 deg), sampled at 5000 points per m^2:

    >>> import numpy as np
    >>> from woody import follow_cylinders
    >>> from woody.synthetic import polyline_cylinders, sample_cylinders, straight_cylinder
    >>> branch = polyline_cylinders(np.array([[0, 0, 0.6], [0.35, 0, 0.95]]), np.array([0.02, 0.02]),
    ...                             first_id=1, parent=0, order=2, branch=1)
    >>> cloud = sample_cylinders(straight_cylinder(0.05, 1.0) + branch, 5e3, seed=2)
    >>> result = follow_cylinders(cloud.points)
    >>> [(b["order"], round(b["radius_m"], 2)) for b in result.branches if b["n_points"] >= 100]
    [(1, 0.05), (2, 0.02)]
    >>> round(result.volume / cloud.truth["volume_m3"], 1)
    1.0
    """
    points = check_points(points)
    try:
        params = FollowParams(**{**(params.__dict__ if params else {}), **overrides})
    except TypeError as exc:
        raise WoodyError(f"unknown cylinder-following parameter: {exc}") from None
    if len(points) < 3:
        raise WoodyError(f"cylinder following needs at least 3 points, got {len(points)}")
    clock = time.perf_counter()
    keep = _subsample(points, params.resolve_radius_m)
    if keep is None:
        return _follow(points, params, progress, {}, anchors)
    result = _follow(points[keep], params, progress, {"subsample_s": time.perf_counter() - clock}, anchors)
    clock = time.perf_counter()
    _, nearest = cKDTree(points[keep]).query(points, workers=-1)
    result.labels = result.labels[nearest]
    counts = np.bincount(result.labels[result.labels >= 0], minlength=len(result.branches))
    for record in result.branches:
        record["n_points"] = int(counts[record["id"]])
    result.stats.update(points=len(points), points_fitted=len(keep),
                        thinned_spacing_m=thinned_spacing(params.resolve_radius_m),
                        labels_s=time.perf_counter() - clock)
    return result


def thinned_spacing(resolve_radius_m: float) -> float:
    """Point spacing that still resolves a branch of this radius (see ``FollowParams.resolve_radius_m``), m."""
    return float(np.pi * resolve_radius_m / ARC_POINTS)


def _subsample(points: np.ndarray, resolve_radius_m: float) -> np.ndarray | None:
    """Indices of the points that cylinder following fits (None: all of them): a random subset at the spacing of
    :func:`thinned_spacing` when the cloud is denser than that."""
    if resolve_radius_m == 0 or len(points) < 7:
        return None
    keep = thin_to_spacing(points, thinned_spacing(resolve_radius_m))
    return keep if len(keep) < len(points) else None


def _follow(points: np.ndarray, params: FollowParams, progress: bool, timings: dict, anchors=None) -> FollowResult:
    """Cylinder following on exactly these points (see :func:`follow_cylinders`)."""
    clock = time.perf_counter()
    tree = cKDTree(points)
    k = min(params.neighbours + 1, len(points))
    # Nominal spacing from the 6th-neighbour distance: on a surface with density lambda it is about
    # sqrt(6 / (pi lambda)) for random and for grid-like sampling alike, so spacing = d6 sqrt(pi / 6).
    sixth = min(6, len(points) - 1)
    spacing_d, _ = tree.query(points, k=sixth + 1)
    spacing = float(np.median(spacing_d[:, sixth]) * np.sqrt(np.pi / sixth))
    precision = params.precision_m if params.precision_m is not None else 2.5 * spacing
    if precision <= 0:
        raise WoodyError("the cloud has duplicate points only; cannot derive a point spacing")
    dist, graph = tree.query(points, k=k, distance_upper_bound=2.0 * precision)
    graph = np.where(np.isfinite(dist), graph, -1).astype(np.int32)[:, 1:]
    del dist
    timings["graph_s"] = time.perf_counter() - clock

    clock = time.perf_counter()
    normals = pca_normals(points, min(10, len(points))) if params.direction == "normals" else None
    branches, owner = grow((points, normals), graph, params, precision, progress, anchors)
    timings["growth_s"] = time.perf_counter() - clock
    grown = len(branches)
    clock = time.perf_counter()
    branches = dissolve_small(branches, params)
    branches = merge_siblings(branches, params)
    branches = merge_into_parents(branches, params)
    if params.mode == "strict":
        branches = merge_contained(branches)
        branches = cut_forks(branches, spacing)
    passes = balance_volume(branches, points, params)
    timings["merge_s"] = time.perf_counter() - clock

    records, labels = _records(branches, params, len(points), spacing)
    filled = extended = doubled = 0
    if params.mode == "strict":
        # The bounds from the points near each fitted section (the pipe model's radii would reach fewer of them).
        bounds = [lateral_radii(r["sections"], points, tree, params.viewpoint, params.footprint_m, spacing)
                  for r in records] \
            if params.footprint_m > 0 and params.viewpoint is not None else None
        apply_pipe_model(records)
        if bounds is not None:
            bound_by_footprint(records, bounds)
            refit_facing(records, points, labels, params.viewpoint, params.footprint_m)
        filled = fill_gaps(records, points, params.bridge_m, params.section_radii)
        extended = extend_over_strips(records, points, params.bridge_m, params.section_radii)
        doubled = drop_doubled(records, labels)
    stats = {"points": len(points), "spacing_m": spacing, "precision_m": precision, "branches_grown": grown,
             "branches": len(records), "unassigned": int((labels < 0).sum()), "balance_passes": passes,
             "gaps_filled": filled, "strips_extended": extended, "doubled_dropped": doubled,
             "max_order": max(b["order"] for b in records), **timings}
    return FollowResult(records, labels, stats)


def _records(branches: list[Branch], params: FollowParams, count: int,
             spacing: float) -> tuple[list[dict], np.ndarray]:
    """Branch records with ids renumbered in breadth-first order from the trunk and orders recomputed (D-M14);
    in strict mode each record's ``reliable`` says which of its sections the points resolve: not those clamped
    at their parent's radius (:func:`_cap_radii`) whose points do not cover their fitted circle
    (:func:`_covered`) and, with ``pipe_model``, not those :func:`_resolved` rejects; a resolved section is cut
    to the radius its points cover (:func:`covered_radii`)."""
    roots = [b for b in branches if b.parent is None]
    order_of, queue = {}, [(r, 1) for r in roots]
    ranked = []
    while queue:
        branch, order = queue.pop(0)
        order_of[id(branch)] = order
        ranked.append(branch)
        queue += [(c, order + 1) for c in branch.children if c.points]
    new_id = {id(b): i for i, b in enumerate(ranked)}
    labels = np.full(count, -1, np.int64)
    records, cover_limits = [], []
    for b in ranked:
        labels[b.points] = new_id[id(b)]
        records.append({"id": new_id[id(b)], "parent": -1 if b.parent is None else new_id[id(b.parent)],
                        "order": order_of[id(b)], "children": [new_id[id(c)] for c in b.children if c.points],
                        "start": b.p1().tolist(), "end": b.p2().tolist(),
                        "direction": None if b.direction is None else b.direction.tolist(),
                        "radius_m": _radius(b, params), "radius_max_m": float(b.r_max), "n_points": len(b.points),
                        "sections": _sections(b, params)})
        anchor = records[records[-1]["parent"]] if records[-1]["parent"] >= 0 else None
        if params.mode != "strict":
            continue
        fitted = list(records[-1]["sections"])
        clamped = _cap_radii(records[-1], anchor, max(params.k_r)) if anchor is not None else [False] * len(fitted)
        limits = covered_radii(fitted, b.coords[b.points], spacing)
        covered = [r <= limit for (_, _, r), limit in zip(fitted, limits)]
        # A clamp that was the parent's error: the child's own circle stands, and the pipe model's test judges it
        # (judged on the clamped radius, its points lie far off it and it would be shrunk again).
        released = [False] * len(fitted)
        if any(clamped):
            own = _on_circle(fitted, b.coords[b.points])
            if not _parent_resolved(records[-1], anchor):  # the clamp rests on a guess: a narrow arc's circle stands
                own = [o or a for o, a in zip(own, _on_arc(fitted, b.coords[b.points], spacing))]
            restored = [c and cov and ok for c, cov, ok in zip(clamped, covered, own)]
            if params.pipe_model and params.footprint_m > 0 and params.viewpoint is not None:
                released = released_clamps(clamped, restored)
            records[-1]["sections"] = [f if k or x else s for f, s, k, x in
                                       zip(fitted, records[-1]["sections"], restored, released)]
        resolved = _resolved(records[-1]["sections"], b.coords[b.points], spacing) if params.pipe_model else \
            [True] * len(clamped)
        records[-1]["reliable"] = [r and (cov or not c) and not x
                                   for r, c, cov, x in zip(resolved, clamped, covered, released)]
        cover_limits.append(limits)
    # A resolved section is cut to the radius its points cover once every child is clamped (the clamps judge the
    # fitted radii); the pipe model judges the others.
    for record, limits in zip(records, cover_limits):  # strict mode only (none otherwise)
        record["sections"] = [(a, e, min(r, limit) if ok else r) for (a, e, r), limit, ok in
                              zip(record["sections"], limits, record["reliable"])]
    return records, labels


#: A section's radius is resolved when it is at least this many point spacings (assumption: a circle needs
#: about three points across the visible half of its circumference, pi r >= 3 spacings) ...
RESOLVED_SPACINGS = 1.0
#: ... and its branch's points beside it lie on it: their median distance to its axis within this fraction of
#: the radius of it and their median absolute deviation from it below this fraction of the radius (a cluster of
#: twigs, a fork fitted as one piece or a circle fitted to the noise of a twig thinner than the spacing, whose
#: pieces tilt from one to the next, scatter wider) ...
RESOLVED_SCATTER = 0.25
#: ... and there are at least this many of them.
RESOLVED_POINTS = 8


def _resolved(sections: list[tuple], points: np.ndarray, spacing: float) -> list[bool]:
    """Whether each section ``(start, end, radius)`` of a branch (m) is resolved by the branch's ``points`` (m)
    that lie beside it (projecting inside it), at the cloud's point ``spacing`` (m)."""
    out = []
    for start, end, radius in sections:
        distance, t = segment_distance(points, np.asarray(start), np.asarray(end))
        beside = distance[(t > 0) & (t < 1)]
        if len(beside) < RESOLVED_POINTS or radius < RESOLVED_SPACINGS * spacing:
            out.append(False)
            continue
        median = float(np.median(beside))
        deviation = float(np.median(np.abs(beside - median)))
        out.append(abs(median - radius) <= RESOLVED_SCATTER * radius and deviation <= RESOLVED_SCATTER * radius)
    return out


#: A section clamped at its parent's radius is taken for a misfit when its points cover less than this fraction
#: of the visible half of its fitted cylinder (``n spacing^2 / (pi r L)``; a one-sided view of a cylinder gives
#: about 2 / pi = 0.64 with the nominal spacing, more with several views), and a resolved section is cut to the
#: radius its points cover at this fraction. Assumption, from four clouds: on a simulated vine and a leafless
#: apple-like tree 73-85 % of the clamped volume lay under it (circles fitted across several twigs), on the two
#: real clouds of ``tlsbench experiment woody-real`` 1 and 14 % (limbs under a parent piece fitted too thin: the
#: clamp there is the parent's error, not the child's).
COVERED_FRACTION = 0.5


def _covered(sections: list[tuple], points: np.ndarray, spacing: float) -> list[bool]:
    """Whether a branch's ``points`` (m) that project inside each section ``(start, end, radius)`` (m) cover at
    least :data:`COVERED_FRACTION` of its visible half surface at the cloud's point ``spacing`` (m)."""
    return [radius <= limit for (_, _, radius), limit in zip(sections, covered_radii(sections, points, spacing))]


def covered_radii(sections: list[tuple], points: np.ndarray, spacing: float) -> list[float]:
    """The widest radius at which each section would still be covered by the branch points that project inside it.

    Covered means :data:`COVERED_FRACTION` of its visible half surface at the cloud's point spacing:
    ``n spacing^2 / (COVERED_FRACTION pi L)`` for ``n`` points inside a section of length ``L``.

    Parameters
    ----------
    sections : list of tuple
        ``(start, end, radius)`` of each section, m.
    points : ndarray, (n, 3)
        The branch's points, m.
    spacing : float
        The cloud's point spacing, m.

    Returns
    -------
    list of float
        Radius per section, m; infinite for a section of no length.
    """
    out = []
    for start, end, _ in sections:
        length = float(np.linalg.norm(np.subtract(end, start)))
        _, t = segment_distance(points, np.asarray(start), np.asarray(end))
        inside = int(((t > 0) & (t < 1)).sum())
        out.append(inside * spacing ** 2 / (COVERED_FRACTION * np.pi * length) if length > 0 else np.inf)
    return out


#: A clamped section whose points cover its fitted circle (:data:`COVERED_FRACTION`) and lie on it, their median
#: absolute distance from it within this fraction of its radius, keeps its own radius: the clamp was the parent's
#: error (a limb grown as the child of a thin piece across a gap, or under a parent piece fitted too thin).
#: Assumption, from the clamped sections of one simulated leafless apple-like tree (seed 2, simulation seed 5):
#: those on 14-21 mm limbs under 2.5 mm parents scattered by 0.05-0.11 of their radius, circles across several
#: twigs by 0.12-0.25 (the clamp held the tree's 2-5 cm limbs to 0.36 of their 1.13 dm3).
ON_CIRCLE_SCATTER = 0.1


def _on_circle(sections: list[tuple], points: np.ndarray) -> list[bool]:
    """Whether at least :data:`RESOLVED_POINTS` of a branch's ``points`` (m) project inside each section
    ``(start, end, radius)`` (m) and lie on its surface (median absolute distance from it at most
    :data:`ON_CIRCLE_SCATTER` of the radius)."""
    out = []
    for start, end, radius in sections:
        beside, _ = _beside(points, start, end)
        out.append(len(beside) >= RESOLVED_POINTS and radius > 0 and
                   float(np.median(np.abs(beside - radius))) <= ON_CIRCLE_SCATTER * radius)
    return out


def _beside(points: np.ndarray, start, end) -> tuple[np.ndarray, np.ndarray]:
    """Distances from the axis ``start``-``end`` (m) of the ``points`` (m) that project inside it (m), and which
    points those are."""
    distance, t = segment_distance(points, np.asarray(start), np.asarray(end))
    inside = (t > 0) & (t < 1)
    return distance[inside], inside


def released_clamps(clamped: list[bool], restored: list[bool]) -> list[bool]:
    """Which clamped sections of a branch take back their fitted radius as unresolved ones.

    A section clamped at its parent's radius whose own circle stands (``restored``: its points cover and lie on
    it) shows the branch wider than its parent, so the clamp of the branch's other sections is the parent's
    error too (a leader followed as a chain of fragments under a thin piece: on the quick suite's leafy tree at
    0.08 deg, 16-17 mm sections of one leader alternated with 4.0 mm ones, the parent's radius). They take their
    fitted radii judged unresolved: the pipe model from the nearest resolved section (the branch's own) and the
    footprint's bounds size them. No section is released in a branch none of whose sections is restored, nor
    without the footprint's bounds (no scanner position or footprint): sized by the pipe model alone, released
    sections widened a real cloud's model (aRchi Tree_1, ``tlsbench experiment woody-real``) from +8.2 to
    +23.0 % volume against its TreeQSM reference.

    Parameters
    ----------
    clamped : list of bool
        Whether each section was clamped at its parent's radius (:func:`_cap_radii`).
    restored : list of bool
        Whether each clamped section keeps its own circle.

    Returns
    -------
    list of bool
        Whether each section is released.

    Examples
    --------
    >>> released_clamps([True, True, False, True], [False, True, False, False])
    [True, False, False, True]
    >>> released_clamps([True, True], [False, False])
    [False, False]
    """
    if not any(restored):
        return [False] * len(clamped)
    return [c and not k for c, k in zip(clamped, restored)]


def apply_pipe_model(records: list[dict]) -> None:
    """Shrink the radii the points do not resolve (``record["reliable"]`` False) by the pipe model from their
    nearest resolved ancestor section (:func:`woody.pipe.pipe_radii`), in place. Records without ``reliable``
    count as resolved."""
    rows = [(i, k) for i, record in enumerate(records) for k in range(len(record["sections"]))]
    cylinders = FollowResult(records, np.zeros(0, np.int64)).cylinders()
    lengths = [float(np.linalg.norm(np.subtract(c["end"], c["start"]))) for c in cylinders]
    reliable = [records[i].get("reliable", [True] * len(records[i]["sections"]))[k] for i, k in rows]
    radii = pipe_radii([c["radius_m"] for c in cylinders], lengths, [c["parent"] for c in cylinders], reliable)
    for (i, k), radius in zip(rows, radii.tolist()):
        start, end, _ = records[i]["sections"][k]
        records[i]["sections"][k] = (start, end, radius)


def bound_by_footprint(records: list[dict], bounds: list[list[float]]) -> None:
    """Cut the radius of each section the points do not resolve (``record["reliable"]`` False: the pipe model
    gave it) to its bound from the points' spread across the line of sight and their count
    (:func:`woody.footprint.lateral_radii`, m; one list per record), in place. Resolved sections keep their
    circles: applied to them too, the bound cut partly occluded stems (a simulated leafless apple-like tree's
    2.3 cm stem at 1.3 m by 14-21 %). Runs after the pipe model; a later pass of it
    (:func:`woody.trunk.follow_tree`) only shrinks radii, so the bound holds.

    Parameters
    ----------
    records : list of dict
        Branch records (``sections`` as ``(start, end, radius)``, m; ``reliable`` per section, absent: resolved).
    bounds : list of list of float
        Radius bound of each section of each record, m (infinite: none).
    """
    for record, limits in zip(records, bounds):
        judged = record.get("reliable", [True] * len(limits))
        record["sections"] = [(a, e, r if ok else min(r, limit))
                              for (a, e, r), limit, ok in zip(record["sections"], limits, judged)]


def refit_facing(records: list[dict], points: np.ndarray, labels: np.ndarray, viewpoint, footprint_m: float) -> None:
    """Cut the radius of each section the points resolve (``record["reliable"]`` True or absent) to the circle of
    its points whose beam lay wholly on it (:func:`woody.footprint.facing_radius`), in place: the points near a
    silhouette lie outside the surface and widened the stems of simulated leafless apple-like trees by 0.5-1.9
    mm. Runs after the pipe model and the footprint bound, and only shrinks.

    Parameters
    ----------
    records : list of dict
        Branch records (``id``, ``sections`` as ``(start, end, radius)``, m; ``reliable`` per section).
    points : ndarray, (n, 3)
        The fitted cloud, m.
    labels : ndarray of int, (n,)
        Branch id of each point (-1: none).
    viewpoint : array_like, (3,)
        Scanner position, m.
    footprint_m : float
        Beam footprint diameter, m.
    """
    order = np.argsort(labels, kind="stable")
    ids = [r["id"] for r in records]
    first, last = np.searchsorted(labels[order], ids), np.searchsorted(labels[order], ids, side="right")
    for record, lo, hi in zip(records, first, last):
        own = points[order[lo:hi]]
        judged = record.get("reliable", [True] * len(record["sections"]))
        sections = []
        for (a, e, r), ok in zip(record["sections"], judged):
            if ok:
                _, t = segment_distance(own, np.asarray(a), np.asarray(e))
                r = min(r, facing_radius(own[(t > 0) & (t < 1)], a, e, r, viewpoint, footprint_m))
            sections.append((a, e, r))
        record["sections"] = sections


def _parent_resolved(record: dict, parent: dict) -> bool:
    """Whether the points resolve the section of ``parent`` nearest to the start of ``record`` (its ``reliable``;
    absent: resolved), the section :func:`_cap_radii` clamps ``record`` at."""
    reliable = parent.get("reliable", [True] * len(parent["sections"]))
    return bool(reliable[_nearest_section(record, parent)])


def _nearest_section(record: dict, parent: dict) -> int:
    """Index of the section of ``parent`` nearest to the start of ``record``."""
    starts = np.array([s[0] for s in parent["sections"]])
    ends = np.array([s[1] for s in parent["sections"]])
    dist, _ = segment_distance(np.repeat(np.asarray(record["start"])[None], len(starts), 0), starts, ends)
    return int(np.argmin(dist))


#: A narrow arc's points must bulge by at least this many point spacings (sagitta) to count as one circle
#: (:func:`_on_arc`). Geometry: the points of a twig thinner than the spacing lie within about two spacings of
#: each other across its axis; seen from an axis D away they span an angle of about 2 asin(s / D) and bulge by
#: D (1 - cos(asin(s / D))), under half a spacing for every D beyond 1.25 spacings (a circle of under 7 mm at the
#: 5.2 mm spacing of a thinned cloud). A real arc of 80 deg bulges by 0.23 of its radius: 5 mm on a 22 mm one.
ARC_SAGITTA_SPACINGS = 0.5


def _on_arc(sections: list[tuple], points: np.ndarray, spacing: float) -> list[bool]:
    """Whether a branch's ``points`` (m) that project inside each section ``(start, end, radius)`` (m) lie on one
    circle about its axis whose radius the spread cap shortened (:func:`_radius`).

    On an arc narrower than 120 deg (a limb half hidden by leaves, or seen edge-on) the spread cap gives less than
    the circle's radius (0.86 of it over 100 deg, 0.69 over 80 deg), so the points lie outside the section's radius
    and :func:`_on_circle` rejects them although they lie on a circle. Here the points' median distance from the
    axis must be at least the radius, their median absolute deviation from that median within
    :data:`ON_CIRCLE_SCATTER` of it, from at least :data:`RESOLVED_POINTS` points, and the arc they span must
    bulge by at least :data:`ARC_SAGITTA_SPACINGS` of the cloud's point ``spacing`` (its sagitta
    ``R (1 - cos(a / 2))``, ``a`` the angle between the 5th and 95th percentile of their angles about the axis):
    the curvature is resolved. A line of points along a twig thinner than the spacing, to which a circle far
    wider than the points was fitted, lies on that circle too but spans no resolved arc. No bound on how much
    the cap cut: the median at most :data:`SPREAD_FACTOR` times the radius rejects every arc under about 90 deg
    (on the quick suite's leafy tree scanned at 0.036 deg, 51 mm leaders seen over 74-82 deg arcs, cut to
    29-30 mm and clamped at their 6 mm parents).

    Parameters
    ----------
    sections : list of tuple
        ``(start, end, radius)`` of each section, m.
    points : ndarray, (n, 3)
        The branch's points, m.
    spacing : float
        The cloud's point spacing, m.

    Returns
    -------
    list of bool
        One per section.
    """
    out = []
    for start, end, radius in sections:
        start, end = np.asarray(start, float), np.asarray(end, float)
        beside, inside = _beside(points, start, end)
        if len(beside) < RESOLVED_POINTS or radius <= 0 or not np.linalg.norm(end - start) > 0:
            out.append(False)
            continue
        own = float(np.median(beside))
        if not (radius <= own and float(np.median(np.abs(beside - own))) <= ON_CIRCLE_SCATTER * own):
            out.append(False)
            continue
        u, v, _ = orthonormal_frame(end - start)
        rel = points[inside] - start
        angle = np.arctan2(rel @ v, rel @ u)
        angle = np.angle(np.exp(1j * (angle - np.angle(np.exp(1j * angle).mean()))))  # about the arc's middle
        low, high = np.quantile(angle, [0.05, 0.95])
        out.append(own * (1.0 - np.cos(0.5 * min(high - low, np.pi))) >= ARC_SAGITTA_SPACINGS * spacing)
    return out


def _cap_radii(record: dict, parent: dict, tolerance: float) -> list[bool]:
    """The radius hierarchy applied to the output: no section of a branch is wider than the section of its
    parent nearest to its start (a cluster of several thin twigs fitted as one fat cylinder is the usual
    cause). The paper's growth test compares with the significant ancestor only; capping by that ancestor
    let the children of thin twigs come out as wide as the trunk (a simulated leafy pear at 0.08 deg:
    +375 % volume, +102 % with the parent's cap). Returns which sections were clamped by more than the
    ``tolerance`` factor (the ``k_r`` a branch's radius may grow by): either the child's circle did not fit
    the wood (one drawn across several twigs) or the parent's did not (:func:`_covered` tells them apart)."""
    limit = parent["sections"][_nearest_section(record, parent)][2]
    clamped = [r > tolerance * limit for _, _, r in record["sections"]]
    record["sections"] = [(a, b, min(r, limit)) for a, b, r in record["sections"]]
    record["radius_m"] = min(record["radius_m"], limit)
    return clamped


def _radius(branch: Branch, params: FollowParams) -> float:
    """The branch's reported radius (``params.radius``: median, mean or largest orthogonal distance), m.

    In strict mode it is at most :data:`SPREAD_FACTOR` times the radius that
    the points' spread across the axis gives (``sqrt(2 lambda)``, with
    ``lambda`` the larger eigenvalue of their covariance across the axis:
    exact for points spread evenly over a half or a full circle). A circle
    fitted to a cluster of thin twigs, or to a line of points along a twig
    thinner than the point spacing, can be far wider than the points.
    """
    radius = float({"max": branch.r_max, "mean": branch.r_mean, "median": branch.r_median}[params.radius])
    if params.mode != "strict" or branch.direction is None or len(branch.points) < 3:
        return radius
    return min(radius, SPREAD_FACTOR * branch.spread_radius())


def _sections(branch: Branch, params: FollowParams) -> list[tuple]:
    """Cylinders ``(start, end, radius)`` of a branch: the whole branch, or pieces of ``section_radii`` radii.

    Each piece is refitted on its own points (direction, axis, radius) so
    that the cylinders follow taper and curvature; a piece whose own axis is
    more than 30 deg off the branch's is refitted along the branch's axis,
    and one with fewer than 8 points keeps the branch's axis and radius. In
    strict mode no piece is wider than ``max(k_r)`` times the piece before
    it (the paper's radius hierarchy along the branch; a fork region fitted
    as one piece is the usual cause).
    """
    whole = [(branch.p1().tolist(), branch.p2().tolist(), _radius(branch, params))]
    if params.section_radii <= 0 or branch.direction is None:
        return whole
    piece = params.section_radii * max(branch.r_median, 1e-9)
    count = min(int((branch.t1 - branch.t0) // piece), len(branch.points))  # r = 0 on collinear points
    if count < 2:
        return whole
    indices = np.asarray(branch.points)
    t = (branch.coords[indices] - branch.axis_point) @ branch.direction
    edges = np.linspace(branch.t0, branch.t1, count + 1)
    out = []
    for k, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        members = indices[(t >= lo) & ((t < hi) if k < count - 1 else (t <= hi))]
        part = copy.copy(branch)
        part.points = members.tolist()
        if len(members) >= 8:
            part.refit()
            if part.direction is not None and angle_deg(part.direction, branch.direction) > 30.0:
                part.refit(branch.direction)  # a piece bends little: an axis far off the branch's is a misfit
        if len(members) < 8 or part.direction is None:
            out.append(((branch.axis_point + lo * branch.direction).tolist(),
                        (branch.axis_point + hi * branch.direction).tolist(), _radius(branch, params)))
        else:
            out.append((part.p1().tolist(), part.p2().tolist(), _radius(part, params)))
    if params.mode == "strict":  # radii do not grow away from the root (beyond the k_r tolerance)
        for k in range(1, len(out)):
            out[k] = (out[k][0], out[k][1], min(out[k][2], max(params.k_r) * out[k - 1][2]))
    return out

"""PROP-SFS on scans: leaves, local frames, corrected ranges, outliers, meshes and traits.

:func:`reconstruct` is the package's main entry point. For every leaf region
of a :class:`tlssim.Scan` (given as a mask or label image, or found by
:func:`leafsfs.leaves.segment_leaves`) it converts intensity to incidence
with the calibration, builds the leaf's local metric frame
(:mod:`leafsfs.frame`), runs the engine (:func:`leafsfs.engine.reconstruct_heights`)
and maps the result back to ranges and world coordinates. It needs no truth.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy import ndimage

from leafsfs.canopy import nearer_ring, pulse_noise, rim_shares, visibility
from leafsfs.edges import bracketed
from leafsfs.engine import HeightResult, reconstruct_heights
from leafsfs.errors import SfsError
from leafsfs.frame import MARGIN_PX, LocalFrame, local_frame
from leafsfs.fusion import noise_tails
from leafsfs.leaves import range_noise, segment_scan
from leafsfs.params import VARIANTS, SfsParams
from leafsfs.preprocess import resolve_calibration, scan_alpha
from leafsfs.surfacetails import surface_tails
from leafsfs.traits import BAND_MAX_BACKGROUND_SPREAD_DN, background_spread, leaf_traits, mixed_band
from leafsfs.woodfit import wood_fitted_range
from tlssim.scan import Scan, grid_to_xyz

#: Smallest leaf region reconstructed, pixels (smaller regions are skipped and listed).
MIN_LEAF_PIXELS = 30
#: Outline pulses with less of their footprint on their leaf than this (:func:`leafsfs.canopy.rim_shares`) are
#: unreliable, corrected on the leaf's surface like mixed pulses: their beam's axis misses the leaf (assumption: the
#: footprint's centre is off the leaf below half of it). Measured on the leafy tree at 0.018 deg (`fused`, pooled
#: scored pulses): 0.5 leaves 21,462 3-sigma outliers (23,639 without), 0.75 leaves 22,126 and damages more good
#: points (4,503 against 3,442; 1,614 without): the propagated surface is least accurate at the outline.
RIM_PARTIAL_SHARE = 0.5
#: Range steps (in range-noise standard deviations) on both sides of an unreliable pulse that prove it mixed
#: (:func:`leafsfs.edges.bracketed`), for its removal where no surface explains it (``SfsParams.unexplained``).
#: Measured on a 1000 x 1000 crop of the leafy tree at 0.018 deg (`fused`, mean per-leaf ROP reduction 3 sigma /
#: good points lost): none removed 0.585 / 0; 3 sigma 0.606 / 0.70 %; 5 sigma 0.605 / 0.26 %; every unreliable
#: pulse that no surface corrects 0.619 / 1.8 % (pure pulses of small pieces of leaves go with them). In the
#: orchard row every removed pulse is one near no surface, and the pure pulses of a hidden leaf's few visible
#: pieces go with them (its good points lost are most of the row's): 800 x 800 crops of the row's 0.018 deg window
#: (leaves with their centroid 60 px inside; near tree / far side) 5 sigma 0.648 / 7.9 % and 0.609 / 0.72 %;
#: 8 sigma 0.659 / 5.8 % and 0.600 / 0.45 %; none removed 0.646 / 0.22 % on the first.
MIXED_PROOF_SIGMA = 8.0
#: A pulse straddling two surfaces whose power share lies within ``OWNER_MARGIN`` of one half, and whose range lies
#: within ``OWNER_TOLERANCE_M`` of the midpoint of their extrapolated distances, has no owner: the truth judges it
#: against the surface that returned most of its power, and which one that is rests on two extrapolated distances
#: whose errors (a wood surface curving away at its silhouette: 5-15 mm on the pears at 0.018 deg) exceed the
#: range's distance from the midpoint. Either distance would then be wrong by up to half the step between the
#: surfaces; with ``SfsParams.unexplained="remove"`` it is removed. A leaf 1 m before a wall keeps all but the
#: pulses within 6 mm of the midpoint. Assumptions: the tolerance is the attribution's range tolerance
#: (:func:`leafsfs.edges.attribute_mixed`); the margin was measured on whole scans at 0.018 deg (`fused`, mean
#: per-leaf ROP reduction 3 sigma / good points lost, leafy tree, margin alone): none 0.628 / 0.40 %; 0.05
#: 0.651 / 0.52 %; 0.1 0.664 / 0.66 %; 0.15 0.676 / 0.83 %.
OWNER_MARGIN = 0.1
OWNER_TOLERANCE_M = 0.006
#: A pulse within this many of its range-noise deviations (:func:`leafsfs.canopy.pulse_noise`) of either surface of
#: its pair is that surface's within the noise, not ownerless (:data:`OWNER_MARGIN`): whichever surface owns it, its
#: range is a good point of one of them (two deviations: 95 % of a pure pulse's noise, assumption). Measured with
#: the truth on the orchard row's window at 0.018 deg (``fused``, the pulses that rule removed, a scratch script,
#: round 18): the good points it removed lie at a median 3.8 deviations from the nearer surface (10 % below 1.3), the
#: outliers at 14.7 (10 % below 4.9); mean per-leaf ROP reduction 3 sigma / 1 cm and good points lost: none kept
#: 0.6814 / 0.7811 / 1.27 %; within 2 deviations kept 0.6810 / 0.7810 / 1.16 %; 3: 0.6803 / 0.7807 / 1.09 %.
OWNER_BAND_SIGMA = 2.0
#: A pulse the unexplained removal would take whose range at least :data:`PIECE_MIN_LINKED` of its 8 neighbours
#: share within ``PIECE_LINK_SIGMA * sqrt(2)`` of its range-noise deviation (the difference of two pulses of one
#: surface, each with that noise; :func:`linked_neighbours`) lies on a piece of a surface, not between two: a
#: mixed pulse's range is set by its footprint's share of each surface and changes from pulse to pulse across an
#: edge, while the pure pulses of a piece of a hidden leaf too small to be a surface agree within their noise. The
#: bracket test (:data:`MIXED_PROOF_SIGMA`) takes such pieces for mixed pulses (a nearer and a farther surface lie
#: within its window). Measured with the truth on the orchard row's window at 0.018 deg (``fused``, whole scan,
#: the pulses the rule removed; mean per-leaf ROP reduction 3 sigma / 1 cm / good points lost, a scratch script,
#: round 18): the removed good points have a median of 6 such neighbours (within 3 sqrt(2) deviations), the removed
#: outliers 1; none kept 0.6814 / 0.7811 / 1.27 %; at least 4 of 8 within 2 sqrt(2) 0.6787 / 0.7803 / 0.86 %; 5:
#: 0.6805 / 0.7812 / 0.95 %; 6: 0.6812 / 0.7812 / 1.08 %; at least 5 within 3 sqrt(2) 0.6789 / 0.7798 / 0.87 %.
#: With :data:`OWNER_BAND_SIGMA`, in the benchmark (``fused``, 0.018 deg, before -> after, 3 sigma / 1 cm / good
#: points lost): leafy tree 0.6804 / 0.8081 / 0.42 % -> 0.6795 / 0.8070 / 0.30 %; pear seed 23 at 4 m 0.7198 /
#: 0.8309 / 0.57 % -> 0.7203 / 0.8312 / 0.41 %; seed 41 at 5 m 0.6756 / 0.7914 / 0.47 % -> 0.6756 / 0.7913 / 0.38 %;
#: not tuned on: seed 101 at 3.5 m 0.7358 / 0.8513 / 0.62 % -> 0.7355 / 0.8511 / 0.51 %, seed 173 at 4 m with a
#: wall 0.7412 / 0.8154 / 0.62 % -> 0.7412 / 0.8154 / 0.56 %; found leaves, false ones and traits unchanged.
PIECE_MIN_LINKED = 5
PIECE_LINK_SIGMA = 2.0
#: Smallest automatic outlier threshold, m (the issue's tau floor, tls-physics §7.10).
OUTLIER_FLOOR_M = 0.002
#: Residual against its surface's core (in the pulse's range-noise standard deviations) beyond which a pulse linked
#: into the surface's outline is mixed (:func:`leafsfs.canopy.rim_mixed`). Measured on the leafy tree at 0.018 deg
#: (`fused`, whole scan, mean per-leaf ROP reduction 3 sigma / good points lost): none 0.649 / 0.59 %; 3 sigma
#: 0.659 / 0.73 %; 3.5 sigma 0.657 / 0.61 %; 4 sigma 0.656 / 0.59 %.
RIM_MIXED_SIGMA = 3.5
#: Residual against a leaf region's local plane (in the pulse's range-noise standard deviations) within which an
#: unlinked, unpaired pulse at its outline joins it (:func:`leafsfs.canopy.grow_outline`; 0: none join).
OUTLINE_GROW_SIGMA = 3.0
#: Largest offset from the plane of the reliable pulses around it, in its modelled range-noise deviations, at which a
#: lone straddling pulse takes that plane's range (farther, it lies on another surface than that plane's).
LONE_TAIL_SIGMA = 4.0
#: Incidence at which the engine's height and the owner surface's extrapolated distance are weighted equally in the
#: corrected distance of a leaf's mixed pulse paired with two surfaces (:func:`engine_owner_weight`), deg. Both
#: estimate the owner's distance at the pulse: the engine propagates the leaf's surface from its interior (least
#: accurate at its outline, where its mixed pulses lie), the plane extrapolates the surface's pure pulses next to
#: the pulse (off where the surface curves). Round 16 weighted them equally everywhere (13,477 -> 13,024 and
#: 22,922 -> 21,906 3-sigma outliers left on the scored pulses of the leafy tree and pear seed 7 at 3 m, 0.018 deg,
#: against the engine alone), which cost two 80 deg single leaves (9 cm, 2.5 and 3.5 m) their ROP reduction
#: (0.964 -> 0.906, 0.921 -> 0.796): there the plane is the worse estimate. Measured with the truth on these pulses
#: of the leafy tree (24,641 pulses, binned by the leaf's intensity-derived incidence next to the pulse): the
#: engine's error (robust SD) is 1.9-2.0 mm up to 72 deg and 2.3-2.7 mm beyond, the plane's grows from 0.6 mm below
#: 30 deg to 1.0 mm at 45-55, 1.8 mm at 65-72 and 2.3 mm beyond 78 deg, about as the secant of the incidence; the
#: 3-sigma outliers left there with equal weights 2,191, the engine alone 2,578, the plane alone 2,407, the weight
#: of :func:`engine_owner_weight` with this angle at 45 / 50 / 55 / 60 / 65 / 70 deg 2,170 / 2,152 / 2,152 / 2,137 /
#: 2,140 / 2,164 (a scratch truth script, round 17).
ENGINE_OWNER_EQUAL_DEG = 60.0
#: Weight of the engine's height in the corrected distance of an outline pulse mostly off its leaf
#: (:data:`RIM_PARTIAL_SHARE`); the rest goes to its measured range. That range is the lit part's centroid's, off the
#: beam's axis by about a footprint radius (biased by the leaf's slope over that offset), and the engine's height is
#: least accurate at the outline; the two errors are largely independent. Chosen on the scored pulses of the leafy
#: tree and pear seed 7 at 3 m, 0.018 deg (``fused``, truth, 3-sigma outliers left, the engine alone -> this weight):
#: 0.5: 13,477 -> 13,047 and 22,922 -> 22,395; 2/3: 12,943 and 22,126; 0.75: 12,992 and 22,195; the good points
#: damaged among these pulses (1,163 and 1,696 with the engine alone) fall (a scratch truth-budget script, round 16).
RIM_ENGINE_WEIGHT = 2.0 / 3.0


@dataclass
class LeafResult:
    """The reconstruction of one leaf region.

    Attributes
    ----------
    label : int
        Region label in :attr:`SfsResult.labels`.
    frame : LocalFrame
        The leaf's metric frame (its ``box`` locates it in the scan).
    heights : HeightResult
        Engine output on the frame's pixel box.
    traits : dict
        Area, normal, elevation, azimuth (:func:`leafsfs.traits.leaf_traits`)
        plus ``n_points`` and ``n_outliers``; ``visible_area_m2`` (the
        measured area, without the half a leaf hides behind its roll), ``cut`` (the leaf is only
        partly visible: an occluder in front of it or the window's border
        cuts it), ``cut_by_border`` and ``occluded_fraction``
        (:func:`leafsfs.canopy.visibility`).
    """

    label: int
    frame: LocalFrame
    heights: HeightResult
    traits: dict

    def mesh_world(self) -> tuple[np.ndarray, np.ndarray]:
        """Mesh vertices in the world frame ``(V, 3)`` and faces ``(F, 3)``."""
        h = self.heights
        return self.frame.world_points(h.vertex_pixels, h.vertices[:, 2]), h.faces


@dataclass
class SfsResult:
    """Outputs of :func:`reconstruct` on the scan grid.

    Attributes
    ----------
    scan : Scan
        The input scan.
    variant : str
    params : SfsParams
    labels : ndarray of int
        Leaf region per pixel (0: not reconstructed).
    range : ndarray
        Corrected range per pixel, m: on leaf pixels judged outliers the
        median of the candidates (or the rim extrapolation), on background
        pulses the background's distance, the measured range elsewhere.
    corrected : ndarray of bool
        Pixels whose range was re-estimated (leaf pixels and background pulses).
    candidates : ndarray of int
        Number of PROP-SFS candidate distances per pixel (rppp counts).
    spread : ndarray
        Range of the candidate distances per pixel, m (NaN without candidates).
    outlier : ndarray of bool
        Measured points judged outliers, whose distance was replaced: mixed
        pulses, and the leaf points ``params.inliers`` replaces.
    alpha : ndarray
        Intensity-derived incidence, rad (smoothed on leaves).
    background : ndarray of bool
        Mixed pulses that a surface other than a leaf (the background)
        dominates, or that a thin part attached to a leaf (a petiole)
        shares with the background; they took the dominant surface's
        distance (the leaf's where the part is attached).
    removed : ndarray of bool
        Mixed pulses that no surface explains, removed (NaN range; also
        ``outlier`` and ``corrected``; ``params.unexplained``).
    leaves : list of LeafResult
    skipped : list of (label, reason)
        Leaf regions that could not be reconstructed.
    """

    scan: Scan
    variant: str
    params: SfsParams
    labels: np.ndarray
    range: np.ndarray
    corrected: np.ndarray
    candidates: np.ndarray
    spread: np.ndarray
    outlier: np.ndarray
    alpha: np.ndarray
    background: np.ndarray
    removed: np.ndarray
    leaves: list = field(default_factory=list)
    skipped: list = field(default_factory=list)

    def corrected_scan(self) -> Scan:
        """A copy of the scan with corrected ranges and points, plus the layers ``outlier``, ``candidates``,
        ``leaf`` (region labels), ``background``, ``removed`` and ``range_spread`` (m); removed pulses have no
        range (NaN)."""
        scan = copy.copy(self.scan)
        scan.range = self.range.copy()
        scan.xyz = grid_to_xyz(scan.range, scan.theta, scan.psi, scan.pose)
        scan.layers = {**self.scan.layers, "outlier": self.outlier.copy(), "candidates": self.candidates.astype(np.int32),
                       "leaf": self.labels.astype(np.int32), "background": self.background.copy(),
                       "removed": self.removed.copy(), "range_spread": self.spread.astype(np.float32)}
        scan.meta = {**self.scan.meta, "leafsfs": {"variant": self.variant, "params": self.params.to_dict()}}
        return scan

    def points(self) -> np.ndarray:
        """Corrected points of the reconstructed pixels (not the removed ones), world frame, ``(n, 3)``."""
        xyz = grid_to_xyz(self.range, self.scan.theta, self.scan.psi, self.scan.pose)
        return xyz[self.corrected & ~self.removed]

    def mesh(self) -> trimesh.Trimesh:
        """All leaf meshes in one :class:`trimesh.Trimesh` (world frame)."""
        parts = [leaf.mesh_world() for leaf in self.leaves]
        vertices = np.concatenate([v for v, _ in parts]) if parts else np.zeros((0, 3))
        offsets = np.cumsum([0] + [len(v) for v, _ in parts])
        faces = np.concatenate([f + o for (_, f), o in zip(parts, offsets)]) if parts else np.zeros((0, 3), int)
        return trimesh.Trimesh(vertices, faces, process=False)

    def traits(self) -> list[dict]:
        """One entry per reconstructed leaf (label plus :attr:`LeafResult.traits`)."""
        return [{"leaf": leaf.label, **leaf.traits} for leaf in self.leaves]

    def rppp(self, region: np.ndarray | None = None, n_max: int = 3) -> dict[str, float]:
        """Redundancy ratios over the reconstructed leaf pixels, or those of ``region`` (see :meth:`HeightResult.rppp`).

        Parameters
        ----------
        region : ndarray of bool or None
            Pixels to count; ``None`` for all reconstructed leaf pixels.
        n_max : int
            Largest candidate count with a ratio of its own; larger counts go to ``rppp_more``.

        Returns
        -------
        dict of str to float
            ``rppp_0`` .. ``rppp_{n_max}`` and ``rppp_more``, fractions of the pixels (0..1).
        """
        counts = self.candidates[self.labels > 0 if region is None else region]
        total = max(len(counts), 1)
        out = {f"rppp_{n}": float(np.sum(counts == n) / total) for n in range(n_max + 1)}
        out["rppp_more"] = float(np.sum(counts > n_max) / total)
        return out


def reconstruct(scan: Scan, mask=None, variant: str = "buffer", params: SfsParams | None = None, *,
                calibration=None) -> SfsResult:
    """Re-estimate the distances of the leaves of a scan from its intensity (PROP-SFS).

    Stages: check the inputs and convert intensity to incidence with the
    calibration; find the leaf regions and the mixed pulses
    (:func:`_leaf_regions`: every mixed pulse goes to the surface that
    returned most of its power, and those dominated by a surface that is
    not a leaf, the wall behind, take that surface's distance, also those
    inside a given ``mask``); per leaf the engine on its local frame
    (:func:`_fit_leaf`), whose corrected distances the leaf's mixed pulses,
    and the inliers as ``params.inliers`` says, take (they are the
    outliers; :func:`_paste_leaf`); finally the traits of each leaf's
    surface with every pulse weighted by the leaf's share of its footprint
    (:func:`_assemble`).

    Parameters
    ----------
    scan : tlssim.Scan
        A simulated or imported scan (truth arrays are not used).
    mask : ndarray of bool or int, optional
        The leaf to reconstruct (boolean image of the scan's shape) or a
        label image of several leaves (0 = none). Default: leaf regions from
        :func:`leafsfs.leaves.segment_scan`.
    variant : {"simple", "sps", "buffer", "fused"}
        PROP-SFS variant.
    params : SfsParams, optional
        Parameters (default :class:`SfsParams`, the thesis' leaf protocol).
    calibration : Calibration or path
        Intensity calibration (:func:`leafsfs.preprocess.resolve_calibration`).

    Raises
    ------
    SfsError
        For a scan without valid pixels, a mask of the wrong shape or type,
        a missing or unreadable calibration, an unknown variant or
        parameters out of range.

    Examples
    --------
    A 5 cm pear leaf 1 m in front of the scanner, upright and turned 20 deg
    from the beam, scanned at 0.1 deg steps (1,369 pulses); every return is
    the leaf, and the calibration inverts the simulator's radiometry for the
    leaf's reflectance (0.48):

    >>> from scenes import scene_from_spec
    >>> from tlssim import setup_from_section, simulate
    >>> from leafsfs.synthetic import LambertCalibration
    >>> scene = scene_from_spec({"objects": [
    ...     {"name": "leaf", "type": "leaf", "preset": "pear", "seed": 7, "length": 0.05,
    ...      "material": "pear-leaf", "pose": {"center": [1.0, 0, 0], "facing": "scanner", "incidence_deg": 20}}]})
    >>> setup = setup_from_section({"window": {"theta_deg": [-1.8, 1.8], "psi_deg": [88.2, 91.8],
    ...                                        "step_deg": 0.1}})
    >>> scan = simulate(scene, setup, seed=0, progress=False)
    >>> result = reconstruct(scan, mask=scan.valid, calibration=LambertCalibration(scan.scanner.model, 0.48))
    >>> [leaf.label for leaf in result.leaves]
    [1]
    >>> traits = result.leaves[0].traits
    >>> round(traits["normal_zenith_deg"]), abs(traits["elevation_deg"]) < 2  # true: 90 and 0 deg
    (90, True)
    """
    params, valid = _check_inputs(scan, variant, params)
    labels = None if mask is None else _labels_from_mask(mask, scan.shape)
    calibration = resolve_calibration(calibration)
    alpha, reliable = scan_alpha(scan.intensity, scan.range, calibration)
    regions = _leaf_regions(scan, alpha, labels, valid, calibration)
    inliers = params.inliers if params.inliers != "auto" else ("refine" if variant == "fused" else "keep")
    grids = _Grids(range=regions.range, corrected=regions.background.copy(),
                   candidates=np.zeros(scan.shape, dtype=int), spread=np.full(scan.shape, np.nan),
                   alpha=alpha.copy())
    fits, skipped = [], []
    boxes = ndimage.find_objects(regions.labels)
    for label in np.unique(regions.labels[regions.labels > 0]):
        # The window the leaf's frame can reach: its region and the pulses it shares, plus the frame's margin. Only
        # that window is read (a whole-scan image per leaf took 5 s of the tree's 0.018 deg scan).
        window = tuple(slice(max(min(a.start, b.start) - MARGIN_PX, 0), min(max(a.stop, b.stop) + MARGIN_PX, n))
                       for a, b, n in zip(boxes[label - 1], regions.shares.box(label), scan.shape))
        region = regions.labels[window] == label
        try:
            fit = _fit_leaf(scan, alpha, region, (regions.shares.crop(label, window) > 0) & ~regions.thin[window],
                            regions.unreliable, variant, params, inliers, window)
        except _Skipped as exc:
            skipped.append((int(label), str(exc)))
            continue
        _paste_leaf(grids, fit, regions.labels[fit.frame.box] == label)
        fits.append((int(label), fit))
    # A leaf's mixed pulse paired with two surfaces and corrected by the engine: between the engine's height and its
    # owner surface's extrapolated distance, the engine weighing more where the leaf turns to grazing next to it.
    both = regions.paired & (regions.labels > 0) & grids.corrected & np.isfinite(regions.owner_range)
    if both.any():
        leaf_pure = (regions.labels > 0) & ~regions.unreliable & np.isfinite(alpha)
        weight = engine_owner_weight(nearest_incidence(alpha, leaf_pure, both))
        grids.range[both] = weight * grids.range[both] + (1 - weight) * regions.owner_range[both]
    # An outline pulse mostly off its leaf and corrected by the engine: between the engine's height and its measured
    # range (RIM_ENGINE_WEIGHT).
    outline = regions.partial & grids.corrected & np.isfinite(grids.range)
    grids.range[outline] = RIM_ENGINE_WEIGHT * grids.range[outline] + (1 - RIM_ENGINE_WEIGHT) * scan.range[outline]
    # Mixed pulses of a leaf region that the engine gave no height (a region skipped, a rim the propagation did not
    # reach or dropped as implausible) take their owner surface's distance extrapolated from its pure pulses.
    left = regions.unreliable & (regions.labels > 0) & ~grids.corrected & np.isfinite(regions.owner_range)
    grids.range[left] = regions.owner_range[left]
    grids.corrected |= left
    if inliers == "refine":
        # Pure pulses outside every leaf region (wood, background, leaves not found) in the tails of their window's
        # noise take their neighbours' plane, as noise_tails moves a leaf's.
        pure = valid & ~regions.unreliable & (regions.labels == 0) & ~grids.corrected
        tails, plane = surface_tails(grids.range, pure, regions.noise)
        grids.range[tails] = plane[tails]
        grids.corrected |= tails
        # A pulse flagged as straddling that no surface pairs or owns and no region holds (on the leafy tree at
        # 0.018 deg 6,139 pulses: 61 % pure on wood, 30 % pure on leaves, 40 % within 2 px of a region) is tested the
        # same way against the plane of the reliable pulses around it, the leaf regions' at their corrected ranges.
        lone = valid & regions.unreliable & ~regions.mixed & (regions.labels == 0) & ~grids.corrected
        tails, plane = surface_tails(grids.range, valid & ~regions.unreliable, regions.noise, tested=lone)
        with np.errstate(invalid="ignore"):
            tails &= np.abs(grids.range - plane) <= LONE_TAIL_SIGMA * regions.noise
        grids.range[tails] = plane[tails]
        grids.corrected |= tails
    single = np.zeros(scan.shape, dtype=bool)
    if params.single_surface == "move" or (params.single_surface == "auto" and inliers == "refine"):
        # An edge pulse within the range noise of one surface that nothing moved takes that surface's distance
        # extrapolated to it (:attr:`_Regions.single_range`) in the corrected scan (:func:`_assemble`; the leaves'
        # traits keep its measured range, which their band's shares were measured with): the pulse is that surface's,
        # and a mixed pulse's range lies off its owner's by the other surface's share of the step between them (a step
        # within the attribution's tolerance but beyond the range noise). Measured with the truth (round 35, `fused`,
        # 0.018 deg): such pulses hold 14 % of the 3-sigma ROP left on the leafy tree's found >= 80 %-visible leaves
        # (69 % of them with a tenth or more of their power from another object); offline, mean per-leaf ROP reduction
        # 3 sigma / 1 cm, leafy tree 0.6961 / 0.8168 -> 0.7008 / 0.8183, pear seed 7 at 3 m 0.7234 / 0.8132 -> 0.7272 /
        # 0.8141 (only those beyond 1 / 2 noise deviations: 0.7004 / 0.6996 and 0.7270 / 0.7265); with the traits taking
        # it too, the leafy tree's median |area error| went 5.77 -> 6.23 % (benchmarked).
        single = np.isfinite(regions.single_range) & (grids.range == scan.range)
    # A pulse whose range proves it mixed and that no surface corrected lies between two surfaces and on neither,
    # unless its neighbours share its range within the noise (a piece of a surface too small to be one).
    removed = regions.mixed & ~grids.corrected & ~single & (params.unexplained == "remove")
    if removed.any():
        removed &= linked_neighbours(scan.range, regions.noise, PIECE_LINK_SIGMA, at=removed) < PIECE_MIN_LINKED
    grids.range[removed] = np.nan
    grids.corrected |= removed
    # A corrected pulse whose pair of surfaces share its power about equally: no surface owns it.
    ownerless = regions.ownerless & grids.corrected & ~removed & (params.unexplained == "remove")
    return _assemble(scan, variant, params, regions, grids, fits, skipped, reliable, removed, ownerless, single)


@dataclass
class _Regions:
    """The leaf regions of a scan and what the mixed pulses tell about them (stage 2 of :func:`reconstruct`).

    Attributes
    ----------
    labels : ndarray of int, 2-D
        Leaf region per pixel (0: none; only pixels with a valid return).
    shares : _Shares
        Per region, its share of every pulse's footprint (1 on its pure
        pulses, the geometric share on its mixed pulses, 0 elsewhere).
    background : ndarray of bool, 2-D
        Mixed pulses given to the surface that dominates them (not a leaf,
        or a thin part attached to one), and the edge pulses within the
        range noise of one surface that is no leaf given its circle's or
        quadric's distance (:func:`leafsfs.woodfit.wood_fitted_range`).
    unreliable : ndarray of bool, 2-D
        Valid pulses whose range straddles two surfaces (or none), and the
        outline pulses of a leaf with most of their footprint off it
        (:data:`RIM_PARTIAL_SHARE`).
    range : ndarray, 2-D
        Measured ranges with the background pulses moved to their owner
        surface's distance, m.
    owner_range : ndarray, 2-D
        Distance of the owner surface of every unreliable pulse, extrapolated
        to it from the surface's pure pulses, m (NaN elsewhere and where no
        pair of surfaces was found).
    mixed : ndarray of bool, 2-D
        Unreliable pulses whose range proves them mixed (:func:`leafsfs.edges.bracketed`).
    thin : ndarray of bool, 2-D
        Mixed pulses beyond the band paired with a leaf's surface
        (:attr:`leafsfs.edges.MixedPulses.thin`): they count for their share
        in the leaf's area, but the leaf's fit does not take them.
    ownerless : ndarray of bool, 2-D
        Unreliable pulses paired with two surfaces that no surface owns
        (:data:`OWNER_MARGIN`, :data:`OWNER_TOLERANCE_M`).
    paired : ndarray of bool, 2-D
        Unreliable pulses of no surface paired with two surfaces (their range straddles them).
    single_range : ndarray, 2-D
        Distance, extrapolated to it, of the one surface within whose range noise a pulse of no surface lies
        (:meth:`leafsfs.edges.MixedPulses.single_range`), m (NaN elsewhere).
    partial : ndarray of bool, 2-D
        Outline pulses of a leaf region with most of their footprint off it (:data:`RIM_PARTIAL_SHARE`; unreliable).
    noise : ndarray, 2-D, or float
        Each pulse's range noise (:func:`leafsfs.canopy.pulse_noise`), m.
    band : _Shares
        Per region, its share of its mixed pulses' footprints and the secant
        of its incidence there (last axis), from their range and intensity
        (:func:`leafsfs.traits.mixed_band`; NaN where unknown).
    """

    labels: np.ndarray
    shares: "_Shares"
    background: np.ndarray
    unreliable: np.ndarray
    range: np.ndarray
    owner_range: np.ndarray
    mixed: np.ndarray
    thin: np.ndarray
    ownerless: np.ndarray
    paired: np.ndarray
    single_range: np.ndarray
    partial: np.ndarray
    noise: np.ndarray | float
    band: "_Shares"


class _Shares:
    """Each region's share of the pulses' footprints, kept on the window where it is not zero.

    A whole-scan image per region would take ``8 x pixels x regions`` bytes
    (13 GB for the 300 leaves of a tree at 0.018 deg).

    Parameters
    ----------
    shape : tuple of int
        The scan grid's shape.
    """

    def __init__(self, shape: tuple):
        self.shape = shape
        self._parts: dict[int, tuple] = {}

    def add(self, label: int, box: tuple, values: np.ndarray) -> None:
        """Record region ``label``'s shares ``values`` on the window ``box`` (a pair of slices)."""
        self._parts[int(label)] = (box, values)

    def box(self, label: int) -> tuple:
        """The window (pair of slices) outside which region ``label`` has no share."""
        return tuple(slice(*sl.indices(n)[:2]) for sl, n in zip(self._parts[int(label)][0], self.shape))

    def crop(self, label: int, box: tuple) -> np.ndarray:
        """Region ``label``'s shares on the window ``box`` (a pair of slices), 0 outside its own window."""
        own, values = self._parts[int(label)]
        (b0, b1), (c0, c1) = ((sl.indices(n)[:2]) for sl, n in zip(box, self.shape))
        (o0, o1), (p0, p1) = ((sl.indices(n)[:2]) for sl, n in zip(own, self.shape))
        out = np.zeros((b1 - b0, c1 - c0) + values.shape[2:])
        r0, r1, q0, q1 = max(b0, o0), min(b1, o1), max(c0, p0), min(c1, p1)
        if r0 < r1 and q0 < q1:
            out[r0 - b0:r1 - b0, q0 - c0:q1 - c0] = values[r0 - o0:r1 - o0, q0 - p0:q1 - p0]
        return out


@dataclass
class _Grids:
    """Per-pixel outputs that the leaves of :func:`reconstruct` are pasted into (see :class:`SfsResult`).

    Attributes
    ----------
    range : ndarray
        Corrected range per pixel, m.
    corrected : ndarray of bool
        Pixels whose range was re-estimated.
    candidates : ndarray of int
        Number of candidate distances per pixel.
    spread : ndarray
        Range of the candidate distances per pixel, m.
    alpha : ndarray
        Incidence per pixel, rad (smoothed on leaves).
    """

    range: np.ndarray
    corrected: np.ndarray
    candidates: np.ndarray
    spread: np.ndarray
    alpha: np.ndarray


@dataclass
class _LeafFit:
    """The engine's result on one leaf region (stage 3 of :func:`reconstruct`).

    Attributes
    ----------
    frame : LocalFrame
        The leaf's metric frame.
    heights : HeightResult
        Engine output on ``frame.box`` (implausible heights set to NaN).
    threshold : float
        Outlier threshold, m.
    done : ndarray of bool
        Pixels of the box that belong to the region and have a height.
    moved : ndarray of bool
        Pixels of the box that take the corrected distance (where ``done``).
    target : ndarray
        The height each pixel takes when moved, m: the engine's, or on the
        pure pulses that ``inliers="refine"`` moves, their neighbours' plane
        (:func:`leafsfs.fusion.noise_tails`).
    """

    frame: LocalFrame
    heights: HeightResult
    threshold: float
    done: np.ndarray
    moved: np.ndarray
    target: np.ndarray


class _Skipped(Exception):
    """A leaf region that cannot be reconstructed; the message says why."""


def no_owner(mixed, range_m: np.ndarray, noise_m: np.ndarray | float) -> np.ndarray:
    """Pulses paired with two surfaces that neither owns: an even split of their power, off both surfaces' noise.

    A pulse whose power share lies within :data:`OWNER_MARGIN` of one half
    and whose range lies within :data:`OWNER_TOLERANCE_M` of the midpoint of
    its pair's extrapolated distances has no owner, unless its range lies
    within :data:`OWNER_BAND_SIGMA` of its range-noise deviations of either
    surface's distance (then it is a good point of that surface, whichever
    one owns it).

    Parameters
    ----------
    mixed : leafsfs.edges.MixedPulses
        The pairs, power shares and extrapolated distances (m) of the mixed pulses.
    range_m : ndarray, 2-D
        Measured ranges, m.
    noise_m : ndarray or float
        Each pulse's range noise (:func:`leafsfs.canopy.pulse_noise`), m.

    Returns
    -------
    ndarray of bool, 2-D

    Examples
    --------
    Two surfaces 10 mm apart, a pulse half way (5 mm from each): ownerless
    with 1 mm of noise, a good point of either surface with 3 mm.

    >>> from leafsfs.edges import MixedPulses
    >>> one = np.ones((1, 1))
    >>> mixed = MixedPulses(0 * one.astype(int), np.array([[[1, 2]]]), 0.5 * one, np.array([[[1.0, 1.01]]]),
    ...                     np.full((1, 1, 2), np.nan), one.astype(int), 0 * one.astype(bool))
    >>> bool(no_owner(mixed, 1.005 * one, 0.001)[0, 0]), bool(no_owner(mixed, 1.005 * one, 0.003)[0, 0])
    (True, False)
    """
    with np.errstate(invalid="ignore"):
        off_half = np.abs(mixed.share - 0.5)
        step = np.abs(mixed.pair_range[..., 0] - mixed.pair_range[..., 1])
        nearer = np.fmin(np.abs(range_m - mixed.pair_range[..., 0]), np.abs(range_m - mixed.pair_range[..., 1]))
        return (mixed.pair[..., 1] > 0) & (off_half < OWNER_MARGIN) & (off_half * step < OWNER_TOLERANCE_M) \
            & ~(nearer <= OWNER_BAND_SIGMA * np.asarray(noise_m, dtype=float))


def linked_neighbours(range_m: np.ndarray, noise_m: np.ndarray | float, sigma: float,
                      at: np.ndarray | None = None) -> np.ndarray:
    """How many of each pulse's 8 neighbours have a range within ``sigma * sqrt(2)`` of its range-noise deviation.

    Two pulses of one smooth surface a pixel apart differ by their noise
    (the difference of two deviations ``noise_m``: ``sqrt(2) noise_m``) and
    by the surface's slope over a pixel (sub-millimetre at the fine steps
    of a canopy scan; assumption: neglected, as the neighbour's own noise
    is taken to be the pulse's).

    Parameters
    ----------
    range_m : ndarray, 2-D
        Measured ranges, m (NaN = no return: never linked).
    noise_m : ndarray or float
        Each pulse's range noise (:func:`leafsfs.canopy.pulse_noise`), m.
    sigma : float
        The bound, in deviations of the difference.
    at : ndarray of bool, 2-D, optional
        The pulses to count for (default: all); memory follows their number,
        not the scan's.

    Returns
    -------
    ndarray of uint8, 2-D
        0..8 per pulse (0 where it has no return or is not counted).

    Examples
    --------
    >>> r = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, 1.5], [1.0, np.nan, 1.0]])
    >>> linked_neighbours(r, 0.001, 2.0)
    array([[3, 4, 2],
           [4, 6, 0],
           [2, 0, 1]], dtype=uint8)
    """
    rows, cols = range_m.shape
    r, c = np.nonzero(np.ones(range_m.shape, bool) if at is None else at)
    value = range_m[r, c].astype(float)
    bound = sigma * np.sqrt(2.0) * np.broadcast_to(np.asarray(noise_m, dtype=float), range_m.shape)[r, c]
    count = np.zeros(len(r), dtype=np.uint8)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di or dj:
                rr, cc = r + di, c + dj
                inside = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
                neighbour = np.full(len(r), np.nan)
                neighbour[inside] = range_m[rr[inside], cc[inside]]
                with np.errstate(invalid="ignore"):
                    count += np.abs(neighbour - value) <= bound
    out = np.zeros(range_m.shape, dtype=np.uint8)
    out[r, c] = count
    return out


def engine_owner_weight(incidence: np.ndarray) -> np.ndarray:
    """Weight of the engine's height against the owner surface's extrapolated distance, by the leaf's incidence.

    The two estimates' errors are taken as independent and weighted by
    their inverse variances: the engine's error as constant, the plane's
    (extrapolating a surface's pure pulses to a pulse beside them) growing
    as the secant of the incidence, the range's rate of change across the
    surface (assumption; a truth measurement on the leafy tree follows the
    secant up to 75 deg, :data:`ENGINE_OWNER_EQUAL_DEG`). The two are equal
    at :data:`ENGINE_OWNER_EQUAL_DEG`; the engine weighs 0.22 at 20 deg,
    0.5 at 60 deg and 0.91 at 80 deg.

    Parameters
    ----------
    incidence : ndarray
        Incidence of the leaf at the pulses, rad (NaN: taken as the equal angle).

    Returns
    -------
    ndarray
        The engine's weight in [0, 1]; the owner's is its complement.
    """
    equal = np.radians(ENGINE_OWNER_EQUAL_DEG)
    ratio = np.cos(np.where(np.isfinite(incidence), incidence, equal)) / np.cos(equal)
    return 1.0 / (1.0 + ratio ** 2)


def nearest_incidence(alpha: np.ndarray, reliable: np.ndarray, at: np.ndarray, size: int = 5) -> np.ndarray:
    """The intensity-derived incidence of the reliable pulses nearest each pulse of ``at``, rad.

    A mixed pulse's own intensity is no incidence (part of its footprint
    is off the surface); the leaf's pure pulses next to it give the
    incidence there, averaged over the reliable pulses of a ``size`` x
    ``size`` window to damp the intensity's noise.

    Parameters
    ----------
    alpha : ndarray, 2-D
        Intensity-derived incidence, rad.
    reliable : ndarray of bool, 2-D
        Pulses whose incidence is trusted.
    at : ndarray of bool, 2-D
        Pulses to give an incidence.
    size : int
        Side of the averaging window, pixels.

    Returns
    -------
    ndarray
        Incidence at the pulses of ``at`` (in the order of ``np.nonzero(at)``), rad; NaN when no pulse is reliable.
    """
    if not reliable.any():
        return np.full(int(np.count_nonzero(at)), np.nan)
    value = np.where(reliable, alpha, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = ndimage.uniform_filter(value, size, mode="constant") / ndimage.uniform_filter(
            reliable.astype(float), size, mode="constant")
    nearest = ndimage.distance_transform_edt(~reliable, return_distances=False, return_indices=True)
    return mean[nearest[0][at], nearest[1][at]]


def _check_inputs(scan: Scan, variant: str, params: SfsParams | None) -> tuple[SfsParams, np.ndarray]:
    """The parameters to use (default :class:`SfsParams`) and the pixels with a range and an intensity.

    Parameters
    ----------
    scan : tlssim.Scan
        The scan to reconstruct.
    variant : str
        PROP-SFS variant name.
    params : SfsParams or None
        Parameters given by the caller.

    Raises
    ------
    SfsError
        For parameters of the wrong type, an unknown variant or a scan without valid pixels.
    """
    params = params or SfsParams()
    if not isinstance(params, SfsParams):
        raise SfsError(f"params must be an SfsParams, got {type(params).__name__}")
    if variant not in VARIANTS:
        raise SfsError(f"unknown PROP-SFS variant {variant!r}; choose one of {', '.join(VARIANTS)}")
    valid = scan.valid & np.isfinite(scan.intensity)
    if not valid.any():
        raise SfsError("the scan has no valid pixels (no returns with range and intensity)")
    return params, valid


def _leaf_regions(scan: Scan, alpha: np.ndarray, labels: np.ndarray | None, valid: np.ndarray,
                  calibration) -> _Regions:
    """Leaf regions, their footprint shares and the background pulses of a scan.

    Parameters
    ----------
    scan : tlssim.Scan
        The scan (ranges in m, intensities in DN).
    alpha : ndarray, 2-D
        Intensity-derived incidence, rad.
    labels : ndarray of int or None
        Given leaf regions (0 = none), or None to take those of
        :func:`leafsfs.leaves.segment_scan`.
    valid : ndarray of bool
        Pixels with a range and an intensity.

    Raises
    ------
    SfsError
        When given regions hold no pixel with a valid return (a scan the segmentation finds no leaf in is
        reconstructed without leaves: its wood and background pulses are still corrected).
    """
    given = labels is not None
    gain = float(scan.scanner.assumed_model.log_gain_dn)  # the recorded model's, else the default preset's
    segmentation = segment_scan(scan.range, scan.theta, scan.psi, alpha, intensity=scan.intensity, gain_dn=gain,
                                rim_sigma=RIM_MIXED_SIGMA, grow_sigma=OUTLINE_GROW_SIGMA)
    mixed = segmentation.mixed
    unreliable = valid & mixed.straddling
    out_range = scan.range.copy()
    background = np.zeros(scan.shape, dtype=bool)
    # A grazing leaf narrows below a footprint towards its tip and base: the mixed pulses there lie beyond the band
    # and are paired as a thin part attached to it, with the leaf's power share (pear leaf, 2.5 m, 80 deg: 78 pulses,
    # median share 0.07, true 0.07), and their area elements are large at grazing.
    with_thin, thin = dataclasses.replace(mixed, thin=np.zeros_like(mixed.thin)), mixed.thin
    partial = np.zeros(scan.shape, dtype=bool)
    fitted = wood_fitted_range(mixed, scan.range, scan.theta, scan.psi, alpha, segmentation.leaf_surfaces,
                               segmentation.band_px, segmentation.noise_m)
    # An edge pulse within the range noise of one surface that is no leaf is that surface's, yet it lies where the
    # surface turns away from the beam: its circle (wood) or quadric there gives its distance, as for the surface's
    # mixed pulses (the plane it was judged against stops short by millimetres).
    on_wood = valid & (mixed.surfaces == 0) & (mixed.pair[..., 1] == 0) & np.isfinite(fitted)
    if labels is None:
        labels = segmentation.leaves
        extents = mixed.extents()
        shares, band = _Shares(scan.shape), _Shares(scan.shape)
        for k in np.unique(labels[labels > 0]):
            surface = segmentation.region_surface(k)
            box = extents[surface]
            share = with_thin.share_of(surface, gain, box)
            band.add(k, box, _band(mixed, surface, box, scan.intensity, gain, calibration, segmentation.band_px))
            # Pure pulses at the outline with nothing beside the leaf count for the part of their footprint on it.
            rim = rim_shares(labels[box] == k, scan.intensity[box], gain, segmentation.footprint_px)
            rim = np.where(_mixes_in_range(labels[box] == k, mixed.pair[box] == surface, segmentation.footprint_px),
                           1.0, rim)
            shares.add(k, box, np.where(share >= 1, np.minimum(share, rim), share))
            partial[box] |= (labels[box] == k) & (share >= 1) & (rim < RIM_PARTIAL_SHARE)
        # Mixed pulses dominated by a surface that is not a leaf (the wall behind) take its distance; so do those of
        # a thin part attached to a leaf (a petiole), at the distance where it is attached when it dominates them.
        background = unreliable & (mixed.owner > 0) & (~np.isin(mixed.owner, segmentation.leaf_surfaces) | mixed.thin)
        background |= on_wood
        # An outline pulse with part of its footprint off the leaf and nothing behind: its range is that of the lit
        # part's centroid, off the beam's axis (biased on a tilted leaf), and its intensity deficit is no incidence.
        unreliable |= valid & partial & (labels > 0)
    else:
        # A given region counts its pixels whole, except the mixed pulses of its main surface, which count (inside
        # the region or just outside it) for their share of that surface; its mixed pulses that another surface
        # dominates (the wall behind) take that surface's distance and leave the region. Each region's shares are
        # kept on the window they can be non-zero in: the region grown by more than a footprint (the rim tests reach
        # one footprint off it) and its main surface's pulses and pairs.
        extents = mixed.extents()
        margin = int(np.ceil(segmentation.footprint_px)) + 2
        shares, band = _Shares(scan.shape), _Shares(scan.shape)
        for k, box in enumerate(ndimage.find_objects(labels), start=1):
            if box is None:
                continue
            main = _main_surface(mixed.surfaces[box], labels[box] == k)
            box = tuple(slice(max(sl.start - margin, 0), min(sl.stop + margin, n)) for sl, n in zip(box, scan.shape))
            if main in extents:
                box = tuple(slice(min(a.start, b.start), max(a.stop, b.stop)) for a, b in zip(box, extents[main]))
            region = labels[box] == k
            band.add(k, box, _band(mixed, main, box, scan.intensity, gain, calibration, segmentation.band_px))
            paired = (mixed.surfaces[box] == 0) & (mixed.pair[box] == main).any(axis=-1)
            own = rim_shares(region, scan.intensity[box], gain, segmentation.footprint_px)
            own = np.where(_mixes_in_range(region, mixed.pair[box] == main, segmentation.footprint_px), 1.0, own)
            shares.add(k, box, np.where(paired, with_thin.share_of(main, gain, box), own))
            background[box] |= (unreliable[box] | on_wood[box]) & region & (mixed.owner[box] > 0) \
                & (mixed.owner[box] != main)
        labels = np.where(background, 0, labels)
    owner_range = np.where(unreliable & (mixed.owner > 0), np.where(np.isfinite(fitted), fitted, mixed.owner_range()),
                           np.nan)
    out_range[background] = np.where(on_wood, fitted, owner_range)[background]
    labels = np.where(valid, labels, 0)
    if given and not labels.any():
        raise SfsError("no leaf pixel with a valid return: the mask selects none")
    # The band is three footprint radii: a mixed pulse has a nearer and a farther pulse within one radius.
    proven = unreliable & bracketed(scan.range, max(1, segmentation.band_px // 3),
                                    MIXED_PROOF_SIGMA * segmentation.noise_m)
    noise = pulse_noise(segmentation.noise_m, scan.intensity, gain)
    ownerless = unreliable & no_owner(mixed, scan.range, noise)
    paired = unreliable & (mixed.surfaces == 0) & (mixed.pair[..., 1] > 0)
    return _Regions(labels, shares, background, unreliable, out_range, owner_range, proven, thin, ownerless, paired,
                    np.where(valid, mixed.single_range(), np.nan), valid & partial & (labels > 0), noise, band)


def _band(mixed, surface: int, box: tuple, intensity: np.ndarray, gain: float, calibration,
          band_px: int) -> np.ndarray:
    """Surface ``surface``'s share and secant of incidence (last axis) on the mixed pulses it shares with another
    surface in the window ``box`` (:func:`leafsfs.traits.mixed_band`), NaN elsewhere and where that surface's pure
    pulses within ``band_px`` vary by more than :data:`leafsfs.traits.BAND_MAX_BACKGROUND_SPREAD_DN`."""
    pair = mixed.pair[box]
    out = np.full(pair.shape[:2] + (2,), np.nan)
    other_surface = np.where(pair[..., 0] == surface, pair[..., 1], np.where(pair[..., 1] == surface, pair[..., 0], 0))
    rows, cols = np.nonzero(other_surface)
    if not len(rows):
        return out
    (r0, _), (c0, _) = ((sl.indices(n)[:2]) for sl, n in zip(box, mixed.surfaces.shape))
    near = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))  # the paired pulses' window
    clean = np.zeros(pair.shape[:2], dtype=bool)
    clean[near] = background_spread(mixed.surfaces, intensity, other_surface[near],
                                    (slice(r0 + near[0].start, r0 + near[0].stop),
                                     slice(c0 + near[1].start, c0 + near[1].stop)), band_px) \
        <= BAND_MAX_BACKGROUND_SPREAD_DN
    for member, other in ((0, 1), (1, 0)):
        sel = (pair[..., member] == surface) & (pair[..., other] > 0) & clean
        share = mixed.share[box] if member == 0 else 1.0 - mixed.share[box]
        out[sel] = mixed_band(share[sel], intensity[box][sel], mixed.pair_intensity[box][..., other][sel],
                              mixed.pair_range[box][..., member][sel], gain, calibration)
    return out


def _mixes_in_range(region: np.ndarray, paired: np.ndarray, rim_px: float) -> np.ndarray:
    """Pulses of ``region`` whose footprint can reach past its outline only onto pulses paired with its surface.

    Where the part of a footprint off the leaf returns (a surface behind),
    its range shows the mixing and :func:`leafsfs.edges.attribute_mixed`
    pairs it; a pulse the range found pure is then wholly on the leaf, and
    its intensity deficit at a grazing leaf's outline is incidence (a few
    degrees more of it at 80 deg take a quarter of the power), not partial
    cover. Only pulses within ``rim_px`` of something else (no return, or
    an unpaired pulse) can lose power to the outline unseen in range.

    Parameters
    ----------
    region : ndarray of bool, 2-D
        The region's pulses.
    paired : ndarray of bool, (rows, cols, 2)
        Mixed pulses paired with the region's surface (either member).
    rim_px : float
        A footprint radius, pixels.

    Returns
    -------
    ndarray of bool, 2-D
    """
    seen = region | paired.any(axis=-1)
    return region & (ndimage.distance_transform_edt(np.pad(seen, 1, constant_values=False))[1:-1, 1:-1] > rim_px)


def _fit_leaf(scan: Scan, alpha: np.ndarray, region: np.ndarray, share: np.ndarray, unreliable: np.ndarray,
              variant: str, params: SfsParams, inliers: str, window: tuple | None = None) -> _LeafFit:
    """Run the engine on one leaf region in its local frame and decide which pixels take its distances.

    Parameters
    ----------
    scan : tlssim.Scan
        The scan (ranges in m).
    alpha : ndarray, 2-D
        Intensity-derived incidence, rad.
    region : ndarray of bool, 2-D
        The leaf's pixels on ``window``.
    share : ndarray of bool, 2-D
        Where the leaf has a share of the pulse's footprint, on ``window``.
    unreliable : ndarray of bool, 2-D
        Pulses whose range straddles two surfaces (whole scan).
    variant : str
        PROP-SFS variant.
    params : SfsParams
        Parameters.
    inliers : {"keep", "test", "refine", "replace"}
        Which measured inliers take the corrected distance (``params.inliers`` resolved).
    window : pair of slices, optional
        Part of the scan holding the region and its shared pulses with the
        frame's margin around them (default: the whole scan); the frame is
        built there only.

    Raises
    ------
    _Skipped
        For a region too small, one the engine rejects or one without a seed curve.
    """
    if region.sum() < MIN_LEAF_PIXELS:
        raise _Skipped(f"{int(region.sum())} pixels (< {MIN_LEAF_PIXELS})")
    w = window or (slice(0, scan.shape[0]), slice(0, scan.shape[1]))
    frame = local_frame(scan.theta[w], scan.psi[w], scan.range[w], region, scan.pose, share)
    inside = region[frame.box]
    frame = dataclasses.replace(frame, box=tuple(slice(b.start + o.start, b.stop + o.start) for b, o in zip(frame.box, w)))
    box = frame.box
    measured = frame.height(scan.range[box])
    try:
        heights = reconstruct_heights(alpha[box], measured, inside, frame.grid, variant, params,
                                      unreliable=unreliable[box])
    except SfsError as exc:
        raise _Skipped(str(exc)) from None
    if not heights.count.any():
        raise _Skipped("no seed curve could be initialised (seed regions too small or unmeasured)")
    pure = inside & ~unreliable[box]
    heights.height[~plausible(heights.height, measured, pure, frame)] = np.nan
    done = inside & np.isfinite(heights.height)
    threshold = params.outlier_threshold_m or outlier_threshold(scan.range[box], pure)
    with np.errstate(invalid="ignore"):
        disagree = np.abs(measured - heights.height) > threshold
    # "refine": the pure pulses in the noise's tails take their neighbours' plane (the fused surface follows the
    # measured heights, so it is no better estimate of a pure pulse than the pulse itself).
    tails, target = np.zeros(inside.shape, dtype=bool), heights.height
    if inliers == "refine":
        sigma = range_noise(np.where(pure, scan.range[box], np.nan))
        noise = pulse_noise(sigma, scan.intensity[box], float(scan.scanner.assumed_model.log_gain_dn))
        tails, plane = noise_tails(measured, pure, frame.grid, sigma, noise)
        target = np.where(tails, plane, heights.height)
        done = done | tails
    moved = unreliable[box] | {"keep": False, "test": disagree, "refine": tails, "replace": True}[inliers]
    return _LeafFit(frame, heights, float(threshold), done, moved, target)


def _paste_leaf(grids: _Grids, fit: _LeafFit, inside: np.ndarray) -> None:
    """Write a leaf's corrected ranges (m), candidate counts, spreads (m) and smoothed incidences (rad) into ``grids``.

    Parameters
    ----------
    grids : _Grids
        The per-pixel outputs, changed in place on the leaf's box.
    fit : _LeafFit
        The leaf's reconstruction.
    inside : ndarray of bool, 2-D
        The leaf's pixels on the frame's box.
    """
    box, heights = fit.frame.box, fit.heights
    sub = grids.range[box]
    sub[fit.done & fit.moved] = fit.frame.range(fit.target[fit.done & fit.moved])
    grids.corrected[box] |= fit.done
    grids.candidates[box] = np.where(inside, heights.count, grids.candidates[box])
    r_hi = fit.frame.range(heights.height + 0.5 * heights.spread)
    r_lo = fit.frame.range(heights.height - 0.5 * heights.spread)
    grids.spread[box] = np.where(inside, r_hi - r_lo, grids.spread[box])
    grids.alpha[box] = np.where(inside, heights.alpha, grids.alpha[box])


def _assemble(scan: Scan, variant: str, params: SfsParams, regions: _Regions, grids: _Grids, fits: list,
              skipped: list, reliable: np.ndarray, removed: np.ndarray, ownerless: np.ndarray,
              single: np.ndarray) -> SfsResult:
    """The result of :func:`reconstruct`: outliers, and each leaf with its traits (area m^2, angles rad).

    Parameters
    ----------
    scan : tlssim.Scan
        The input scan.
    variant : str
        PROP-SFS variant.
    params : SfsParams
        Parameters.
    regions : _Regions
        Leaf regions and footprint shares.
    grids : _Grids
        Per-pixel outputs with every leaf pasted in.
    fits : list of (int, _LeafFit)
        The reconstructed leaves, by region label.
    skipped : list of (int, str)
        Regions not reconstructed, and why.
    reliable : ndarray of bool
        Pixels whose intensity-derived incidence is reliable.
    removed : ndarray of bool
        Pulses removed (NaN in ``grids.range``).
    ownerless : ndarray of bool
        Corrected pulses that no surface owns: removed from the corrected
        scan after the traits (they count there for their shares at their
        corrected distances).
    single : ndarray of bool
        Pulses within the range noise of one surface that take its
        extrapolated distance in the corrected scan, after the traits.
    """
    labels, corrected, out_range = regions.labels, grids.corrected, grids.range
    outlier = corrected & (out_range != scan.range)
    leaves = []
    tolerance = 3 * range_noise(scan.range) if fits else math.nan
    seen = visibility(labels, scan.range, tolerance) if fits else {}
    for label, fit in fits:
        box = fit.frame.box
        region = labels[box] == label  # the frame's box holds the whole region
        # The traits of the output: corrected distances of the leaf's outliers, measured ones of its inliers.
        height = fit.frame.height(np.where(region & corrected[box], out_range[box], np.nan))
        traits = {**leaf_traits(fit.frame, height, regions.shares.crop(label, box), params.trait_smoothing_m,
                                regions.band.crop(label, box), nearer_ring(region, scan.range[box], tolerance, None)),
                  "n_points": int(region.sum()), "n_outliers": int((outlier[box] & region).sum()),
                  "unreliable_alpha_fraction": float(np.mean(~reliable[box][region])),
                  "outlier_threshold_m": fit.threshold}
        # Whether the measured area is the whole leaf's (leafsfs.canopy.visibility).
        traits.update(cut=seen[label]["cut"], cut_by_border=seen[label]["border"],
                      occluded_fraction=seen[label]["occluded_fraction"])
        leaves.append(LeafResult(label, fit.frame, fit.heights, traits))
    out_range = np.where(ownerless, np.nan, np.where(single, regions.single_range, out_range))
    corrected = corrected | single
    outlier |= ownerless | (single & (out_range != scan.range))
    removed = removed | ownerless
    return SfsResult(scan, variant, params, labels, out_range, corrected, grids.candidates, grids.spread, outlier,
                     grids.alpha, regions.background, removed, leaves, skipped)


def plausible(height: np.ndarray, measured: np.ndarray, pure: np.ndarray, frame: LocalFrame) -> np.ndarray:
    """Which reconstructed heights a leaf can have: within its pure pulses' heights widened by its width, m.

    A propagation that runs away (incidences near 90 deg, where ``tan(alpha)``
    explodes) gives heights far outside anything the leaf spans; such pixels
    keep their measured distance. The bound lets the surface rise or fall by
    the diagonal of its bounding box (a 45 deg slope across the whole leaf)
    beyond the heights of its pure pulses.

    Parameters
    ----------
    height : ndarray
        Reconstructed height per pixel of the leaf's box, m.
    measured : ndarray
        Measured height per pixel of the box, m (NaN without return).
    pure : ndarray of bool
        The leaf's pure (reliable) pulses in the box.
    frame : LocalFrame
        The leaf's local frame; its grid gives the box's size in m.

    Returns
    -------
    ndarray of bool
        Pixels whose height is within the bound (always False where ``height`` is NaN).
    """
    rows, cols = np.nonzero(pure)
    if not len(rows):
        return np.isfinite(height)
    corners = frame.grid.to_continuous(np.array([[rows.min(), cols.min()], [rows.max(), cols.max()]], float))
    width = float(np.linalg.norm(corners[1] - corners[0]))
    low, high = np.nanmin(measured[pure]) - width, np.nanmax(measured[pure]) + width
    with np.errstate(invalid="ignore"):
        return (height >= low) & (height <= high)


def outlier_threshold(range_m: np.ndarray, pure: np.ndarray) -> float:
    """``max(3 sigma, 2 mm)``, sigma the range noise of a leaf's pure pulses (:func:`leafsfs.leaves.range_noise`), m.

    The issue's outlier rule (tls-physics §7.10) with the truth replaced by
    the reconstruction: a measured point farther than this from its
    corrected distance is an outlier.

    Parameters
    ----------
    range_m : ndarray
        Measured range per pixel, m.
    pure : ndarray of bool
        The leaf's pure pulses.

    Returns
    -------
    float
        Outlier distance, m.
    """
    sigma = range_noise(np.where(pure, range_m, np.nan))
    return max(3.0 * sigma, OUTLIER_FLOOR_M) if np.isfinite(sigma) else OUTLIER_FLOOR_M


def _main_surface(surfaces: np.ndarray, region: np.ndarray) -> int:
    """The surface label holding most of a region's pure pulses (0 if none)."""
    inside = surfaces[region]
    inside = inside[inside > 0]
    return int(np.bincount(inside).argmax()) if len(inside) else 0


def _labels_from_mask(mask, shape) -> np.ndarray:
    mask = np.asarray(mask)
    if mask.shape != shape:
        raise SfsError(f"mask has shape {mask.shape}; it must match the scan grid {shape}")
    if mask.dtype == bool:
        return mask.astype(int)
    if not np.issubdtype(mask.dtype, np.integer) or mask.min() < 0:
        raise SfsError(f"mask must be boolean or a non-negative integer label image, got dtype {mask.dtype}")
    return mask.astype(int)

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
import functools
from dataclasses import dataclass, field

import numpy as np
import trimesh

from leafsfs.engine import HeightResult, reconstruct_heights
from leafsfs.errors import SfsError
from leafsfs.frame import LocalFrame, local_frame
from leafsfs.leaves import range_noise, segment_scan
from leafsfs.params import VARIANTS, SfsParams
from leafsfs.preprocess import resolve_calibration, scan_alpha
from leafsfs.traits import leaf_traits
from tlssim.scan import Scan, grid_to_xyz

#: Smallest leaf region reconstructed, pixels (smaller regions are skipped and listed).
MIN_LEAF_PIXELS = 30
#: Smallest automatic outlier threshold, m (the issue's tau floor, tls-physics §7.10).
OUTLIER_FLOOR_M = 0.002
#: Log-amplifier gain assumed when the scan does not record its scanner model, DN per e-fold (the FARO LS880
#: value derived from the Sensors 2011 Table 2 offsets, tls-physics §A.2).
LOG_GAIN_DN = 263.0


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
        plus ``n_points`` and ``n_outliers``.
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
    leaves: list = field(default_factory=list)
    skipped: list = field(default_factory=list)

    def corrected_scan(self) -> Scan:
        """A copy of the scan with corrected ranges and points, plus the layers ``outlier``, ``candidates``,
        ``leaf`` (region labels), ``background`` and ``range_spread`` (m)."""
        scan = copy.copy(self.scan)
        scan.range = self.range.copy()
        scan.xyz = grid_to_xyz(scan.range, scan.theta, scan.psi, scan.pose)
        scan.layers = {**self.scan.layers, "outlier": self.outlier.copy(), "candidates": self.candidates.astype(np.int32),
                       "leaf": self.labels.astype(np.int32), "background": self.background.copy(),
                       "range_spread": self.spread.astype(np.float32)}
        scan.meta = {**self.scan.meta, "leafsfs": {"variant": self.variant, "params": self.params.to_dict()}}
        return scan

    def points(self) -> np.ndarray:
        """Corrected points of the reconstructed pixels, world frame, ``(n, 3)``."""
        xyz = grid_to_xyz(self.range, self.scan.theta, self.scan.psi, self.scan.pose)
        return xyz[self.corrected]

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
        """Redundancy ratios over the reconstructed leaf pixels, or those of ``region`` (see :meth:`HeightResult.rppp`)."""
        counts = self.candidates[self.labels > 0 if region is None else region]
        total = max(len(counts), 1)
        out = {f"rppp_{n}": float(np.sum(counts == n) / total) for n in range(n_max + 1)}
        out["rppp_more"] = float(np.sum(counts > n_max) / total)
        return out


def reconstruct(scan: Scan, mask=None, variant: str = "buffer", params: SfsParams | None = None, *,
                calibration=None) -> SfsResult:
    """Re-estimate the distances of the leaves of a scan from its intensity (PROP-SFS).

    Steps: intensity to incidence (the calibration); surfaces and mixed
    pulses (:func:`leafsfs.leaves.segment_scan`): every mixed pulse goes to
    the surface that returned most of its power, and those dominated by a
    surface that is not a leaf (the wall behind) take that surface's
    distance (also those inside a given ``mask``); per leaf the
    engine on its local frame; the leaf's mixed pulses, and the inliers as
    ``params.inliers`` says, take the corrected distance (they are the
    outliers); traits of that surface with every pulse weighted by the
    leaf's share of its footprint.

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
    calibration : Calibration, path or "model"
        Intensity calibration (:func:`leafsfs.preprocess.resolve_calibration`).

    Raises
    ------
    SfsError
        For a scan without valid pixels, a mask of the wrong shape or type,
        a missing or unreadable calibration, an unknown variant or
        parameters out of range.
    """
    params = params or SfsParams()
    if not isinstance(params, SfsParams):
        raise SfsError(f"params must be an SfsParams, got {type(params).__name__}")
    if variant not in VARIANTS:
        raise SfsError(f"unknown PROP-SFS variant {variant!r}; choose one of {', '.join(VARIANTS)}")
    valid = scan.valid & np.isfinite(scan.intensity)
    if not valid.any():
        raise SfsError("the scan has no valid pixels (no returns with range and intensity)")
    labels = None if mask is None else _labels_from_mask(mask, scan.shape)
    calibration = resolve_calibration(calibration, scan)
    alpha, reliable = scan_alpha(scan.intensity, scan.range, calibration)
    segmentation = segment_scan(scan.range, scan.theta, scan.psi, alpha, intensity=scan.intensity)
    gain = float(scan.scanner_model.get("log_gain_dn", LOG_GAIN_DN))
    mixed = segmentation.mixed
    unreliable = valid & mixed.straddling
    out_range = scan.range.copy()
    background = np.zeros(scan.shape, dtype=bool)
    if labels is None:
        labels = segmentation.leaves
        surface_of = {k: segmentation.region_surface(k) for k in np.unique(labels[labels > 0])}
        # Each leaf's share image is computed when its leaf is reconstructed (one full-scan image per leaf region
        # at once took 12.6 GB on a 300-leaf tree at 0.018 deg); only the part in the leaf's box is kept.
        shares = {k: functools.partial(mixed.share_of, s, gain) for k, s in surface_of.items()}
        # Mixed pulses dominated by a surface that is not a leaf (the wall behind) take its distance; so do those of
        # a thin part attached to a leaf (a petiole), at the distance where it is attached when it dominates them.
        background = unreliable & (mixed.owner > 0) & (~np.isin(mixed.owner, segmentation.leaf_surfaces) | mixed.thin)
    else:
        # A given region counts its pixels whole, except the mixed pulses of its main surface, which count (inside
        # the region or just outside it) for their share of that surface; its mixed pulses that another surface
        # dominates (the wall behind) take that surface's distance and leave the region.
        shares = {}
        for k in np.unique(labels[labels > 0]):
            main = _main_surface(mixed.surfaces, labels == k)
            paired = (mixed.surfaces == 0) & (mixed.pair == main).any(axis=-1)
            shares[k] = functools.partial(np.asarray, np.where(paired, mixed.share_of(main, gain),
                                                               (labels == k).astype(float)))
            background |= unreliable & (labels == k) & (mixed.owner > 0) & (mixed.owner != main)
        labels = np.where(background, 0, labels)
    out_range[background] = mixed.owner_range()[background]
    labels = np.where(valid, labels, 0)
    if not labels.any():
        raise SfsError("no leaf pixel with a valid return: the mask (or the leaf segmentation) selects none")
    inliers = params.inliers if params.inliers != "auto" else ("refine" if variant == "fused" else "keep")
    corrected = background.copy()
    candidates = np.zeros(scan.shape, dtype=int)
    spread = np.full(scan.shape, np.nan)
    smoothed = alpha.copy()
    leaves, skipped = [], []
    for label in np.unique(labels[labels > 0]):
        region = labels == label
        if region.sum() < MIN_LEAF_PIXELS:
            skipped.append((int(label), f"{int(region.sum())} pixels (< {MIN_LEAF_PIXELS})"))
            continue
        share = shares[label]()
        frame = local_frame(scan.theta, scan.psi, scan.range, region, scan.pose, share > 0)
        box = frame.box
        shares[label] = share[box].copy()
        measured = frame.height(scan.range[box])
        try:
            heights = reconstruct_heights(alpha[box], measured, region[box], frame.grid, variant, params,
                                          unreliable=unreliable[box])
        except SfsError as exc:
            skipped.append((int(label), str(exc)))
            continue
        if not heights.count.any():
            skipped.append((int(label), "no seed curve could be initialised (seed regions too small or unmeasured)"))
            continue
        heights.height[~plausible(heights.height, measured, region[box] & ~unreliable[box], frame)] = np.nan
        done = region[box] & np.isfinite(heights.height)
        threshold = params.outlier_threshold_m or outlier_threshold(scan.range[box], region[box] & ~unreliable[box])
        with np.errstate(invalid="ignore"):
            disagree = np.abs(measured - heights.height) > threshold
        moved = unreliable[box] | {"keep": False, "test": disagree, "refine": ~disagree, "replace": True}[inliers]
        sub = out_range[box]
        sub[done & moved] = frame.range(heights.height[done & moved])
        corrected[box] |= done
        candidates[box] = np.where(region[box], heights.count, candidates[box])
        r_hi = frame.range(heights.height + 0.5 * heights.spread)
        r_lo = frame.range(heights.height - 0.5 * heights.spread)
        spread[box] = np.where(region[box], r_hi - r_lo, spread[box])
        smoothed[box] = np.where(region[box], heights.alpha, smoothed[box])
        leaves.append(LeafResult(int(label), frame, heights, {"outlier_threshold_m": float(threshold)}))
    outlier = corrected & (out_range != scan.range)
    result = SfsResult(scan, variant, params, labels, out_range, corrected, candidates, spread, outlier, smoothed,
                       background, leaves, skipped)
    for leaf in leaves:
        region = labels == leaf.label
        box = leaf.frame.box
        # The traits of the output: corrected distances of the leaf's outliers, measured ones of its inliers.
        height = leaf.frame.height(np.where(region & corrected, out_range, np.nan)[box])
        leaf.traits = {**leaf_traits(leaf.frame, height, shares[leaf.label], params.trait_smoothing_m),
                       "n_points": int(region.sum()), "n_outliers": int((outlier & region).sum()),
                       "unreliable_alpha_fraction": float(np.mean(~reliable[region])), **leaf.traits}
    return result


def plausible(height: np.ndarray, measured: np.ndarray, pure: np.ndarray, frame: LocalFrame) -> np.ndarray:
    """Which reconstructed heights a leaf can have: within its pure pulses' heights widened by its width, m.

    A propagation that runs away (incidences near 90 deg, where ``tan(alpha)``
    explodes) gives heights far outside anything the leaf spans; such pixels
    keep their measured distance. The bound lets the surface rise or fall by
    the diagonal of its bounding box (a 45 deg slope across the whole leaf)
    beyond the heights of its pure pulses.
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

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
from dataclasses import dataclass, field

import numpy as np
import trimesh

from leafsfs.engine import HeightResult, reconstruct_heights
from leafsfs.errors import SfsError
from leafsfs.frame import LocalFrame, local_frame
from leafsfs.leaves import edge_pixels, segment_leaves
from leafsfs.params import VARIANTS, SfsParams
from leafsfs.preprocess import resolve_calibration, scan_alpha
from leafsfs.traits import leaf_traits
from tlssim.scan import Scan, grid_to_xyz

#: Smallest leaf region reconstructed, pixels (smaller regions are skipped and listed).
MIN_LEAF_PIXELS = 30


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
        Corrected range per pixel, m: the median of the candidates (or the
        rim extrapolation) on leaf pixels, the measured range elsewhere.
    corrected : ndarray of bool
        Pixels whose range was re-estimated.
    candidates : ndarray of int
        Number of PROP-SFS candidate distances per pixel (rppp counts).
    spread : ndarray
        Range of the candidate distances per pixel, m (NaN without candidates).
    outlier : ndarray of bool
        Measured points farther than ``params.outlier_threshold_m`` from
        their corrected distance.
    alpha : ndarray
        Intensity-derived incidence, rad (smoothed on leaves).
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
    leaves: list = field(default_factory=list)
    skipped: list = field(default_factory=list)

    def corrected_scan(self) -> Scan:
        """A copy of the scan with corrected ranges and points, plus the layers ``outlier``, ``candidates``,
        ``leaf`` (region labels) and ``range_spread`` (m)."""
        scan = copy.copy(self.scan)
        scan.range = self.range.copy()
        scan.xyz = grid_to_xyz(scan.range, scan.theta, scan.psi, scan.pose)
        scan.layers = {**self.scan.layers, "outlier": self.outlier.copy(), "candidates": self.candidates.astype(np.int32),
                       "leaf": self.labels.astype(np.int32), "range_spread": self.spread.astype(np.float32)}
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

    def rppp(self, n_max: int = 3) -> dict[str, float]:
        """Redundancy ratios over all reconstructed leaf pixels (see :meth:`HeightResult.rppp`)."""
        counts = self.candidates[self.labels > 0]
        total = max(len(counts), 1)
        out = {f"rppp_{n}": float(np.sum(counts == n) / total) for n in range(n_max + 1)}
        out["rppp_more"] = float(np.sum(counts > n_max) / total)
        return out


def reconstruct(scan: Scan, mask=None, variant: str = "buffer", params: SfsParams | None = None, *,
                calibration=None) -> SfsResult:
    """Re-estimate the distances of the leaves of a scan from its intensity (PROP-SFS).

    Parameters
    ----------
    scan : tlssim.Scan
        A simulated or imported scan (truth arrays are not used).
    mask : ndarray of bool or int, optional
        The leaf to reconstruct (boolean image of the scan's shape) or a
        label image of several leaves (0 = none). Default: leaf regions from
        :func:`leafsfs.leaves.segment_leaves`.
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
    labels = None
    if mask is not None:
        labels = _labels_from_mask(mask, scan.shape)
    calibration = resolve_calibration(calibration, scan)
    alpha, reliable = scan_alpha(scan.intensity, scan.range, calibration)
    if labels is None:
        labels = segment_leaves(scan.range, scan.theta, scan.psi, alpha)
    labels = np.where(valid, labels, 0)
    mixed = edge_pixels(scan.range, scan.theta, scan.psi, alpha)
    if not labels.any():
        raise SfsError("no leaf pixel with a valid return: the mask (or the leaf segmentation) selects none")
    out_range = scan.range.copy()
    corrected = np.zeros(scan.shape, dtype=bool)
    candidates = np.zeros(scan.shape, dtype=int)
    spread = np.full(scan.shape, np.nan)
    smoothed = alpha.copy()
    leaves, skipped = [], []
    for label in np.unique(labels[labels > 0]):
        region = labels == label
        if region.sum() < MIN_LEAF_PIXELS:
            skipped.append((int(label), f"{int(region.sum())} pixels (< {MIN_LEAF_PIXELS})"))
            continue
        frame = local_frame(scan.theta, scan.psi, scan.range, region, scan.pose)
        box = frame.box
        try:
            heights = reconstruct_heights(alpha[box], frame.height(scan.range[box]), region[box], frame.grid,
                                          variant, params, unreliable=mixed[box])
        except SfsError as exc:
            skipped.append((int(label), str(exc)))
            continue
        if not heights.count.any():
            skipped.append((int(label), "no seed curve could be initialised (seed regions too small or unmeasured)"))
            continue
        done = region[box] & np.isfinite(heights.height)
        sub = out_range[box]
        sub[done] = frame.range(heights.height[done])
        corrected[box] |= done
        candidates[box] = np.where(region[box], heights.count, candidates[box])
        r_hi = frame.range(heights.height + 0.5 * heights.spread)
        r_lo = frame.range(heights.height - 0.5 * heights.spread)
        spread[box] = np.where(region[box], r_hi - r_lo, spread[box])
        smoothed[box] = np.where(region[box], heights.alpha, smoothed[box])
        leaves.append(LeafResult(int(label), frame, heights, {}))
    with np.errstate(invalid="ignore"):
        outlier = corrected & (np.abs(scan.range - out_range) > params.outlier_threshold_m)
    result = SfsResult(scan, variant, params, labels, out_range, corrected, candidates, spread, outlier, smoothed,
                       leaves, skipped)
    for leaf in leaves:
        region = labels == leaf.label
        leaf.traits = {**leaf_traits(leaf.frame, leaf.heights.height, region[leaf.frame.box], params.trait_smoothing_m),
                       "n_points": int(region.sum()), "n_outliers": int((outlier & region).sum()),
                       "unreliable_alpha_fraction": float(np.mean(~reliable[region]))}
    return result


def _labels_from_mask(mask, shape) -> np.ndarray:
    mask = np.asarray(mask)
    if mask.shape != shape:
        raise SfsError(f"mask has shape {mask.shape}; it must match the scan grid {shape}")
    if mask.dtype == bool:
        return mask.astype(int)
    if not np.issubdtype(mask.dtype, np.integer) or mask.min() < 0:
        raise SfsError(f"mask must be boolean or a non-negative integer label image, got dtype {mask.dtype}")
    return mask.astype(int)

"""PROP-SFS on a tiled scan (:mod:`tlssim.tiled`): window by window, with overlaps, into a tiled corrected scan.

A scan larger than memory is reconstructed in windows of whole columns.
The scan's columns are cut into *cores* of ``core_cols`` columns; window
``k`` is core ``k`` widened on either side by a margin: the columns a leaf
of ``leaf_size_m`` spans at the core's nearest pulses (:func:`margin_columns`). Every leaf
region found in window ``k`` is kept from that window only when its
centroid column lies in core ``k``, so a leaf cut by a core border is
reconstructed once, from the window where it lies whole. A kept region
that comes within :data:`GUARD_COLS` columns of a window border that is
not the scan's border (the leaf is wider than the margin) makes the window
run again with twice the margin, up to ``max_margin`` columns; a region
still cut then is kept and its traits say ``cut_by_border``.

The corrected scan is written as a tiled scan (one tile per core): a
pixel takes the values of the window that kept the region covering it
(window ``k`` or a neighbour; a kept region reaches at most ``margin``
columns past its core), and otherwise those of its own core's window,
where the pixels of a region that window did not keep get back their
measured range. So at most three windows' outputs are in memory at a time.
Leaves are numbered in core order; every tile's metadata holds the
traits of its core's leaves, so an interrupted run resumes with the
tiles that check (:func:`tlssim.tiled.start_tiled`) and recomputes only
the windows the remaining cores need. ``traits.json`` gathers all leaves.

Not handled: a 360 deg scan's first and last columns are neighbours in
the scene, but the windows do not wrap around (a leaf cut by the scan's
own seam gives two regions, as on an untiled scan).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from leafsfs.errors import SfsError
from leafsfs.frame import MARGIN_PX
from leafsfs.outputs import json_ready
from leafsfs.params import VARIANTS, SfsParams
from leafsfs.preprocess import resolve_calibration
from leafsfs.reconstruct import reconstruct
from tlssim.scan import GRID_KEYS, TRUTH_KEYS, Scan, grid_to_xyz
from tlssim.tiled import INDEX, TiledScan, add_tile, open_tiled, start_tiled

#: Columns a kept region must stay away from a window's inner border to count as whole: the leaf frame's
#: margin plus the segmentation's neighbourhood (about a footprint, at least 5 x 5 pulses; assumption: 5).
GUARD_COLS = MARGIN_PX + 5
#: Largest leaf extent assumed by default, m: about twice the mean pear-leaf blade length measured in the
#: lab (6.47 cm, scenes.leaf), for the petiole and larger leaves (assumption).
LEAF_SIZE_M = 0.12
#: Memory of a reconstruction per pulse of its window, bytes: the ``leafsfs reconstruct`` process peaked at 664 MB
#: on windows of 1.0 M pulses of the orchard row at 0.018 deg (``fused``), imports included.
RECONSTRUCT_BYTES_PER_PULSE = 650


@dataclasses.dataclass
class _Window:
    """What one window contributes: its outputs over its columns ``w0:w1`` and the leaves it kept."""

    w0: int
    w1: int
    margin: int
    range: np.ndarray
    outlier: np.ndarray
    candidates: np.ndarray
    leaf: np.ndarray  # rank of the kept leaf (1..n) per pixel, 0 elsewhere
    claim: np.ndarray  # pixels of the regions (reconstructed or skipped) this window keeps
    background: np.ndarray
    spread: np.ndarray
    corrected: np.ndarray
    core: Scan  # the input scan's core columns
    traits: list = dataclasses.field(default_factory=list)
    skipped: list = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class TiledResult:
    """Summary of :func:`reconstruct_tiled`.

    Attributes
    ----------
    scan : TiledScan
        The corrected scan (layers ``outlier``, ``candidates``, ``leaf``, ``background``, ``range_spread``).
    traits : list of dict
        One entry per leaf (``leaf``: its label in the ``leaf`` layer, plus the traits of
        :attr:`leafsfs.reconstruct.LeafResult.traits`, ``core`` and ``margin_cols``).
    skipped : list of dict
        Regions not reconstructed (``core``, ``reason``).
    pulses : int
        Pulses of the cores written by this call.
    windows : int
        Windows reconstructed by this call (resumed cores need none).
    elapsed_s : float
        Wall time of this call, s.
    """

    scan: TiledScan
    traits: list
    skipped: list
    pulses: int
    windows: int
    elapsed_s: float

    @property
    def pulses_per_s(self) -> float:
        """Throughput of this call, pulses of the scan per second of wall time."""
        return self.pulses / self.elapsed_s if self.elapsed_s > 0 else math.inf


def core_columns(rows: int, budget_bytes: float, margin: int) -> int:
    """Columns per core that keep a window (core plus two margins) within a memory budget.

    Parameters
    ----------
    rows : int
        Rows of the scan.
    budget_bytes : float
        Memory for one window's reconstruction, bytes (:data:`RECONSTRUCT_BYTES_PER_PULSE` per pulse).
    margin : int
        Margin columns on either side of a core.

    Returns
    -------
    int
        Columns per core, at least ``margin`` (a window never holds less than its own margins' worth).
    """
    window = int(budget_bytes // (RECONSTRUCT_BYTES_PER_PULSE * max(rows, 1)))
    return max(window - 2 * margin, margin, 1)


def reconstruct_tiled(tiled: TiledScan, outdir, variant: str = "buffer", params: SfsParams | None = None, *,
                      calibration=None, core_cols: int = 512, leaf_size_m: float = LEAF_SIZE_M,
                      max_margin: int = 2048, progress=None) -> TiledResult:
    """Reconstruct the leaves of a tiled scan window by window into ``outdir`` (tiled scan plus ``traits.json``).

    Parameters
    ----------
    tiled : TiledScan
        The scan (:func:`tlssim.tiled.open_tiled`), complete.
    outdir : str or Path
        Output directory: the corrected tiled scan goes to ``outdir/corrected``, the traits of
        every leaf to ``outdir/traits.json``. An interrupted run into the same directory resumes.
    variant : {"simple", "sps", "buffer", "fused"}
        PROP-SFS variant.
    params : SfsParams, optional
        Parameters (default :class:`SfsParams`).
    calibration : Calibration or path
        Intensity calibration (:func:`leafsfs.preprocess.resolve_calibration`).
    core_cols : int
        Columns per core (and per output tile), ``>= 1``.
    leaf_size_m : float
        Largest leaf extent, m: a window's margin is the columns it spans at the nearest pulses of
        the core (:func:`margin_columns`).
    max_margin : int
        Largest margin of a window, columns.
    progress : callable, optional
        Called with the number of pulses of every finished core.

    Returns
    -------
    TiledResult

    Raises
    ------
    SfsError
        For bad window sizes, an incomplete scan, or an output directory holding another reconstruction.
    """
    from tlssim.errors import ScanError

    if core_cols < 1 or max_margin < GUARD_COLS or not leaf_size_m > 0:
        raise SfsError(f"tiled reconstruction needs core_cols >= 1, max_margin >= {GUARD_COLS} and leaf_size_m > 0, "
                       f"got {core_cols}, {max_margin}, {leaf_size_m}")
    if variant not in VARIANTS:
        raise SfsError(f"unknown variant {variant!r}; allowed: {', '.join(VARIANTS)}")
    if not tiled.complete:
        raise SfsError(f"{tiled.path}: the tiled scan is incomplete; finish (resume) the scan first")
    start = time.perf_counter()
    params = params or SfsParams()
    calibration = resolve_calibration(calibration)
    rows, cols = tiled.shape
    outdir = Path(outdir)
    identity = {"scan": tiled.index.get("fingerprint"), "tiles": [t.sha256 for t in tiled.tiles], "variant": variant,
                "params": params.to_dict(), "calibration": repr(calibration), "margin": [leaf_size_m, max_margin]}
    fingerprint = hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()).hexdigest()
    header = {key: tiled.index[key] for key in ("shape", "scanner", "scanner_position", "scanner_rotation",
                                                "object_names", "theta_columns", "psi_rows", "has_truth")}
    header["meta"] = {**tiled.meta, "leafsfs": {"variant": variant, "params": params.to_dict(),
                                               "source": str(tiled.path)}}
    try:
        index, todo = start_tiled(outdir / "corrected", header, fingerprint, core_cols)
    except ScanError as exc:
        raise SfsError(str(exc)) from None
    core_cols = int(index["tile_cols"])
    n_cores = -(-cols // core_cols)
    # Leaves are numbered in core order: the count before the first core to write comes from the written tiles.
    written = {t["col0"] // core_cols: t for t in index["tiles"]}
    offsets = {0: 0}
    cache: dict[int, _Window] = {}
    windows_run = 0

    def window(k: int) -> _Window:
        nonlocal windows_run
        if k not in cache:
            cache[k] = _reconstruct_window(tiled, k * core_cols, min(cols, (k + 1) * core_cols), leaf_size_m,
                                           max_margin, variant, params, calibration)
            windows_run += 1
        return cache[k]

    def offset(k: int) -> int:
        j = max(offsets)
        while j < k:  # the leaves of core j: from its written tile, else from its window
            kept = _tile_leafsfs(outdir / "corrected", written[j])["leaves"] if j in written else window(j).traits
            offsets[j + 1] = offsets[j] + len(kept)
            j += 1
        return offsets[k]

    for c0, c1 in todo:
        k = c0 // core_cols
        tile, leaves, skipped = _assemble_core(k, c0, c1, [(j, window(j), offset(j)) for j in (k - 1, k, k + 1)
                                                           if 0 <= j < n_cores])
        tile.meta = {**tiled.meta, "columns": [c0, c1],
                     "leafsfs": {"variant": variant, "leaves": json_ready(leaves), "skipped": skipped}}
        add_tile(outdir / "corrected", index, c0, tile)
        written[k] = next(t for t in index["tiles"] if t["col0"] == c0)
        for j in [j for j in cache if j < k]:
            del cache[j]
        if progress is not None:
            progress(rows * (c1 - c0))
    corrected = open_tiled(outdir / "corrected")
    traits, skipped = [], []
    for k in sorted(written):
        info = _tile_leafsfs(outdir / "corrected", written[k])
        traits += info["leaves"]
        skipped += info["skipped"]
    report = {"variant": variant, "source": str(tiled.path), "core_cols": core_cols, "leaves": traits,
              "skipped": skipped, "params": params.to_dict()}
    (outdir / "traits.json").write_text(json.dumps(json_ready(report), indent=1, allow_nan=False))
    return TiledResult(corrected, traits, skipped, rows * sum(c1 - c0 for c0, c1 in todo), windows_run,
                       time.perf_counter() - start)


def _tile_leafsfs(path: Path, entry: dict) -> dict:
    """The ``leafsfs`` metadata (leaves, skipped) of a written tile, read without its arrays."""
    with np.load(path / entry["file"], allow_pickle=False) as data:
        return json.loads(str(data["meta"]))["leafsfs"]


def margin_columns(scan: Scan, leaf_size_m: float, max_margin: int) -> int:
    """Margin of a window around a core: the columns a leaf of ``leaf_size_m`` spans at the core's nearest pulses.

    A column is ``r sin(psi) dtheta`` wide at range ``r`` and zenith ``psi``; the nearest pulses are the
    1st percentile of ``r sin(psi)`` (a stray near return does not set the margin).

    Parameters
    ----------
    scan : Scan
        The core's columns.
    leaf_size_m : float
        Largest leaf extent, m.
    max_margin : int
        Largest margin, columns.

    Returns
    -------
    int
        Columns, from :data:`GUARD_COLS` to ``max_margin``.
    """
    if scan.shape[1] < 2 or not scan.valid.any():
        return GUARD_COLS
    step = float(np.nanmedian(np.abs(np.diff(scan.theta, axis=1))))
    radius = float(np.percentile((scan.range * np.sin(scan.psi))[scan.valid], 1.0))
    if not (step > 0 and radius > 0):
        return max_margin
    return int(np.clip(math.ceil(leaf_size_m / (radius * step)) + GUARD_COLS, GUARD_COLS, max_margin))


def _reconstruct_window(tiled: TiledScan, c0: int, c1: int, leaf_size_m: float, max_margin: int, variant: str,
                        params: SfsParams, calibration) -> _Window:
    """Reconstruct the window of core ``c0:c1``, widening it while a leaf it keeps touches an inner border."""
    cols = tiled.shape[1]
    margin = margin_columns(tiled.load_columns(c0, c1), leaf_size_m, max_margin)
    while True:
        w0, w1 = max(0, c0 - margin), min(cols, c1 + margin)
        scan = tiled.load_columns(w0, w1)
        try:
            result = reconstruct(scan, None, variant, params, calibration=calibration)
        except SfsError:  # no leaf in this window (inputs were checked before the first window)
            return _empty_window(scan, w0, w1, c0, c1, margin)
        labels = result.labels
        n = int(labels.max()) if labels.size else 0
        counts = np.bincount(labels.ravel(), minlength=n + 1)
        column = np.broadcast_to(np.arange(w0, w1, dtype=np.float64), labels.shape)
        centroid = np.bincount(labels.ravel(), weights=column.ravel(), minlength=n + 1) / np.maximum(counts, 1)
        mine = (centroid >= c0) & (centroid < c1) & (counts > 0)
        mine[0] = False
        kept = [leaf for leaf in result.leaves if mine[leaf.label]]
        slices = ndimage.find_objects(labels)
        touching = any((w0 > 0 and slices[leaf.label - 1][1].start < GUARD_COLS)
                       or (w1 < cols and slices[leaf.label - 1][1].stop > w1 - w0 - GUARD_COLS) for leaf in kept)
        if not touching or margin >= max_margin or (w0 == 0 and w1 == cols):
            break
        margin = min(2 * max(margin, 1), max_margin)
    rank = np.zeros(n + 1, dtype=np.int32)
    rank[[leaf.label for leaf in kept]] = np.arange(1, len(kept) + 1, dtype=np.int32)
    # A window keeps its regions and the pulses corrected outside any region (background pulses) whose nearest
    # region it keeps; the others get back their measured values here (another core's window gives them).
    loose = result.corrected & (labels == 0)
    owner = labels
    if loose.any() and (labels > 0).any():
        nearest = ndimage.distance_transform_edt(labels == 0, return_distances=False, return_indices=True)
        owner = labels[tuple(nearest)]
    claim = mine[labels] | (loose & mine[owner])
    dropped = ((labels > 0) | loose) & ~claim
    traits = [{**leaf.traits, "margin_cols": margin, "centroid_col": float(centroid[leaf.label])} for leaf in kept]
    skipped = [reason for label, reason in result.skipped if mine[label]]
    core = _copy_scan(scan.crop(slice(None), slice(c0 - w0, c1 - w0)))
    return _Window(w0, w1, margin, np.where(dropped, scan.range, result.range), result.outlier & ~dropped,
                   np.where(dropped, 0, result.candidates), rank[labels], claim, result.background & ~dropped,
                   np.where(dropped, np.nan, result.spread), result.corrected & ~dropped, core, traits, skipped)


def _empty_window(scan: Scan, w0: int, w1: int, c0: int, c1: int, margin: int) -> _Window:
    """The contribution of a window without leaves: the measured scan, nothing corrected."""
    none = np.zeros(scan.shape, dtype=bool)
    return _Window(w0, w1, margin, scan.range, none, np.zeros(scan.shape, np.int32), np.zeros(scan.shape, np.int32),
                   none, none, np.full(scan.shape, np.nan), none, _copy_scan(scan.crop(slice(None), slice(c0 - w0, c1 - w0))))


def _copy_scan(scan: Scan) -> Scan:
    """A scan whose arrays are copies (a crop holds views that would keep the whole window alive)."""
    arrays = {key: getattr(scan, key).copy() for key in GRID_KEYS + TRUTH_KEYS if getattr(scan, key) is not None}
    return dataclasses.replace(scan, **arrays, layers={k: v.copy() for k, v in scan.layers.items()})


_OUTPUTS = ("range", "outlier", "candidates", "background", "spread")


def _assemble_core(k: int, c0: int, c1: int, windows: list) -> tuple[Scan, list, list]:
    """The corrected tile of core ``k`` (columns ``c0:c1``) from its window and the regions its neighbours keep.

    Parameters
    ----------
    k : int
        Core number.
    c0, c1 : int
        The core's columns.
    windows : list of (int, _Window, int)
        Core number, window and leaf-label offset of core ``k`` and of its existing neighbours.

    Returns
    -------
    tile : Scan
        The corrected scan of the core's columns.
    leaves : list of dict
        Traits of the leaves kept by core ``k``'s window, with their labels.
    skipped : list of dict
        Regions of core ``k``'s window not reconstructed.
    """
    grids, leaf = None, None
    for j, window, offset in sorted(windows, key=lambda item: item[0] != k):  # core k's own window first
        a, b = max(c0, window.w0), min(c1, window.w1)
        if a >= b:
            continue
        src, dst = slice(a - window.w0, b - window.w0), slice(a - c0, b - c0)
        if j == k:
            grids = {name: getattr(window, name)[:, src].copy() for name in _OUTPUTS}
            leaf = np.where(window.leaf[:, src] > 0, window.leaf[:, src] + offset, 0).astype(np.int32)
            own, own_offset = window, offset
            continue
        claim = window.claim[:, src]  # a neighbour's region replaces this window's view of its pixels
        for name in _OUTPUTS:
            grids[name][:, dst][claim] = getattr(window, name)[:, src][claim]
        leaf[:, dst][claim] = np.where(window.leaf[:, src] > 0, window.leaf[:, src] + offset, 0)[claim]
    tile = own.core
    layers = {**tile.layers, "outlier": grids["outlier"], "candidates": grids["candidates"].astype(np.int32),
              "leaf": leaf, "background": grids["background"], "range_spread": grids["spread"].astype(np.float32)}
    scan = dataclasses.replace(tile, range=grids["range"], layers=layers,
                               xyz=grid_to_xyz(grids["range"], tile.theta, tile.psi, tile.pose))
    leaves = [{"leaf": own_offset + i + 1, "core": k, **t} for i, t in enumerate(own.traits)]
    skipped = [{"core": k, "reason": reason} for reason in own.skipped]
    return scan, leaves, skipped


def is_tiled(path) -> bool:
    """Whether ``path`` is a tiled scan directory (holds an index)."""
    return Path(path).is_dir() and (Path(path) / INDEX).is_file()

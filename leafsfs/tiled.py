"""PROP-SFS on a tiled scan (:mod:`tlssim.tiled`): window by window, with overlaps, into a tiled corrected scan.

A scan larger than memory is reconstructed in windows. The scan's columns
are cut into *cores* of ``core_cols`` columns, and its rows into *bands* of
``band_rows`` rows (default: one band of all rows); window ``(b, k)`` is the
rectangle of band ``b`` and core ``k`` widened on every side by margins: the
columns (:func:`margin_columns`) and rows (:func:`margin_rows`) a leaf of
``leaf_size_m`` spans at the rectangle's nearest pulses. So the margins
follow the distance row band by row band: the ground at the tripod, the
nearest surface of a field scan, widens only the windows of the bottom band.
Every leaf region found in a window is kept from that window only when its
centroid lies in the window's core rectangle, so a leaf cut by a core or
band border is reconstructed once, from the window where it lies whole. A
kept region that comes within :data:`GUARD_COLS` pulses of a window border
that is not the scan's border (the leaf is wider than the margin) makes the
window run again with twice the margins, up to ``max_margin``; a region
still cut then is kept and its traits say ``cut_by_border``.

The corrected scan is written as a tiled scan (one tile per core): a
pixel takes the values of the window that kept the region covering it
(a kept region reaches at most a margin past its core rectangle), and
otherwise those of the window of its own core rectangle, where the pixels of a
region that window did not keep get back their measured range. A window
is kept as its outputs over its core rectangle (until that core is
written) and the pixels it keeps beyond it; a core's tile is written member
by member, its input arrays read one at a time, so this process holds a few
cores' outputs, not their whole tiles (:func:`plan_windows` sizes the
cores and bands for a memory budget of the whole run).
Leaves are numbered in core order, then band order; every tile's metadata holds the
traits of its core's leaves, so an interrupted run resumes with the
tiles that check (:func:`tlssim.tiled.start_tiled`) and recomputes only
the windows the remaining cores need. ``traits.json`` gathers all leaves.

The windows are independent: with ``workers > 1`` they run in that many
worker processes, a few ahead of the core being written, and the cores are
still assembled one at a time in column order from the same windows, so
the output has the same bytes for any number of workers. The windows
depend on ``core_cols`` and ``band_rows``, not on the input scan's tile
size (:meth:`tlssim.tiled.TiledScan.load_columns` gives the same pulses for
any tiling), so the output has the same bytes for any input tiling too.

A 360 deg scan (:func:`is_full_circle`) is closed at its seam: its first
and last columns are neighbours in the scene, so the windows of the first
and last cores wrap around (their azimuths continued by 2 pi past the
seam), the first and last cores are neighbours, and a leaf cut by the seam
is one leaf, kept by the window that holds its centroid. The first core is
then written last, as it takes regions from the last core's windows.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import hashlib
import itertools
import json
import math
import multiprocessing
import time
import zipfile
import zlib
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import numpy as np
from scipy import ndimage

from leafsfs.errors import SfsError
from leafsfs.frame import MARGIN_PX
from leafsfs.outputs import json_ready
from leafsfs.params import VARIANTS, SfsParams
from leafsfs.preprocess import resolve_calibration
from leafsfs.reconstruct import reconstruct
from leafsfs.strays import SCOPES, remove_strays
from tlssim.pattern import ScannerPose
from tlssim.scan import GRID_KEYS, META_KEYS, TRUTH_KEYS, Scan, ScannerDescription, grid_to_xyz, write_npz
from tlssim.tiled import INDEX, TiledScan, add_tile_members, concat_columns, open_tiled, start_tiled

#: Columns a kept region must stay away from a window's inner border to count as whole: the leaf frame's
#: margin plus the segmentation's neighbourhood (the edge test's disc, ``leafsfs.leaves``; assumption: 5 columns).
GUARD_COLS = MARGIN_PX + 5
#: Largest leaf extent assumed by default, m: about twice the mean pear-leaf blade length measured in the
#: lab (6.47 cm, scenes.leaf), for the petiole and larger leaves (assumption).
LEAF_SIZE_M = 0.12
#: :func:`plan_windows` cuts a scan of more than twice as many rows into bands (a full 160 deg scan at 0.018 deg has
#: 8,889; the plan tries bands of :data:`MIN_BAND_ROWS` to :data:`MAX_BAND_ROWS`): the ground near the tripod then
#: widens only the bottom band's windows. A scan of fewer rows is also tried as one band.
BAND_ROWS = 1024
#: Columns from the scan's start whose margins size the windows of the ``leafsfs reconstruct`` command (a fixed
#: count rather than the first tile, so that the windows do not depend on how the scan was tiled).
SIZING_COLS = 1024
#: Memory of a scored reconstruction per pulse of its window, bytes (:func:`core_columns`): the benchmark's scoring
#: of the orchard-row window at 0.018 deg (``fused``; imports, the window's scan and its truth included) peaked at
#: 2,206 MB on two windows of 7.0 M pulses (315 bytes per pulse) and at 3,120 MB on one window of 11.1 M (281).
#: The 650 used before came from a 1.0 M-pulse window, where the imports weigh more.
RECONSTRUCT_BYTES_PER_PULSE = 330
#: Peak memory of a window's reconstruction per pulse of the window, bytes, for :func:`plan_windows`: the windows
#: of one 598-column core of the full orchard row at 0.018 deg (``fused``, round 20; maximum RSS after each, in
#: one process) peaked at 1.03 GB after a window of 1420 x 1098 pulses (rows 6144-7168 and their margins) and at
#: 1.73 GB after one of 1546 x 1540 (rows 7168-8192, near the tripod): 643 bytes per pulse over 0.2 GB, rounded
#: up. (Round 18 measured 1,034 on a window of 1546 x 1200 of the same rows.)
PEAK_WINDOW_BYTES_PER_PULSE = 700
#: Memory of the process that assembles and writes the cores, per pulse of a core, bytes (:func:`plan_windows`):
#: the outputs of the cores held (about 19 bytes per pulse each, up to three cores), the core being written and
#: its points (about 64), and the input members read one at a time (assumption, from the arrays' sizes).
ASSEMBLY_BYTES_PER_PULSE = 150
#: Memory of a Python process with ``leafsfs`` imported, bytes (0.12 GB measured; rounded up).
PROCESS_BYTES = 0.2e9
#: Most rows per band :func:`plan_windows` tries on a scan of more rows: taller bands reconstruct fewer row margins
#: twice, but their column margins are those of their nearest rows.
MAX_BAND_ROWS = 4096
#: Fewest rows per band :func:`plan_windows` tries (halving :data:`MAX_BAND_ROWS`).
MIN_BAND_ROWS = 128


@dataclasses.dataclass
class _Window:
    """What one window contributes: its outputs over its core rectangle and where it keeps pixels beyond it.

    ``core`` is the window's core rectangle ``(r0, r1, c0, c1)``; ``margins`` its row and column margins.
    ``inside`` holds the outputs (:data:`_OUTPUTS` and ``leaf``, the rank 1..n of the kept leaf, 0 elsewhere)
    over the core rectangle (``None`` once its core is assembled); ``outside`` the pixels beyond it of the
    regions (reconstructed or skipped) the window keeps: ``row``, ``col`` (columns of the scan, continued past
    a 360 deg scan's seam: below 0 or from ``cols`` on) and the same outputs there. So a window held for its
    neighbours costs a few bytes per kept pixel, not its whole extent.
    """

    core: tuple
    margins: tuple
    inside: dict | None
    outside: dict
    traits: list = dataclasses.field(default_factory=list)
    skipped: list = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class TiledResult:
    """Summary of :func:`reconstruct_tiled`.

    Attributes
    ----------
    scan : TiledScan
        The corrected scan (layers ``outlier``, ``candidates``, ``leaf``, ``background``, ``removed``,
        ``range_spread``).
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


@dataclasses.dataclass
class WindowPlan:
    """Cores and bands of a tiled reconstruction within a memory budget (:func:`plan_windows`).

    Attributes
    ----------
    core_cols, band_rows : int
        Columns per core and rows per band (:func:`reconstruct_tiled`).
    window : (int, int)
        Rows and columns of the largest window expected (the sampled columns' margins).
    peak_bytes : float
        Expected peak of the whole run (this process and the workers), bytes.
    fits : bool
        Whether ``peak_bytes`` is within the budget (else the smallest windows tried).
    """

    core_cols: int
    band_rows: int
    window: tuple
    peak_bytes: float
    fits: bool


def plan_windows(tiled: TiledScan, budget_bytes: float, workers: int = 1, leaf_size_m: float = LEAF_SIZE_M,
                 band_rows: int | None = None, samples: int = 4) -> WindowPlan:
    """Cores and bands whose windows keep a whole tiled reconstruction (all its processes) within a budget.

    The margins are measured on ``samples`` stretches of :data:`SIZING_COLS` columns spread over the scan
    (fixed columns, so that the plan does not depend on the scan's tiling), per band; the largest window
    is that of the band with the widest margins. The run's peak is taken as this process
    (:data:`PROCESS_BYTES` plus :data:`ASSEMBLY_BYTES_PER_PULSE` per pulse of a core) plus ``workers``
    windows (:data:`PROCESS_BYTES` plus :data:`PEAK_WINDOW_BYTES_PER_PULSE` per pulse; with one worker the
    window runs in this process). Bands of all rows (up to twice :data:`BAND_ROWS`) and of :data:`MAX_BAND_ROWS`
    rows halved down to :data:`MIN_BAND_ROWS` are tried: the plan is the one that reconstructs the fewest margins
    twice.

    Parameters
    ----------
    tiled : TiledScan
        The scan.
    budget_bytes : float
        Memory of the whole run, bytes.
    workers : int
        Worker processes (:func:`reconstruct_tiled`).
    leaf_size_m : float
        Largest leaf extent, m (:func:`margin_columns`).
    band_rows : int, optional
        Rows per band (default: chosen as above).
    samples : int
        Stretches of columns whose margins are measured.

    Returns
    -------
    WindowPlan
        The plan that reconstructs the fewest pulses per pulse of the scan among those that fit; when none
        fits, the one with the smallest peak (``fits`` False).
    """
    rows, cols = tiled.shape
    width = min(cols, SIZING_COLS)
    starts = sorted({(i * cols // samples) // width * width for i in range(samples)})
    if band_rows is not None:
        choices = [band_rows]
    else:
        halved = (MAX_BAND_ROWS // 2 ** i for i in range(MAX_BAND_ROWS.bit_length()))
        choices = ([rows] if rows <= 2 * BAND_ROWS else []) + [b for b in halved if MIN_BAND_ROWS <= b < rows]
    # per band choice and band: the largest row and column margins over the samples (one sample in memory)
    found = {band: [[0, 0] for _ in range(0, rows, band)] for band in choices}
    for c0 in starts:
        sample = _grid_columns(tiled, c0, min(cols, c0 + width), slice(None))
        for band, per_band in found.items():
            for (r0, most) in zip(range(0, rows, band), per_band):
                part = sample.crop(slice(r0, min(rows, r0 + band)), slice(None))
                most[0] = max(most[0], 0 if band >= rows else margin_rows(part, leaf_size_m, 2048))
                most[1] = max(most[1], margin_columns(part, leaf_size_m, 2048))
        del sample
    plans = []
    for band in choices:
        starts_r = range(0, rows, band)
        heights = [min(rows, r0 + band + mr) - max(0, r0 - mr) for r0, (mr, _) in zip(starts_r, found[band])]
        margins = [mc for _, mc in found[band]]

        def peak(core, heights=heights, margins=margins):
            window = max(h * min(cols, core + 2 * m) for h, m in zip(heights, margins))
            processes = PROCESS_BYTES * (1 + (workers if workers > 1 else 0))
            return processes + rows * core * ASSEMBLY_BYTES_PER_PULSE + workers * window * PEAK_WINDOW_BYTES_PER_PULSE

        lo, hi = 1, cols  # the widest core that fits: peak() grows with the core
        while lo < hi:
            mid = (lo + hi + 1) // 2
            lo, hi = (mid, hi) if peak(mid) <= budget_bytes else (lo, mid - 1)
        cost = sum(h * min(cols, lo + 2 * m) for h, m in zip(heights, margins)) / (rows * lo)
        worst = max(zip(heights, margins), key=lambda hm: hm[0] * min(cols, lo + 2 * hm[1]))
        plans.append((peak(lo) > budget_bytes, cost if peak(lo) <= budget_bytes else peak(lo),
                      WindowPlan(lo, band, (worst[0], min(cols, lo + 2 * worst[1])), peak(lo),
                                 peak(lo) <= budget_bytes)))
    return min(plans, key=lambda plan: plan[:2])[2]


def reconstruct_tiled(tiled: TiledScan, outdir, variant: str = "buffer", params: SfsParams | None = None, *,
                      calibration=None, core_cols: int = 512, band_rows: int | None = None,
                      leaf_size_m: float = LEAF_SIZE_M, max_margin: int = 2048, workers: int = 1,
                      progress=None, strays: str | None = None) -> TiledResult:
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
    band_rows : int, optional
        Rows per band, ``>= 1`` (default: all rows, one band).
    leaf_size_m : float
        Largest leaf extent, m: a window's margins are the columns and rows it spans at the nearest
        pulses of the window's core rectangle (:func:`margin_columns`, :func:`margin_rows`).
    max_margin : int
        Largest margin of a window, columns or rows.
    workers : int
        Processes that reconstruct windows, ``>= 1`` (1: all in this process). Each holds one window
        (about :data:`PEAK_WINDOW_BYTES_PER_PULSE` per pulse); this process holds the outputs of up to
        ``2 x workers`` finished windows and of the cores it assembles from (about 19 bytes per pulse of their
        core rectangles), and the core it writes (:data:`ASSEMBLY_BYTES_PER_PULSE` in all).
    progress : callable, optional
        Called as ``progress(done, total)`` with the windows reconstructed so far and the windows this run needs
        (a resumed run also reconstructs the windows of the written cores next to the cores it still writes).
    strays : {"moved", "unclaimed", "isolated", "outside"}, optional
        Scope of the stray-point rule after PROP-SFS (:func:`leafsfs.strays.remove_strays`, its default
        settings), applied in every window before it is cut to its core, so that the margins hold the
        neighbours the rule reads (default: none).

    Returns
    -------
    TiledResult

    Raises
    ------
    SfsError
        For bad window sizes, an incomplete scan, or an output directory holding another reconstruction.
    """
    from tlssim.errors import ScanError

    rows, cols = tiled.shape
    band_rows = rows if band_rows is None else band_rows
    if core_cols < 1 or band_rows < 1 or max_margin < GUARD_COLS or not leaf_size_m > 0 or workers < 1:
        raise SfsError(f"tiled reconstruction needs core_cols >= 1, band_rows >= 1, max_margin >= {GUARD_COLS}, "
                       f"leaf_size_m > 0 and workers >= 1, got {core_cols}, {band_rows}, {max_margin}, "
                       f"{leaf_size_m}, {workers}")
    if variant not in VARIANTS:
        raise SfsError(f"unknown variant {variant!r}; allowed: {', '.join(VARIANTS)}")
    if strays is not None and strays not in SCOPES:
        raise SfsError(f"stray scope must be one of {SCOPES}, got {strays!r}")
    if not tiled.complete:
        raise SfsError(f"{tiled.path}: the tiled scan is incomplete; finish (resume) the scan first")
    start = time.perf_counter()
    params = params or SfsParams()
    calibration = resolve_calibration(calibration)
    outdir = Path(outdir)
    wrap = is_full_circle(tiled.theta_columns)
    identity = {"scan": tiled.index.get("fingerprint"), "tiles": [t.sha256 for t in tiled.tiles], "variant": variant,
                "params": params.to_dict(), "calibration": repr(calibration), "margin": [leaf_size_m, max_margin],
                **({} if band_rows >= rows else {"band_rows": band_rows}), **({"wrap": True} if wrap else {}),
                **({} if strays is None else {"strays": strays})}
    fingerprint = hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()).hexdigest()
    header = {key: tiled.index[key] for key in ("shape", "scanner", "scanner_position", "scanner_rotation",
                                                "object_names", "theta_columns", "psi_rows", "has_truth")}
    header["meta"] = {**tiled.meta, "leafsfs": {"variant": variant, "params": params.to_dict(),
                                               "source": str(tiled.path),
                                               **({} if strays is None else {"strays": strays})}}
    try:
        index, todo = start_tiled(outdir / "corrected", header, fingerprint, core_cols)
    except ScanError as exc:
        raise SfsError(str(exc)) from None
    core_cols = int(index["tile_cols"])
    n_cores = -(-cols // core_cols)
    bands = [(r0, min(rows, r0 + band_rows)) for r0 in range(0, rows, band_rows)]
    # Leaves are numbered in core order: the count before the first core to write comes from the written tiles.
    written = {t["col0"] // core_cols: t for t in index["tiles"]}
    offsets = {0: 0}
    cache: dict[tuple[int, int], _Window] = {}

    def neighbours(k: int) -> list:
        if wrap:
            return list(dict.fromkeys((k + d) % n_cores for d in (-1, 0, 1)))
        return [j for j in (k - 1, k, k + 1) if 0 <= j < n_cores]

    if wrap:  # the first core takes regions from the last core's windows: it is written last
        todo = sorted(todo, key=lambda columns: (columns[0] == 0, columns[0]))
    # The loop below asks for windows in this order (every band of a core and its neighbours, core by core).
    uses = [[(b, j) for j in neighbours(c0 // core_cols) for b in range(len(bands))] for c0, _ in todo]
    if todo and todo[-1][0] == 0 and len(todo) > 1:  # an unwritten first core numbers the leaves of every other
        uses[0] = [(b, 0) for b in range(len(bands))] + uses[0]  # one: its windows come first
    needed = list(dict.fromkeys(key for keys in uses for key in keys))
    last_use = {key: i for i, keys in enumerate(uses) for key in keys}
    tasks = [((b, j), (bands[b], (j * core_cols, min(cols, (j + 1) * core_cols)), leaf_size_m, max_margin,
                       variant, params, calibration, wrap, strays)) for b, j in needed]
    results = _in_order(tiled, tasks, workers)

    done = 0
    if progress is not None:
        progress(done, len(needed))

    def window(b: int, k: int) -> _Window:
        nonlocal done
        while (b, k) not in cache:
            key, value = next(results)
            cache[key] = value
            done += 1
            if progress is not None:
                progress(done, len(needed))
        return cache[b, k]

    def core_traits(k: int) -> list:
        return [t for b in range(len(bands)) for t in window(b, k).traits]

    def offset(k: int) -> int:
        j = max(offsets)
        while j < k:  # the leaves of core j: from its written tile, else from its windows
            kept = _tile_leafsfs(outdir / "corrected", written[j])["leaves"] if j in written else core_traits(j)
            offsets[j + 1] = offsets[j] + len(kept)
            j += 1
        return offsets[k]

    writer = ThreadPoolExecutor(1)  # writes core k (compression, SHA-256: no GIL) while core k + 1 is assembled
    pending = None
    try:
        for i, (c0, c1) in enumerate(todo):
            k = c0 // core_cols
            windows = []
            for j in neighbours(k):
                label = offset(j)
                for b in range(len(bands)):
                    windows.append((j, window(b, j), label))
                    label += len(window(b, j).traits)
            grids, leaves, skipped = _assemble_core(k, rows, c0, c1, cols, windows)
            meta = {**tiled.meta, "columns": [c0, c1],
                    "leafsfs": {"variant": variant, "leaves": json_ready(leaves), "skipped": skipped}}
            if pending is not None:
                pending.result()
            pending = writer.submit(add_tile_members, outdir / "corrected", index, c0, c1,
                                    functools.partial(_write_core, tiled, c0, c1, grids, meta))
            for _, used, _ in windows:
                if used.core[2] == c0:  # the core is assembled: only the pixels beyond it are still needed
                    used.inside = None
            del grids, windows
            for key in [key for key in cache if last_use.get(key, -1) <= i]:
                del cache[key]
        if pending is not None:
            pending.result()
    finally:
        writer.shutdown(wait=True)
    written = {t["col0"] // core_cols: t for t in index["tiles"]}
    corrected = open_tiled(outdir / "corrected")
    traits, skipped = [], []
    for k in sorted(written):
        info = _tile_leafsfs(outdir / "corrected", written[k])
        traits += info["leaves"]
        skipped += info["skipped"]
    report = {"variant": variant, "source": str(tiled.path), "core_cols": core_cols, "band_rows": band_rows,
              "leaves": traits, "skipped": skipped, "params": params.to_dict()}
    (outdir / "traits.json").write_text(json.dumps(json_ready(report), indent=1, allow_nan=False))
    results.close()
    return TiledResult(corrected, traits, skipped, rows * sum(c1 - c0 for c0, c1 in todo), len(needed),
                       time.perf_counter() - start)


def _in_order(tiled: TiledScan, tasks: list, workers: int):
    """Yield ``(key, window)`` for ``(key, arguments of _reconstruct_window after the scan)`` tasks, in order.

    With ``workers > 1`` the windows run in that many spawned processes, up to ``2 x workers`` of them
    running or waiting ahead of the one asked for; with one, here, when asked for.
    """
    if workers == 1:
        for key, args in tasks:
            yield key, _reconstruct_window(tiled, *args)
        return
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        ahead: collections.deque = collections.deque()
        try:
            for key, args in tasks:
                ahead.append((key, pool.submit(_window_task, str(tiled.path), *args)))
                if len(ahead) >= 2 * workers:
                    key, future = ahead.popleft()
                    yield key, _result(future)
            while ahead:
                key, future = ahead.popleft()
                yield key, _result(future)
        finally:
            for _, future in ahead:
                future.cancel()


def _result(future) -> _Window:
    """A worker's window, or a one-line error when its process died."""
    try:
        return future.result()
    except BrokenProcessPool:
        raise SfsError("a window's worker process died (out of memory?); run again with fewer --workers or a smaller "
                       "--memory-budget: the finished tiles are kept") from None


_OPENED: dict[str, TiledScan] = {}


def _window_task(path: str, *args) -> _Window:
    """:func:`_reconstruct_window` on the tiled scan at ``path``, in a worker process (opened once per process)."""
    if path not in _OPENED:
        _OPENED[path] = open_tiled(path)
    return _reconstruct_window(_OPENED[path], *args)


def is_full_circle(theta_columns: np.ndarray) -> bool:
    """Whether a scan's columns go once around (360 deg): its last column is a step before its first.

    Parameters
    ----------
    theta_columns : ndarray
        Azimuth of every column, rad, increasing at a regular step.

    Returns
    -------
    bool
        True when the columns times the median step make 2 pi within half a step.
    """
    theta = np.asarray(theta_columns, dtype=np.float64)
    if theta.size < 3:
        return False
    step = float(np.median(np.diff(theta)))
    return step > 0 and abs(theta.size * step - 2 * math.pi) < step / 2


def _load_window(tiled: TiledScan, w0: int, w1: int, rows: slice) -> Scan:
    """Columns ``w0:w1`` of a scan, continued past its seam when ``w0 < 0`` or ``w1 > cols`` (360 deg scans).

    Columns before the first or after the last come from the other end of the scan, their azimuths shifted
    by 2 pi so that they continue the window's (the points are the same). Only the arrays the reconstruction
    reads are loaded (:func:`_grid_columns`).
    """
    cols = tiled.shape[1]
    parts = []
    if w0 < 0:
        part = _grid_columns(tiled, cols + w0, cols, rows)
        parts.append(dataclasses.replace(part, theta=part.theta - 2 * math.pi))
    parts.append(_grid_columns(tiled, max(0, w0), min(cols, w1), rows))
    if w1 > cols:
        part = _grid_columns(tiled, 0, w1 - cols, rows)
        parts.append(dataclasses.replace(part, theta=part.theta + 2 * math.pi))
    window = concat_columns(parts)
    window.meta = {**tiled.meta, "columns": [int(w0), int(w1)]}
    return window


def _grid_columns(tiled: TiledScan, col0: int, col1: int, rows: slice) -> Scan:
    """Rows ``rows`` of the columns ``col0:col1`` of a tiled scan, grid arrays only (no truth, no layers).

    Only the tiles' grid members are decompressed (about half of a simulated tile's bytes), each only up to
    the window's last row (:func:`_member_rows`), and only the window's rows of them are kept.
    """
    parts = []
    for tile in tiled.tiles:
        if tile.col1 > col0 and tile.col0 < col1:
            cut = slice(max(col0, tile.col0) - tile.col0, min(col1, tile.col1) - tile.col0)
            try:
                with zipfile.ZipFile(tiled.path / tile.file) as data:
                    arrays = {key: np.ascontiguousarray(_member_rows(data, key, rows)[:, cut]) for key in GRID_KEYS}
            except (OSError, ValueError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
                raise SfsError(f"{tiled.path / tile.file}: unreadable tile ({exc})") from None
            parts.append(Scan(**arrays, pose=tiled.pose, scanner=tiled.scanner, object_names=tiled.object_names,
                              meta=dict(tiled.meta)))
    return concat_columns(parts)


#: Bytes of a tile's member inflated at a time when a window's rows are read (:func:`_member_rows`).
_READ_BYTES = 1 << 18


def _member_rows(data: zipfile.ZipFile, key: str, rows: slice) -> np.ndarray:
    """Rows ``rows`` of the array ``key`` of an NPZ archive, decompressed only up to the last of them.

    The rows of a C-ordered ``.npy`` are consecutive bytes, so the member is read (inflated) up to the
    last row asked for, and only the rows asked for are held: a window of the top bands of a tile no
    longer inflates the whole member, nor holds it. Fortran-ordered members, ``.npy`` format versions
    other than 1.0 and 2.0 and slices with a step are loaded whole and sliced.

    Parameters
    ----------
    data : zipfile.ZipFile
        The open NPZ archive.
    key : str
        Member name, without ``.npy``.
    rows : slice
        Rows of the array's first axis.

    Returns
    -------
    ndarray
        ``array[rows]``, writable, C-ordered.
    """
    with data.open(f"{key}.npy") as stream:
        version = np.lib.format.read_magic(stream)
        headers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
        shape, fortran, dtype = headers[version](stream) if version in headers else ((), True, None)
        start, stop, step = rows.indices(shape[0]) if shape else (0, 0, 1)
        if fortran or step != 1 or not shape or dtype.hasobject:
            stream.seek(0)
            return np.ascontiguousarray(np.lib.format.read_array(stream, allow_pickle=False)[rows])
        row_bytes = math.prod(shape[1:]) * dtype.itemsize
        skip = start * row_bytes
        while skip > 0:  # the rows before: inflated and dropped, a piece at a time
            piece = len(stream.read(min(_READ_BYTES, skip)))
            if not piece:
                raise ValueError(f"{key}.npy: fewer bytes than its header says")
            skip -= piece
        buffer = bytearray(max(stop - start, 0) * row_bytes)
        view, done = memoryview(buffer), 0
        while done < len(buffer):  # in pieces: a read of many megabytes copies its bytes over and over
            piece = stream.read(min(_READ_BYTES, len(buffer) - done))
            if not piece:
                raise ValueError(f"{key}.npy: fewer bytes than its header says")
            view[done:done + len(piece)] = piece
            done += len(piece)
    return np.frombuffer(buffer, dtype=dtype).reshape((max(stop - start, 0),) + tuple(shape[1:]))


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
        The core's pulses (its columns, or the rectangle of a band and a core).
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
    return _margin(scan.range * np.sin(scan.psi), scan.valid, step, leaf_size_m, max_margin)


def margin_rows(scan: Scan, leaf_size_m: float, max_margin: int) -> int:
    """Margin of a window around a band: the rows a leaf of ``leaf_size_m`` spans at the band's nearest pulses.

    A row is ``r dpsi`` tall at range ``r``; the nearest pulses are the 1st percentile of ``r``.

    Parameters
    ----------
    scan : Scan
        The pulses of the window's core rectangle (a band's rows of a core's columns).
    leaf_size_m : float
        Largest leaf extent, m.
    max_margin : int
        Largest margin, rows.

    Returns
    -------
    int
        Rows, from :data:`GUARD_COLS` to ``max_margin``.
    """
    if scan.shape[0] < 2 or not scan.valid.any():
        return GUARD_COLS
    step = float(np.nanmedian(np.abs(np.diff(scan.psi, axis=0))))
    return _margin(scan.range, scan.valid, step, leaf_size_m, max_margin)


def _margin(extent: np.ndarray, valid: np.ndarray, step_rad: float, leaf_size_m: float, max_margin: int) -> int:
    """Grid steps a leaf of ``leaf_size_m`` spans, a step being ``extent x step_rad`` (1st percentile), plus guard."""
    radius = float(np.percentile(extent[valid], 1.0))
    if not (step_rad > 0 and radius > 0):
        return max_margin
    return int(np.clip(math.ceil(leaf_size_m / (radius * step_rad)) + GUARD_COLS, GUARD_COLS, max_margin))


def _reconstruct_window(tiled: TiledScan, band: tuple, core: tuple, leaf_size_m: float, max_margin: int,
                        variant: str, params: SfsParams, calibration, wrap: bool = False,
                        strays: str | None = None) -> _Window:
    """Reconstruct the window of a band's rows ``r0:r1`` and a core's columns ``c0:c1``.

    The window widens (both margins doubled) while a leaf it keeps comes near an inner border. With
    ``wrap`` (a 360 deg scan) its columns continue past the scan's seam (:func:`_load_window`), up to
    the whole scan. With ``strays``, the stray-point rule in that scope then judges the whole window.
    """
    (r0, r1), (c0, c1) = band, core
    rows, cols = tiled.shape
    inner = _grid_columns(tiled, c0, c1, slice(r0, r1))
    margin_r = 0 if (r0, r1) == (0, rows) else margin_rows(inner, leaf_size_m, max_margin)
    margin_c = margin_columns(inner, leaf_size_m, max_margin)
    del inner
    while True:
        h0, h1 = max(0, r0 - margin_r), min(rows, r1 + margin_r)
        w0, w1 = c0 - margin_c, c1 + margin_c
        if not wrap or w1 - w0 >= cols:
            w0, w1 = max(0, w0), min(cols, w1)
        scan = _load_window(tiled, w0, w1, slice(h0, h1))
        try:
            result = reconstruct(scan, None, variant, params, calibration=calibration)
        except SfsError:  # no return in this window (inputs were checked before the first window)
            return _empty_window(scan, (h0, h1, w0, w1), (r0, r1, c0, c1), (margin_r, margin_c))
        labels = result.labels
        n = int(labels.max()) if labels.size else 0
        counts = np.maximum(np.bincount(labels.ravel(), minlength=n + 1), 1)
        centre = [np.bincount(labels.ravel(), weights=np.broadcast_to(position, labels.shape).ravel(),
                              minlength=n + 1) / counts
                  for position in (np.arange(h0, h1, dtype=np.float64)[:, None], np.arange(w0, w1, dtype=np.float64))]
        mine = (centre[0] >= r0) & (centre[0] < r1) & (centre[1] >= c0) & (centre[1] < c1)
        mine &= np.bincount(labels.ravel(), minlength=n + 1) > 0
        mine[0] = False
        kept = [leaf for leaf in result.leaves if mine[leaf.label]]
        slices = ndimage.find_objects(labels)
        seam = wrap and w1 - w0 < cols  # both column borders are inside the scene
        touching = any(_near_inner_border(slices[leaf.label - 1], (h0, h1, w0, w1), (rows, cols), seam)
                       for leaf in kept)
        if not touching or max(margin_r, margin_c) >= max_margin or ((h0, h1, w0, w1) == (0, rows, 0, cols)):
            break
        margin_c = min(2 * max(margin_c, 1), max_margin)
        margin_r = 0 if (r0, r1) == (0, rows) else min(2 * max(margin_r, 1), max_margin)
    if strays is not None:
        result = remove_strays(result, strays)
    rank = np.zeros(n + 1, dtype=np.int32)
    rank[[leaf.label for leaf in kept]] = np.arange(1, len(kept) + 1, dtype=np.int32)
    # A window keeps its regions and the pulses corrected outside any region (background pulses) whose nearest
    # region it keeps, or that lie in its core: the window of their nearest region overrides these where it
    # holds them (:func:`_assemble_core`). The others get back their measured values here.
    loose = result.corrected & (labels == 0)
    owner = labels
    if loose.any() and (labels > 0).any():
        nearest = ndimage.distance_transform_edt(labels == 0, return_distances=False, return_indices=True)
        owner = labels[tuple(nearest)]
    in_core = np.zeros(labels.shape, bool)
    in_core[r0 - h0:r1 - h0, c0 - w0:c1 - w0] = True
    claim = mine[labels] | (loose & (mine[owner] | in_core))
    dropped = ((labels > 0) | loose) & ~claim
    traits = [{**leaf.traits, "margin_cols": margin_c, "margin_rows": margin_r,
               "centroid_col": float(centre[1][leaf.label] % cols), "centroid_row": float(centre[0][leaf.label])}
              for leaf in kept]
    skipped = [reason for label, reason in result.skipped if mine[label]]
    outputs = {"range": np.where(dropped, scan.range, result.range), "outlier": result.outlier & ~dropped,
               "candidates": np.where(dropped, 0, result.candidates).astype(np.int32),
               "background": result.background & ~dropped,
               "spread": np.where(dropped, np.nan, result.spread).astype(np.float32), "leaf": rank[labels]}
    return _split_window((h0, h1, w0, w1), (r0, r1, c0, c1), (margin_r, margin_c), outputs, claim, traits, skipped)


def _split_window(extent: tuple, core: tuple, margins: tuple, outputs: dict, claim: np.ndarray, traits: list,
                  skipped: list) -> _Window:
    """A window's outputs over its core rectangle, dense, and its kept pixels beyond it, as a list."""
    (h0, _, w0, _), (r0, r1, c0, c1) = extent, core
    inner = (slice(r0 - h0, r1 - h0), slice(c0 - w0, c1 - w0))
    beyond = claim.copy()
    beyond[inner] = False
    where = np.nonzero(beyond)
    outside = {"row": (where[0] + h0).astype(np.int32), "col": where[1] + w0,
               **{name: value[where] for name, value in outputs.items()}}
    inside = {name: np.ascontiguousarray(value[inner]) for name, value in outputs.items()}
    return _Window(core, margins, inside, outside, traits, skipped)


def _near_inner_border(where: tuple, extent: tuple, shape: tuple, seam: bool = False) -> bool:
    """Whether a region (``find_objects`` slices) comes within the guard of a window border inside the scan.

    With ``seam`` both column borders are inside (a window continued past a 360 deg scan's seam).
    """
    (h0, h1, w0, w1), (rows, cols) = extent, shape
    rows_of, cols_of = where
    return ((h0 > 0 and rows_of.start < GUARD_COLS) or (h1 < rows and rows_of.stop > h1 - h0 - GUARD_COLS)
            or ((seam or w0 > 0) and cols_of.start < GUARD_COLS)
            or ((seam or w1 < cols) and cols_of.stop > w1 - w0 - GUARD_COLS))


def _empty_window(scan: Scan, extent: tuple, core: tuple, margins: tuple) -> _Window:
    """The contribution of a window without returns: the measured scan, nothing corrected."""
    none = np.zeros(scan.shape, dtype=bool)
    outputs = {"range": scan.range, "outlier": none, "candidates": np.zeros(scan.shape, np.int32), "background": none,
               "spread": np.full(scan.shape, np.nan, np.float32), "leaf": np.zeros(scan.shape, np.int32)}
    return _split_window(extent, core, margins, outputs, none, [], [])


_OUTPUTS = ("range", "outlier", "candidates", "background", "spread")


def _assemble_core(k: int, rows: int, c0: int, c1: int, cols: int, windows: list) -> tuple[dict, list, list]:
    """The corrected grids of core ``k`` (columns ``c0:c1``) from its windows and the regions its neighbours keep.

    Parameters
    ----------
    k : int
        Core number.
    rows : int
        Rows of the scan.
    c0, c1 : int
        The core's columns.
    cols : int
        Columns of the scan: a window continued past a 360 deg scan's seam gives its columns ``c + cols``
        and ``c - cols`` to column ``c``.
    windows : list of (int, _Window, int)
        Core number, window and leaf-label offset of every band's window of core ``k`` and of its existing
        neighbours.

    Returns
    -------
    grids : dict of str to ndarray
        The core's :data:`_OUTPUTS` and ``leaf`` (the leaves' labels), ``rows x (c1 - c0)``.
    leaves : list of dict
        Traits of the leaves kept by core ``k``'s windows, with their labels.
    skipped : list of dict
        Regions of core ``k``'s windows not reconstructed.
    """
    grids = {name: None for name in _OUTPUTS}
    leaf = np.zeros((rows, c1 - c0), np.int32)
    leaves, skipped = [], []

    def numbered(rank, offset):
        return np.where(rank > 0, rank + offset, 0).astype(np.int32)

    for j, window, offset in windows:  # first each band's own window over its core rectangle
        if j != k:
            continue
        r0, r1 = window.core[:2]
        for name in _OUTPUTS:
            value = window.inside[name]
            if grids[name] is None:
                grids[name] = np.empty((rows, c1 - c0), value.dtype)
            grids[name][r0:r1] = value
        leaf[r0:r1] = numbered(window.inside["leaf"], offset)
        leaves += [{"leaf": offset + i + 1, "core": k, **t} for i, t in enumerate(window.traits)]
        skipped += [{"core": k, "reason": reason} for reason in window.skipped]
    for (j, window, offset), shift in itertools.product(windows, (0, -cols, cols)):
        # then the regions any window keeps outside its own core rectangle
        outside = window.outside
        here = (outside["col"] >= c0 + shift) & (outside["col"] < c1 + shift)
        if not here.any():
            continue
        dst = (outside["row"][here], outside["col"][here] - shift - c0)
        for name in _OUTPUTS:
            grids[name][dst] = outside[name][here]
        leaf[dst] = numbered(outside["leaf"][here], offset)
    return {**grids, "leaf": leaf}, leaves, skipped


def _write_core(tiled: TiledScan, c0: int, c1: int, grids: dict, meta: dict, file: Path) -> Path:
    """Write the corrected tile of columns ``c0:c1`` to ``file``, member by member (:func:`_core_members`)."""
    return write_npz(file, _core_members(tiled, c0, c1, grids, meta))


def _core_members(tiled: TiledScan, c0: int, c1: int, grids: dict, meta: dict):
    """Yield ``(name, array)``: the corrected tile of columns ``c0:c1`` as :meth:`Scan.save` writes it.

    The tile is the input scan's columns with the corrected range, its points and the layers of the
    reconstruction (``outlier``, ``candidates``, ``leaf``, ``background``, ``removed``, ``range_spread``)
    added to (or replacing) the input's. The input's arrays are read from its tiles one member at a time,
    and the points computed a band of rows at a time, so that the whole tile is never in memory.
    """
    parts = [(tiled.path / tile.file, slice(max(c0, tile.col0) - tile.col0, min(c1, tile.col1) - tile.col0))
             for tile in tiled.tiles if tile.col1 > c0 and tile.col0 < c1]

    def columns(key):
        pieces = []
        for file, cut in parts:
            with np.load(file, allow_pickle=False) as data:
                pieces.append(data[key][:, cut])
        return pieces[0] if len(pieces) == 1 else np.concatenate(pieces, axis=1)

    with np.load(parts[0][0], allow_pickle=False) as data:
        files = list(data.files)
        pose = ScannerPose(data["scanner_position"], data["scanner_rotation"])
        scanner = ScannerDescription.from_dict(json.loads(str(data["scanner"])))
        names = [str(n) for n in data["object_names"]] if "object_names" in files else None
    added = {"outlier": grids["outlier"], "candidates": grids["candidates"], "leaf": grids["leaf"],
             "background": grids["background"], "removed": grids["outlier"] & np.isnan(grids["range"]),
             "range_spread": grids["spread"]}
    for key in GRID_KEYS + TRUTH_KEYS:
        if key == "xyz":
            yield key, _points(grids["range"], columns("theta"), columns("psi"), pose)
        elif key in files:
            yield key, grids["range"] if key == "range" else columns(key)
    layers = [key for key in files if key not in GRID_KEYS + TRUTH_KEYS + META_KEYS]
    for key in layers + [key for key in added if key not in layers]:
        yield key, added[key] if key in added else columns(key)
    yield "scanner_position", pose.position
    yield "scanner_rotation", pose.rotation
    yield "scanner", np.array(json.dumps(scanner.to_dict()))
    yield "meta", np.array(json.dumps(meta))
    if names is not None:
        yield "object_names", np.array(names, dtype=str)


#: Rows of a tile whose points are computed at once when it is written (about 24 bytes per pulse each, and
#: three times that in passing).
_POINT_ROWS = 256


def _points(range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray, pose: ScannerPose) -> np.ndarray:
    """:func:`tlssim.scan.grid_to_xyz` a band of :data:`_POINT_ROWS` rows at a time (the same values)."""
    xyz = np.empty(range_m.shape + (3,))
    for r0 in range(0, range_m.shape[0], _POINT_ROWS):
        rows = slice(r0, r0 + _POINT_ROWS)
        xyz[rows] = grid_to_xyz(range_m[rows], theta[rows], psi[rows], pose)
    return xyz


def is_tiled(path) -> bool:
    """Whether ``path`` is a tiled scan directory (holds an index)."""
    return Path(path).is_dir() and (Path(path) / INDEX).is_file()

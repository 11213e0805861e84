"""Scan simulation: scene + scanner set-up -> :class:`~tlssim.scan.Scan`.

The scan grid is traced in chunks of whole columns (fixed azimuth, all
zenith rows, in the order the zenith mirror sweeps them) so that memory stays
bounded; each chunk's sub-rays form one Dr.Jit wavefront
(:meth:`tlssim.backend.TraceScene.trace`). Per pulse, the phasor sums give the
distance (:mod:`tlssim.ranging`), and the sub-ray returns give the truth
(dominant object, mixed fraction, incidence). The detector chain then turns
the summed returns into range and intensity (:mod:`tlssim.detector`).

Random streams: every azimuth column has its own counter-based stream,
``SeedSequence(seed, spawn_key=(column,))``, that draws the rotation of each
pulse's sub-ray layout, the instants of the scan smear and the detector's
amplitude and range noise (:func:`column_draws`). A scan can therefore be
simulated in tiles of whole columns (:func:`simulate_columns`,
:func:`simulate_tiled`) with the same bytes as in one piece.
"""

from __future__ import annotations

import hashlib
import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from scenes.scene import Scene
from tlssim.backend import SubrayHits, TraceScene, select_backend
from tlssim.beam import BeamSamples, sample_beam
from tlssim.bsdf import reflectance_table
from tlssim.detector import PulseReturns, detect_with_noise
from tlssim.errors import ScanError
from tlssim.pattern import ScannerPose, ScanWindow, grid_directions, rotation_from_yaw_pitch_roll
from tlssim.ranging import unwrap_distance
from tlssim.scan import Scan, ScannerDescription
from tlssim.scanner import ScannerModel, get_preset
from tlssim.tiled import INDEX, TiledScan, add_tile, available_memory_bytes, open_tiled, start_tiled

#: Default number of sub-rays traced per wavefront (bounds memory).
CHUNK_SUBRAYS = 1 << 21

_SECTION_KEYS = ("preset", "position", "orientation", "window")


@dataclass(frozen=True)
class ScanSetup:
    """Everything about the scanner for one scan: model, pose and window."""

    model: ScannerModel
    pose: ScannerPose
    window: ScanWindow


def setup_from_section(section: dict, preset: str | None = None, model: ScannerModel | None = None,
                       **overrides) -> ScanSetup:
    """Build a :class:`ScanSetup` from a scene file's ``scanner`` section.

    Parameters
    ----------
    section : dict
        Keys ``preset``, ``position`` (m), ``orientation`` (``yaw_deg``,
        ``pitch_deg``, ``roll_deg``), ``window`` (``theta_deg``, ``psi_deg``,
        optional ``step_deg``) and any :class:`ScannerModel` field as an
        override (e.g. ``step_deg``, ``divergence_deg``).
    preset : str, optional
        Preset to use instead of the section's (default ``faro-ls880``).
    model : ScannerModel, optional
        Model to use instead of any preset (the section's model fields and
        ``overrides`` still apply on top of it).
    **overrides
        Scanner-model fields overriding both the preset and the section.

    Raises
    ------
    ScanError
        On unknown keys or invalid values (the message says which).
    """
    section = dict(section or {})
    changes = {**{k: v for k, v in section.items() if k not in _SECTION_KEYS}, **overrides}
    if model is None:
        model = get_preset(preset or section.get("preset", "faro-ls880"), **changes)
    elif changes:
        model = model.replace(**changes)
    orientation = section.get("orientation") or {}
    if not isinstance(orientation, dict) or set(orientation) - {"yaw_deg", "pitch_deg", "roll_deg"}:
        raise ScanError(f"scanner orientation must be a mapping of yaw_deg, pitch_deg, roll_deg; got {orientation!r}")
    pose = ScannerPose(section.get("position", [0.0, 0.0, 0.0]), rotation_from_yaw_pitch_roll(**orientation))
    window = section.get("window")
    if not isinstance(window, dict) or not {"theta_deg", "psi_deg"} <= set(window):
        raise ScanError(f"scanner window must give theta_deg and psi_deg ranges in degrees, got {window!r}")
    unknown = set(window) - {"theta_deg", "psi_deg", "step_deg"}
    if unknown:
        raise ScanError(f"unknown window field(s) {sorted(unknown)}; allowed: theta_deg, psi_deg, step_deg")
    window = ScanWindow(window["theta_deg"], window["psi_deg"], window.get("step_deg", model.step_deg))
    window.check_within(model)
    return ScanSetup(model, pose, window)


def simulate(scene: Scene, setup: ScanSetup, seed: int = 0, backend: str = "auto",
             progress: bool = True, chunk_subrays: int = CHUNK_SUBRAYS) -> Scan:
    """Simulate a phase-shift scan of ``scene``.

    Parameters
    ----------
    scene : Scene
        What to scan.
    setup : ScanSetup
        Scanner model, pose and window.
    seed : int
        Seed of every random draw (same seed, same bytes).
    backend : {"auto", "llvm", "cuda"}
        Ray-tracing backend.
    progress : bool
        Show a progress bar.
    chunk_subrays : int
        Sub-rays per wavefront (memory bound: about 100 bytes each).

    Returns
    -------
    Scan
        Measured range, intensity and points with the truth of every pulse.

    Examples
    --------
    A 1 m wall 2.5 m in front of the scanner, scanned on a 1 deg x 1 deg
    window at 0.05 deg steps (441 pulses):

    >>> from scenes import scene_from_spec
    >>> scene = scene_from_spec({"objects": [
    ...     {"name": "wall", "type": "plane", "size": [1, 1], "material": {"reflectance": 0.5},
    ...      "pose": {"center": [2.5, 0, 0], "facing": "scanner"}}]})
    >>> setup = setup_from_section({"window": {"theta_deg": [-0.5, 0.5], "psi_deg": [89.5, 90.5],
    ...                                        "step_deg": 0.05}})
    >>> scan = simulate(scene, setup, seed=0, progress=False)
    >>> scan.shape, bool(scan.valid.all())
    ((21, 21), True)
    >>> round(float(np.median(scan.range)), 2)  # m
    2.5
    """
    model, window = setup.model, setup.window
    window.check_within(model)
    check_scan_memory(window.shape)
    job = prepare_scan(scene, setup, backend)
    with tqdm(total=job.rows * job.cols, unit="pulse", unit_scale=True, disable=not progress,
              desc=f"scan {scene.name or 'scene'}") as bar:
        return simulate_columns(job, 0, job.cols, seed, chunk_subrays, bar.update)


@dataclass(frozen=True)
class ScanJob:
    """A scene uploaded for one scan set-up: what every tile of the scan shares.

    Attributes
    ----------
    scene : Scene
        What is scanned.
    setup : ScanSetup
        Scanner model, pose and window.
    traced : TraceScene
        The scene on the ray-tracing backend.
    beam : BeamSamples
        Sub-ray layout of every pulse.
    backend : str
        Backend used (``"llvm"`` or ``"cuda"``).
    """

    scene: Scene
    setup: ScanSetup
    traced: TraceScene
    beam: BeamSamples
    backend: str

    @property
    def rows(self) -> int:
        """Zenith rows of the window."""
        return self.setup.window.shape[0]

    @property
    def cols(self) -> int:
        """Azimuth columns of the window."""
        return self.setup.window.shape[1]


def prepare_scan(scene: Scene, setup: ScanSetup, backend: str = "auto") -> ScanJob:
    """Select the backend and upload ``scene`` for ``setup`` (no tracing yet).

    Parameters
    ----------
    scene : Scene
        What to scan.
    setup : ScanSetup
        Scanner model, pose and window.
    backend : {"auto", "llvm", "cuda"}
        Ray-tracing backend (``auto``: CUDA when a GPU is usable).

    Returns
    -------
    ScanJob
        The uploaded scene with the scan's beam, ready for :func:`simulate_columns`.
    """
    used = select_backend(backend)
    return ScanJob(scene, setup, trace_scene(scene, setup.model, setup.pose),
                   sample_beam(setup.model.n_subrays, setup.model.beam_profile), used)


def column_draws(seed: int, c0: int, c1: int, rows: int, smear: bool) -> dict[str, np.ndarray]:
    """The random draws of the pulses of columns ``c0:c1``, one counter-based stream per column.

    Column ``c`` draws from ``SeedSequence(seed, spawn_key=(c,))``, in this
    order: the spin of each pulse's sub-ray layout (rad, uniform in
    [0, 2 pi)), the instants of the scan smear (uniform in [0, 1), only when
    the model smears), then the detector's amplitude and range noise
    (standard normal); all float32, the precision the tracer takes. A column's draws therefore do not depend on
    which other columns are simulated with it: a scan cut into tiles of
    whole columns gives the same bytes whatever the tile size.

    Parameters
    ----------
    seed : int
        Seed of the scan.
    c0, c1 : int
        First and past-the-last column.
    rows : int
        Pulses per column.
    smear : bool
        Whether the model smears the beam (draws the instants).

    Returns
    -------
    dict of str to ndarray, shape (c1 - c0, rows)
        ``spin``, ``instants`` (or ``None``), ``amplitude_noise``, ``range_noise``.
    """
    n = c1 - c0
    draws = {"spin": np.empty((n, rows), np.float32), "instants": np.empty((n, rows), np.float32) if smear else None,
             "amplitude_noise": np.empty((n, rows), np.float32), "range_noise": np.empty((n, rows), np.float32)}
    for i in range(n):
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(c0 + i,)))
        rng.random(rows, dtype=np.float32, out=draws["spin"][i])
        draws["spin"][i] *= np.float32(2.0 * math.pi)
        if smear:
            rng.random(rows, dtype=np.float32, out=draws["instants"][i])
        rng.standard_normal(rows, dtype=np.float32, out=draws["amplitude_noise"][i])
        rng.standard_normal(rows, dtype=np.float32, out=draws["range_noise"][i])
    return draws


def simulate_columns(job: ScanJob, c0: int, c1: int, seed: int = 0, chunk_subrays: int = CHUNK_SUBRAYS,
                     progress=None) -> Scan:
    """Simulate the columns ``c0:c1`` of a scan (all zenith rows): one tile of a tiled scan.

    Every column draws from its own random stream (:func:`column_draws`) and
    the detector's range filter runs along the zenith within a column, so
    the tile holds exactly the bytes of the same columns of the whole scan.
    Each wavefront (a chunk of whole columns) goes through the detector as
    soon as it is traced and is written into the output grids: no
    intermediate grid of the whole tile is held.

    Parameters
    ----------
    job : ScanJob
        The uploaded scene and set-up (:func:`prepare_scan`).
    c0, c1 : int
        First and past-the-last azimuth column of the window.
    seed : int
        Seed of the scan.
    chunk_subrays : int
        Sub-rays per wavefront (memory bound: about 100 bytes each).
    progress : callable, optional
        Called with the number of pulses traced after each wavefront.

    Returns
    -------
    Scan
        The tile: ``rows x (c1 - c0)`` pulses with their truth; ``meta["columns"]`` is ``[c0, c1]``.
    """
    model, pose, window = job.setup.model, job.setup.pose, job.setup.window
    theta_axis, psi_axis = window.angles()
    theta_axis = theta_axis[c0:c1]
    rows, cols = len(psi_axis), len(theta_axis)
    smear_rad = model.smear_fraction * math.radians(window.step_deg[1])
    grids = {key: np.empty((rows, cols) + shape, dtype) for key, shape, dtype in _OUTPUT_LAYOUT}
    cols_per_chunk = max(1, chunk_subrays // (rows * job.beam.count))
    # The tracer takes float32 angles: cast once per tile, not per wavefront.
    theta32, psi32 = theta_axis.astype(np.float32), psi_axis.astype(np.float32)
    chunks = [(a, min(cols, a + cols_per_chunk)) for a in range(0, cols, cols_per_chunk)]

    def start(a, b):
        """Draw and launch the wavefront of columns ``a:b`` of the tile, traced row by row (psi outer, theta
        inner) so that every result is already a block of the output grids; the draws are per column."""
        draws = {key: None if value is None else np.ascontiguousarray(value.T)
                 for key, value in column_draws(seed, c0 + a, c0 + b, rows, smear_rad > 0).items()}
        return draws, job.traced.start_trace(
            model, job.beam, pose, np.tile(theta32[a:b], rows), np.repeat(psi32, b - a),
            draws["spin"].ravel(), smear_rad, None if draws["instants"] is None else draws["instants"].ravel())

    pending = start(*chunks[0])
    for index, (a, b) in enumerate(chunks):
        width = b - a

        def on_grid(values):
            """A wavefront's per-pulse values (row-major over the chunk) as its (psi, theta) block."""
            return values.reshape((rows, width) + values.shape[1:])

        draws, finish = pending
        hits = finish()
        if index + 1 < len(chunks):  # the next wavefront's kernels run while this one is post-processed
            pending = start(*chunks[index + 1])
        dist, amp = _pulse_returns(hits, model)
        returns = PulseReturns(distance_m=on_grid(dist), amplitude=on_grid(amp), power=on_grid(hits.total_power))
        grids["range"][:, a:b], grids["intensity"][:, a:b] = detect_with_noise(
            model, returns, draws["amplitude_noise"], draws["range_noise"])
        for key, value in pulse_truth(hits, job.traced.face_normals).items():
            if value.ndim == 1:
                grids[key][:, a:b] = on_grid(value)
            else:
                for i in range(value.shape[1]):
                    grids[key][:, a:b, i] = on_grid(value[:, i])
        # One component at a time: numpy's loops over a trailing axis of 3 cost about 10x more.
        xyz, ranges = grids["xyz"][:, a:b], grids["range"][:, a:b]
        directions = grid_directions(theta_axis[a:b], psi_axis, pose.rotation)
        for i in range(3):
            np.multiply(ranges, directions[..., i], out=xyz[..., i])
            xyz[..., i] += pose.position[i]
        del hits, returns, draws
        if progress is not None:
            progress(width * rows)

    theta_grid, psi_grid = np.meshgrid(theta_axis, psi_axis)
    layers = {key: grids.pop(key) for key in _TRUTH_LAYERS}
    return Scan(
        theta=theta_grid,
        psi=psi_grid,
        pose=pose,
        scanner=ScannerDescription(model, window),
        object_names=job.scene.object_names,
        meta={"scene": job.scene.name, "seed": int(seed), "backend": job.backend, "frame": "world",
              **({} if (c0, c1) == (0, job.cols) else {"columns": [int(c0), int(c1)]})},
        layers=layers,
        **grids,
    )


#: Memory budget of a tiled scan when no tile size is given, bytes.
TILE_BUDGET_BYTES = 2 * 1024**3


def tile_columns(shape: tuple[int, int], budget_bytes: int = TILE_BUDGET_BYTES,
                 chunk_subrays: int = CHUNK_SUBRAYS) -> int:
    """Columns per tile so that simulating one tile stays within a memory budget.

    The budget holds one tile (:data:`BYTES_PER_PULSE` per pulse) and one
    wavefront (about 100 bytes per sub-ray); the scene comes on top.

    Parameters
    ----------
    shape : (int, int)
        Grid shape ``(rows, cols)`` of the scan, pulses.
    budget_bytes : int
        Memory for the tile and the wavefront, bytes.
    chunk_subrays : int
        Sub-rays per wavefront.

    Returns
    -------
    int
        Columns per tile, between 1 and ``cols``.

    Raises
    ------
    ScanError
        If not even one column fits the budget.
    """
    rows, cols = int(shape[0]), int(shape[1])
    room = budget_bytes - 100 * chunk_subrays
    if room < rows * BYTES_PER_PULSE:
        raise ScanError(f"a memory budget of {budget_bytes / 1e9:.2f} GB cannot hold one column of {rows} pulses "
                        f"and a wavefront of {chunk_subrays:,} sub-rays; give at least "
                        f"{(rows * BYTES_PER_PULSE + 100 * chunk_subrays) / 1e9:.2f} GB")
    return max(1, min(cols, room // (rows * BYTES_PER_PULSE)))


def scan_fingerprint(scene: Scene, setup: ScanSetup, seed: int, backend: str) -> str:
    """SHA-256 identifying a scan: the scene's mesh and materials, the scanner, pose, window, seed and backend.

    Parameters
    ----------
    scene : Scene
        What is scanned.
    setup : ScanSetup
        Scanner model, pose and window.
    seed : int
        Seed of the scan.
    backend : str
        Backend used (``"llvm"`` or ``"cuda"``: their float rounding differs).
    """
    digest = hashlib.sha256()
    vertices, faces, face_object = scene.merged_mesh()
    for array in (vertices, faces, face_object):
        digest.update(np.ascontiguousarray(array).tobytes())
    described = {"objects": [[o.name, o.type, o.material.reflectance, o.material.transmittance] for o in scene.objects],
                 "scanner": ScannerDescription(setup.model, setup.window).to_dict(),
                 "position": np.asarray(setup.pose.position).tolist(),
                 "rotation": np.asarray(setup.pose.rotation).tolist(), "seed": int(seed), "backend": backend}
    digest.update(json.dumps(described, sort_keys=True).encode())
    return digest.hexdigest()


def simulate_tiled(scene: Scene, setup: ScanSetup, path, seed: int = 0, tile_cols: int | None = None,
                   budget_bytes: int = TILE_BUDGET_BYTES, backend: str = "auto", progress: bool = True,
                   chunk_subrays: int = CHUNK_SUBRAYS) -> TiledScan:
    """Simulate a scan tile by tile into a directory (:mod:`tlssim.tiled`); resumes an interrupted one.

    Only one tile is in memory at a time. The tiles hold the same bytes
    whatever their size (:func:`column_draws`): ``simulate`` of the whole
    window gives the same arrays. Where ``path`` holds an interrupted write
    of the same scan, the tiles that check (size and SHA-256 in the index)
    are kept and only the others are simulated.

    Parameters
    ----------
    scene : Scene
        What to scan.
    setup : ScanSetup
        Scanner model, pose and window.
    path : str or Path
        Output directory.
    seed : int
        Seed of every random draw (same seed, same bytes).
    tile_cols : int, optional
        Columns per tile (default: the interrupted write's, else from ``budget_bytes``).
    budget_bytes : int
        Memory budget of one tile when ``tile_cols`` is not given, bytes (:func:`tile_columns`).
    backend : {"auto", "llvm", "cuda"}
        Ray-tracing backend.
    progress : bool
        Show a progress bar.
    chunk_subrays : int
        Sub-rays per wavefront.

    Returns
    -------
    TiledScan
        The finished scan, opened lazily.
    """
    window = setup.window
    window.check_within(setup.model)
    job = prepare_scan(scene, setup, backend)
    theta_axis, psi_axis = window.angles()
    header = {"shape": [job.rows, job.cols], "scanner": ScannerDescription(setup.model, window).to_dict(),
              "scanner_position": np.asarray(setup.pose.position, float).tolist(),
              "scanner_rotation": np.asarray(setup.pose.rotation, float).tolist(),
              "object_names": scene.object_names, "theta_columns": theta_axis.tolist(), "psi_rows": psi_axis.tolist(),
              "has_truth": True,
              "meta": {"scene": scene.name, "seed": int(seed), "backend": job.backend, "frame": "world"}}
    fingerprint = scan_fingerprint(scene, setup, seed, job.backend)
    if tile_cols is None and not (Path(path) / INDEX).is_file():
        tile_cols = tile_columns(window.shape, budget_bytes, chunk_subrays)
    index, todo = start_tiled(path, header, fingerprint, tile_cols)
    with tqdm(total=sum(c1 - c0 for c0, c1 in todo) * job.rows, unit="pulse", unit_scale=True,
              disable=not progress, desc=f"scan {scene.name or 'scene'} ({len(todo)} tiles)") as bar:
        for c0, c1 in todo:
            add_tile(path, index, c0, simulate_columns(job, c0, c1, seed, chunk_subrays, bar.update))
    return open_tiled(path)


#: Memory the simulator holds per pulse, bytes: the column-major accumulators and truth layers, their
#: (psi, theta) copies and the output scan's grids. Measured: the orchard row at 0.036 deg (44 M pulses)
#: peaked at 8.8 GB, i.e. about 200 B per pulse.
BYTES_PER_PULSE = 200
#: A scan estimated above this size is simulated with a warning, bytes.
WARN_SCAN_BYTES = 2 * 1024**3


def check_scan_memory(shape: tuple[int, int], available_bytes: int | None = None) -> int:
    """Estimate a scan's peak memory; refuse it when it cannot fit, warn when it is large.

    Parameters
    ----------
    shape : (int, int)
        Grid shape ``(rows, cols)`` of the scan window, pulses.
    available_bytes : int, optional
        Memory available to the process, bytes (default: ``MemAvailable`` of
        ``/proc/meminfo``; no refusal where the system does not report it).

    Returns
    -------
    int
        The estimated peak memory, bytes.

    Raises
    ------
    ScanError
        If the estimate exceeds the available memory; the message names the
        grid, the estimate and how to make the scan smaller.
    """
    pulses = int(shape[0]) * int(shape[1])
    need = pulses * BYTES_PER_PULSE
    if available_bytes is None:
        available_bytes = available_memory_bytes()
    advice = ("simulate it in tiles on disk (`tlssim scan SCENE -o DIR --memory-budget GB`, or simulate_tiled), "
              "or use a larger step_deg or a smaller window")
    if available_bytes is not None and need > available_bytes:
        raise ScanError(f"a scan of {shape[0]} x {shape[1]} = {pulses:,} pulses needs about {need / 1e9:,.1f} GB, "
                        f"more than the {available_bytes / 1e9:,.1f} GB available: {advice}")
    if need > WARN_SCAN_BYTES:
        warnings.warn(f"a scan of {shape[0]} x {shape[1]} = {pulses:,} pulses will hold about {need / 1e9:,.1f} GB "
                      f"in memory ({advice} to lower it)", stacklevel=3)
    return need


def trace_scene(scene: Scene, model: ScannerModel, pose: ScannerPose) -> TraceScene:
    """Upload ``scene`` to the ray-tracing backend with the materials the model needs.

    Parameters
    ----------
    scene : Scene
        The scene to upload (vertices in m).
    model : ScannerModel
        Scanner model; selects the BSDF the materials need.
    pose : ScannerPose
        Scanner position (m) and orientation.

    Returns
    -------
    TraceScene
        The uploaded scene, ready for tracing.
    """
    vertices, faces, face_object = scene.merged_mesh()
    reflectance = np.array([o.material.reflectance for o in scene.objects])
    table = None
    if model.bsdf_plugin is not None:
        uses_bsdf = np.array([o.type in model.bsdf_object_types for o in scene.objects])
        table = reflectance_table(model.bsdf_plugin, reflectance, uses_bsdf)
    transmittance = np.array([o.material.transmittance for o in scene.objects]) if model.leaf_transmission else None
    return TraceScene(vertices, faces, face_object, reflectance, pose.position, transmittance, table)


#: The grids of a simulated scan: key, trailing shape, dtype (the Scan's own fields, then the truth layers).
_OUTPUT_LAYOUT = (
    ("range", (), np.float64),
    ("intensity", (), np.float32),
    ("xyz", (3,), np.float64),
    ("truth_range", (), np.float64),
    ("truth_id", (), np.int32),
    ("mixed_fraction", (), np.float32),
    ("incidence", (), np.float32),
    ("truth_normal", (3,), np.float32),
    ("truth_second_id", (), np.int32),
    ("second_fraction", (), np.float32),
)
#: Truth arrays stored as extra scan layers rather than as the Scan's own truth fields.
_TRUTH_LAYERS = ("truth_second_id", "second_fraction")


def _pulse_returns(hits: SubrayHits, model: ScannerModel) -> tuple[np.ndarray, np.ndarray]:
    """Per-pulse distance (phasor phase) and amplitude (phasor magnitude at the lowest frequency)."""
    distance = unwrap_distance(hits.phasors, model.mod_freqs_hz)
    amplitude = np.hypot(*hits.phasors[0])
    return np.where(amplitude > 0, distance, np.nan), amplitude


def pulse_truth(hits: SubrayHits, face_normals: np.ndarray) -> dict[str, np.ndarray]:
    """Ground truth of each pulse from its sub-ray returns.

    Parameters
    ----------
    hits : SubrayHits
        Traced sub-rays of ``n`` pulses.
    face_normals : ndarray, shape (F, 3)
        Unit normal of every triangle of the traced mesh.

    Returns
    -------
    dict
        ``truth_range`` (central sub-ray distance, m), ``truth_id`` (object
        with the largest returned power), ``mixed_fraction`` (power share of
        the other objects), ``incidence`` (rad) and ``truth_normal`` (facing
        the scanner), the last two taken on the sub-ray of the dominant object
        nearest to the beam centre; ``truth_second_id`` and
        ``second_fraction``, the object with the next largest returned power
        and its share (so a leaf's share of any pulse it touches is known
        exactly where at most two objects meet). NaN / -1 where nothing
        returned power; -1 and 0 on pure pulses.
    """
    dominant = hits.object_high.copy()
    share = np.where(dominant >= 0, hits.total_power, 0.0)
    second = np.full_like(dominant, -1)
    second_share = np.zeros(len(dominant))
    first, first_prim = hits.first, hits.first_prim
    mixed = hits.mixed
    if len(mixed):
        obj, power, prim = hits.mixed_object_id, hits.mixed_power, hits.mixed_prim
        returned = (obj >= 0) & (power > 0)
        rows = np.arange(len(mixed))
        # Power of the object of every sub-ray, summed over the pulse; the best wins.
        per_candidate = np.einsum("mjk,mk->mj", obj[:, :, None] == obj[:, None, :], np.where(returned, power, 0.0))
        per_candidate[~returned] = -1.0
        best = per_candidate.argmax(axis=1)
        dominant[mixed] = obj[rows, best]
        share[mixed] = per_candidate[rows, best]
        others = np.where(obj == dominant[mixed][:, None], -1.0, per_candidate)
        runner_up = others.argmax(axis=1)
        second[mixed] = obj[rows, runner_up]
        second_share[mixed] = others[rows, runner_up]
        first = first.copy()
        first[mixed] = np.argmax((obj == dominant[mixed][:, None]) & returned, axis=1)
        first_prim = first_prim.copy()
        first_prim[mixed] = prim[rows, first[mixed]]

    has = dominant >= 0
    # One component at a time (numpy's loops over a trailing axis of 3 are slow); the same sums as
    # np.sum(normal * axis, axis=1), bit for bit.
    normal = [np.take(face_normals[:, i], first_prim) for i in range(3)]
    facing = normal[0] * hits.axis[:, 0] + normal[1] * hits.axis[:, 1] + normal[2] * hits.axis[:, 2]
    away = facing > 0
    truth_normal = np.empty((3, len(has)))
    for i in range(3):
        np.negative(normal[i], out=normal[i], where=away)
        truth_normal[i] = np.where(has, normal[i], np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        mixed_fraction = np.clip(1.0 - share / hits.total_power, 0.0, 1.0)
    return {
        "truth_range": np.where(np.isfinite(hits.central_t), hits.central_t, np.nan),
        "truth_id": np.where(has, dominant, -1).astype(np.int32),
        "mixed_fraction": np.where(has, mixed_fraction, np.nan),
        "incidence": np.where(has, np.arccos(np.clip(np.abs(facing), 0.0, 1.0)), np.nan),
        "truth_normal": truth_normal.T,
        "truth_second_id": second.astype(np.int32),
        "second_fraction": np.divide(second_share, hits.total_power, out=np.zeros(len(second)),
                                     where=hits.total_power > 0),
    }

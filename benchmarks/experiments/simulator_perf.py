"""Throughput benchmark: simulator pulses/s against the backend's raw first-hit rate (``tlsbench perf simulator``).

Both are measured in the same process on the same sub-rays: the raw rate is
``ray_intersect_preliminary`` on pre-built sub-rays (distance and primitive
evaluated, nothing else), with the simulator's own flags
(:meth:`tlssim.backend.TraceScene.first_hits`: coherent rays), after the
simulator's own one-time scene set-up (:func:`tlssim.simulate.trace_scene`,
timed with it, since the simulator's time holds it too); the simulator rate
is :func:`tlssim.simulate` end to end (ray generation, tracing, radiometry,
phasor sums, truth, detector). ``efficiency = pulses/s x sub-rays / raw
rays/s``. On a shared machine the wall-clock rates of the two measurements
see different loads, so the report also gives ``efficiency_cpu``, the same
ratio on the process's CPU time (all threads), which other jobs do not
inflate. Memory: the process's peak resident memory during each scan
(Linux: the peak is reset before it), and that peak less the scan's output
arrays, which is what must not grow with the window; ``peak_rss_mb`` is the
whole run's (the raw measurement included). ``--profile``
prints where the simulator's time goes (cProfile of one scan, the Dr.Jit
kernels show up in ``numpy.asarray``, where their results are read).
"""

from __future__ import annotations

import cProfile
import gc
import json
import platform
import pstats
import resource
import statistics
import time

import numpy as np

import scenes
from benchmarks.errors import BenchError
from tlssim.backend import BACKENDS, select_backend
from tlssim.beam import sample_beam
from tlssim.pattern import ScanWindow
from tlssim.scan import GRID_KEYS, TRUTH_KEYS
from tlssim.simulate import CHUNK_SUBRAYS, ScanSetup, setup_from_section, simulate, trace_scene

PERF_SCENE = "wavy-sheet"


def perf_setup(size: int) -> tuple[scenes.Scene, ScanSetup]:
    """The benchmark scene and a centred window of ``size x size`` pulses."""
    scene = scenes.build(PERF_SCENE)
    setup = setup_from_section(scene.scanner)
    half = 0.5 * (size - 1) * setup.model.step_deg
    window = ScanWindow((-half, half), (90.0 - half, 90.0 + half), setup.model.step_deg)
    return scene, ScanSetup(setup.model, setup.pose, window)


def raw_first_hit_rate(scene: scenes.Scene, setup: ScanSetup) -> tuple[float, float, float]:
    """Rays/s of ``ray_intersect_preliminary`` on the simulator's own sub-rays (same chunks), scene set-up included.

    The scene is prepared as the simulator prepares it (:func:`tlssim.simulate.trace_scene`: BVH build and
    upload) and that one-time set-up is timed with the tracing, as it is in the simulator's own time, so the
    two rates count the same work around the simulator's extra per-pulse work. The sub-rays' random
    spins and instants are drawn per chunk, so this measurement holds one chunk, whatever the window.

    Parameters
    ----------
    scene : scenes.Scene
        The scene to trace (vertices in m).
    setup : ScanSetup
        Scanner model, pose (m) and window of the scan.

    Returns
    -------
    wall : float
        Ray-intersection rate, rays per wall-clock second.
    cpu : float
        The same per second of the process's CPU time (all threads).
    setup_s : float
        Wall-clock seconds of the scene set-up (part of ``wall``'s time).
    """
    import drjit as dr

    model, pose, window = setup.model, setup.pose, setup.window
    start, start_cpu = time.perf_counter(), time.process_time()
    traced = trace_scene(scene, model, pose)
    dr.sync_thread()
    setup_s = time.perf_counter() - start
    elapsed, cpu = setup_s, time.process_time() - start_cpu
    beam = sample_beam(model.n_subrays, model.beam_profile)
    theta_axis, psi_axis = window.angles()
    rows = len(psi_axis)
    cols_per_chunk = max(1, CHUNK_SUBRAYS // (rows * beam.count))
    rng = np.random.default_rng(0)
    smear_rad = model.smear_fraction * np.radians(window.step_deg[1])
    count = 0
    for c0 in range(0, len(theta_axis), cols_per_chunk):
        theta = np.repeat(theta_axis[c0:c0 + cols_per_chunk], rows)
        psi = np.tile(psi_axis, len(theta) // rows)
        spin, instants = rng.uniform(0, 2 * np.pi, len(theta)), rng.uniform(0, 1, len(theta))
        ray, _ = traced.subrays(model, beam, pose, theta, psi, spin, smear_rad, instants)
        dr.eval(ray)
        start, start_cpu = time.perf_counter(), time.process_time()
        dr.eval(*traced.first_hits(ray))
        dr.sync_thread()
        elapsed += time.perf_counter() - start
        cpu += time.process_time() - start_cpu
        count += len(theta) * beam.count
    return count / elapsed, count / cpu, setup_s


def _memory_kb(key: str) -> int | None:
    """A ``/proc/self/status`` memory figure (``VmRSS``, ``VmHWM``), kB; ``None`` where unavailable."""
    try:
        for line in open("/proc/self/status", encoding="ascii"):
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return None


def _reset_peak() -> bool:
    """Reset the process's peak resident memory (Linux ``clear_refs`` 5); whether it could."""
    try:
        with open("/proc/self/clear_refs", "w", encoding="ascii") as handle:
            handle.write("5")
        return True
    except OSError:
        return False


def _output_bytes(scan) -> int:
    """Bytes of a scan's per-pulse arrays (grid, truth and layers): the output that must be in memory."""
    arrays = [getattr(scan, key) for key in GRID_KEYS + TRUTH_KEYS] + list(scan.layers.values())
    return int(sum(a.nbytes for a in arrays if a is not None))


def simulate_measured(scene: scenes.Scene, setup: ScanSetup, seed: int, backend: str) -> dict:
    """One timed scan with the peak memory during that scan alone.

    Parameters
    ----------
    scene : scenes.Scene
        The scene.
    setup : ScanSetup
        Scanner model, pose (m) and window.
    seed : int
        Noise seed.
    backend : str
        Ray-tracing backend.

    Returns
    -------
    dict
        ``wall_s`` and ``cpu_s`` (s); ``output_mb`` (the scan's arrays), ``start_mb`` (the process's resident
        memory when the scan starts, Dr.Jit's cache of freed blocks emptied first: the interpreter, Mitsuba,
        LLVM and what earlier scans left), ``peak_mb`` (the process's peak resident memory during this scan:
        the peak is reset before it), ``beyond_output_mb`` (``peak_mb`` less the output), ``growth_mb``
        (``peak_mb`` less ``start_mb`` and the output: what the scan itself needed beyond its output) and
        ``drjit_peak_mb`` (the peak of Dr.Jit's own allocations during the scan, host memory on the LLVM
        backend, the GPU's on CUDA), MB of 2**20 bytes (as ``peak_rss_mb``); the resident-memory figures are
        ``None`` where the peak cannot be reset (not Linux).
    """
    import drjit as dr

    jit = dr.JitBackend.CUDA if backend == "cuda" else dr.JitBackend.LLVM
    gc.collect()
    dr.flush_malloc_cache()  # blocks an earlier scan freed would otherwise count as this one's start
    start_kb = _memory_kb("VmRSS")
    dr.detail.malloc_clear_statistics()
    reset = _reset_peak() and start_kb is not None
    start, start_cpu = time.perf_counter(), time.process_time()
    scan = simulate(scene, setup, seed=seed, progress=False, backend=backend)
    wall, cpu = time.perf_counter() - start, time.process_time() - start_cpu
    peak = _memory_kb("VmHWM") if reset else None
    output_mb = _output_bytes(scan) / 2**20
    if peak is None:
        peak_mb = beyond = growth = None
    else:
        peak_mb = peak / 1024
        beyond, growth = peak_mb - output_mb, peak_mb - output_mb - start_kb / 1024
    return {"wall_s": wall, "cpu_s": cpu, "output_mb": output_mb, "peak_mb": peak_mb,
            "start_mb": None if peak is None else start_kb / 1024, "beyond_output_mb": beyond,
            "growth_mb": growth, "drjit_peak_mb": dr.detail.malloc_watermark(jit) / 2**20}


def run_perf(size: int = 500, repeat: int = 3, backend: str = "auto") -> dict:
    """Measure throughput and memory; returns a JSON-ready report.

    Parameters
    ----------
    size : int
        The window is ``size x size`` pulses.
    repeat : int
        Repetitions; medians are reported.
    backend : {"auto", "llvm", "cuda"}
        Ray-tracing backend.
    """
    import drjit as dr

    used = select_backend(backend)
    scene, setup = perf_setup(size)
    warm_scene, warm_setup = perf_setup(32)
    simulate(warm_scene, warm_setup, progress=False, backend=used)  # JIT compilation, not timed
    pulses = size * size
    runs, raw_rates, raw_cpu, setups = [], [], [], []
    for i in range(repeat):
        runs.append(simulate_measured(scene, setup, i, used))
        wall, cpu, setup_s = raw_first_hit_rate(scene, setup)
        raw_rates.append(wall)
        raw_cpu.append(cpu)
        setups.append(setup_s)
    subrays = setup.model.n_subrays
    pulses_per_s = statistics.median(pulses / r["wall_s"] for r in runs)
    raw = statistics.median(raw_rates)

    def median_mb(key):
        values = [r[key] for r in runs if r[key] is not None]
        return statistics.median(values) if values else None

    return {
        "scene": PERF_SCENE,
        "triangles": int(sum(len(o.faces) for o in scene.objects)),
        "window_pulses": [size, size],
        "subrays": subrays,
        "backend": used,
        "threads": int(dr.thread_count()) if used == "llvm" else None,
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "repeat": repeat,
        "raw_rays_per_s": raw,
        "scene_setup_s": statistics.median(setups),
        "pulses_per_s": pulses_per_s,
        "subrays_per_s": pulses_per_s * subrays,
        "efficiency": pulses_per_s * subrays / raw,
        "efficiency_cpu": statistics.median(pulses / r["cpu_s"] for r in runs) * subrays / statistics.median(raw_cpu),
        "scan_output_mb": median_mb("output_mb"),
        "scan_peak_mb": median_mb("peak_mb"),
        "scan_peak_beyond_output_mb": median_mb("beyond_output_mb"),
        "scan_start_mb": median_mb("start_mb"),
        "scan_growth_beyond_output_mb": median_mb("growth_mb"),
        "scan_drjit_peak_mb": median_mb("drjit_peak_mb"),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def add_parser(sub) -> None:
    """Register ``simulator`` with the ``tlsbench perf`` sub-commands."""
    p = sub.add_parser("simulator", help="simulator throughput and memory",
                       description="Scan a fixed built-in scene; report raw rays/s, pulses/s, efficiency, peak memory.")
    p.add_argument("--size", type=int, default=500, help="window of SIZE x SIZE pulses (default 500)")
    p.add_argument("--repeat", type=int, default=3, help="repetitions, medians reported (default 3)")
    p.add_argument("--backend", choices=BACKENDS, default="auto")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--profile", action="store_true",
                   help="also profile one scan (cProfile, 15 functions of most own time) after the measurement")
    p.set_defaults(func=run)


def run(args) -> int:
    """Measure with the parsed arguments and print the report."""
    if args.size < 2 or args.repeat < 1:
        raise BenchError("--size must be >= 2 and --repeat >= 1")
    report = run_perf(size=args.size, repeat=args.repeat, backend=args.backend)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        _print_report(report, args.size)
    if args.profile:
        profile_scan(args.size, args.backend)
    return 0


def profile_scan(size: int, backend: str = "auto", top: int = 15) -> None:
    """Print a cProfile of one scan of the perf window (the ``top`` functions of most own time).

    Parameters
    ----------
    size : int
        The window is ``size x size`` pulses.
    backend : {"auto", "llvm", "cuda"}
        Ray-tracing backend.
    top : int
        Functions listed.
    """
    scene, setup = perf_setup(size)
    profiler = cProfile.Profile()
    profiler.enable()
    simulate(scene, setup, progress=False, backend=backend)
    profiler.disable()
    pstats.Stats(profiler).sort_stats("tottime").print_stats(top)


def _print_report(report: dict, size: int) -> None:
    print(f"scene {report['scene']} ({report['triangles']} triangles), {size}x{size} pulses, "
          f"{report['subrays']} sub-rays, backend {report['backend']}, medians of {report['repeat']}")
    print(f"  raw first-hit rate   {report['raw_rays_per_s'] / 1e6:8.2f} Mrays/s "
          f"(scene set-up {report['scene_setup_s']:.2f} s included, as in the simulator's time)")
    print(f"  simulator            {report['pulses_per_s'] / 1e3:8.1f} kpulses/s "
          f"({report['subrays_per_s'] / 1e6:.2f} Msub-rays/s)")
    print(f"  efficiency           {report['efficiency']:8.2f}  (goal >= 0.85)")
    print(f"  efficiency, CPU time {report['efficiency_cpu']:8.2f}  (the same on the process's CPU time)")
    if report["scan_peak_mb"] is not None:
        print(f"  one scan's peak RSS  {report['scan_peak_mb']:8.0f} MB: output {report['scan_output_mb']:.0f} MB "
              f"+ {report['scan_peak_beyond_output_mb']:.0f} MB beyond it")
        print(f"    of which           {report['scan_start_mb']:8.0f} MB resident when the scan starts, "
              f"{report['scan_growth_beyond_output_mb']:.0f} MB grown during it "
              f"(Dr.Jit's own allocations peak at {report['scan_drjit_peak_mb']:.0f} MB)")
    print(f"  peak memory (RSS)    {report['peak_rss_mb']:8.0f} MB  (the process, the raw measurement included)")

"""Throughput benchmark: simulator pulses/s against the backend's raw first-hit rate (``tlsbench perf simulator``).

Both are measured in the same process on the same sub-rays: the raw rate is
``ray_intersect_preliminary`` on pre-built sub-rays (distance and primitive
evaluated, nothing else), with the simulator's own flags
(:meth:`tlssim.backend.TraceScene.first_hits`: coherent rays); the simulator rate is :func:`tlssim.simulate` end
to end (ray generation, tracing, radiometry, phasor sums, truth, detector).
``efficiency = pulses/s x sub-rays / raw rays/s``. On a shared machine the
wall-clock rates of the two measurements see different loads, so the report
also gives ``efficiency_cpu``, the same ratio on the process's CPU time (all
threads), which other jobs do not inflate; ``--profile`` prints where the
simulator's time goes (cProfile of one scan, the Dr.Jit kernels show up in
``numpy.asarray``, where their results are read).
"""

from __future__ import annotations

import cProfile
import json
import platform
import pstats
import resource
import statistics
import time

import numpy as np

import scenes
from benchmarks.errors import BenchError
from tlssim.backend import BACKENDS, TraceScene, select_backend
from tlssim.beam import sample_beam
from tlssim.pattern import ScanWindow
from tlssim.simulate import CHUNK_SUBRAYS, ScanSetup, setup_from_section, simulate

PERF_SCENE = "wavy-sheet"


def perf_setup(size: int) -> tuple[scenes.Scene, ScanSetup]:
    """The benchmark scene and a centred window of ``size x size`` pulses."""
    scene = scenes.build(PERF_SCENE)
    setup = setup_from_section(scene.scanner)
    half = 0.5 * (size - 1) * setup.model.step_deg
    window = ScanWindow((-half, half), (90.0 - half, 90.0 + half), setup.model.step_deg)
    return scene, ScanSetup(setup.model, setup.pose, window)


def raw_first_hit_rate(scene: scenes.Scene, setup: ScanSetup) -> tuple[float, float]:
    """Rays/s of ``ray_intersect_preliminary`` on the simulator's own sub-rays (same chunks).

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
    """
    import drjit as dr

    model, pose, window = setup.model, setup.pose, setup.window
    vertices, faces, face_object = scene.merged_mesh()
    traced = TraceScene(vertices, faces, face_object, np.ones(len(scene.objects)), pose.position)
    beam = sample_beam(model.n_subrays, model.beam_profile)
    theta_axis, psi_axis = window.angles()
    rows = len(psi_axis)
    cols_per_chunk = max(1, CHUNK_SUBRAYS // (rows * beam.count))
    rng = np.random.default_rng(0)
    spin = rng.uniform(0, 2 * np.pi, rows * len(theta_axis))
    instants = rng.uniform(0, 1, rows * len(theta_axis))
    smear_rad = model.smear_fraction * np.radians(window.step_deg[1])
    elapsed, cpu, count = 0.0, 0.0, 0
    for c0 in range(0, len(theta_axis), cols_per_chunk):
        theta = np.repeat(theta_axis[c0:c0 + cols_per_chunk], rows)
        psi = np.tile(psi_axis, len(theta) // rows)
        ray, _ = traced.subrays(model, beam, pose, theta, psi, spin[:len(theta)], smear_rad, instants[:len(theta)])
        dr.eval(ray)
        start, start_cpu = time.perf_counter(), time.process_time()
        dr.eval(*traced.first_hits(ray))
        dr.sync_thread()
        elapsed += time.perf_counter() - start
        cpu += time.process_time() - start_cpu
        count += len(theta) * beam.count
    return count / elapsed, count / cpu


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
    sim_rates, sim_cpu, raw_rates, raw_cpu = [], [], [], []
    for i in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        simulate(scene, setup, seed=i, progress=False, backend=used)
        sim_rates.append(pulses / (time.perf_counter() - start))
        sim_cpu.append(pulses / (time.process_time() - start_cpu))
        wall, cpu = raw_first_hit_rate(scene, setup)
        raw_rates.append(wall)
        raw_cpu.append(cpu)
    subrays = setup.model.n_subrays
    pulses_per_s = statistics.median(sim_rates)
    raw = statistics.median(raw_rates)
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
        "pulses_per_s": pulses_per_s,
        "subrays_per_s": pulses_per_s * subrays,
        "efficiency": pulses_per_s * subrays / raw,
        "efficiency_cpu": statistics.median(sim_cpu) * subrays / statistics.median(raw_cpu),
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
    print(f"  raw first-hit rate   {report['raw_rays_per_s'] / 1e6:8.2f} Mrays/s")
    print(f"  simulator            {report['pulses_per_s'] / 1e3:8.1f} kpulses/s "
          f"({report['subrays_per_s'] / 1e6:.2f} Msub-rays/s)")
    print(f"  efficiency           {report['efficiency']:8.2f}  (goal >= 0.85)")
    print(f"  efficiency, CPU time {report['efficiency_cpu']:8.2f}  (the same on the process's CPU time)")
    print(f"  peak memory (RSS)    {report['peak_rss_mb']:8.0f} MB")

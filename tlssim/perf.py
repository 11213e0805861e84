"""Throughput benchmark: simulator pulses/s against the backend's raw first-hit rate.

Both are measured in the same process on the same sub-rays: the raw rate is
``ray_intersect_preliminary`` on pre-built sub-rays (distance and primitive
evaluated, nothing else); the simulator rate is :func:`tlssim.simulate` end
to end (ray generation, tracing, radiometry, phasor sums, truth, detector).
``efficiency = pulses/s x sub-rays / raw rays/s``.
"""

from __future__ import annotations

import platform
import resource
import statistics
import time

import numpy as np

import scenes
from tlssim.backend import TraceScene, select_backend
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


def raw_first_hit_rate(scene: scenes.Scene, setup: ScanSetup) -> float:
    """Rays/s of ``ray_intersect_preliminary`` on the simulator's own sub-rays (same chunks)."""
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
    elapsed, count = 0.0, 0
    for c0 in range(0, len(theta_axis), cols_per_chunk):
        theta = np.repeat(theta_axis[c0:c0 + cols_per_chunk], rows)
        psi = np.tile(psi_axis, len(theta) // rows)
        ray, _ = traced.subrays(model, beam, pose, theta, psi, spin[:len(theta)], smear_rad, instants[:len(theta)])
        dr.eval(ray)
        start = time.perf_counter()
        hit = traced.mi_scene.ray_intersect_preliminary(ray, False)
        dr.eval(hit.t, hit.prim_index)
        dr.sync_thread()
        elapsed += time.perf_counter() - start
        count += len(theta) * beam.count
    return count / elapsed


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
    sim_rates, raw_rates = [], []
    for i in range(repeat):
        start = time.perf_counter()
        simulate(scene, setup, seed=i, progress=False, backend=used)
        sim_rates.append(pulses / (time.perf_counter() - start))
        raw_rates.append(raw_first_hit_rate(scene, setup))
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
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }

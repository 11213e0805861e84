"""Build time of the big built-in scenes, and optionally their scan time.

Run ``tlsbench perf scenes [--repeat N] [--scan] [NAME ...]``; it prints
one line per scene with the median build time (wall and CPU, since the
machine may be shared) over ``N`` builds, the object
and triangle counts, and with ``--scan`` the time of one simulated scan of
the scene's own window (default scanner settings, no progress bar).
"""

from __future__ import annotations

import platform
import statistics
import time

import scenes
from tlssim.simulate import setup_from_section, simulate

DEFAULT_SCENES = ("orchard-row", "leafy-tree", "leafless-tree", "leaf-cluster", "leaf-1.5m", "surface-hemisphere")


def add_parser(sub) -> None:
    """Register ``scenes`` with the ``tlsbench perf`` sub-commands."""
    p = sub.add_parser("scenes", help="build (and scan) time of the big built-in scenes",
                       description=__doc__.splitlines()[0])
    p.add_argument("names", nargs="*", default=list(DEFAULT_SCENES), help="built-in scenes to time")
    p.add_argument("--repeat", type=int, default=3, help="builds per scene (median reported)")
    p.add_argument("--scan", action="store_true", help="also time one scan of each scene's window")
    p.set_defaults(func=run)


def run(args) -> int:
    """Print one line of timings per scene of ``args.names``."""
    print(f"machine: {platform.machine()} {platform.processor() or ''}, python {platform.python_version()}")
    for name in args.names:
        times, cpu = [], []
        for _ in range(max(1, args.repeat)):
            start, start_cpu = time.perf_counter(), time.process_time()
            scene = scenes.build(name)
            times.append(time.perf_counter() - start)
            cpu.append(time.process_time() - start_cpu)
        triangles = sum(len(o.faces) for o in scene.objects)
        line = (f"{name:<20} build {statistics.median(times):6.2f} s wall, {statistics.median(cpu):6.2f} s CPU "
                f"(medians of {len(times)})  "
                f"{len(scene.objects):6d} objects  {triangles / 1e6:6.3f} M triangles")
        if args.scan:
            setup = setup_from_section(scene.scanner)
            start = time.perf_counter()
            simulate(scene, setup, progress=False)
            rows, cols = setup.window.shape
            line += f"  scan {time.perf_counter() - start:6.1f} s ({rows} x {cols} pulses)"
        print(line, flush=True)
    return 0

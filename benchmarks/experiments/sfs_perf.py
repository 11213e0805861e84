"""Runtime of PROP-SFS against alpha-matrix size and quantisation (thesis ch.5 §3.4), with a profile.

Run as ``tlsbench perf sfs``.

The thesis fitted ``t = 0.022 a_tot^1.37 / eps_alpha^1.12 + 14`` on
hemispheres of sides 25-58 (digest A15: a shape target, not absolute
times). Here: hemispheres of the given sides (radius = half the side) at
eps_alpha = 5, 10, 15 and 20 % (seed 20 %), the engine alone (buffer
variant, no smoothing), medians of ``repeat`` runs; the log-log slopes of
time against the object's pixel count and against eps_alpha; the simulated
leaf scenes (``leaf-1.5m`` ... ``leaf-5m``: real leaf masks with their true
incidence as alpha); and a cProfile of a hemisphere of about 10 000 pixels
grouped by module. Run it on one core (``OMP_NUM_THREADS=1``) on an
otherwise idle machine for comparable numbers.
"""

from __future__ import annotations

import cProfile
import json
import os
import platform
import pstats
import statistics
import time

import numpy as np

import scenes
from benchmarks.errors import BenchError
from leafsfs.engine import reconstruct_heights
from leafsfs.params import SfsParams
from leafsfs.synthetic import sample_surface
from scenes.surfaces import get_surface
from tlssim.simulate import setup_from_section, simulate

EPSILONS = (0.05, 0.10, 0.15, 0.20)
LEAF_SCENES = ("leaf-1.5m", "leaf-3m", "leaf-5m")


def _params(eps: float) -> SfsParams:
    return SfsParams(n_smooth=0, quantization="percentile", eps_alpha=eps, eps_seed=0.2, alpha_max_deg=85,
                     seed_cutoff=None)


def _time(run, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _hemisphere(side: int):
    return sample_surface(get_surface("hemisphere", radius=side / 2.0), side)


def _slope(x, y) -> float:
    return float(np.polyfit(np.log(x), np.log(y), 1)[0])


def leaf_inputs():
    """``(name, alpha, height, mask)`` of the simulated leaf scenes (true incidence, noise-free ranges)."""
    out = []
    for name in LEAF_SCENES:
        scene = scenes.build(name)
        scan = simulate(scene, setup_from_section(scene.scanner), seed=0, progress=False)
        mask = (scan.truth_id == 0) & (scan.mixed_fraction < 0.05)
        out.append((name, np.where(mask, scan.incidence, np.nan), scan.range, mask))
    return out


def run_perf(sizes, repeat: int = 3) -> dict:
    """Measure; returns a JSON-ready report (seconds).

    Parameters
    ----------
    sizes : iterable of int
        Side lengths of the sampled hemispheres, pixels.
    repeat : int
        Runs per measurement (the median is kept).

    Returns
    -------
    dict
        Machine description and per size the run times, s.
    """
    report = {"machine": f"{platform.machine()} {platform.processor() or ''}".strip(), "cpus": os.cpu_count(),
              "omp_threads": os.environ.get("OMP_NUM_THREADS", "unset"), "repeat": repeat, "hemispheres": []}
    for side in sizes:
        sample = _hemisphere(side)
        row = {"side": side, "pixels": int(sample.mask.sum()), "seconds": {}}
        for eps in EPSILONS:
            row["seconds"][f"{eps:.2f}"] = _time(lambda: reconstruct_heights(
                sample.alpha, sample.height, sample.mask, sample.grid, "buffer", _params(eps)), repeat)
        report["hemispheres"].append(row)
    pixels = [r["pixels"] for r in report["hemispheres"]]
    report["size_exponent"] = {eps: _slope(pixels, [r["seconds"][eps] for r in report["hemispheres"]])
                               for eps in report["hemispheres"][0]["seconds"]} if len(pixels) > 1 else {}
    report["epsilon_exponent"] = {r["side"]: _slope(EPSILONS, list(r["seconds"].values()))
                                  for r in report["hemispheres"]}
    try:
        leaves = leaf_inputs()
    except Exception as exc:  # the simulator's backend may be unavailable
        report["leaves"] = f"not measured: {exc}"
    else:
        report["leaves"] = []
        for name, alpha, height, mask in leaves:
            seconds = _time(lambda: reconstruct_heights(alpha, height, mask, variant="buffer",
                                                        params=SfsParams(n_smooth=20)), repeat)
            report["leaves"].append({"scene": name, "pixels": int(mask.sum()), "seconds": seconds})
    report["profile"] = profile_10k()
    return report


def profile_10k(top: int = 12) -> dict:
    """cProfile of the buffer variant on a hemisphere of about 10 000 pixels: seconds by module and top functions."""
    sample = _hemisphere(113)
    profiler = cProfile.Profile()
    profiler.enable()
    reconstruct_heights(sample.alpha, sample.height, sample.mask, sample.grid, "buffer", SfsParams(n_smooth=20))
    profiler.disable()
    stats = pstats.Stats(profiler).stats
    by_module: dict[str, float] = {}
    functions = []
    for (filename, line, name), (_, _, tottime, cumtime, _) in stats.items():
        module = _module_name(filename)
        by_module[module] = by_module.get(module, 0.0) + tottime
        if "leafsfs" in filename:
            functions.append((cumtime, f"{module}.{name}"))
    functions.sort(reverse=True)
    return {"pixels": int(sample.mask.sum()), "total_s": sum(by_module.values()),
            "self_seconds_by_module": dict(sorted(by_module.items(), key=lambda kv: -kv[1])[:top]),
            "cumulative_top": [{"function": f, "seconds": round(t, 4)} for t, f in functions[:top]]}


def _module_name(filename: str) -> str:
    parts = filename.replace("\\", "/").split("/")
    for root in ("leafsfs", "numpy", "scipy", "skimage", "matplotlib"):
        if root in parts:
            index = len(parts) - 1 - parts[::-1].index(root)
            return ".".join(parts[index:]).removesuffix(".py") if root == "leafsfs" else root
    return "python" if filename.startswith("~") or "<" in filename else os.path.basename(filename)


def print_report(report: dict) -> str:
    """The report as text."""
    lines = [f"PROP-SFS engine runtime (buffer variant), {report['machine']}, {report['cpus']} CPUs, "
             f"OMP_NUM_THREADS={report['omp_threads']}, medians of {report['repeat']}"]
    lines.append("hemispheres: side  pixels  " + "  ".join(f"eps={e}" for e in report["hemispheres"][0]["seconds"]))
    for row in report["hemispheres"]:
        lines.append(f"             {row['side']:4d} {row['pixels']:7d}  "
                     + "  ".join(f"{t:8.3f}" for t in row["seconds"].values()))
    if report["size_exponent"]:
        lines.append("log-log slope of time vs pixels: "
                     + ", ".join(f"eps {e}: {s:.2f}" for e, s in report["size_exponent"].items())
                     + "  (thesis eq 3.10: 1.37)")
    lines.append("log-log slope of time vs eps_alpha: "
                 + ", ".join(f"side {k}: {s:.2f}" for k, s in report["epsilon_exponent"].items())
                 + "  (thesis: -1.12)")
    if isinstance(report["leaves"], str):
        lines.append(f"leaf masks: {report['leaves']}")
    else:
        for leaf in report["leaves"]:
            lines.append(f"leaf mask {leaf['scene']:10s} {leaf['pixels']:6d} px  {leaf['seconds']:.3f} s "
                         f"(20 smoothing passes, shell rule T3)")
    prof = report["profile"]
    lines.append(f"profile, hemisphere of {prof['pixels']} px (20 passes, T3): {prof['total_s']:.3f} s under cProfile")
    lines += [f"  {module:32s} {seconds:7.3f} s" for module, seconds in prof["self_seconds_by_module"].items()]
    lines.append("  cumulative, leafsfs functions:")
    lines += [f"  {item['function']:48s} {item['seconds']:7.3f} s" for item in prof["cumulative_top"]]
    return "\n".join(lines)


def add_parser(sub) -> None:
    """Register ``sfs`` with the ``tlsbench perf`` sub-commands."""
    p = sub.add_parser("sfs", help="PROP-SFS runtime against alpha-matrix size and quantisation",
                       description="Time the engine on hemispheres of growing size and on leaf masks; fit the "
                                   "log-log slope; profile one 10 000-pixel leaf.")
    p.add_argument("--sizes", default="25,50,100,150,200", help="matrix sides (default 25,50,100,150,200)")
    p.add_argument("--repeat", type=int, default=3, help="repetitions per case, medians reported (default 3)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args) -> int:
    """Measure with the parsed arguments and print the report."""
    try:
        sizes = [int(s) for s in args.sizes.split(",")]
    except ValueError:
        raise BenchError(f"--sizes must be comma-separated integers, got {args.sizes!r}") from None
    if any(s < 10 for s in sizes) or args.repeat < 1:
        raise BenchError("--sizes must be >= 10 and --repeat >= 1")
    report = run_perf(sizes, args.repeat)
    print(json.dumps(report, indent=1) if args.json else print_report(report))
    return 0

"""Run time and peak memory of both methods against point count (``tlsbench perf woody``).

Each measurement runs in a fresh process (``multiprocessing`` spawn), so
that its peak resident memory is its own: the figure reported is the peak
RSS of the run minus the RSS right before it (imports and the cloud
excluded). Clouds are drawn on fixed geometry at increasing density:

- STEP: a 15 m conifer stem with branch stubs (:func:`woody.synthetic.conifer_stem`),
  oracle normals, Hough cells 2 cm / 1 cm, radii 2-30 cm, at most 20 tuboids;
- cylinder following: the apple-like tree (:func:`woody.synthetic.apple_like_tree`).

Both methods thin clouds denser than they need first (STEP to a quarter of
its Hough cell, cylinder following to the spacing of ``resolve_radius_m``),
so above a few points per cm² only the thinning and the labelling of every
point grow with N (KD-trees, N log N); the report gives the time per
``N log2 N`` unit and the points each method used.
"""

from __future__ import annotations

import json
import multiprocessing
import platform
import resource
import time

import numpy as np

from benchmarks.errors import BenchError


def _geometry(method: str):
    from woody.synthetic import apple_like_tree, conifer_stem

    return conifer_stem() if method == "step" else apple_like_tree(0)


def _measure(method: str, size: int, queue) -> None:
    from woody.geometry import cylinders_volume
    from woody.synthetic import sample_cylinders

    cylinders = _geometry(method)
    area = sum(np.pi * (c["radius_m"] + c["radius_end_m"]) * np.linalg.norm(np.subtract(c["end"], c["start"]))
               for c in cylinders)
    cloud = sample_cylinders(cylinders, size / area, seed=1)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    start = time.perf_counter()
    if method == "step":
        from woody.step import step

        result = step(cloud.points, cloud.normals, r_min_m=0.02, r_max_m=0.30, max_tuboids=20, refine=False)
    else:
        from woody.cylinders import follow_cylinders

        result = follow_cylinders(cloud.points)
    elapsed = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    queue.put({"method": method, "points": int(len(cloud.points)), "time_s": elapsed,
               "peak_mb": max(peak - before, 0) / 1024.0, "stats": result.stats,
               "volume_error": result.volume / cylinders_volume(cylinders) - 1.0})


def run_perf(sizes, methods, on_row=None) -> dict:
    """Measure each method at each point count (one fresh process per run).

    Parameters
    ----------
    sizes : iterable of int
        Target point counts of the clouds (the sampled count is near it).
    methods : iterable of str
        Methods to measure.
    on_row : callable, optional
        Called with each row as soon as its run is done (the table is printed row by row).

    Returns
    -------
    dict
        Machine description and ``rows``: per method and size the point count,
        ``time_s`` (s), ``peak_mb`` (MB) and ``us_per_nlogn`` (µs).
    """
    from tqdm import tqdm

    context = multiprocessing.get_context("spawn")
    rows = []
    runs = [(method, size) for method in methods for size in sizes]
    for method, size in (bar := tqdm(runs, desc="bench woody", unit="run", leave=False)):
        bar.set_postfix_str(f"{method} at {size:,} points")
        queue = context.Queue()
        worker = context.Process(target=_measure, args=(method, size, queue))
        worker.start()
        row = queue.get()
        worker.join()
        row["us_per_nlogn"] = 1e6 * row["time_s"] / (row["points"] * np.log2(row["points"]))
        rows.append(row)
        if on_row is not None:
            on_row(row)
    return {**_machine(), "rows": rows}


def _header() -> str:
    return f"{'method':<10} {'points':>9} {'time_s':>9} {'peak_MB':>9} {'us/NlogN':>9}  notes"


def _row_line(row: dict) -> str:
    stats = row["stats"]
    if row["method"] == "step":
        note = (f"Hough {stats['occupied_cells']} cells = {stats['hough_bytes'] / 1e6:.1f} MB "
                f"(dense would be {stats['dense_cells'] * 4 / 1e6:.0f} MB), {stats['tuboids']} tuboids, "
                f"{stats['points_used']:,} points used")
    else:
        note = f"{stats['branches']} branches, {stats.get('points_fitted', stats['points']):,} points fitted"
    note += f", volume error {100 * row['volume_error']:+.1f} %"
    return (f"{row['method']:<10} {row['points']:>9} {row['time_s']:>9.2f} {row['peak_mb']:>9.1f} "
            f"{row['us_per_nlogn']:>9.3f}  {note}")


def _machine() -> dict:
    return {"machine": f"{platform.machine()} {platform.processor() or ''}".strip(), "cpus": multiprocessing.cpu_count()}


def _machine_line(report: dict) -> str:
    return f"machine: {report['machine']}, {report['cpus']} cpus; peak memory = peak RSS of the run above its start"


def add_parser(sub) -> None:
    """Register ``woody`` with the ``tlsbench perf`` sub-commands."""
    p = sub.add_parser("woody", help="STEP and cylinder following: time and peak memory against point count")
    p.add_argument("--sizes", default="1e4,3e4,1e5,3e5,1e6", help="comma-separated point counts")
    p.add_argument("--methods", default="step,cylinders", help="comma-separated: step, cylinders")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args) -> int:
    """Measure with the parsed arguments and print the report."""
    try:
        sizes = [int(float(s)) for s in args.sizes.split(",")]
    except ValueError:
        raise BenchError(f"--sizes must be comma-separated numbers, got {args.sizes!r}") from None
    methods = [m.strip() for m in args.methods.split(",")]
    if not sizes or min(sizes) < 100 or set(methods) - {"step", "cylinders"}:
        raise BenchError("--sizes must be point counts >= 100 and --methods a subset of step, cylinders")
    if args.json:
        print(json.dumps(run_perf(sizes, methods), indent=2))
        return 0
    from tqdm import tqdm

    print(_machine_line(_machine()))
    print(_header(), flush=True)
    run_perf(sizes, methods, on_row=lambda row: tqdm.write(_row_line(row)))  # each row above the progress bar
    return 0

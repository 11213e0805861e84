"""The ``tlsbench`` command line.

``tlsbench main -o DIR`` is what ``make bench`` runs: for now it scans every
built-in scene and writes the scans and a summary (the benchmark harness grows
from here).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from tlssim.clitools import run_main


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tlsbench", description="Benchmark harness of the TLS laboratory.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    p = sub.add_parser("main", help="the main job: scan the built-in scenes, write scans and a summary")
    p.add_argument("-o", "--output", default="bench-out", help="output directory (default bench-out)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=run_main_job)
    return parser


def run_main_job(args) -> int:
    import scenes
    from tlssim.simulate import setup_from_section, simulate

    out = Path(args.output)
    rows = []
    for name in scenes.names():
        scene = scenes.build(name)
        setup = setup_from_section(scene.scanner)
        start = time.perf_counter()
        scan = simulate(scene, setup, seed=args.seed, progress=True)
        elapsed = time.perf_counter() - start
        scan.save(out / "scans" / f"{name}.npz")
        valid = scan.valid
        rows.append({"scene": name, "pulses": int(valid.size), "returns": int(valid.sum()),
                     "mixed_returns": int((scan.mixed_fraction[valid] > 0.01).sum()),
                     "runtime_s": round(elapsed, 3)})
    (out / "summary.json").write_text(json.dumps(rows, indent=2))
    width = max(len(r["scene"]) for r in rows)
    print(f"{'scene':<{width}}  {'pulses':>9}  {'returns':>9}  {'mixed':>7}  {'runtime_s':>9}")
    for r in rows:
        print(f"{r['scene']:<{width}}  {r['pulses']:>9}  {r['returns']:>9}  {r['mixed_returns']:>7}  {r['runtime_s']:>9}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_main(build_parser(), argv if argv is not None else sys.argv[1:])

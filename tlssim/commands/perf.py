"""``tlssim perf``: simulator throughput against the backend's raw ray rate."""

from __future__ import annotations

import json

from tlssim.backend import BACKENDS


def add_parser(sub) -> None:
    p = sub.add_parser("perf", help="measure simulator throughput and memory",
                       description="Scan a fixed built-in scene; report raw rays/s, pulses/s, efficiency, peak memory.")
    p.add_argument("--size", type=int, default=500, help="window of SIZE x SIZE pulses (default 500)")
    p.add_argument("--repeat", type=int, default=3, help="repetitions, medians reported (default 3)")
    p.add_argument("--backend", choices=BACKENDS, default="auto")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args) -> int:
    from tlssim.perf import run_perf

    if args.size < 2 or args.repeat < 1:
        raise ValueError("--size must be >= 2 and --repeat >= 1")
    report = run_perf(size=args.size, repeat=args.repeat, backend=args.backend)
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"scene {report['scene']} ({report['triangles']} triangles), {args.size}x{args.size} pulses, "
          f"{report['subrays']} sub-rays, backend {report['backend']}, medians of {report['repeat']}")
    print(f"  raw first-hit rate   {report['raw_rays_per_s'] / 1e6:8.2f} Mrays/s")
    print(f"  simulator            {report['pulses_per_s'] / 1e3:8.1f} kpulses/s "
          f"({report['subrays_per_s'] / 1e6:.2f} Msub-rays/s)")
    print(f"  efficiency           {report['efficiency']:8.2f}  (goal >= 0.6)")
    print(f"  peak memory (RSS)    {report['peak_rss_mb']:8.0f} MB")
    return 0

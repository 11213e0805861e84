"""``tlssim diff A B``: compare two scans of the same grid pulse by pulse (two backends, versions or seeds)."""

from __future__ import annotations

import json

from tlssim.compare import compare_scans
from tlssim.scan import Scan


def add_parser(sub) -> None:
    p = sub.add_parser("diff", help="compare two NPZ scans of the same grid pulse by pulse",
                       description="Per layer: pulses compared, returned by one scan only, identical, and the "
                                   "max / 99th percentile / median absolute difference. Exits 1 when more than "
                                   "--allow-fraction of the pulses differ in range by more than --tolerance-mm or "
                                   "return in one scan only.")
    p.add_argument("a", help="first scan (.npz)")
    p.add_argument("b", help="second scan (.npz)")
    p.add_argument("--tolerance-mm", type=float, default=1.0,
                   help="range difference counted as differing, mm (default 1)")
    p.add_argument("--allow-fraction", type=float, default=0.0,
                   help="fraction of the pulses allowed to differ before the exit status is 1 (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args) -> int:
    report = compare_scans(Scan.load(args.a), Scan.load(args.b), tolerance_m=args.tolerance_mm * 1e-3)
    rng = report["layers"]["range"]
    differing = rng["differing"] + rng["only_a"] + rng["only_b"]
    pulses = report["shape"][0] * report["shape"][1]
    report["differing_fraction"] = differing / pulses
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        print(f"{pulses:,} pulses; {differing:,} ({report['differing_fraction']:.2e}) differ in range by more than "
              f"{args.tolerance_mm:g} mm or return in one scan only")
        print(f"{'layer':<15} {'unit':>4} {'compared':>10} {'only A':>7} {'only B':>7} {'equal':>7} "
              f"{'max':>10} {'p99':>10} {'median':>10} {'differ':>7}")
        for name, s in report["layers"].items():
            print(f"{name:<15} {s['unit']:>4} {s['compared']:>10,} {s['only_a']:>7,} {s['only_b']:>7,} "
                  f"{s['equal']:>7.4f} {s['max']:>10.3g} {s['p99']:>10.3g} {s['median']:>10.3g} "
                  f"{s.get('differing', ''):>7}")
    return int(report["differing_fraction"] > args.allow_fraction)

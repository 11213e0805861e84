"""``tlssim truth``: the ground truth of every object of a scene."""

from __future__ import annotations

import json

import scenes

#: Bulky truth fields left out unless --full is given.
BULKY = ("outline", "labels", "params", "frame")


def add_parser(sub) -> None:
    p = sub.add_parser("truth", help="print the ground truth of a scene's objects",
                       description="One entry per object: id (the scans' truth_id), name, type, and for leaves "
                                   "area_m2, normal, elevation_deg, azimuth_deg; for woody objects their cylinders.")
    p.add_argument("scene", help="scene file (YAML) or built-in scene name (see `tlssim scenes`)")
    p.add_argument("--json", action="store_true", help="print a JSON list (default: one line per object)")
    p.add_argument("--full", action="store_true", help="include bulky fields (leaf outlines, surface frames)")
    p.set_defaults(func=run)


def run(args) -> int:
    entries = scenes.load(args.scene).truth()
    if not args.full:
        entries = [{k: v for k, v in e.items() if k not in BULKY} for e in entries]
    if args.json:
        print(json.dumps(entries, indent=1))
        return 0
    for e in entries:
        line = f"{e['id']:6d}  {e['name']:<28} {e['type']:<9}"
        if e["type"] == "leaf":
            line += (f" area {e['area_m2'] * 1e4:6.2f} cm2  elevation {e['elevation_deg']:6.1f} deg  "
                     f"azimuth {e['azimuth_deg']:6.1f} deg")
        elif "cylinders" in e:
            line += f" {len(e['cylinders'])} cylinders, volume {e['volume_m3'] * 1e3:.3f} dm3"
        print(line)
    return 0

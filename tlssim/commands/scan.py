"""``tlssim scan``: simulate a scan of a scene file or built-in scene."""

from __future__ import annotations

import json

import scenes
from tlssim.backend import BACKENDS
from tlssim.simulate import setup_from_section, simulate


def add_parser(sub) -> None:
    p = sub.add_parser("scan", help="simulate a scan of a scene file or built-in scene",
                       description="Simulate a phase-shift scan; writes an NPZ scan (and optionally a PLY cloud).")
    p.add_argument("scene", help="scene file (YAML) or built-in scene name (see `tlssim scenes`)")
    p.add_argument("-o", "--output", required=True, help="output scan file (.npz)")
    p.add_argument("--scanner", default=None, help="scanner preset (default: the scene's, else faro-ls880)")
    p.add_argument("--subrays", type=int, default=None, help="sub-rays per pulse (default: the preset's, 19)")
    p.add_argument("--seed", type=int, default=0, help="random seed (same seed, same bytes)")
    p.add_argument("--backend", choices=BACKENDS, default="auto", help="ray-tracing backend")
    p.add_argument("--ply", default=None, help="also write the returned points as a PLY point cloud")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    scene = scenes.load(args.scene)
    overrides = {} if args.subrays is None else {"n_subrays": args.subrays}
    setup = setup_from_section(scene.scanner, preset=args.scanner, **overrides)
    scan = simulate(scene, setup, seed=args.seed, backend=args.backend, progress=not args.quiet)
    path = scan.save(args.output)
    if args.ply:
        scan.to_ply(args.ply)
    summary = {"output": str(path), "shape": list(scan.shape), "returns": int(scan.valid.sum()),
               "backend": scan.meta["backend"]}
    print(json.dumps(summary))
    return 0

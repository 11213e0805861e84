"""``tlssim scan``: simulate a scan of a scene file or built-in scene, in memory or tile by tile on disk."""

from __future__ import annotations

import json

import scenes
from tlssim.backend import BACKENDS
from tlssim.errors import ScanError
from tlssim.simulate import setup_from_section, simulate, simulate_tiled


def add_parser(sub) -> None:
    p = sub.add_parser("scan", help="simulate a scan of a scene file or built-in scene",
                       description="Simulate a phase-shift scan; writes an NPZ scan (and optionally a PLY cloud), or, "
                                   "with --tile-cols or --memory-budget, a tiled scan directory written tile by tile "
                                   "(resumed where it stopped when run again; same bytes whatever the tile size).")
    p.add_argument("scene", help="scene file (YAML) or built-in scene name (see `tlssim scenes`)")
    p.add_argument("-o", "--output", required=True, help="output scan file (.npz), or directory of a tiled scan")
    p.add_argument("--scanner", default=None, help="scanner preset (default: the scene's, else faro-ls880)")
    p.add_argument("--subrays", type=int, default=None, help="sub-rays per pulse (default: the preset's, 19)")
    p.add_argument("--step-deg", type=float, default=None, help="angular step, deg (default: the scene's)")
    p.add_argument("--theta-deg", type=float, nargs=2, default=None, metavar=("LO", "HI"),
                   help="azimuth range of the window, deg (default: the scene's)")
    p.add_argument("--psi-deg", type=float, nargs=2, default=None, metavar=("LO", "HI"),
                   help="zenith range of the window, deg (default: the scene's)")
    p.add_argument("--seed", type=int, default=0, help="random seed (same seed, same bytes)")
    p.add_argument("--backend", choices=BACKENDS, default="auto",
                   help="ray-tracing backend (auto: CUDA when a GPU is usable, else LLVM)")
    p.add_argument("--tile-cols", type=int, default=None,
                   help="write a tiled scan of TILE_COLS azimuth columns per tile (default with --memory-budget: "
                        "from the budget; on resume: the interrupted scan's)")
    p.add_argument("--memory-budget", type=float, default=None, metavar="GB",
                   help="write a tiled scan whose tiles fit this memory budget, GB")
    p.add_argument("--ply", default=None, help="also write the returned points as a PLY point cloud (in-memory scans)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    scene = scenes.load(args.scene)
    overrides = {} if args.subrays is None else {"n_subrays": args.subrays}
    section = dict(scene.scanner)
    window = dict(section.get("window") or {})
    for key, value in (("theta_deg", args.theta_deg), ("psi_deg", args.psi_deg), ("step_deg", args.step_deg)):
        if value is not None:
            window[key] = value
    if args.step_deg is not None:
        overrides["step_deg"] = args.step_deg
    setup = setup_from_section({**section, "window": window}, preset=args.scanner, **overrides)
    if args.tile_cols is not None or args.memory_budget is not None:
        if args.ply:
            raise ScanError("--ply is for scans in memory; export a tiled scan with `tlssim export DIR OUT.las`")
        if args.memory_budget is not None and args.memory_budget <= 0:
            raise ScanError(f"--memory-budget must be positive, got {args.memory_budget}")
        budget = {} if args.memory_budget is None else {"budget_bytes": int(args.memory_budget * 1e9)}
        tiled = simulate_tiled(scene, setup, args.output, seed=args.seed, tile_cols=args.tile_cols,
                               backend=args.backend, progress=not args.quiet, **budget)
        print(json.dumps({"output": str(tiled.path), "shape": list(tiled.shape), "tiles": len(tiled.tiles),
                          "tile_cols": tiled.tile_cols, "backend": tiled.meta["backend"]}))
        return 0
    scan = simulate(scene, setup, seed=args.seed, backend=args.backend, progress=not args.quiet)
    path = scan.save(args.output)
    if args.ply:
        scan.to_ply(args.ply)
    summary = {"output": str(path), "shape": list(scan.shape), "returns": int(scan.valid.sum()),
               "backend": scan.meta["backend"]}
    print(json.dumps(summary))
    return 0

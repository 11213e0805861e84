"""The ``woody`` command line.

- ``woody reconstruct CLOUD --method step|cylinders -o OUTDIR``: reconstruct
  the woody structure of a point cloud (NPZ, PLY, LAS, E57) and write
  ``cylinders.json`` (cylinder list, volume, run statistics), ``mesh.ply``
  and the method's own output (``tuboids.json`` for STEP; ``branches.json``
  with the skeleton and ``point_labels.npy`` for cylinder following).

The experiments of the woody spec and the run-time benchmark are
``tlsbench experiment woody`` and ``tlsbench perf woody``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from tlssim.clitools import run_main


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every command."""
    parser = argparse.ArgumentParser(prog="woody", description="Woody-structure reconstruction from point clouds.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("reconstruct", help="reconstruct tubes or cylinders from a point cloud",
                       description="Reconstruct the woody structure of a point cloud (.npz, .ply, .las, .e57).")
    p.add_argument("cloud", help="point-cloud file")
    p.add_argument("--method", choices=("step", "cylinders"), required=True)
    p.add_argument("-o", "--output", required=True, help="output directory")
    p.add_argument("--normals", choices=("auto", "pca", "file"), default="auto",
                   help="STEP normals: from the file (e.g. a simulated scan's truth), PCA, or the file's when present "
                        "(default auto)")
    p.add_argument("--cell-m", type=float, default=0.02, help="STEP Hough cell in x, y, z, m (default 0.02)")
    p.add_argument("--radius-step-m", type=float, default=0.01, help="STEP Hough cell in r, m (default 0.01)")
    p.add_argument("--r-min-m", type=float, default=0.02, help="STEP smallest radius, m (default 0.02)")
    p.add_argument("--r-max-m", type=float, default=0.30, help="STEP largest radius, m (default 0.30)")
    p.add_argument("--max-tuboids", type=int, default=None, help="STEP: stop after this many tuboids")
    p.add_argument("--no-refine", action="store_true", help="STEP: keep the Hough-space circles (no point re-fit)")
    p.add_argument("--precision-m", type=float, default=None,
                   help="cylinders: largest point-to-branch distance, m (default 2.5 x point spacing)")
    p.add_argument("--sections", type=float, default=4.0,
                   help="cylinders: output cylinder length in branch radii; 0 = one per branch (default 4)")
    p.set_defaults(func=run_reconstruct)

    return parser


def run_reconstruct(args) -> int:
    from woody.cloud import read_cloud
    from woody.errors import WoodyError

    cloud = read_cloud(args.cloud)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    if args.method == "step":
        from woody.step import step

        if args.normals == "file" and cloud.normals is None:
            raise WoodyError(f"{args.cloud}: --normals file, but the file holds no normals")
        normals = cloud.normals if args.normals in ("file", "auto") else None
        result = step(cloud.points, normals, viewpoints=cloud.viewpoints, cell_m=args.cell_m,
                      radius_step_m=args.radius_step_m, r_min_m=args.r_min_m, r_max_m=args.r_max_m,
                      max_tuboids=args.max_tuboids, refine=not args.no_refine, progress=True)
        (out / "tuboids.json").write_text(json.dumps([t.to_dict() for t in result.tuboids]))
    else:
        from woody.cylinders import follow_cylinders

        result = follow_cylinders(cloud.points, precision_m=args.precision_m, section_radii=args.sections,
                                  progress=True)
        nodes, edges = result.skeleton()
        (out / "branches.json").write_text(json.dumps({"branches": result.branches, "skeleton": {
            "nodes": nodes.tolist(), "edges": edges.tolist()}}))
        np.save(out / "point_labels.npy", result.labels)
    cylinders = result.cylinders()
    summary = {"method": args.method, "cloud": str(args.cloud), "volume_m3": result.volume, "stats": result.stats,
               "cylinders": cylinders}
    (out / "cylinders.json").write_text(json.dumps(summary, default=float))
    result.mesh().export(out / "mesh.ply")
    kind = "tuboids" if args.method == "step" else "branches"
    count = len(result.tuboids) if args.method == "step" else len(result.branches)
    print(f"{count} {kind}, {len(cylinders)} cylinders, volume {result.volume * 1e3:.3f} dm^3 -> {out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``woody`` console script."""
    return run_main(build_parser(), argv if argv is not None else sys.argv[1:])


if __name__ == "__main__":
    sys.exit(main())

"""The ``woody`` command line.

- ``woody reconstruct CLOUD --method step|cylinders -o OUTDIR``: reconstruct
  the woody structure of a point cloud (NPZ, PLY, LAS, E57) and write
  ``cylinders.json`` (cylinder list, volume, DBH, run statistics),
  ``qsm_cylinders.csv`` (the TreeQSM-style cylinder table), ``mesh.ply``
  and the method's own output (``tuboids.json`` for STEP; ``branches.json``
  with the skeleton and ``point_labels.npy`` for cylinder following; the
  other method's files left by an earlier run are removed);
- ``woody separate CLOUD -o WOOD``: the cloud's wood points, leaves, needles
  and strays left out from the geometry alone (:mod:`woody.leafwood`),
  written as ``.npz``, ``.ply`` or ``.las``/``.laz`` (a LAS input keeps its
  records' other fields), and with ``--labels`` a per-point 1 (wood) / 0;
- ``woody dbh CLOUD``: diameter at breast height of every stem, with its
  arc coverage, fit residual and quality flag (``--json`` for one object).

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
    p.add_argument("--cell-m", type=float, default=None,
                   help="STEP Hough cell in x, y, z, m (default: 0.02, or two point spacings on sparser clouds)")
    p.add_argument("--radius-step-m", type=float, default=None,
                   help="STEP Hough cell in r, m (default: 0.01, or 0.4 cells on sparse clouds)")
    p.add_argument("--r-min-m", type=float, default=None,
                   help="STEP smallest radius, m (default: 0.02, or 1.5 radius cells on sparse clouds)")
    p.add_argument("--r-max-m", type=float, default=0.30, help="STEP largest radius, m (default 0.30)")
    p.add_argument("--max-tuboids", type=int, default=None, help="STEP: stop after this many tuboids")
    p.add_argument("--no-refine", action="store_true", help="STEP: keep the Hough-space circles (no point re-fit)")
    p.add_argument("--precision-m", type=float, default=None,
                   help="cylinders: largest point-to-branch distance, m (default 2.5 x point spacing)")
    p.add_argument("--sections", type=float, default=4.0,
                   help="cylinders: output cylinder length in branch radii; 0 = one per branch (default 4)")
    p.add_argument("--ground-z", type=float, default=None,
                   help="ground height for the DBH and the trunk, m (default: found from the lowest points)")
    p.add_argument("--no-trunk", action="store_true",
                   help="cylinders: plain cylinder following (default: the trunk is followed first from the ground "
                        "up by circle fits, the ground left out)")
    p.add_argument("--pipe-model", action=argparse.BooleanOptionalAction, default=True,
                   help="cylinders: radii the points do not resolve (under one point spacing, or scattered) follow "
                        "the pipe model from their nearest resolved ancestor (default; --no-pipe-model: off)")
    p.add_argument("--separate", action=argparse.BooleanOptionalAction, default=False,
                   help="cylinders: leave out the points woody separate finds are not wood (leaves, needles, "
                        "strays) before following the trunk and the branches; they get label -1 (default off)")
    p.add_argument("--resolve-radius-m", type=float, default=None,
                   help="cylinders: thinnest branch radius to resolve; denser clouds are thinned at random to a "
                        "point spacing of pi r / 6 first, 0 keeps every point (default 0.01 m)")
    p.set_defaults(func=run_reconstruct)

    p = sub.add_parser("separate", help="the wood points of a tree's cloud, leaves and needles left out",
                       description="Leaf/wood separation from the geometry alone (woody.leafwood): the points the "
                                   "shortest paths from the tree's base run through, and those next to them.")
    p.add_argument("cloud", help="point-cloud file")
    p.add_argument("-o", "--output", required=True, help="the wood points: .npz, .ply, .las or .laz")
    p.add_argument("--labels", default=None, help="also write a per-point label (1 wood, 0 not) to this .npy file")
    p.add_argument("--reach-m", type=float, default=None,
                   help="smallest reach of the wood's core beyond a point, m (default woody.leafwood.REACH_M)")
    p.set_defaults(func=run_separate)

    p = sub.add_parser("dbh", help="diameter at breast height of the stems of a point cloud",
                       description="DBH of every stem crossing breast height: a robust circle fit on a thin slice, "
                                   "with the arc coverage, the fit residual and a quality flag.")
    p.add_argument("cloud", help="point-cloud file")
    p.add_argument("--ground-z", type=float, default=None,
                   help="ground height, m (default: found from the lowest points under each stem)")
    p.add_argument("--height", type=float, default=1.3, help="measurement height above the ground, m (default 1.3)")
    p.add_argument("--slice", type=float, default=0.1, help="height of the fitted slice, m (default 0.1)")
    p.add_argument("--viewpoint", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="scanner position of a single scan, m; with --footprint the circles model the beam's "
                        "widening of thin stems' silhouettes (default: the file's scanner position, when it holds "
                        "one scan: E57 pose, tlssim scan)")
    p.add_argument("--footprint", type=float, nargs=2, default=None, metavar=("EXIT_M", "GROWTH"),
                   help="the scanner's beam: 1/e2 diameter at the exit, m, and its growth per metre of range "
                        "(twice the tangent of the divergence half-angle), e.g. 0.003 0.000489 for the FARO LS880")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run_dbh)

    return parser


def run_reconstruct(args) -> int:
    from woody.cloud import read_cloud
    from woody.dbh import dbh_summary
    from woody.qsm import write_qsm_csv
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
        from woody.trunk import follow_tree

        settings = {"precision_m": args.precision_m, "section_radii": args.sections,
                    "pipe_model": args.pipe_model, "progress": True}
        if args.resolve_radius_m is not None:
            settings["resolve_radius_m"] = args.resolve_radius_m
        result = follow_cylinders(cloud.points, **settings) if args.no_trunk else \
            follow_tree(cloud.points, ground_z=args.ground_z, separate=args.separate, **settings)
        nodes, edges = result.skeleton()
        (out / "branches.json").write_text(json.dumps({"branches": result.branches, "skeleton": {
            "nodes": nodes.tolist(), "edges": edges.tolist()}}))
        np.save(out / "point_labels.npy", result.labels)
    own = {"step": ("tuboids.json",), "cylinders": ("branches.json", "point_labels.npy")}
    for name in own["cylinders" if args.method == "step" else "step"]:
        (out / name).unlink(missing_ok=True)  # an earlier run's files of the other method
    cylinders = result.cylinders()
    dbh = dbh_summary(cloud.points, cylinders, ground_z=args.ground_z)
    summary = {"method": args.method, "cloud": str(args.cloud), "volume_m3": result.volume, "dbh": dbh,
               "stats": result.stats, "cylinders": cylinders}
    (out / "cylinders.json").write_text(json.dumps(summary, default=float))
    write_qsm_csv(cylinders, out / "qsm_cylinders.csv")
    result.mesh().export(out / "mesh.ply")
    kind = "tuboids" if args.method == "step" else "branches"
    count = len(result.tuboids) if args.method == "step" else len(result.branches)
    stem = f"DBH {dbh['stems'][0]['dbh_m'] * 100:.1f} cm ({dbh['stems'][0]['flag']})" if "stems" in dbh else "no DBH"
    print(f"{count} {kind}, {len(cylinders)} cylinders, volume {result.volume * 1e3:.3f} dm^3, {stem} -> {out}")
    return 0


def run_separate(args) -> int:
    from woody.cloud import read_cloud
    from woody.errors import WoodyError
    from woody.leafwood import REACH_M, separate_wood

    out = Path(args.output)
    if out.suffix.lower() not in (".npz", ".ply", ".las", ".laz"):
        raise WoodyError(f"{out}: the wood points are written as .npz, .ply, .las or .laz")
    cloud = read_cloud(args.cloud)
    wood = separate_wood(cloud.points, reach_m=REACH_M if args.reach_m is None else args.reach_m)
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.suffix.lower() == ".npz":
        from tlssim.scan import write_npz

        write_npz(out, {"points": cloud.points[wood]})
    elif out.suffix.lower() == ".ply":
        from tlssim.scan import write_ply_points

        write_ply_points(out, [(a, "<f8", cloud.points[wood, i]) for i, a in enumerate("xyz")])
    else:
        _write_las(args.cloud, cloud.points, wood, out)
    if args.labels:
        np.save(args.labels, wood.astype(np.uint8))
    print(f"{int(wood.sum())} of {len(wood)} points are wood ({wood.mean() * 100:.1f} %) -> {out}")
    return 0


def _write_las(source, points: np.ndarray, wood: np.ndarray, out: Path) -> None:
    """The wood points as LAS/LAZ: a LAS source's records (every field kept), else a new LAS 1.4 of x, y, z."""
    import laspy

    if Path(source).suffix.lower() in (".las", ".laz"):
        las = laspy.read(str(source))
        las.points = las.points[wood]
    else:
        las = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
        las.header.offsets = points.min(axis=0)
        las.header.scales = np.full(3, 1e-4)
        las.x, las.y, las.z = points[wood].T
    las.write(str(out))


def run_dbh(args) -> int:
    from woody.cloud import read_cloud, single_viewpoint
    from woody.dbh import measure_dbh

    cloud = read_cloud(args.cloud)
    viewpoint = args.viewpoint
    if viewpoint is None and args.footprint is not None:
        viewpoint = single_viewpoint(cloud)
        if viewpoint is None:
            print("woody dbh: --footprint needs the scanner position: the file holds none (or several scans); "
                  "give --viewpoint X Y Z, or the plain circle fit is used", file=sys.stderr)
    stems = measure_dbh(cloud.points, ground_z=args.ground_z, height_m=args.height,
                        slice_m=args.slice, viewpoint=viewpoint, footprint=args.footprint)
    if args.json:
        print(json.dumps({"cloud": str(args.cloud), "stems": [s.to_dict() for s in stems]}, indent=2))
        return 0
    for stem in stems:
        x, y, _ = stem.centre
        print(f"DBH {stem.dbh_m * 100:.2f} cm at {stem.height_m:.2f} m above the ground (z {stem.ground_z_m:.3f} m), "
              f"stem at x {x:.3f} y {y:.3f} m; arc {stem.arc_deg:.0f} deg, residual {stem.residual_m * 1e3:.1f} mm, "
              f"{stem.n_points} points: {stem.flag}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``woody`` console script."""
    return run_main(build_parser(), argv if argv is not None else sys.argv[1:])


if __name__ == "__main__":
    sys.exit(main())

"""The ``leafsfs`` command line: ``leafsfs reconstruct SCAN --calibration FILE -o OUTDIR``, ``leafsfs calibrate``.

The engine's run-time benchmark and the buffer/fused comparison are
``tlsbench perf sfs`` and ``tlsbench experiment sfs-compare``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from tlssim.clitools import run_main

#: The ``--variant`` of ``leafsfs reconstruct`` that runs ``fused`` and then :func:`leafsfs.strays.remove_strays`.
STRAY_VARIANT = "fused-stray"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every ``leafsfs`` command."""
    from leafsfs.params import VARIANTS
    from leafsfs.strays import SCOPES

    parser = argparse.ArgumentParser(prog="leafsfs", description="PROP-SFS leaf reconstruction from TLS intensity.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    p = sub.add_parser("reconstruct", help="correct the leaf distances of a scan",
                       description="Re-estimate the leaf distances of a scan from its intensity (PROP-SFS) and "
                                   "write corrected.npz, mesh.ply, traits.json and preview.png.")
    p.add_argument("scan", help="scan file: .npz (tlssim), .e57 or .ptx, or a tiled scan directory ('tlssim scan "
                                "-o DIR --tile-cols/--memory-budget'), reconstructed window by window")
    p.add_argument("-o", "--outdir", required=True, help="output directory")
    p.add_argument("--variant", choices=(*VARIANTS, STRAY_VARIANT), default="buffer",
                   help=f"PROP-SFS variant (default buffer); {STRAY_VARIANT}: fused, then the pulses it moved that "
                        "the stray-point rule flags removed (leafsfs.strays; on a tiled scan window by window)")
    p.add_argument("--stray-scope", choices=SCOPES,
                   help=f"with --variant {STRAY_VARIANT}: the pulses the rule judges (default moved; outside: "
                        "fused's changes kept only within its leaves, the rule on all pulses outside them and, within "
                        "them, on the measured and the corrected ranges (moves beyond its tolerance of pulses it keeps "
                        "undone), for coarse steps such as 0.08 deg)")
    p.add_argument("--calibration", required=True,
                   help="calibration JSON file ('leafsfs calibrate', or 'tlsbench experiment calibration' for a "
                        "simulated scanner)")
    p.add_argument("--mask", help="NPZ file with a boolean or integer label array 'mask' of the scan's shape "
                                  "(default: automatic leaf segmentation)")
    p.add_argument("--params", help="JSON file of PROP-SFS parameters (leafsfs.SfsParams fields)")
    p.add_argument("--core-cols", type=int,
                   help="tiled scan: columns per output tile, each reconstructed in a window of it plus margins "
                        "(default: from --memory-budget)")
    p.add_argument("--band-rows", type=int,
                   help="tiled scan: rows per band, each with margins of its own (default: from --memory-budget, "
                        "at most all rows up to 2048 rows, else 1024)")
    p.add_argument("--memory-budget", type=float, default=3.5,
                   help="tiled scan: memory of the whole run (this process and its workers), GB, that sizes the "
                        "cores and bands (default 3.5)")
    p.add_argument("--workers", type=int, default=1,
                   help="tiled scan: processes reconstructing windows at once (default 1); the output is the same "
                        "for any number")
    p.add_argument("--leaf-size-m", type=float,
                   help="tiled scan: largest leaf extent, m; a window's margin is the columns it spans at the "
                        "nearest pulses (default 0.12)")
    p.set_defaults(func=_reconstruct)
    p = sub.add_parser("calibrate", help="fit the intensity calibration from a panel table and a goniometer table",
                       description="Fit the distance correction (panel table) and the intensity-incidence relation "
                                   "(goniometer table), both measured with 'tlssim calibrate'; write the "
                                   "calibration JSON that 'leafsfs reconstruct --calibration' takes, and a PNG.")
    p.add_argument("panels", help="panel table (JSON) of a panel-series scan")
    p.add_argument("goniometer", help="goniometer table (JSON) of a goniometer scan")
    p.add_argument("-o", "--output", default="calibration.json", help="calibration file (default calibration.json)")
    p.add_argument("--mode", choices=("additive", "ratio"), default="additive", help="distance-correction form")
    p.set_defaults(func=_calibrate)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``leafsfs`` console script."""
    return run_main(build_parser(), argv if argv is not None else sys.argv[1:])


def _reconstruct(args) -> int:
    import numpy as np

    from leafsfs.errors import SfsError
    from leafsfs.outputs import write_outputs
    from leafsfs.params import SfsParams
    from leafsfs.reconstruct import reconstruct

    from leafsfs.strays import remove_strays
    from leafsfs.tiled import is_tiled

    if args.stray_scope is not None and args.variant != STRAY_VARIANT:
        raise SfsError(f"--stray-scope needs --variant {STRAY_VARIANT}")
    scan = None if is_tiled(args.scan) else _load_scan(Path(args.scan))
    mask = None
    if args.mask:
        try:
            with np.load(args.mask, allow_pickle=False) as data:
                mask = data["mask"]
        except (OSError, ValueError, KeyError) as exc:
            raise SfsError(f"{args.mask}: not an NPZ file with a 'mask' array ({exc})") from None
    params = SfsParams()
    if args.params:
        try:
            changes = json.loads(Path(args.params).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise SfsError(f"{args.params}: not a readable JSON file of parameters ({exc})") from None
        if not isinstance(changes, dict):
            raise SfsError(f"{args.params}: parameters must be a JSON object of SfsParams fields")
        params = params.replace(**{k: tuple(v) if isinstance(v, list) else v for k, v in changes.items()})
    if is_tiled(args.scan):
        return _reconstruct_tiled(args, params, mask)
    stray = args.variant == STRAY_VARIANT
    result = reconstruct(scan, mask, "fused" if stray else args.variant, params, calibration=args.calibration)
    if stray:
        result = remove_strays(result, args.stray_scope or "moved")
    paths = write_outputs(result, args.outdir)
    print(f"{len(result.leaves)} leaves, {int(result.corrected.sum())} distances corrected, "
          f"{int(result.outlier.sum())} outliers ({int(result.removed.sum())} removed); rppp_1 {result.rppp()['rppp_1']:.3f}")
    for kind, path in paths.items():
        print(f"  {kind:10s} {path}")
    return 0


def _reconstruct_tiled(args, params, mask) -> int:
    from tqdm import tqdm

    from leafsfs.errors import SfsError
    from leafsfs.tiled import LEAF_SIZE_M, plan_windows, reconstruct_tiled
    from tlssim.tiled import open_tiled

    if mask is not None:
        raise SfsError("--mask is not supported on a tiled scan (leaves are found window by window)")
    tiled = open_tiled(args.scan)
    leaf_size = args.leaf_size_m if args.leaf_size_m is not None else LEAF_SIZE_M
    plan = plan_windows(tiled, args.memory_budget * 1e9, args.workers, leaf_size, args.band_rows)
    core_cols = args.core_cols or plan.core_cols
    if args.core_cols:
        print(f"cores of {core_cols} columns, bands of {plan.band_rows} rows")
    else:
        print(f"cores of {core_cols} columns, bands of {plan.band_rows} rows; largest window about {plan.window[0]} "
              f"x {plan.window[1]} pulses; expected peak of the run {plan.peak_bytes / 1e9:.1f} GB" + (
                  "" if plan.fits else f", over the {args.memory_budget:g} GB budget (the smallest windows tried): "
                                       "use fewer --workers or a larger --memory-budget"))
    with tqdm(unit="window", desc="reconstruct") as bar:
        def show(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        stray = args.variant == STRAY_VARIANT
        result = reconstruct_tiled(tiled, args.outdir, "fused" if stray else args.variant, params,
                                   calibration=args.calibration, core_cols=core_cols, band_rows=plan.band_rows,
                                   leaf_size_m=leaf_size, workers=args.workers, progress=show,
                                   strays=(args.stray_scope or "moved") if stray else None)
    print(f"{len(result.traits)} leaves in {len(result.scan.tiles)} tiles of {core_cols} columns; "
          f"{result.windows} windows run in {result.elapsed_s:.1f} s on {args.workers} worker(s): "
          f"{result.pulses_per_s:,.0f} pulses/s")
    print(f"  corrected  {result.scan.path}\n  traits     {Path(args.outdir) / 'traits.json'}")
    return 0


def _calibrate(args) -> int:
    from leafsfs.calibration import fit_calibration, panel_statistics
    from leafsfs.calibration_plot import plot_calibration
    from tlssim.calibration import load_table

    panels, model = load_table(args.panels, "panels")
    goniometer, _ = load_table(args.goniometer, "goniometer")
    calibration = fit_calibration(panels, goniometer, args.mode, model)
    path = calibration.save(args.output)
    png = plot_calibration(panels, goniometer, calibration, Path(args.output).with_suffix(".png"))
    stats = panel_statistics(panels, calibration.curve, args.mode)
    print(f"f99({calibration.curve.reference_distance_m} m) = {calibration.curve.reference_dn:.1f} DN; mean shift "
          "below it by reflectance: " + ", ".join(f"{rho:.2f}: {s['mean_shift_dn']:.0f} DN" for rho, s in stats.items()))
    print(f"  {path}\n  {png}")
    return 0


def _load_scan(path: Path):
    from leafsfs.errors import SfsError
    from tlssim.scan import Scan

    suffix = path.suffix.lower()
    if suffix == ".npz":
        return Scan.load(path)
    if suffix in (".e57", ".ptx"):
        from tlssim import formats

        return formats.import_scan(path)
    raise SfsError(f"{path}: unknown scan format {suffix!r}; allowed: .npz, .e57, .ptx")


if __name__ == "__main__":
    sys.exit(main())

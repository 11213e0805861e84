"""``tlssim export`` and ``tlssim import``: convert scans between NPZ and E57, PTX, LAS/LAZ."""

from __future__ import annotations

import json


def add_parser(sub) -> None:
    p = sub.add_parser("export", help="write a scan as E57, PTX, LAS or LAZ",
                       description="Convert an NPZ scan or a tiled scan directory to the format of OUTPUT's extension (.e57, .ptx, .las, .laz).")
    p.add_argument("scan", help="scan file (.npz) or tiled scan directory (streamed to every format)")
    p.add_argument("output", help="output file (.e57, .ptx, .las or .laz)")
    p.set_defaults(func=run_export)
    p = sub.add_parser("import", help="read an E57, PTX, LAS or LAZ scan into NPZ or a tiled scan",
                       description="Convert a structured scan file (.e57, .ptx, or .las/.laz written by tlssim) "
                                   "to an NPZ scan, or stream it tile by tile into a tiled scan directory; E57 and "
                                   "PTX give scans without truth.")
    p.add_argument("input", help="scan file (.e57, .ptx, .las or .laz)")
    p.add_argument("output", nargs="?", help="output scan file (.npz), or a directory: the scan is then streamed "
                                             "into a tiled scan, tile by tile (resumable)")
    p.add_argument("-o", "--output", dest="output_option", metavar="OUTPUT", help="the same as OUTPUT")
    p.add_argument("--tile-cols", type=int, help="columns per tile of a streamed import (default: tiles of about 2 GB)")
    p.set_defaults(func=run_import)


def run_export(args) -> int:
    from tlssim.formats import export_scan
    from tlssim.tiled import open_scan

    scan = open_scan(args.scan)
    path = export_scan(scan, args.output)
    print(json.dumps({"output": str(path), "shape": list(scan.shape)}))
    return 0


def run_import(args) -> int:
    from pathlib import Path

    from tlssim.errors import ScanError
    from tlssim.formats import import_scan, import_tiled

    if (args.output is None) == (args.output_option is None):
        raise ScanError("tlssim import needs one output: OUTPUT or -o OUTPUT (a .npz file or a directory)")
    output = args.output or args.output_option
    if Path(output).suffix.lower() != ".npz":
        tiled = import_tiled(args.input, output, args.tile_cols)
        print(json.dumps({"output": str(tiled.path), "shape": list(tiled.shape), "tiles": len(tiled.tiles),
                          "truth": tiled.has_truth}))
        return 0
    scan = import_scan(args.input)
    path = scan.save(output)
    print(json.dumps({"output": str(path), "shape": list(scan.shape), "returns": int(scan.valid.sum()),
                      "truth": scan.has_truth}))
    return 0

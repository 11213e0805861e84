"""``tlssim calibrate``: measure the calibration table of a panel-series or goniometer scan.

A ``panel-series`` scan gives the mean intensity and distance of every panel;
a ``goniometer`` scan gives the plane-fit incidence and the interior returns
of every leaf. Both write the table as JSON (:func:`tlssim.calibration.save_table`)
and a plot of the raw intensities as PNG. ``leafsfs calibrate PANELS.json
GONIOMETER.json`` fits the intensity calibration from the two tables.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def add_parser(sub) -> None:
    p = sub.add_parser("calibrate", help="measure the calibration table of a panel-series or goniometer scan",
                       description="Measure the panel table (panel-series scan) or the goniometer table (goniometer "
                                   "scan); write JSON and PNG. Fit them with 'leafsfs calibrate'.")
    p.add_argument("scan", help="scan of the built-in scene 'panel-series' or 'goniometer' (.npz)")
    p.add_argument("-o", "--output", default=None,
                   help="output prefix (default: next to the scan); writes PREFIX.json and PREFIX.png")
    p.set_defaults(func=run)


def run(args) -> int:
    from tlssim.calibration import goniometer_table, panel_table, save_table
    from tlssim.errors import ScanError
    from tlssim.scan import Scan

    scan = Scan.load(args.scan)
    prefix = Path(args.output) if args.output else Path(args.scan).with_suffix("")
    names = scan.object_names or []
    if any(name.startswith("panel-") for name in names):
        kind, table = "panels", panel_table(scan)
        png_path = _plot_panels(prefix, table)
    elif any(name.startswith("leaf-") for name in names):
        kind, table = "goniometer", goniometer_table(scan)
        png_path = _plot_goniometer(prefix, table)
    else:
        raise ScanError(f"{args.scan}: neither a panel-series nor a goniometer scan (no calibration objects)")
    model = None if scan.scanner.model is None else scan.scanner.model.to_dict()
    json_path = save_table(table, prefix.with_name(prefix.name + ".json"), kind, model)
    print(json.dumps({"table": kind, "json": str(json_path), "png": str(png_path), "rows": len(table["name"])}))
    return 0


def _plot_panels(prefix: Path, table: dict) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for rho in np.unique(table["reflectance"])[::-1]:
        chosen = np.isclose(table["reflectance"], rho)
        ax.plot(table["distance_m"][chosen], table["intensity_dn"][chosen], "o-", ms=3, lw=0.8, label=f"{rho:.0%}")
    ax.set_xscale("log")
    ax.set_xlabel("distance (m)")
    ax.set_ylabel("raw intensity (DN)")
    ax.legend(fontsize=7, ncol=2)
    return _save(fig, prefix)


def _plot_goniometer(prefix: Path, table: dict) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for axis, marker in (("vertical", "o"), ("horizontal", "s")):
        chosen = table["rotation_axis"] == axis
        ax.plot(np.degrees(table["alpha_rad"][chosen]), table["intensity_dn"][chosen], marker, ms=4,
                label=f"{axis} axis")
    ax.set_xlabel("incidence from the plane fit (deg)")
    ax.set_ylabel("mean raw intensity (DN)")
    ax.legend(fontsize=8)
    return _save(fig, prefix)


def _save(fig, prefix: Path) -> Path:
    path = prefix.with_name(prefix.name + ".png")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path

"""``tlssim calibrate``: fit the intensity calibrations from a panel-series or goniometer scan.

A ``panel-series`` scan gives the 99 % reference curve ``f99(d)`` with the
Table 2 statistics of every panel; a ``goniometer`` scan gives the
intensity-incidence relation (it needs a reference curve: ``--curve``, or
else the panel series is simulated with the scan's scanner model). Both write
the fitted curves as JSON and a plot as PNG.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path

import numpy as np


def add_parser(sub) -> None:
    p = sub.add_parser("calibrate", help="fit intensity calibrations from a panel-series or goniometer scan",
                       description="Fit the distance correction (panel-series scan) or the intensity-incidence "
                                   "relation (goniometer scan); write JSON and PNG.")
    p.add_argument("scan", help="scan of the built-in scene 'panel-series' or 'goniometer' (.npz)")
    p.add_argument("-o", "--output", default=None,
                   help="output prefix (default: next to the scan); writes PREFIX.json and PREFIX.png")
    p.add_argument("--curve", default=None, help="reference curve or calibration JSON (goniometer scans)")
    p.add_argument("--mode", choices=("additive", "ratio"), default="additive", help="distance-correction form")
    p.add_argument("--seed", type=int, default=0, help="seed of the panel simulation when --curve is not given")
    p.set_defaults(func=run)


def run(args) -> int:
    from tlssim.errors import ScanError
    from tlssim.scan import Scan

    scan = Scan.load(args.scan)
    prefix = Path(args.output) if args.output else Path(args.scan).with_suffix("")
    names = scan.object_names or []
    if any(name.startswith("panel-") for name in names):
        summary = _panels(scan, prefix, args.mode)
    elif any(name.startswith("leaf-") for name in names):
        summary = _goniometer(scan, prefix, args)
    else:
        raise ScanError(f"{args.scan}: neither a panel-series nor a goniometer scan (no calibration objects)")
    print(json.dumps(summary))
    return 0


def _panels(scan, prefix: Path, mode: str) -> dict:
    from tlssim.calibration import panel_statistics, panel_table, reference_curve_from_scan

    table = panel_table(scan)
    curve = reference_curve_from_scan(scan)
    stats = panel_statistics(table, curve, mode)
    document = {"format": "tlssim-reference-curve", "mode": mode, "reference_curve": asdict(curve),
                "reference_dn": curve.reference_dn, "panels": {k: v.tolist() for k, v in table.items()},
                "statistics": {f"{rho:.2f}": value for rho, value in stats.items()}}
    json_path = _write_json(prefix, document)
    png_path = _plot_panels(prefix, table, curve, mode)
    return {"json": str(json_path), "png": str(png_path), "f99_at_reference_dn": round(curve.reference_dn, 2)}


def _goniometer(scan, prefix: Path, args) -> dict:
    from tlssim.calibration import (Calibration, ReferenceCurve, calibrate_model, fit_incidence_relation,
                                    goniometer_table)
    from tlssim.errors import ScanError
    from tlssim.scanner import ScannerModel

    if args.curve:
        try:
            data = json.loads(Path(args.curve).read_text())
            curve = ReferenceCurve.from_dict(data["reference_curve"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ScanError(f"{args.curve}: not a reference curve or calibration JSON ({exc!r})") from None
    else:
        curve = calibrate_model(ScannerModel.from_dict(scan.scanner_model), seed=args.seed).curve
    table = goniometer_table(scan, curve, args.mode)
    relation = fit_incidence_relation(table["alpha_rad"], table["corrected_dn"])
    calibration = Calibration(curve, relation, args.mode, scan.scanner_model)
    document = {**calibration.to_dict(), "stations": {k: v.tolist() for k, v in table.items()}}
    json_path = _write_json(prefix, document)
    png_path = _plot_goniometer(prefix, table, relation)
    return {"json": str(json_path), "png": str(png_path), "stations": len(table["name"])}


def _write_json(prefix: Path, document: dict) -> Path:
    path = prefix.with_name(prefix.name + ".json")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(document, indent=1))
    return path


def _plot_panels(prefix: Path, table: dict, curve, mode: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tlssim.calibration import correct_distance

    fig, (raw, corrected) = plt.subplots(1, 2, figsize=(11, 4.5), sharex=True)
    d = np.geomspace(table["distance_m"].min(), table["distance_m"].max(), 200)
    raw.plot(d, curve(d), "k-", lw=1, label="f99 fit")
    for rho in np.unique(table["reflectance"])[::-1]:
        chosen = np.isclose(table["reflectance"], rho)
        distance, intensity = table["distance_m"][chosen], table["intensity_dn"][chosen]
        raw.plot(distance, intensity, "o-", ms=3, lw=0.8, label=f"{rho:.0%}")
        corrected.plot(distance, correct_distance(intensity, distance, curve, mode), "o-", ms=3, lw=0.8)
    for ax, title in ((raw, "raw intensity"), (corrected, f"distance-corrected ({mode})")):
        ax.set_xscale("log")
        ax.axvline(curve.valid_from_m, color="0.6", ls=":", lw=1)
        ax.set_xlabel("distance (m)")
        ax.set_ylabel("intensity (DN)")
        ax.set_title(title)
    raw.legend(fontsize=7, ncol=2)
    return _save(fig, prefix)


def _plot_goniometer(prefix: Path, table: dict, relation) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for axis, marker in (("vertical", "o"), ("horizontal", "s")):
        chosen = table["rotation_axis"] == axis
        ax.errorbar(np.degrees(table["alpha_rad"][chosen]), table["corrected_dn"][chosen],
                    yerr=table["corrected_std_dn"][chosen], fmt=marker, ms=4, lw=0.8, label=f"{axis} axis")
    alpha = np.linspace(0.0, relation.fit_range_rad[1], 200)
    ax.plot(np.degrees(alpha), np.polyval(relation.polynomial, alpha), "k-", lw=1, label="4th-order polynomial")
    ax.plot(np.degrees(relation.lut_alpha_rad), relation.lut_dn, "r--", lw=1, label="monotone table")
    ax.axvline(math.degrees(relation.validity_limit_rad), color="0.6", ls=":", lw=1, label="validity limit")
    ax.set_xlabel("incidence from the plane fit (deg)")
    ax.set_ylabel("distance-corrected intensity (DN)")
    ax.legend(fontsize=8)
    return _save(fig, prefix)


def _save(fig, prefix: Path) -> Path:
    path = prefix.with_name(prefix.name + ".png")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path

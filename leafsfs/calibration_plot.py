"""A figure of a fitted calibration: the reference curve over the panels, and the intensity-incidence relation."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from leafsfs.calibration import Calibration, correct_distance, station_intensities


def plot_calibration(panels: dict, goniometer: dict, calibration: Calibration, path) -> Path:
    """Write a PNG: panels raw and distance-corrected with ``f99``; goniometer stations with the relation.

    Parameters
    ----------
    panels, goniometer : dict of ndarray
        The tables the calibration was fitted from
        (:func:`tlssim.calibration.panel_table`, :func:`tlssim.calibration.goniometer_table`).
    calibration : Calibration
        The fitted calibration.
    path : str or Path
        Output PNG.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curve, relation, mode = calibration.curve, calibration.incidence, calibration.mode
    fig, (raw, corrected, gonio) = plt.subplots(1, 3, figsize=(16, 4.5))
    d = np.geomspace(panels["distance_m"].min(), panels["distance_m"].max(), 200)
    raw.plot(d, curve(d), "k-", lw=1, label="f99 fit")
    for rho in np.unique(panels["reflectance"])[::-1]:
        chosen = np.isclose(panels["reflectance"], rho)
        distance, intensity = panels["distance_m"][chosen], panels["intensity_dn"][chosen]
        raw.plot(distance, intensity, "o-", ms=3, lw=0.8, label=f"{rho:.0%}")
        corrected.plot(distance, correct_distance(intensity, distance, curve, mode), "o-", ms=3, lw=0.8)
    for ax, title in ((raw, "raw intensity"), (corrected, f"distance-corrected ({mode})")):
        ax.set_xscale("log")
        ax.axvline(curve.valid_from_m, color="0.6", ls=":", lw=1)
        ax.set_xlabel("distance (m)")
        ax.set_ylabel("intensity (DN)")
        ax.set_title(title)
    raw.legend(fontsize=7, ncol=2)
    mean, std = station_intensities(goniometer, curve, mode)
    for axis, marker in (("vertical", "o"), ("horizontal", "s")):
        chosen = goniometer["rotation_axis"] == axis
        gonio.errorbar(np.degrees(goniometer["alpha_rad"][chosen]), mean[chosen], yerr=std[chosen], fmt=marker, ms=4,
                       lw=0.8, label=f"{axis} axis")
    alpha = np.linspace(0.0, relation.fit_range_rad[1], 200)
    gonio.plot(np.degrees(alpha), np.polyval(relation.polynomial, alpha), "k-", lw=1, label="4th-order polynomial")
    gonio.plot(np.degrees(relation.lut_alpha_rad), relation.lut_dn, "r--", lw=1, label="monotone table")
    gonio.axvline(math.degrees(relation.validity_limit_rad), color="0.6", ls=":", lw=1, label="validity limit")
    gonio.set_xlabel("incidence from the plane fit (deg)")
    gonio.set_ylabel("distance-corrected intensity (DN)")
    gonio.legend(fontsize=8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path

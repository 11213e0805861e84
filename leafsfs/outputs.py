"""Files of a reconstruction: corrected scan, mesh, traits and a preview image."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from leafsfs.reconstruct import SfsResult


def write_outputs(result: SfsResult, outdir) -> dict[str, Path]:
    """Write ``corrected.npz``, ``mesh.ply``, ``traits.json`` and ``preview.png`` into ``outdir``.

    ``corrected.npz`` is a :class:`tlssim.Scan` with the input's keys, the
    corrected ranges and points, and the layers ``outlier``, ``candidates``,
    ``leaf`` and ``range_spread``. ``traits.json`` holds one entry per leaf
    (``area_m2``, ``elevation_deg``, ``azimuth_deg``, ``n_points``,
    ``n_outliers`` and the other traits), the redundancy ratios and the
    parameters.

    Parameters
    ----------
    result : SfsResult
        The reconstruction (:func:`leafsfs.reconstruct`).
    outdir : str or Path
        Output folder (created if missing; existing files of these names are replaced).

    Returns
    -------
    dict of str to Path
        The written files by kind.
    """
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    paths = {"corrected": result.corrected_scan().save(outdir / "corrected.npz")}
    paths["mesh"] = outdir / "mesh.ply"
    result.mesh().export(paths["mesh"])
    report = {"variant": result.variant, "leaves": json_ready(result.traits()),
              "skipped": [{"leaf": label, "reason": reason} for label, reason in result.skipped],
              "rppp": result.rppp(), "n_corrected": int(result.corrected.sum()),
              "n_outliers": int(result.outlier.sum()), "n_removed": int(result.removed.sum()), "params": result.params.to_dict()}
    paths["traits"] = outdir / "traits.json"
    paths["traits"].write_text(json.dumps(report, indent=1, allow_nan=False))
    paths["preview"] = preview(result, outdir / "preview.png")
    return paths


def json_ready(value):
    """NaN and infinities become null (JSON has no such numbers), recursively."""
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    return None if isinstance(value, float) and not math.isfinite(value) else value


def preview(result: SfsResult, path) -> Path:
    """Two panels over the leaves: smoothed alpha with the iso-alpha curves, and the range correction (mm).

    Parameters
    ----------
    result : SfsResult
        The reconstruction (:func:`leafsfs.reconstruct`).
    path : str or Path
        The PNG file to write.

    Returns
    -------
    Path
        ``path``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows, cols = np.nonzero(result.labels)
    if len(rows):
        box = (slice(max(rows.min() - 5, 0), rows.max() + 6), slice(max(cols.min() - 5, 0), cols.max() + 6))
    else:
        box = (slice(None), slice(None))
    leaf = result.labels[box] > 0
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.8), constrained_layout=True)
    alpha = np.where(leaf, np.degrees(result.alpha[box]), np.nan)
    image = axes[0].imshow(alpha, cmap="viridis", vmin=0, vmax=90, interpolation="nearest")
    fig.colorbar(image, ax=axes[0], label="alpha (deg, smoothed)")
    for item in result.leaves:
        for _, _, _, points in item.heights.curves:
            closed = np.vstack([points, points[:1]])
            axes[0].plot(closed[:, 1] + item.frame.box[1].start - (box[1].start or 0),
                         closed[:, 0] + item.frame.box[0].start - (box[0].start or 0), color="white", lw=0.6)
    axes[0].set_title(f"iso-alpha curves ({result.variant})")
    change = np.where(leaf, 1e3 * (result.range[box] - result.scan.range[box]), np.nan)
    limit = max(1.0, float(np.nanmax(np.abs(change)))) if np.isfinite(change).any() else 1.0
    norm = matplotlib.colors.SymLogNorm(linthresh=1.0, vmin=-limit, vmax=limit)
    image = axes[1].imshow(change, cmap="coolwarm", norm=norm, interpolation="nearest")
    fig.colorbar(image, ax=axes[1], label="corrected - measured range (mm)")
    out_r, out_c = np.nonzero(result.outlier[box])
    axes[1].plot(out_c, out_r, ",", color="black")
    axes[1].set_title(f"correction; {int(result.outlier.sum())} outliers (black)")
    for ax in axes:
        ax.set_xlabel("column (theta)")
        ax.set_ylabel("row (psi)")
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path

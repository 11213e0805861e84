"""Buffer against fused: the numbers behind the fused variant (``tlsbench experiment sfs-compare``).

Two experiments, each reporting, per variant, the median and 90th
percentile of the absolute height (range) error and the share of pixels
within a tolerance:

1. analytic surfaces (hemisphere, ellipsoid, saddle, complex eq 3.3) with
   +-2.8 deg uniform alpha noise, a global alpha bias of -5, 0 or +5 deg (a
   mis-calibrated intensity) and 0.5 % height noise; 5 smoothing passes,
   10 % quantisation; errors relative to ``h_max - h_min``, tolerance 5 %;
2. the simulated ``leaf-1.5m`` scan with the Lambertian inverse of the
   simulator's radiometric chain (:class:`leafsfs.synthetic.LambertCalibration`)
   assuming leaf reflectance 0.40, 0.48 (the truth) or 0.58; errors in mm
   against the true range on leaf pixels (central ray on the leaf), for all
   of them and for the mixed ones (more than 10 % of the power from
   elsewhere), tolerance 2 mm.
"""

from __future__ import annotations

import json

import numpy as np

import scenes
from leafsfs.engine import reconstruct_heights
from leafsfs.params import SfsParams
from leafsfs.reconstruct import reconstruct
from leafsfs.synthetic import LambertCalibration, sample_surface
from scenes.surfaces import get_surface
from tlssim.simulate import setup_from_section, simulate

SURFACES = (("hemisphere", 41), ("ellipsoid", 40), ("saddle", 50), ("complex", 80))
BIASES = (-5.0, 0.0, 5.0)
REFLECTANCES = (0.40, 0.48, 0.58)
VARIANTS = ("buffer", "fused")


def _summary(errors: np.ndarray, tolerance: float) -> dict:
    return {"median": float(np.median(errors)), "p90": float(np.quantile(errors, 0.9)),
            "within": float(np.mean(errors < tolerance))}


def compare_surfaces(seed: int = 2, surfaces=SURFACES, biases=BIASES) -> list[dict]:
    """Experiment 1 (see the module docstring).

    Parameters
    ----------
    seed : int
        Seed of the alpha and height noise.
    surfaces : sequence of (str, int)
        Surface names and the side of their alpha matrix (pixels).
    biases : sequence of float
        Global alpha biases, degrees.

    Returns
    -------
    list of dict
        One row per surface and bias (see :func:`print_comparison`).
    """
    rows = []
    for name, side in surfaces:
        for bias in biases:
            sample = sample_surface(get_surface(name), side, alpha_noise_deg=2.8, alpha_bias_deg=bias,
                                    height_noise=0.005, seed=seed)
            params = SfsParams(n_smooth=5, quantization="percentile", eps_alpha=0.1, eps_seed=0.2,
                               alpha_max_deg=85, rim_px=0, sigma_range_m=0.005 * sample.height_range)
            row = {"surface": name, "bias_deg": bias}
            for variant in VARIANTS:
                result = reconstruct_heights(sample.alpha, sample.height, sample.mask, sample.grid, variant, params)
                errors = np.abs(result.height - sample.truth)[result.count > 0] / sample.height_range
                row[variant] = _summary(errors, 0.05)
            rows.append(row)
    return rows


def compare_leaf(seed: int = 0, reflectances=REFLECTANCES) -> list[dict]:
    """Experiment 2 (see the module docstring).

    Parameters
    ----------
    seed : int
        Seed of the simulated scan.
    reflectances : sequence of float
        Leaf reflectances the calibration assumes.

    Returns
    -------
    list of dict
        One row per assumed reflectance (range errors in mm, areas in cm²).
    """
    scene = scenes.build("leaf-1.5m")
    scan = simulate(scene, setup_from_section(scene.scanner), seed=seed, progress=False)
    leaf_id = scan.object_names.index("leaf")
    on_leaf = (scan.truth_id == leaf_id) & (np.abs(scan.truth_range - np.nanmedian(scan.range[scan.truth_id == leaf_id]))
                                            < 0.2)
    rows = []
    for reflectance in reflectances:
        row = {"assumed_reflectance": reflectance}
        for variant in VARIANTS:
            result = reconstruct(scan, variant=variant, calibration=LambertCalibration(scan.scanner.model,
                                                                                      reflectance))
            ok = on_leaf & result.corrected
            errors = 1e3 * np.abs(result.range - scan.truth_range)
            mixed = ok & (scan.mixed_fraction > 0.1)
            row[variant] = {"all": _summary(errors[ok], 2.0), "mixed": _summary(errors[mixed], 2.0),
                            "area_cm2": 1e4 * result.traits()[0]["area_m2"] if result.leaves else float("nan")}
        row["true_area_cm2"] = 1e4 * scene.objects[leaf_id].truth["area_m2"]
        rows.append(row)
    return rows


def print_comparison(surfaces: list[dict], leaf: list[dict]) -> str:
    """Both experiments as text tables.

    Parameters
    ----------
    surfaces : list of dict
        Rows of the analytic-surface experiment (``surface``, ``bias_deg`` in
        degrees, per variant the ``median``, ``p90`` and ``within`` of the
        relative height error).
    leaf : list of dict
        Rows of the simulated-leaf experiment (range errors in mm).

    Returns
    -------
    str
        Both tables as text.
    """
    lines = ["analytic surfaces, +-2.8 deg alpha noise, 0.5 % height noise: |error| / (h_max - h_min)",
             f"{'surface':11s} {'bias':>5s}  " + "  ".join(f"{v + ' median  p90  <5%':>25s}" for v in VARIANTS)]
    for row in surfaces:
        lines.append(f"{row['surface']:11s} {row['bias_deg']:+5.1f}  " + "  ".join(
            f"{row[v]['median']:12.4f} {row[v]['p90']:6.3f} {row[v]['within']:5.2f}" for v in VARIANTS))
    lines.append("simulated leaf-1.5m, calibration assuming reflectance rho (true 0.48): |range error| mm")
    lines.append(f"{'rho':>5s}  {'variant':7s} {'all: median':>11s} {'p90':>6s} {'<2mm':>5s}  "
                 f"{'mixed: median':>13s} {'p90':>6s} {'<2mm':>5s}  {'area cm2':>8s}")
    for row in leaf:
        for v in VARIANTS:
            a, m = row[v]["all"], row[v]["mixed"]
            lines.append(f"{row['assumed_reflectance']:5.2f}  {v:7s} {a['median']:11.2f} {a['p90']:6.2f} "
                         f"{a['within']:5.2f}  {m['median']:13.2f} {m['p90']:6.2f} {m['within']:5.2f}  "
                         f"{row[v]['area_cm2']:8.1f}")
    lines.append(f"true leaf area {leaf[0]['true_area_cm2']:.1f} cm2" if leaf else "")
    return "\n".join(lines)


def add_parser(sub) -> None:
    """Register ``sfs-compare`` with the ``tlsbench experiment`` sub-commands."""
    p = sub.add_parser("sfs-compare", help="PROP-SFS buffer against fused on analytic surfaces and a simulated leaf",
                       description="The accuracy of the buffer and fused variants under alpha noise and bias "
                                   "(analytic surfaces) and under a biased calibration (simulated leaf).")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--quick", action="store_true",
                   help="the hemisphere without bias and the true reflectance only (a check that it runs)")
    p.set_defaults(func=run)


def run(args) -> int:
    """Run both experiments and print them."""
    if args.quick:
        surfaces, leaf = compare_surfaces(surfaces=SURFACES[:1], biases=(0.0,)), compare_leaf(reflectances=(0.48,))
    else:
        surfaces, leaf = compare_surfaces(), compare_leaf()
    print(json.dumps({"surfaces": surfaces, "leaf": leaf}, indent=1) if args.json else print_comparison(surfaces, leaf))
    return 0

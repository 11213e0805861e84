"""DBH of one-sided stems: simulated single scans of upright stems against their true diameter.

Each case is an open tube (a stem of ``diameter`` metres, 2 m tall) standing
on a 3 m x 3 m ground plane, scanned once by the FARO-LS880-class preset
from ``distance`` metres at an angular step of ``step`` degrees, the scanner
1.5 m above the ground. :func:`woody.dbh.measure_dbh` gets the points alone
(no scanner position, the ground found from the cloud) and its DBH is
compared with the tube's diameter. The issue's goal: stems of 5-50 cm seen
from 2-10 m within 3 %. With ``--beam`` it also gets what a single scan's
user knows besides the points: the scan's origin (the scanner position) and
the instrument's beam (exit diameter and divergence of the preset,
:meth:`tlssim.scanner.ScannerModel.beam_radius_m`), and models the widening
of thin stems' silhouettes by the footprint (:func:`woody.circles.fit_circle_beam`).

Run ``tlsbench experiment dbh-stems`` (``--quick`` for a smaller grid,
``--csv FILE`` to keep the table). ``--densities`` instead reconstructs a
one-sided 30 cm stem, 3 m tall (points drawn on its lit half with 1 mm of
noise), at 0.75, 3 and 30 pts/cm² with :func:`woody.trunk.follow_tree`
(``--plain`` adds plain cylinder following, minutes per density) and prints
the model's diameter at 1.3 m and its volume error. ``--diameters``,
``--distances``, ``--steps`` replace the grid.
"""

from __future__ import annotations

import csv
import time

import numpy as np

from scenes import scene_from_spec
from scenes.builtin import window_around
from tlssim.scanner import get_preset
from tlssim.simulate import setup_from_section, simulate
from woody.dbh import measure_dbh
from woody.errors import WoodyError

#: Scanner height above the ground, m, and stem height, m.
SCANNER_HEIGHT_M, STEM_LENGTH_M = 1.5, 2.0
DIAMETERS_M = (0.05, 0.1, 0.2, 0.3, 0.5)
DISTANCES_M = (2.0, 4.0, 7.0, 10.0)
STEPS_DEG = (0.036, 0.066)


def stem_scan(diameter_m: float, distance_m: float, step_deg: float, seed: int = 0) -> np.ndarray:
    """Points of one simulated scan of an upright stem on a ground plane.

    Parameters
    ----------
    diameter_m : float
        Stem diameter, m.
    distance_m : float
        Horizontal distance from the scanner to the stem axis, m.
    step_deg : float
        Angular step of the scan, degrees.
    seed : int
        Seed of the simulation.

    Returns
    -------
    ndarray, (n, 3)
        The returned points, m (ground at z = 0).
    """
    position = [0.0, 0.0, SCANNER_HEIGHT_M]
    spec = {"name": "stem", "scanner": {"preset": "faro-ls880", "position": position},
            "objects": [{"name": "stem", "type": "tube", "radius": diameter_m / 2, "length": STEM_LENGTH_M,
                         "material": "bark", "pose": {"translate": [distance_m, 0.0, STEM_LENGTH_M / 2]}},
                        {"name": "ground", "type": "plane", "size": [3.0, 3.0],
                         "pose": {"translate": [distance_m, 0.0, 0.0]}}]}
    scene = scene_from_spec(spec, source="dbh stem")
    stem = np.concatenate([o.vertices for o in scene.objects if o.name == "stem"])
    window = {**window_around(stem, position), "step_deg": step_deg}
    setup = setup_from_section({"preset": "faro-ls880", "position": position, "window": window})
    return simulate(scene, setup, seed=seed, progress=False).points()


def preset_beam(name: str = "faro-ls880") -> tuple[float, float]:
    """A scanner preset's beam as :func:`woody.dbh.measure_dbh` takes it.

    Parameters
    ----------
    name : str
        Preset name (:func:`tlssim.scanner.get_preset`).

    Returns
    -------
    tuple of float
        The 1/e² diameter at the exit, m, and its growth per metre of range (twice the tangent of the
        divergence half-angle), m/m.
    """
    model = get_preset(name)
    return 2.0 * model.beam_radius_m(0.0), 2.0 * (model.beam_radius_m(1.0) - model.beam_radius_m(0.0))


def run(diameters=DIAMETERS_M, distances=DISTANCES_M, steps=STEPS_DEG, seed: int = 0,
        beam: bool = False) -> list[dict]:
    """One row per (diameter, distance, step): true and measured DBH, error, arc, residual, flag, times.

    Parameters
    ----------
    diameters, distances : sequence of float
        Stem diameters and scanner distances, m.
    steps : sequence of float
        Angular steps, degrees.
    seed : int
        Seed of every simulation.
    beam : bool
        Give :func:`woody.dbh.measure_dbh` the scanner position and the preset's beam (:func:`preset_beam`).

    Returns
    -------
    list of dict
    """
    known = {"viewpoint": [0.0, 0.0, SCANNER_HEIGHT_M], "footprint": preset_beam()} if beam else {}
    rows = []
    for step in steps:
        for distance in distances:
            for diameter in diameters:
                start = time.perf_counter()
                points = stem_scan(diameter, distance, step, seed=seed)
                simulated = time.perf_counter()
                row = {"diameter_m": diameter, "distance_m": distance, "step_deg": step, "points": len(points),
                       "spacing_mm": 1e3 * distance * np.radians(step)}
                try:
                    stem = measure_dbh(points, **known)[0]
                    row.update(dbh_m=stem.dbh_m, error_pct=100 * (stem.dbh_m / diameter - 1), arc_deg=stem.arc_deg,
                               residual_mm=1e3 * stem.residual_m, fitted=stem.n_points, flag=stem.flag,
                               ground_z_mm=1e3 * stem.ground_z_m)
                except WoodyError as exc:
                    row.update(dbh_m=float("nan"), error_pct=float("nan"), flag=f"error: {exc}")
                row.update(scan_s=simulated - start, dbh_s=time.perf_counter() - simulated)
                rows.append(row)
                print(_line(row), flush=True)
    return rows


def densities(per_cm2=(0.75, 3.0, 30.0), plain: bool = False, seed: int = 1) -> list[dict]:
    """Diameter at 1.3 m and volume error of a one-sided 30 cm stem reconstructed at several densities.

    Parameters
    ----------
    per_cm2 : sequence of float
        Point densities, points per cm².
    plain : bool
        Also run plain cylinder following.
    seed : int
        Seed of the points and their noise.

    Returns
    -------
    list of dict
    """
    from woody.cylinders import follow_cylinders
    from woody.dbh import model_diameter_at
    from woody.geometry import cylinders_volume
    from woody.synthetic import sample_cylinders
    from woody.trunk import follow_tree

    stem = [{"id": 0, "parent": -1, "order": 0, "branch": 0, "start": [0, 0, 0], "end": [0, 0, 3.0],
             "radius_m": 0.15}]
    rows = []
    for density in per_cm2:
        rng = np.random.default_rng(seed)
        points = sample_cylinders(stem, density * 1e4, seed=rng, view=(-1.0, 0.0, 0.0)).points
        points[:, 0] += rng.normal(0.0, 0.001, len(points))
        for name, method in (("follow_tree", follow_tree), ("follow_cylinders", follow_cylinders))[:2 if plain else 1]:
            start = time.perf_counter()
            result = method(points)
            cylinders = result.cylinders()
            diameter = model_diameter_at(cylinders, 1.3)
            row = {"method": name, "pts_per_cm2": density, "points": len(points),
                   "diameter_m": float("nan") if diameter is None else diameter,
                   "volume_error_pct": 100 * (result.volume / cylinders_volume(stem) - 1),
                   "branches": len(result.branches), "seconds": time.perf_counter() - start}
            rows.append(row)
            print(f"{name:16s} {density:5.2f} pts/cm2 {len(points):7d} pts  D(1.3 m) {row['diameter_m']:.4f} m  "
                  f"volume {row['volume_error_pct']:+6.1f} %  {row['branches']:5d} branches  {row['seconds']:.1f} s",
                  flush=True)
    return rows


def _line(row: dict) -> str:
    return (f"{row['diameter_m'] * 100:5.0f} cm {row['distance_m']:5.1f} m {row['step_deg']:6.3f} deg "
            f"{row['spacing_mm']:5.1f} mm {row['points']:8d} pts  DBH {row['dbh_m'] * 100:7.2f} cm "
            f"{row['error_pct']:+6.2f} %  arc {row.get('arc_deg', float('nan')):5.0f} deg  "
            f"res {row.get('residual_mm', float('nan')):4.1f} mm  n {row.get('fitted', 0):6d}  "
            f"ground {row.get('ground_z_mm', float('nan')):+5.1f} mm  {row['flag']}  {row['dbh_s']:.2f} s")


def add_parser(sub) -> None:
    """Register ``dbh-stems`` with the ``tlsbench experiment`` sub-commands."""
    p = sub.add_parser("dbh-stems", help="DBH of simulated one-sided stems (5-50 cm, 2-10 m)",
                       description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="3 diameters x 2 distances x 1 step")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--beam", action="store_true",
                   help="give the DBH the scanner position and the preset's beam (footprint-aware circles)")
    p.add_argument("--diameters", default=None, help="comma-separated stem diameters, m (replace the grid's)")
    p.add_argument("--distances", default=None, help="comma-separated distances, m (replace the grid's)")
    p.add_argument("--steps", default=None, help="comma-separated angular steps, deg (replace the grid's)")
    p.add_argument("--csv", default=None, help="write the table to this CSV file")
    p.add_argument("--densities", action="store_true",
                   help="instead: a one-sided 30 cm stem reconstructed at 0.75, 3 and 30 pts/cm2")
    p.add_argument("--plain", action="store_true", help="with --densities: also plain cylinder following")
    p.set_defaults(func=run_command)


def run_command(args) -> int:
    """Run the grid (or the density study) with the parsed arguments, print one line per case and a summary."""
    if args.densities:
        densities(plain=args.plain, seed=args.seed)
        return 0
    grid = ((0.05, 0.2, 0.5), (2.0, 10.0), (0.066,)) if args.quick else (DIAMETERS_M, DISTANCES_M, STEPS_DEG)
    grid = tuple(default if given is None else tuple(float(v) for v in given.split(","))
                 for given, default in zip((args.diameters, args.distances, args.steps), grid))
    rows = run(*grid, seed=args.seed, beam=args.beam)
    errors = np.abs([r["error_pct"] for r in rows])
    within = np.nan_to_num(errors, nan=np.inf) <= 3.0
    print(f"{int(within.sum())}/{len(rows)} within 3 %; |error| median {np.nanmedian(errors):.2f} %, "
          f"max {np.nanmax(errors):.2f} %")
    if args.csv:
        with open(args.csv, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=sorted({k for r in rows for k in r}))
            writer.writeheader()
            writer.writerows(rows)
    return 0

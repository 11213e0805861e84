"""The experiments of the woody spec (Part C), rebuilt on synthetic clouds (``tlsbench experiment woody``).

Each experiment prints a table and writes ``<name>.json`` (and a plot where
one helps) under the output directory. Clouds are drawn on truth cylinders
(:mod:`woody.synthetic`), seeded; STEP runs with oracle normals and with
PCA normals (at the scale of least surface variation,
:func:`woody.normals.multiscale_normals`) oriented towards the scanner(s) that see each point, with and
without the circle re-fit ("hs" = Hough-space circles only).

- ``density`` (STEP DS1 a): cylinder r = 0.5 m, L = 2 m, 10 densities from
  14 down to 1.4 pts/cm^2 (spec D-S12), Hough cells 2 cm / 1 cm, radii 0.4-0.6 m;
- ``occlusion`` (DS1 b): visible sector 10-360 deg in 10 deg steps, 3 pts/cm^2,
  one scanner facing the sector (a ring of four where it cannot see every point);
- ``noise`` (DS1 c): uniform coordinate noise 0-5 cm, 3 pts/cm^2;
- ``tube`` (DS2): winding tapering tube, one or two views, decimation and
  noise, cells 3 cm / 1 cm, with and without a cap of 10 tuboids;
- ``conifer`` (DS3): 15 m stem with 15 cm branch stubs seen from one side;
  taper error in 10 cm bins and DBH;
- ``trees`` (Méndez M1/M2 and cross-method): apple-like and vine-like trees,
  one-sided at the paper's density (about 0.75 pts/cm^2, the monolateral
  mobile scan of the spec's C.1) and two-sided at 3 pts/cm^2; cylinder
  following scored on volume, branches, orders and topology; STEP on the
  same clouds for the limbs;
- ``directions`` (Méndez M0): axis direction of 100 random cylinder clouds
  (r = 5 cm, L = 50 cm, 200 points, 1 mm noise) by covariance, iterative
  search and normals.

Goals fixed beforehand by the project: STEP diameter error below 1 cm while
at least 40 deg of arc is visible; cylinder-following volume error within
10 % on the leafless trees.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from benchmarks.errors import BenchError
from woody.cylfit import fit_direction
from woody.cylinders import follow_cylinders
from woody.normals import multiscale_normals, pca_normals
from woody.scoring import score
from woody.step import step
from woody.synthetic import (add_noise, apple_like_tree, conifer_stem, curved_tube, sample_cylinders,
                             straight_cylinder, vine_like)

EXPERIMENTS = ("density", "occlusion", "noise", "tube", "conifer", "trees", "directions")

#: Distance of the virtual scanners from the object, m (their position only orients PCA normals).
SCANNER_DISTANCE_M = 10.0


def ring_viewpoints(points: np.ndarray, normals: np.ndarray, azimuths_deg, height_m: float = 1.0) -> np.ndarray:
    """Position of the scanner that sees each point best, among scanners on a ring around the origin.

    Parameters
    ----------
    points : ndarray
        Point coordinates, m, shape ``(n, 3)``.
    normals : ndarray
        Unit normal of each point, shape ``(n, 3)``.
    azimuths_deg : array_like
        Azimuth of each scanner on the ring, degrees; the ring's radius is
        :data:`SCANNER_DISTANCE_M`.
    height_m : float
        Height of the scanners, m.

    Returns
    -------
    ndarray
        The chosen scanner position per point, m, shape ``(n, 3)``.
    """
    az = np.radians(np.asarray(azimuths_deg, float))
    scanners = np.column_stack([SCANNER_DISTANCE_M * np.cos(az), SCANNER_DISTANCE_M * np.sin(az),
                                np.full(len(az), height_m)])
    sight = scanners[None, :, :] - points[:, None, :]
    sight /= np.linalg.norm(sight, axis=2, keepdims=True)
    return scanners[np.argmax(np.einsum("nsi,ni->ns", sight, normals), axis=1)]


def _step_runs(cloud, points, viewpoints, truth, variants=(("oracle", False), ("oracle", True), ("pca", False),
                                                            ("pca", True)), **kwargs) -> list[dict]:
    """STEP with oracle and PCA normals, Hough-only and re-fitted circles; one scored row per variant."""
    rows = []
    for normals_kind in ("oracle", "pca"):
        if all(kind != normals_kind for kind, _ in variants):
            continue
        normals = cloud.normals if normals_kind == "oracle" else multiscale_normals(points, 16, viewpoints)[0]
        for refine in (False, True):
            if (normals_kind, refine) not in variants:
                continue
            start = time.perf_counter()
            result = step(points, normals, refine=refine, **{"normal_levels": 4, **kwargs})
            elapsed = time.perf_counter() - start
            s = score(truth, result.cylinders(), min_tolerance_m=2 * kwargs.get("cell_m", 0.02))
            rows.append({"normals": normals_kind, "circles": "refit" if refine else "hs", "points": len(points),
                         "tuboids": len(result.tuboids), "diameter_bias_cm": 100 * s["diameter_error_m"]["bias"],
                         "diameter_mae_cm": 100 * s["diameter_error_m"]["mae"],
                         "diameter_max_cm": 100 * s["diameter_error_m"]["max"],
                         "radius_mae_cm": 100 * s["radius_error_m"]["mae"], "completeness": s["completeness"],
                         "precision": s["precision"], "time_s": elapsed, "taper": s["taper"]})
    return rows


def _cylinder_kwargs() -> dict:
    return {"cell_m": 0.02, "radius_step_m": 0.01, "r_min_m": 0.40, "r_max_m": 0.60}


def exp_density(quick: bool, seed: int) -> list[dict]:
    """STEP on a straight cylinder at 10 point densities (DS1 a); one scored row per density and variant.

    Parameters
    ----------
    quick : bool
        Run two densities only (a smoke test).
    seed : int
        Seed of the sampled clouds.

    Returns
    -------
    list of dict
        Rows with the density (pts/cm^2) and the diameter errors (cm).
    """
    levels = np.geomspace(14.0, 1.4, 10) if not quick else np.array([3.0, 1.4])
    truth = {"cylinders": straight_cylinder()}
    rows = []
    for level in levels:
        cloud = sample_cylinders(truth["cylinders"], level * 1e4, seed=seed)
        views = ring_viewpoints(cloud.points, cloud.normals, [0, 90, 180, 270])
        for row in _step_runs(cloud, cloud.points, views, truth, **_cylinder_kwargs()):
            rows.append({"density_pts_cm2": float(level), **row})
    return rows


def occlusion_viewpoints(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Scanners that orient the PCA normals of a cylinder seen over a sector centred on +x.

    One scanner facing the sector (on +x at :data:`SCANNER_DISTANCE_M`)
    when it sees every point, as for sectors up to about 170 deg; a wider
    sector needs scanners around it (the ring of four of
    :func:`ring_viewpoints`), or the normals of the far side are oriented
    inwards and STEP's snakes wander (the 350 deg sector took minutes per
    run instead of a second).

    Parameters
    ----------
    points, normals : ndarray
        Points (m) and their true unit normals, shape ``(n, 3)``.

    Returns
    -------
    ndarray
        Scanner position per point, m, shape ``(n, 3)``.
    """
    scanner = np.array([SCANNER_DISTANCE_M, 0.0, 1.0])
    if np.all(np.einsum("ni,ni->n", scanner - points, normals) > 0):
        return np.broadcast_to(scanner, points.shape)
    return ring_viewpoints(points, normals, [0, 90, 180, 270])


def exp_occlusion(quick: bool, seed: int) -> list[dict]:
    """STEP on a straight cylinder with a visible sector of 10 to 360 deg (DS1 b); one row per arc and variant.

    Parameters
    ----------
    quick : bool
        Run five arcs only (a smoke test).
    seed : int
        Seed of the sampled clouds.

    Returns
    -------
    list of dict
        Rows with the visible arc (``arc_deg``, degrees) and the diameter errors (cm).
    """
    arcs = np.arange(10, 361, 10) if not quick else np.array([10, 40, 90, 180, 360])
    truth = {"cylinders": straight_cylinder()}
    rows = []
    for arc in arcs:
        cloud = sample_cylinders(truth["cylinders"], 3e4, seed=seed, arc_deg=float(arc))
        views = occlusion_viewpoints(cloud.points, cloud.normals)
        for row in _step_runs(cloud, cloud.points, views, truth, **_cylinder_kwargs()):
            rows.append({"arc_deg": int(arc), **row})
    return rows


def exp_noise(quick: bool, seed: int, kind: str = "uniform",
              variants=(("oracle", False), ("oracle", True), ("pca", False), ("pca", True))) -> list[dict]:
    """STEP on a straight cylinder with coordinate noise of 0 to 5 cm (DS1 c); one row per level and variant.

    Parameters
    ----------
    quick : bool
        Run three noise levels only (a smoke test).
    seed : int
        Seed of the sampled cloud and noise.
    kind : {"uniform", "gaussian"}
        Noise of amplitude A per coordinate: U(-A, A) (the spec's default
        reading of the paper's "random noise", woody.md D-S13) or N(0, A^2)
        (the spec's second reading).
    variants : sequence of (str, bool)
        ``(normals, refine)`` pairs run (see :func:`_step_runs`).

    Returns
    -------
    list of dict
        Rows with the noise level A (cm), its kind and the diameter errors (cm).
    """
    levels = np.arange(0.0, 5.01, 0.5) if not quick else np.array([0.0, 1.0, 2.5])
    truth = {"cylinders": straight_cylinder()}
    cloud = sample_cylinders(truth["cylinders"], 3e4, seed=seed)
    views = ring_viewpoints(cloud.points, cloud.normals, [0, 90, 180, 270])
    rows = []
    for level in levels:
        points = add_noise(cloud.points, level / 100.0, seed=seed + 1, kind=kind)
        for row in _step_runs(cloud, points, views, truth, variants, **_cylinder_kwargs()):
            rows.append({"noise_cm": float(level), "noise_kind": kind, **row})
    return rows


def exp_tube(quick: bool, seed: int) -> list[dict]:
    """STEP on a winding tapering tube seen from one or two sides, decimated and noisy (DS2).

    Parameters
    ----------
    quick : bool
        Run the full-density conditions only (a smoke test).
    seed : int
        Seed of the sampled clouds and noise.

    Returns
    -------
    list of dict
        One scored row per condition and variant (errors in m).
    """
    truth = {"cylinders": curved_tube()}
    kwargs = {"cell_m": 0.03, "radius_step_m": 0.01, "r_min_m": 0.04, "r_max_m": 0.35}
    rows = []
    conditions = [("two views", 1.0, 0.0), ("one view", 1.0, 0.0)]
    if not quick:
        conditions += [("two views", f, 0.0) for f in (0.75, 0.5, 0.25, 0.1)]
        conditions += [("two views", 1.0, a) for a in (0.01, 0.02, 0.03, 0.04)]
    for views_kind, keep, noise in conditions:
        view = None if views_kind == "two views" else (1.0, 0.0, 0.0)
        cloud = sample_cylinders(truth["cylinders"], 3e4 * keep, seed=seed, view=view)
        azimuths = [0, 180] if view is None else [0]
        viewpoints = ring_viewpoints(cloud.points, cloud.normals, azimuths, height_m=1.5)
        points = add_noise(cloud.points, noise, seed=seed + 1)
        for cap in (None, 10):
            for row in _step_runs(cloud, points, viewpoints, truth, variants=(("pca", True),), max_tuboids=cap,
                                  **kwargs):
                rows.append({"views": views_kind, "kept": keep, "noise_cm": 100 * noise, "cap": cap or 0, **row})
    return rows


def exp_conifer(quick: bool, seed: int) -> list[dict]:
    """STEP on a conifer stem with branch stubs seen from one side (DS3): taper error and DBH.

    Parameters
    ----------
    quick : bool
        Use a 6 m stem instead of 15 m (a smoke test).
    seed : int
        Seed of the stem and its sampled cloud.

    Returns
    -------
    list of dict
        One scored row per variant (errors in m).
    """
    height = 6.0 if quick else 15.0
    truth = {"cylinders": conifer_stem(height_m=height, seed=seed)}
    cloud = sample_cylinders(truth["cylinders"], 1e4, seed=seed, view=(1.0, 0.0, 0.0))
    views = ring_viewpoints(cloud.points, cloud.normals, [0], height_m=1.5)
    rows = []
    for row in _step_runs(cloud, cloud.points, views, truth, cell_m=0.02, radius_step_m=0.01, r_min_m=0.02,
                          r_max_m=0.25):
        bins = row["taper"]["bins"]
        dbh = [b for b in bins if abs(b["height_m"] - 1.3) < 0.051]
        rows.append({**row, "taper_ok_height_m": row["taper"]["taper_ok_height_m"],
                     "dbh_error_cm": 100 * dbh[0]["diameter_error_m"] if dbh and dbh[0]["diameter_error_m"] is not None
                     else None})
    return rows


def exp_trees(quick: bool, seed: int) -> list[dict]:
    """Cylinder following and STEP on apple-like and vine-like trees, one- and two-sided sampling.

    Parameters
    ----------
    quick : bool
        Run cylinder following only, without STEP (a smoke test).
    seed : int
        Seed of the trees and their sampled clouds.

    Returns
    -------
    list of dict
        One row per tree, sampling and method (``volume_error_pct`` signed, %; times in s).
    """
    rows = []
    trees = {"apple-like": apple_like_tree(seed), "vine-like": vine_like(seed)}
    samplings = {"one side 0.75 pts/cm2": (0.75e4, (1.0, 0.0, 0.0)), "two sides 3 pts/cm2": (3e4, None)}
    for name, cylinders in trees.items():
        truth = {"cylinders": cylinders}
        for label, (density, view) in samplings.items():
            cloud = sample_cylinders(cylinders, density, seed=seed, view=view)
            for mode, overrides in (("spec", {}), ("paper", PAPER_MODE)):
                start = time.perf_counter()
                result = follow_cylinders(cloud.points, **overrides)
                elapsed = time.perf_counter() - start
                s = score(truth, result.cylinders())
                topo = s["topology"] or {}
                rows.append({"tree": name, "sampling": label, "method": f"cylinders ({mode})",
                             "points": len(cloud.points), "volume_error_pct": 100 * s["volume_error"],
                             "volume_true_dm3": 1e3 * s["volume_true_m3"], "branches_rec": topo.get("branches_rec"),
                             "branches_true": topo.get("branches_true"), "max_order_rec": topo.get("max_order_rec"),
                             "max_order_true": topo.get("max_order_true"), "edge_recall": topo.get("edge_recall"),
                             "completeness": s["completeness"], "radius_bias_mm": 1e3 * s["radius_error_m"]["bias"],
                             "time_s": elapsed})
            if quick:
                continue
            start = time.perf_counter()
            viewpoints = ring_viewpoints(cloud.points, cloud.normals, [0] if view else [0, 180])
            result = step(cloud.points, pca_normals(cloud.points, 16, viewpoints),
                          cell_m=0.02, radius_step_m=0.005, r_min_m=0.01, r_max_m=0.05)
            elapsed = time.perf_counter() - start
            s = score(truth, result.cylinders())
            rows.append({"tree": name, "sampling": label, "method": "step (pca)", "points": len(cloud.points),
                         "volume_error_pct": 100 * s["volume_error"], "volume_true_dm3": 1e3 * s["volume_true_m3"],
                         "branches_rec": len(result.tuboids), "completeness": s["completeness"],
                         "radius_bias_mm": 1e3 * s["radius_error_m"]["bias"], "time_s": elapsed})
    return rows


#: Cylinder following read literally from the paper (see woody.cylinders for each choice).
PAPER_MODE = {"direction": "covariance", "axis": "centroid", "inclusion": "max", "radius": "max",
              "mode": "faithful", "section_radii": 0.0, "min_branch_points": 1}


def exp_directions(quick: bool, seed: int, noise_m: float = 0.001, arc_deg: float = 360.0,
                   estimators=("covariance", "iterative", "normals")) -> list[dict]:
    """Axis direction of random cylinder clouds by covariance, iterative search and normals (Méndez M0).

    Each cloud: 200 points on a cylinder of radius 5 cm and length 50 cm (our
    choices: the paper states none of them).

    Parameters
    ----------
    quick : bool
        Use 20 clouds instead of 100 (a smoke test).
    seed : int
        Seed of the directions and clouds.
    noise_m : float
        S.d. of the Gaussian noise added to each coordinate, m.
    arc_deg : float
        Visible sector about the axis, deg (360: the whole circumference).
    estimators : sequence of str
        Which of ``covariance``, ``iterative`` and ``normals`` to run.

    Returns
    -------
    list of dict
        One row per method: angular errors (degrees) and run time (s).
    """
    rng = np.random.default_rng(seed)
    count = 20 if quick else 100
    errors = {key: [] for key in estimators}
    times = {key: 0.0 for key in errors}
    for _ in range(count):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        start, end = -0.25 * d, 0.25 * d
        cyl = [{"start": start.tolist(), "end": end.tolist(), "radius_m": 0.05, "radius_end_m": 0.05}]
        area = 2 * np.pi * 0.05 * 0.5 * arc_deg / 360.0
        cloud = sample_cylinders(cyl, 200 / area, seed=int(rng.integers(2 ** 31)), arc_deg=arc_deg)
        points = add_noise(cloud.points, noise_m, seed=int(rng.integers(2 ** 31)), kind="gaussian")
        for method in errors:
            clock = time.perf_counter()
            if method == "normals":
                normals = pca_normals(points, 10)
                axis = np.linalg.eigh(normals.T @ normals)[1][:, 0]
            else:
                axis = fit_direction(points, method)
            times[method] += time.perf_counter() - clock
            errors[method].append(np.degrees(np.arccos(min(abs(axis @ d), 1.0))))
    return [{"estimator": m, "clouds": count, "angle_mean_deg": float(np.mean(e)), "angle_sd_deg": float(np.std(e)),
             "ms_per_call": 1e3 * times[m] / count} for m, e in errors.items()]


_RUNNERS = {"density": exp_density, "occlusion": exp_occlusion, "noise": exp_noise, "tube": exp_tube,
            "conifer": exp_conifer, "trees": exp_trees, "directions": exp_directions}

_COLUMNS = {
    "density": ["density_pts_cm2", "normals", "circles", "points", "tuboids", "diameter_bias_cm", "diameter_mae_cm",
                "diameter_max_cm", "completeness", "time_s"],
    "occlusion": ["arc_deg", "normals", "circles", "points", "tuboids", "diameter_bias_cm", "diameter_mae_cm",
                  "diameter_max_cm", "completeness", "time_s"],
    "noise": ["noise_cm", "normals", "circles", "tuboids", "diameter_bias_cm", "diameter_mae_cm", "diameter_max_cm",
              "completeness", "time_s"],
    "tube": ["views", "kept", "noise_cm", "cap", "points", "tuboids", "radius_mae_cm", "completeness", "precision",
             "time_s"],
    "conifer": ["normals", "circles", "points", "tuboids", "diameter_bias_cm", "diameter_mae_cm", "dbh_error_cm",
                "taper_ok_height_m", "completeness", "time_s"],
    "trees": ["tree", "sampling", "method", "points", "volume_true_dm3", "volume_error_pct", "branches_rec",
              "branches_true", "max_order_rec", "max_order_true", "edge_recall", "completeness", "radius_bias_mm",
              "time_s"],
    "directions": ["estimator", "clouds", "angle_mean_deg", "angle_sd_deg", "ms_per_call"],
}


def format_table(rows: list[dict], columns: list[str]) -> str:
    """Rows as a fixed-width text table (floats with 3 significant decimals).

    Parameters
    ----------
    rows : list of dict
        Table rows.
    columns : list of str
        Keys to show, in order; a missing or ``None`` value shows as ``-``.

    Returns
    -------
    str
        The table, one line per row under a header.
    """
    def cell(value):
        if value is None:
            return "-"
        if isinstance(value, float):
            return f"{value:.3g}" if abs(value) < 1e4 else f"{value:.0f}"
        return str(value)

    table = [[cell(r.get(c)) for c in columns] for r in rows]
    widths = [max(len(c), *(len(t[i]) for t in table)) if table else len(c) for i, c in enumerate(columns)]
    lines = ["  ".join(c.rjust(w) for c, w in zip(columns, widths))]
    lines += ["  ".join(v.rjust(w) for v, w in zip(t, widths)) for t in table]
    return "\n".join(lines)


def goal_lines(name: str, rows: list[dict]) -> list[str]:
    """The project's goals checked on an experiment's rows (empty for experiments without a goal).

    ``occlusion``, ``density``, ``noise``: STEP diameter MAE below 1 cm
    (for occlusion: on the arcs of 40 deg and more), per normals/circles
    variant, with the worst case; ``trees``: cylinder-following |volume
    error| within 10 %, per tree, sampling and mode.

    Parameters
    ----------
    name : str
        Experiment name (one of :data:`EXPERIMENTS`).
    rows : list of dict
        The experiment's rows (``diameter_mae_cm`` in cm, ``volume_error_pct`` in %).

    Returns
    -------
    list of str
        One line per checked goal, "met" or "NOT met" with the worst case.
    """
    lines = []
    if name in ("occlusion", "density", "noise"):
        for normals in ("oracle", "pca"):
            for circles in ("hs", "refit"):
                sel = [r for r in rows if r["normals"] == normals and r["circles"] == circles
                       and (name != "occlusion" or r["arc_deg"] >= 40)]
                if not sel:
                    continue
                worst = max(sel, key=lambda r: r["diameter_mae_cm"])
                key = {"occlusion": "arc_deg", "density": "density_pts_cm2", "noise": "noise_cm"}[name]
                verdict = "met" if worst["diameter_mae_cm"] < 1.0 else "NOT met"
                lines.append(f"goal diameter MAE < 1 cm{' (arc >= 40 deg)' if name == 'occlusion' else ''}, "
                             f"{normals} normals, {circles}: {verdict}; worst {worst['diameter_mae_cm']:.2f} cm "
                             f"at {key} = {worst[key]:g}")
    elif name == "trees":
        for r in rows:
            if r["method"].startswith("cylinders"):
                verdict = "met" if abs(r["volume_error_pct"]) <= 10.0 else "NOT met"
                lines.append(f"goal |volume error| <= 10 %, {r['tree']}, {r['sampling']}, {r['method']}: {verdict} "
                             f"({r['volume_error_pct']:+.1f} %)")
    return lines


def _plot(name: str, rows: list[dict], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes_key = {"density": "density_pts_cm2", "occlusion": "arc_deg", "noise": "noise_cm"}.get(name)
    if axes_key:
        fig, ax = plt.subplots(figsize=(6, 4))
        for normals in ("oracle", "pca"):
            for circles in ("hs", "refit"):
                sel = [r for r in rows if r["normals"] == normals and r["circles"] == circles]
                ax.plot([r[axes_key] for r in sel], [r["diameter_mae_cm"] for r in sel], marker="o",
                        label=f"{normals} normals, {circles}")
        ax.axhline(1.0, color="grey", ls="--", lw=1, label="goal 1 cm")
        ax.set_xlabel(axes_key)
        ax.set_ylabel("diameter MAE, cm")
        ax.set_yscale("log")
        ax.set_title(f"STEP, cylinder r = 0.5 m: {name}")
        ax.legend(fontsize=7)
    elif name == "conifer":
        fig, ax = plt.subplots(figsize=(6, 4))
        for r in rows:
            bins = [b for b in r["taper"]["bins"] if b["diameter_error_m"] is not None]
            ax.plot([100 * b["diameter_error_m"] for b in bins], [b["height_m"] for b in bins],
                    label=f"{r['normals']} normals, {r['circles']}")
        ax.axvline(0, color="grey", lw=1)
        ax.set_xlabel("diameter error, cm")
        ax.set_ylabel("height, m")
        ax.set_title("STEP taper error, conifer stem")
        ax.legend(fontsize=7)
    else:
        return
    fig.tight_layout()
    fig.savefig(out / f"{name}.png", dpi=120)
    plt.close(fig)


def run_all(out: Path, only=None, quick: bool = False, seed: int = 0) -> dict:
    """Run the selected experiments, print their tables, write JSON and plots under ``out``.

    Parameters
    ----------
    out : Path
        Output folder (created if missing).
    only : iterable of str or None
        Experiments to run; ``None`` for all of :data:`EXPERIMENTS`.
    quick : bool
        Smoke-test sizes.
    seed : int
        Seed of every experiment.

    Returns
    -------
    dict
        Rows per experiment name.
    """
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for name in only or EXPERIMENTS:
        start = time.perf_counter()
        rows = _RUNNERS[name](quick, seed)
        results[name] = rows
        print(f"\n== {name} ({time.perf_counter() - start:.0f} s)")
        print(format_table(rows, _COLUMNS[name]))
        for line in goal_lines(name, rows):
            print(line)
        (out / f"{name}.json").write_text(json.dumps(rows, indent=1, default=float))
        _plot(name, rows, out)
    return results


def add_parser(sub) -> None:
    """Register ``woody`` with the ``tlsbench experiment`` sub-commands."""
    p = sub.add_parser("woody", help="the woody experiments (tables, JSON, plots)",
                       description="Cylinder sweeps (density, occlusion, noise), curved tube, conifer stem, "
                                   "apple-like and vine-like trees.")
    p.add_argument("-o", "--output", default="woody-experiments", help="output directory")
    p.add_argument("--only", default=None, help=f"comma-separated subset of: {', '.join(EXPERIMENTS)}")
    p.add_argument("--quick", action="store_true", help="fewer levels and lower densities (a smoke run)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=run)


def run(args) -> int:
    """Run the selected experiments with the parsed arguments."""
    only = None if args.only is None else [name.strip() for name in args.only.split(",") if name.strip()]
    unknown = sorted(set(only or []) - set(EXPERIMENTS))
    if unknown:
        raise BenchError(f"unknown experiment(s) {unknown}; choose from {', '.join(EXPERIMENTS)}")
    run_all(Path(args.output), only=only, quick=args.quick, seed=args.seed)
    return 0

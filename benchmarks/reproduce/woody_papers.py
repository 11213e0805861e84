"""STEP (Ravaglia et al. 2017) DS1-DS3 and Méndez et al. Tables 6, 8 and Fig. 4, on the woody experiments.

The clouds and runs are those of :mod:`benchmarks.experiments.woody_experiments`
(synthetic clouds on truth cylinders); this module turns their rows into
reproduction rows. Both papers show their results as figures, or keep them
out of the spec (Table 6 and Table 8 results are held back, woody.md
B.11): the published column is empty except for the inputs Table 8 does
state, and the rows test what the papers' text claims. Where no claim
exists, the project's goal fixed beforehand (diameter error below 1 cm
while at least 40 deg of arc is visible) is tested and named as such.
DS4 (the SimpleTree open data) needs real clouds that are not in the
project and is not reproduced. Every experiment but Table 6 is heavy
(minutes even in its quick form): ``--quick`` runs them only when named.
"""

from __future__ import annotations

import numpy as np

from benchmarks.experiments import woody_experiments as woody
from benchmarks.reproduce.core import Row, register

GOAL = "project goal (woody_experiments: STEP diameter MAE below 1 cm); the paper's DS1 figure is held back"
#: Table 8 of Méndez et al.: model properties of the simulated trees (points, order, volume dm^3).
TABLE8 = {"apple-like": ("Apple tree (simulated)", 2350, 7, 2.80), "vine-like": ("Vine (simulated)", 4941, 10, 6.83)}


def _step_rows(rows: list[dict], key: str, unit: str, goal_from: float = -np.inf) -> list[Row]:
    out = []
    for r in rows:
        variant = f"{r['normals']} normals, {'refit' if r['circles'] == 'refit' else 'Hough'}"
        x = float(r[key])
        holds = bool(r["diameter_mae_cm"] < 1.0) if x >= goal_from else None
        out.append(Row(f"{variant}/{key} {x:g}", "diameter MAE", "cm", r["diameter_mae_cm"], x=x, series=variant,
                       source=GOAL if holds is not None else "ours (paper's figure held back)",
                       claim="diameter MAE below 1 cm" if holds is not None else "", holds=holds,
                       note=f"{unit}; {r['tuboids']} tuboid(s), completeness {r['completeness']:.2f}"))
    return out


@register("step-ds1a", "STEP DS1 (a), Fig. 4: radius error against point density",
          description="Cylinder r = 0.5 m, L = 2 m, 10 densities 14-1.4 pts/cm^2, Hough cells 2 cm / 1 cm, "
                      "oracle and PCA normals, Hough-space and re-fitted circles.",
          findings="The paper's radius errors are in a figure kept out of the spec; our rows test the project's "
                   "goal instead (named as such in each row).", heavy=True)
def ds1a(quick: bool, seed: int) -> list[Row]:
    """Rows of DS1 (a) (diameter MAE per density and variant).

    Parameters
    ----------
    quick : bool
        Two densities.
    seed : int
        Seed of the clouds.
    """
    return _step_rows(woody.exp_density(quick, seed), "density_pts_cm2", "pts/cm^2")


@register("step-ds1b", "STEP DS1 (b), Fig. 4: radius error against the visible sector (occlusion)",
          description="Cylinder r = 0.5 m seen over a sector of 10-360 deg, 3 pts/cm^2.",
          findings="Below 40 deg of arc a circle is poorly constrained (the project's goal starts at 40 deg); the "
                   "narrow arcs are reported, not judged.", heavy=True)
def ds1b(quick: bool, seed: int) -> list[Row]:
    """Rows of DS1 (b) (diameter MAE per visible arc and variant; judged from 40 deg).

    Parameters
    ----------
    quick : bool
        Five arcs.
    seed : int
        Seed of the clouds.
    """
    return _step_rows(woody.exp_occlusion(quick, seed), "arc_deg", "deg of arc", goal_from=40.0)


@register("step-ds1c", "STEP DS1 (c), Fig. 4: diameter error against coordinate noise 0-5 cm",
          description="Cylinder r = 0.5 m, 3 pts/cm^2, uniform coordinate noise 0-5 cm (0-10 % of the radius).",
          findings="The paper's figure is held back; the rows test the project's goal.", heavy=True)
def ds1c(quick: bool, seed: int) -> list[Row]:
    """Rows of DS1 (c) (diameter MAE per noise level and variant).

    Parameters
    ----------
    quick : bool
        Three noise levels.
    seed : int
        Seed of the cloud and noise.
    """
    return _step_rows(woody.exp_noise(quick, seed), "noise_cm", "cm of noise")


@register("step-ds2", "STEP DS2, Figs 5-7: complex tube, one or two views, decimation and noise",
          description="Winding tapering tube, front/back views, decimated to 75-10 % and with 1-4 cm noise, with "
                      "and without a cap of 10 tuboids (PCA normals, re-fitted circles).",
          findings="Results are figures in the paper; the row tests its statement that two-view clouds are more "
                   "resilient than single-view ones (completeness and radius error).", heavy=True)
def ds2(quick: bool, seed: int) -> list[Row]:
    """Rows of DS2 (radius MAE and completeness per condition; the two-view claim).

    Parameters
    ----------
    quick : bool
        Full-density conditions only.
    seed : int
        Seed of the clouds and noise.
    """
    rows = woody.exp_tube(quick, seed)
    out = []
    for r in rows:
        label = f"{r['views']}/kept {r['kept']:g}/noise {r['noise_cm']:g} cm/cap {r['cap']}"
        out.append(Row(label, "radius MAE", "cm", r["radius_mae_cm"], x=100 * r["kept"] - r["noise_cm"],
                       series=f"{r['views']}, cap {r['cap']}", source="ours (paper's figures)",
                       note=f"completeness {r['completeness']:.2f}, {r['tuboids']} tuboids"))
    full = {r["views"]: r for r in rows if r["kept"] == 1.0 and r["noise_cm"] == 0 and r["cap"] == 0}
    if {"one view", "two views"} <= set(full):
        one, two = full["one view"], full["two views"]
        out.append(Row("two views more resilient", "completeness", "fraction", two["completeness"],
                       source="STEP DS2 text", holds=bool(two["completeness"] >= one["completeness"]
                                                           and two["radius_mae_cm"] <= one["radius_mae_cm"]),
                       claim="two-view clouds are more resilient than single-view ones (completeness at least as "
                             "high, radius error no higher)",
                       note=f"one view: completeness {one['completeness']:.2f}, radius MAE "
                            f"{one['radius_mae_cm']:.2f} cm; two views: {two['radius_mae_cm']:.2f} cm"))
    return out


@register("step-ds3", "STEP DS3, Fig. 8: conifer stem taper seen from one side",
          description="A 15 m conifer stem with 15 cm branch stubs sampled from one side; taper error in 10 cm bins "
                      "and the DBH.",
          findings="The paper's taper error (with its 0.4 cm bark bias) is a figure kept out of the spec; the row "
                   "tests its statement that accuracy falls in the upper stem.", heavy=True)
def ds3(quick: bool, seed: int) -> list[Row]:
    """Rows of DS3 (DBH error, taper-ok height, the upper-stem claim).

    Parameters
    ----------
    quick : bool
        A 6 m stem.
    seed : int
        Seed of the stem and cloud.
    """
    out = []
    for r in woody.exp_conifer(quick, seed):
        variant = f"{r['normals']} normals, {'refit' if r['circles'] == 'refit' else 'Hough'}"
        bins = [b for b in r["taper"]["bins"] if b["diameter_error_m"] is not None]
        heights = np.array([b["height_m"] for b in bins])
        errors = np.abs([b["diameter_error_m"] for b in bins]) * 100
        out.append(Row(f"{variant}/DBH error", "DBH error", "cm", r["dbh_error_cm"] if r["dbh_error_cm"] is not None
                       else float("nan"), series=variant, source="ours (paper's figure)"))
        if len(bins) >= 4:
            middle = np.median(heights)
            low, high = float(errors[heights <= middle].mean()), float(errors[heights > middle].mean())
            out.append(Row(f"{variant}/upper stem worse", "mean |diameter error|, upper half", "cm", high,
                           series=variant, source="STEP DS3 text", holds=high > low,
                           claim="accuracy falls in the upper stem (occlusions, mixed points)",
                           note=f"lower half {low:.2f} cm"))
    return out


@register("mendez-table6", "Méndez et al. Table 6: axis direction by covariance against iterative search",
          description="100 random cylinder clouds (r = 5 cm, L = 50 cm, 200 points, 1 mm noise: our choices, the "
                      "paper does not state them); angle between the true and the estimated axis, and time per call.",
          findings="Table 6's values are held back from the spec: ours only, for a comparison by hand.")
def table6(quick: bool, seed: int) -> list[Row]:
    """Rows of Table 6 (mean and s.d. of the angle error, time per call, per estimator).

    Parameters
    ----------
    quick : bool
        20 clouds.
    seed : int
        Seed of the directions and clouds.
    """
    out = []
    for r in woody.exp_directions(quick, seed):
        for key, quantity, unit in (("angle_mean_deg", "mean angle error", "deg"),
                                    ("angle_sd_deg", "s.d. of angle error", "deg"),
                                    ("ms_per_call", "time per call", "ms")):
            out.append(Row(f"{r['estimator']}/{quantity}", quantity, unit, r[key], series=r["estimator"],
                           source="Méndez Table 6 (values held back)"))
    return out


@register("mendez-table8", "Méndez et al. Table 8: cylinder following on the simulated apple tree and vine",
          description="Apple-like and vine-like synthetic trees (woody.synthetic), one side at about 0.75 pts/cm^2 "
                      "(the monolateral mobile scan) and two sides at 3 pts/cm^2; cylinder following as the spec "
                      "reads it and literally as printed ('paper' mode).",
          findings="Table 8's results are held back; its model properties are compared to show how far our "
                   "synthetic trees are from the paper's SIMLIDAR trees (the scene, not the method). The paper's "
                   "text reports over-branching and an over-estimated volume; the claim rows test that on ours.", heavy=True)
def table8(quick: bool, seed: int) -> list[Row]:
    """Rows of Table 8 (model properties, volume error, branches; the over-branching claim).

    Parameters
    ----------
    quick : bool
        Cylinder following only (no STEP on the trees).
    seed : int
        Seed of the trees and clouds.
    """
    out = []
    seen = set()
    for r in woody.exp_trees(quick, seed):
        label = f"{r['tree']}/{r['sampling']}/{r['method']}"
        out.append(Row(f"{label}/volume error", "volume error", "%", r["volume_error_pct"], series=r["method"],
                       source="ours (Table 8 values held back)", note=f"{r.get('branches_rec')} branches rebuilt, "
                       f"{r.get('branches_true')} true"))
        if r["method"] == "cylinders (paper)" and r.get("branches_true"):
            out.append(Row(f"{label}/over-branching and volume over-estimate", "claim", "%", r["volume_error_pct"],
                           source="Méndez sec. Results (Table 8 discussion)", series=r["method"],
                           holds=bool(r["volume_error_pct"] > 0 and r["branches_rec"] > r["branches_true"]),
                           claim="more branches than the model and an over-estimated total volume"))
        if r["tree"] in TABLE8 and r["tree"] not in seen:
            seen.add(r["tree"])
            name, _, order, volume = TABLE8[r["tree"]]
            out.append(Row(f"{r['tree']}/model volume", "model volume", "dm^3", r["volume_true_dm3"], volume,
                           0.5 * volume, "50 %: a tree of the same size class (the paper's SIMLIDAR tree is not "
                           "available; this compares the scene, not the method)", f"Méndez Table 8, {name}"))
            if r.get("max_order_true") is not None:
                out.append(Row(f"{r['tree']}/model order", "model order", "", float(r["max_order_true"]),
                               float(order), 2.0, "2 orders: same branching depth class (scene, not method)",
                               f"Méndez Table 8, {name}"))
    return out

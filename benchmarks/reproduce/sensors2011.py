"""Balduzzi et al. 2011 (Sensors 11(2):1657): Table 2, the goniometer curve and the inversion precision.

The panel series (seven reflectances at the 14 distances of the paper) and
the goniometer (a leaf on a 3 % board at 2.16 m, 0-85 deg) are simulated
with the ``faro-ls880`` preset by
:func:`benchmarks.experiments.calibration.simulate_tables`; Table 2's
columns are measured with :func:`leafsfs.calibration.panel_statistics`.
The paper's two 3 % materials (Canson paper and paint) are both compared
with our single 3 % panel.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

import scenes
from benchmarks.experiments.calibration import simulate_tables, simulated_calibration
from benchmarks.reproduce.core import OUTSIDE, Row, register
from leafsfs.calibration import fit_calibration, panel_statistics, reference_curve_from_table
from scenes.builtin import window_around
from scenes.scenefile import scene_from_spec
from tlssim.calibration import patch_incidence
from tlssim.scanner import get_preset
from tlssim.simulate import setup_from_section, simulate

SOURCE = "Sensors 2011 Table 2"
#: Table 2 of the paper: material, reflectance, mean shift, s.d. of shift, raw DN at 3.56 m, RMSE after correction.
TABLE2 = (("83 % Canson", 0.83, 30.24, 3.90, 1749.0, 2.98), ("80 % Canson", 0.80, 27.84, 4.88, 1750.0, 2.50),
          ("68 % Canson", 0.68, 79.07, 5.76, 1705.0, 1.60), ("48 % Canson", 0.48, 169.55, 5.36, 1619.0, 3.66),
          ("22 % grey card", 0.22, 399.30, 29.87, 1408.0, 11.49), ("3 % Canson", 0.03, 884.93, 49.66, 839.0, 21.52),
          ("3 % paint", 0.03, 961.55, 34.09, 935.0, 11.49))
#: f99(d_ref) of the paper's distance correction, DN (Sensors 2011, distance-correction section).
F99_REF_DN = 1781.45
#: Validity limit of the intensity-to-incidence inversion, deg (Sensors 2011 / thesis ch.6: 55-60 deg).
INVERSION_LIMIT_DEG = 60.0
#: Precision of the inversion below the limit, deg (issue 12's reading of the paper; the measured figure is held back).
INVERSION_PRECISION_DEG = 5.0
#: Largest power share from other objects of a return kept as "pure" on the in-situ leaves. A share f from a surface
#: dr behind moves a phase-shift range by about f dr, so keeping f dr below the ~2 mm range noise for the wall 1 m
#: behind the built-in leaves needs f < 0.002 (an assumption from the mixing model, tls-physics §2.9). The edge pulses
#: with one outer sub-ray on the wall carry f = 0.050-0.076 and 5 cm of range error.
PURE_MAX_MIXED = 0.002

_SHIFT_TOL = ("2 x the published s.d. of the shift (column ii): the published mean is itself spread that much "
              "over distance")
_RMSE_TOL = ("4 DN for rho >= 48 %, 10 DN below (the paper's own quality bounds: < 4 DN for rho > 48 %, "
             "> 10 DN for rho < 22 %)")
_SD_TOL = "50 % of the published value (a spread is known to within a factor, not a DN)"
#: Why a Table 2 row is outside, by column (modelling assumptions, measured: the experiment's findings).
_TABLE2_WHY = {"mean shift": "modelling assumption: one log-amplifier gain k for every material (the paper's "
                             "per-material k is 131-211 DN), so the 83-48 % shifts come out too large (findings)",
               "raw at 3.56 m": "modelling assumption: raw = f99(3.56 m) - shift, so column (i)'s one-gain offset "
                                "(findings); for the 3 % paint, one Lambertian 3 % material modelled",
               "shift s.d.": "modelling assumption: the curves are exact vertical translations in the model, so the "
                             "shift hardly varies with distance (0.3-2 DN against 4-50; findings)",
               "corrected RMSE": "modelling assumption: exact translations, so the correction leaves almost nothing "
                                 "(the real targets' departures are not modelled; findings)"}


@register("sensors2011-table2", "Sensors 2011 Table 2: seven materials, intensity against distance",
          description="Simulated panel series (faro-ls880 preset, 14 distances 0.35-10 m), the 99 % curve fitted "
                      "piecewise, and the four columns of Table 2 per material: (i) mean shift below the 99 % curve "
                      "beyond 1 m, (ii) its s.d. over distance, (iii) raw DN at 3.56 m, (iv) RMSE of the corrected "
                      "intensity beyond 1 m.",
          findings="Columns (i) and (iii): the simulator's intensity is I = C + k ln(rho cos a g(d)) with one gain "
                   "k = 263 DN per e-fold fitted on the whole table (tls-physics A.2, a modelling assumption); a "
                   "single k cannot give the paper's 83/80/68 % papers (their per-material k is 131-211) and its "
                   "48 % one at once, so the high-reflectance shifts come out 16-28 DN too large. Column (ii) and "
                   "the low-reflectance column (iv): in the model the curves are exact vertical translations and "
                   "each panel value is a mean over hundreds of returns, so the shift hardly varies with distance "
                   "(0.3-2 DN against the paper's 4-50 DN); the real targets' departures from a translation "
                   "(non-Lambertian papers, the attenuator's reflectance dependence) are not modelled. Column "
                   "(iii) follows (i) at one distance (raw = f99(3.56 m) - shift), so the 83-48 % papers' raw "
                   "values are 15-29 DN low for the same reason; the paper's two 3 % materials differ by 96 DN at "
                   "3.56 m (Canson 839, paint 935) where the model has one 3 % panel (859 DN, near the Canson): the "
                   "paint row is outside for that (one Lambertian 3 % material modelled, an assumption).")
def table2(quick: bool, seed: int) -> list[Row]:
    """Rows of Table 2 (four columns per material and the 99 % reference value).

    Parameters
    ----------
    quick : bool
        Unused: the panel series is small (about 10 s).
    seed : int
        Seed of the simulation.
    """
    panels, _ = simulate_tables(get_preset("faro-ls880"), seed)
    curve = reference_curve_from_table(panels)
    stats = panel_statistics(panels, curve)
    rows = [Row("99 %/raw at 3.56 m", "raw DN at 3.56 m", "DN", float(curve(curve.reference_distance_m)),
                F99_REF_DN, 2.0, "2 DN: the simulator's reference DN is set to the paper's f99(d_ref); what is left "
                "is the fit of the piecewise curve", "Sensors 2011 distance correction: f99(3.56 m) = 1781.45 DN",
                x=0.99)]
    for material, rho, shift, shift_sd, raw, rmse in TABLE2:
        ours = stats[min(stats, key=lambda r: abs(r - rho))]
        common = dict(x=rho)
        rows += [
            Row(f"{material}/mean shift", "(i) mean shift", "DN", ours["mean_shift_dn"], shift, 2 * shift_sd,
                _SHIFT_TOL, f"{SOURCE} (i)", **common),
            Row(f"{material}/shift s.d.", "(ii) s.d. of shift", "DN", ours["shift_std_dn"], shift_sd, 0.5 * shift_sd,
                _SD_TOL, f"{SOURCE} (ii)", **common),
            Row(f"{material}/raw at 3.56 m", "raw DN at 3.56 m", "DN", ours["raw_at_reference_dn"], raw,
                2 * shift_sd, _SHIFT_TOL, f"{SOURCE} (iii)", **common),
            Row(f"{material}/corrected RMSE", "(iv) RMSE after correction", "DN", ours["corrected_rmse_dn"], rmse,
                4.0 if rho >= 0.48 else 10.0, _RMSE_TOL, f"{SOURCE} (iv)", **common),
        ]
    return [replace(r, note=_TABLE2_WHY[r.key.split("/")[1]]) if r.verdict == OUTSIDE and "/" in r.key
            and r.key.split("/")[1] in _TABLE2_WHY else r for r in rows]


@register("sensors2011-goniometer", "Sensors 2011 Fig. (goniometer): leaf intensity against incidence, and the "
          "inversion precision below 60 deg",
          description="Simulated goniometer (leaf on a 3 % board at 2.16 m, both rotation axes, 0-85 deg), the "
                      "calibration fitted on it (distance correction + 4th-order polynomial), then the inversion "
                      "applied to single returns of a second goniometer scan with another seed, to the same scan "
                      "without intensity noise, and to each station's mean intensity.",
          findings="The paper's measured curve and its inversion precision are held back from the spec: the "
                   "published column stays empty and the rows test the published trends (intensity falls with "
                   "incidence, the rotation axis hardly matters) and the +-5 deg precision below 60 deg. Our "
                   "intensity slopes are reported for a comparison against the paper's figure by hand. The "
                   "inversion row is outside on single returns, for the simulator's intensity noise (3 DN at the "
                   "reference target, growing as the signal falls: an assumption of the simulator, tls-physics "
                   "7.4), measured (seed 0; seeds 1 and 2, not looked at first, in brackets): near normal incidence "
                   "the simulated curve falls by about 1.3 DN/deg, and a single return's inverted angle has an s.d. "
                   "of 4.7-5.1 deg at 0-10 deg against 0.7-1.3 deg at 45-60 deg; p95 8.3 deg (7.9, 8.4). The same "
                   "test scan without intensity noise gives p95 1.5 deg (1.3, 1.1), and inverting each station's "
                   "mean intensity gives at most 1.5 deg (1.1, 1.1) below 60 deg: the calibration and the inversion "
                   "are right, the noise of one return is what leaves +-5 deg (a modelling assumption, not a "
                   "defect). Whether the paper's precision is on single returns or on means is not stated: the "
                   "judged row keeps the strict reading (single returns), the other two are reported.")
def goniometer(quick: bool, seed: int) -> list[Row]:
    """Rows of the goniometer experiment (trends, slopes, inversion precision).

    Parameters
    ----------
    quick : bool
        Unused: the goniometer scene is small.
    seed : int
        Seed of the calibration scans (the inversion is tested on ``seed + 1``).
    """
    model = get_preset("faro-ls880")
    panels, table = simulate_tables(model, seed)
    calibration = fit_calibration(panels, table, scanner_model=model.to_dict())
    rows = []
    corrected = calibration.corrected(table["intensity_dn"], np.full(len(table["alpha_rad"]), 2.16))
    alpha_deg = np.degrees(table["alpha_rad"])
    by_axis = {}
    for axis in np.unique(table["rotation_axis"]):
        chosen = table["rotation_axis"] == axis
        order = np.argsort(alpha_deg[chosen])
        a, i = alpha_deg[chosen][order], corrected[chosen][order]
        by_axis[str(axis)] = dict(zip(table["nominal_deg"][chosen][order], i))
        rows.append(Row(f"{axis}/monotone", "corrected DN falls with incidence", "share of steps", float(
            np.mean(np.diff(i) < 0)), claim="intensity falls monotonically with incidence (Sensors 2011 sec. 3.2)",
            holds=bool(np.all(np.diff(i[a < 80]) < 0)), source="Sensors 2011 / thesis ch.6 Fig. (I against alpha)",
            series=str(axis), note="ours: share of 0-85 deg steps where the intensity falls; the claim is tested "
                                   "below 80 deg where the footprint stays on the leaf"))
        slopes = []
        for low, high in ((0, 30), (30, 60), (60, 85)):
            band = (a >= low) & (a <= high)
            slopes.append(float(np.polyfit(a[band], i[band], 1)[0]) if band.sum() >= 2 else float("nan"))
            rows.append(Row(f"{axis}/slope {low}-{high} deg", "intensity slope", "DN/deg", slopes[-1],
                            source="ours; the published slopes are kept out of the spec (compare with the paper's "
                                   "figure by hand)", x=(low + high) / 2, series=str(axis)))
        rows.append(Row(f"{axis}/slopes steepen", "intensity slope", "DN/deg", slopes[-1], series=f"{axis} (claim)",
                        claim="intensity falls gently near normal incidence and steeply towards grazing incidence "
                              "(tls-physics §6 item 6, the k ln cos(alpha) shape)",
                        holds=bool(slopes[0] < 0 and slopes[0] > slopes[1] > slopes[2]),
                        source="Sensors 2011 Fig. (I against alpha)", x=85.0))
    common = sorted(set(by_axis.get("vertical", {})) & set(by_axis.get("horizontal", {})))
    common = [n for n in common if n < INVERSION_LIMIT_DEG]
    if common:
        gap = float(np.max([abs(by_axis["vertical"][n] - by_axis["horizontal"][n]) for n in common]))
        rows.append(Row("axis difference", "largest |vertical - horizontal| below 60 deg", "DN", gap,
                        claim="the rotation axis changes the curve only slightly (judged negligible)",
                        holds=gap < 10.0, source="Sensors 2011 sec. 3.2", note="'slightly' read as < 10 DN, the "
                        "corrected-intensity spread the paper accepts for rho < 22 % (an assumption)"))
    _, test = simulate_tables(model, seed + 1)
    error, station_error = inversion_errors(calibration.alpha, test)
    p95 = float(np.quantile(error, 0.95)) if len(error) else float("nan")
    rows.append(Row("inversion p95 below 60 deg", "inversion error (single returns)", "deg", p95,
                    claim=f"incidence recovered within +-{INVERSION_PRECISION_DEG:g} deg below "
                          f"{INVERSION_LIMIT_DEG:g} deg (issue 12; the paper's measured precision is held back)",
                    holds=bool(p95 <= INVERSION_PRECISION_DEG), source="Sensors 2011 sec. 3.2 / thesis ch.6",
                    note="ours on single returns: near normal incidence the curve is flat (about 1.3 DN/deg), so "
                         "the intensity noise of one return moves its angle by several degrees (rows below: "
                         "without that noise, and on station means)"))
    rows.append(Row("inversion RMS below 60 deg", "inversion error (single returns)", "deg",
                    float(np.sqrt(np.mean(error**2))) if len(error) else float("nan"),
                    source="ours only (for the page)"))
    quiet, _ = inversion_errors(calibration.alpha, simulate_tables(replace(model, intensity_noise_dn=0.0), seed + 1)[1])
    rows.append(Row("inversion p95 below 60 deg, no intensity noise", "inversion error (single returns)", "deg",
                    float(np.quantile(quiet, 0.95)) if len(quiet) else float("nan"),
                    source="ours only: the same test scan with intensity_noise_dn = 0 (the noise's share)"))
    rows.append(Row("inversion of station means, largest error below 60 deg", "inversion error (station means)",
                    "deg", float(np.max(station_error)) if len(station_error) else float("nan"),
                    source="ours only: each station's mean intensity inverted (the reading of the precision on "
                           "means; the paper does not say which)"))
    return rows


def inversion_errors(alpha_of, table: dict) -> tuple[np.ndarray, np.ndarray]:
    """Inversion errors below :data:`INVERSION_LIMIT_DEG` on single returns and on station means.

    Parameters
    ----------
    alpha_of : callable
        ``alpha_of(intensity_dn, range_m)`` -> incidence in rad (a calibration's inversion).
    table : dict of ndarray
        A goniometer table (:func:`tlssim.calibration.goniometer_table`): ``alpha_rad`` per station,
        ``sample_station``, ``sample_intensity_dn`` and ``sample_range_m`` per return.

    Returns
    -------
    single, means : ndarray
        ``|estimate - truth|`` in deg for every return of a station below the limit, and for the mean
        intensity (at the mean range) of each such station.
    """
    truth = np.degrees(np.asarray(table["alpha_rad"], float))
    station = np.asarray(table["sample_station"])
    intensity, range_m = np.asarray(table["sample_intensity_dn"], float), np.asarray(table["sample_range_m"], float)
    below = truth[station] < INVERSION_LIMIT_DEG
    single = np.abs(np.degrees(alpha_of(intensity, range_m)) - truth[station])[below]
    kept = [k for k in range(len(truth)) if truth[k] < INVERSION_LIMIT_DEG and np.any(station == k)]
    mean_i = np.array([intensity[station == k].mean() for k in kept])
    mean_r = np.array([range_m[station == k].mean() for k in kept])
    means = np.abs(np.degrees(alpha_of(mean_i, mean_r)) - truth[kept]) if kept else np.zeros(0)
    return single, means


def pure_returns(scan, name: str) -> np.ndarray:
    """Mask of the returns of object ``name`` with less than :data:`PURE_MAX_MIXED` of their power from elsewhere.

    Parameters
    ----------
    scan : tlssim.scan.Scan
        A simulated scan with its truth layers.
    name : str
        Object name in ``scan.object_names``.
    """
    mixed = np.nan_to_num(scan.mixed_fraction, nan=1.0)
    return scan.valid & (scan.truth_id == scan.object_names.index(name)) & (mixed < PURE_MAX_MIXED)


#: Radius of the "flat part" sub-selected on each leaf, m: the paper chose flat parts by hand; ours are the pure
#: returns within this distance of the leaf's median point (an assumption: about a quarter of a 9 cm leaf's width).
FLAT_PART_RADIUS_M = 0.01
#: Farthest flat-part sub-selection of the paper, m (Sensors 2011 Table 3: 1.32-4.30 m; none possible on tree 15).
TABLE3_MAX_DISTANCE_M = 4.30


def scene_delta_alpha(scene, seed: int, flat_radius_m: float | None = None) -> np.ndarray:
    """Per-point ``delta alpha = alpha_I - alpha_LSR`` (eq 5) on the object ``leaf`` of a scene, degrees.

    ``alpha_I`` inverts each pure return's intensity with the simulated
    calibration of the faro-ls880 preset; ``alpha_LSR`` is the incidence of
    the plane fitted to the whole leaf (:func:`tlssim.calibration.patch_incidence`).

    Parameters
    ----------
    scene : scenes.scene.Scene
        A scene with an object named ``leaf`` and a scanner window around it.
    seed : int
        Seed of the scan and of the calibration scans.
    flat_radius_m : float or None
        Keep only the pure returns within this distance of their median point (a sub-selected flat part, with
        its own plane), m; ``None``: the whole leaf.

    Returns
    -------
    ndarray
        Delta alpha of the leaf's pure returns (less than :data:`PURE_MAX_MIXED` of the power from elsewhere),
        degrees.
    """
    calibration = simulated_calibration(get_preset("faro-ls880"), seed)
    scan = simulate(scene, setup_from_section(scene.scanner), seed=seed, progress=False)
    pure = pure_returns(scan, "leaf")
    if flat_radius_m is not None:
        xyz = scan.xyz[pure]
        part = np.zeros_like(pure)
        part[pure] = np.linalg.norm(xyz - np.median(xyz, axis=0), axis=1) < flat_radius_m
        pure = part
    alpha_lsr = patch_incidence(scan.xyz[pure])
    alpha_i = calibration.alpha(scan.intensity[pure], scan.range[pure])
    return np.degrees(alpha_i - alpha_lsr)


def leaf_delta_alpha(distance_m: float, seed: int, flat_radius_m: float | None = None) -> np.ndarray:
    """:func:`scene_delta_alpha` on the built-in ``leaf-<d>m`` scene (1.5, 3 or 5 m), degrees.

    Parameters
    ----------
    distance_m : float
        Distance of the leaf, m: 1.5, 3 or 5 (the built-in scenes).
    seed : int
        Seed of the scan and of the calibration scans.
    flat_radius_m : float or None
        Radius of the flat part sub-selected, m (``None``: the whole leaf).
    """
    return scene_delta_alpha(scenes.build(f"leaf-{distance_m:g}m"), seed, flat_radius_m)


#: Bends of the leaves with a simple curvature (no roll, no twist), deg: the built-in leaf has bend 10, roll 24 deg.
BENDS_DEG = (0.0, 30.0, 60.0)


def bent_leaf_delta_alpha(bend_deg: float, seed: int, distance_m: float = 3.0,
                          wrinkle_m: float | None = None) -> np.ndarray:
    """:func:`scene_delta_alpha` on the built-in leaf bent along its midrib only (no roll, no twist), degrees.

    Parameters
    ----------
    bend_deg : float
        Bend of the midrib, deg (0: a flat leaf).
    seed : int
        Seed of the scan and of the calibration scans.
    distance_m : float
        Distance of the leaf, m (20 deg incidence and the wall 1 m behind, as in ``leaf-<d>m``).
    wrinkle_m : float or None
        Wrinkle amplitude, m, with a wavelength of 10 times it along the midrib (``None``: the leaf's own
        sub-millimetre wrinkles).
    """
    spec = {"name": "bent-leaf", "scanner": {"preset": "faro-ls880", "position": [0, 0, 0]},
            "objects": [{"name": "leaf", "type": "leaf", "preset": "pear", "seed": 7, "length": 0.09,
                         "bend_deg": bend_deg, "roll_deg": 0.0, "twist_deg": 0.0, "material": "pear-leaf",
                         "pose": {"center": [distance_m, 0, 0], "facing": "scanner", "incidence_deg": 20,
                                  "rotation_axis": "horizontal"}},
                        {"name": "wall", "type": "plane", "size": [1.0, 1.0], "material": "wall",
                         "pose": {"center": [distance_m + 1.0, 0, 0], "facing": "scanner"}}]}
    if wrinkle_m is not None:
        spec["objects"][0].update(wrinkle_amplitude=wrinkle_m, wrinkle_wavelength=10 * wrinkle_m)
    scene = scene_from_spec(spec, source="bent leaf (sensors2011-insitu)")
    leaf = np.concatenate([o.vertices for o in scene.objects if o.name == "leaf"])
    return scene_delta_alpha(scene.with_scanner(window=window_around(leaf, [0, 0, 0], 0.4)), seed)


#: Distances of the attached leaves' flat parts, m: the span of the paper's sub-selections (Table 3: 1.32-4.30 m).
ATTACHED_DISTANCES_M = (1.5, 3.0, 4.3)
#: Fewest pure returns in a flat part for its own plane (an assumption: about 1 deg of tilt precision for 2 mm
#: of range noise over a 2 cm patch).
MIN_FLAT_RETURNS = 50


def attached_flat_parts(distance_m: float, seed: int) -> list[tuple[int, float]]:
    """Flat parts of the leaves of a shoot (the ``leaf-cluster`` twig: eight overlapping pear leaves) at a distance.

    The twig of the built-in ``leaf-cluster`` scene is moved to ``distance_m``
    (wall 1 m behind it); on each of its leaves the pure returns within
    :data:`FLAT_PART_RADIUS_M` of the leaf's median point are the flat part,
    with their own plane as reference (eq 5).

    Parameters
    ----------
    distance_m : float
        Scanner-to-twig distance, m.
    seed : int
        Seed of the scan and of the calibration scans.

    Returns
    -------
    list of (int, float)
        Per leaf with at least :data:`MIN_FLAT_RETURNS` returns in its flat part: that count and the median delta
        alpha, degrees.
    """
    spec = {"name": "attached-leaves", "scanner": {"preset": "faro-ls880", "position": [0, 0, 0]},
            "objects": [{"name": "shoot", "type": "tree", "preset": "shoot", "seed": 3, "leaf_detail": 0.25,
                         "pose": {"translate": [distance_m, -0.15, 0.0], "rotate": {"axis": [0, 1, 0],
                                                                                    "angle_deg": -90}}},
                        {"name": "wall", "type": "plane", "size": [1.5, 1.0], "material": "wall",
                         "pose": {"center": [distance_m + 1.0, 0, 0], "facing": "scanner"}}]}
    scene = scene_from_spec(spec, source="attached leaves (sensors2011-insitu)")
    shoot = np.concatenate([o.vertices for o in scene.objects if o.name != "wall"])
    scene = scene.with_scanner(window=window_around(shoot, [0, 0, 0], 0.3))
    calibration = simulated_calibration(get_preset("faro-ls880"), seed)
    scan = simulate(scene, setup_from_section(scene.scanner), seed=seed, progress=False)
    parts = []
    for name in scan.object_names:
        if "leaf" not in name.rsplit("/", 1)[-1]:
            continue
        pure = pure_returns(scan, name)
        if not pure.any():
            continue
        xyz = scan.xyz[pure]
        near = np.linalg.norm(xyz - np.median(xyz, axis=0), axis=1) < FLAT_PART_RADIUS_M
        if near.sum() < MIN_FLAT_RETURNS:
            continue
        alpha_i = calibration.alpha(scan.intensity[pure][near], scan.range[pure][near])
        parts.append((int(near.sum()), float(np.median(np.degrees(alpha_i - patch_incidence(xyz[near]))))))
    return parts


def skewness(values: np.ndarray) -> float:
    """Sample skewness (third standardised moment) of ``values``; NaN under three values."""
    return float(np.mean((values - values.mean()) ** 3) / np.std(values) ** 3) if len(values) > 2 else float("nan")


def bimodality(values: np.ndarray) -> float:
    """Sarle's bimodality coefficient ``(g^2 + 1) / (k + 3 (n-1)^2 / ((n-2)(n-3)))`` (g skewness, k excess kurtosis).

    Above 5/9 (0.555, the uniform distribution's value) a distribution is read as bi- or multimodal.

    Parameters
    ----------
    values : ndarray
        Samples (at least four).

    Returns
    -------
    float
        The coefficient (dimensionless); NaN under four values.
    """
    n = len(values)
    if n < 4:
        return float("nan")
    kurtosis = float(np.mean((values - values.mean()) ** 4) / np.std(values) ** 4) - 3.0
    return (skewness(values) ** 2 + 1.0) / (kurtosis + 3.0 * (n - 1) ** 2 / ((n - 2) * (n - 3)))


#: Wrinkle amplitudes of the wrinkled-leaf rows, m (wavelength 10 x; an assumption: the paper gives no size).
WRINKLES_M = (0.002, 0.003)


@register("sensors2011-insitu", "Sensors 2011 sec. 3.3 (eq 5): delta alpha on whole leaves and flat parts at 1.5, 3 "
          "and 5 m, flat parts of attached leaves, and bent and wrinkled leaves",
          description="The built-in curved 9 cm pear leaf at 20 deg incidence (leaf-1.5m, leaf-3m, leaf-5m), the "
                      "simulated calibration inverted on its pure returns, delta alpha = alpha_I - alpha_LSR per "
                      "point against the plane fitted to the whole leaf, and to a flat part (the returns within 1 cm "
                      "of the leaf's centre, with its own plane); the same leaf bent along its midrib only "
                      "(bend 0, 30, 60 deg, no roll or twist) at 3 m, reported; flat, with 2 and 3 mm wrinkles, 3 m; "
                      "the flat parts of the eight leaves of a shoot (leaf-cluster) at 1.5, 3 and 4.3 m.",
          findings="The paper's in-situ results are qualitative: whole leaves with a simple curvature give a skewed, "
                   "shifted delta-alpha distribution, and the distance correction leaves no clear difference between "
                   "distances. Thresholds for 'skewed' (|skewness| > 0.3), 'shifted' (|median| > 1 deg) and 'no clear "
                   "difference' (medians within 3 deg) are our assumptions, stated in the rows. Measured: on the "
                   "built-in leaf the distribution is symmetric and centred (skewness -0.02 to -0.05, median -0.2 / "
                   "-0.8 / -0.6 deg at 1.5 / 3 / 5 m, s.d. about 10.6 deg): outside, a modelling difference of the "
                   "leaf's shape, not fixed. Round 9 measured the cause (seed 0): it is the leaf, not the noise (round"
                   " 8 blamed the noise, wrongly). The true per-pulse incidence minus alpha_LSR already has an s.d. of"
                   " 10.0-10.1 deg, skewness +0.12 to +0.14 and median within 0.1 deg; the intensity noise adds only "
                   "about 3 deg. The built-in leaf (pear seed 7) is cupped: roll 24 deg, bend 10 deg, and a roll "
                   "spreads the facets symmetrically about the mean plane (the same leaf with roll 25 deg and no bend:"
                   " s.d. 10.5, skewness 0.00, median -0.8). The same leaf bent along its midrib only, the paper's "
                   "'simple curvature', gives the paper's shape as the bend grows: skewness -0.39 / -0.37 / +0.41 and "
                   "median -0.84 / +0.74 / +2.65 deg at bend 0 / 30 / 60 deg, 3 m (rows 'bend ...', reported, not "
                   "judged: the paper gives no curvature; seed 1, not looked at first: +0.44 and +2.47 at 60 deg); on "
                   "the flat leaf the noise alone, through the curved I-alpha inversion, is skewed -0.39 and shifted "
                   "-0.8 deg. The 5 m median of -4.5 deg (round 8) was a defect of this experiment, fixed: its 'pure' "
                   "returns were those with less than 5 % of their power from elsewhere, and at 5 m the edge pulses "
                   "with one outer sub-ray on the wall 1 m behind carry 4.96 % (7.6 % at 1.5 m, 5.2 % at 3 m), so 15 "
                   "of 1241 returns, pulled 47-53 mm back by the phase-shift mixing, tilted the reference plane to "
                   "23.0 deg against 19.2 deg without them (seed 0; the inversion was never the cause: alpha_I - true "
                   "incidence -0.2 / -0.5 / -0.4 deg). Pure now means a share below 0.2 %, which keeps the mixing's "
                   "range error under the 2 mm noise: 'no clear difference' within for seeds 0-3 (spread 0.6 / 1.2 / "
                   "0.4 / 0.4 deg; seeds 1-3 not looked at before the fix). Round 11 added the paper's own reading "
                   "of that claim, on flat parts (sec. 3.3.2: a flat part of each attached leaf sub-selected by hand,"
                   " its own plane as reference; ours: the pure returns within 1 cm of the leaf's median point, an "
                   "assumption): medians +2.7 / +2.3 / +0.2 deg at 1.5 / 3 / 5 m (seed 0; seeds 1-3, not looked at "
                   "first: +2.8 / +2.0 / +5.0, +2.5 / +3.5 / -1.2, +2.7 / +2.3 / +8.2). Up to 3 m the spread is "
                   "0.35-1.05 deg on all four seeds; the 5 m patch (117 returns over 2 cm, 2 mm range noise) has a "
                   "plane whose tilt is uncertain by about 2 deg per seed, the paper's 'the farther the tree, the "
                   "harder a correct LSR' (Table 3: no sub-selection beyond 4.30 m, none on tree 15). The judged "
                   "row therefore keeps the paper's range (1.5 and 3 m; chosen after seeing the 5 m spread of 2.5 / "
                   "3.0 / 4.7 / 5.9 deg, which the row's note reports). Wrinkled leaves (sec. 3.3.3: 'multimodal'; "
                   "tls-physics §6 item 11's check: 'skewed or multimodal'): a flat leaf with sinusoidal wrinkles "
                   "of 2 / 3 mm (wavelength 2 / 3 cm, an assumption) gives skewness -0.80 / -0.82 and median +7.3 / "
                   "+8.6 deg (seed 0): skewed, so within; its bimodality coefficient 0.49 / 0.52 (seed 1: 0.48 / "
                   "0.53) stays under 5/9, so ours is skewed rather than clearly multimodal. Flat parts of "
                   "attached leaves (the leaf-cluster shoot's eight overlapping leaves moved to 1.5 / 3 / 4.3 m, "
                   "the span of the paper's Table 3; every leaf keeps a flat part of 50 or more returns at each "
                   "distance, 75-1,420, so Table 3's falling count is not reproduced, only its returns per part, "
                   "which fall as 1/d^2): "
                   "medians over the leaves +2.9 / +4.1 / +3.4 deg (seed 0; seeds 1-3, not looked at first: spread "
                   "2.96 / 1.37 / 2.23 deg against 1.23), within the 3 deg set in round 8. Per leaf the medians "
                   "range from -5 to +18 deg but each leaf keeps its own value at every distance (e.g. -2.4 / -3.9 "
                   "/ -2.6 deg): the leaf near normal incidence (LSR 5-8 deg) reads +9 to +12 deg, where the flat "
                   "top of the I-alpha curve turns intensity noise into a one-sided angle error; the +16 to +18 deg "
                   "of a leaf at 15-18 deg is not looked into.")
def insitu(quick: bool, seed: int) -> list[Row]:
    """Rows of the in-situ delta-alpha analysis (median, s.d., skewness per distance; the paper's claims).

    Parameters
    ----------
    quick : bool
        Unused: the six scans take about 4 s.
    seed : int
        Seed of the scans.
    """
    distances = (1.5, 3.0, 5.0)
    rows, medians = [], []
    for d in distances:
        delta = leaf_delta_alpha(d, seed)
        median = float(np.median(delta))
        skew = skewness(delta)
        medians.append(median)
        rows += [Row(f"{d:g} m/median", "median delta alpha", "deg", median, x=d, source="ours (paper's figure)",
                     note=f"{len(delta)} pure returns"),
                 Row(f"{d:g} m/s.d.", "s.d. of delta alpha", "deg", float(np.std(delta)), x=d,
                     source="ours (paper's figure)"),
                 Row(f"{d:g} m/skewed and shifted", "claim", "skewness", skew, x=d,
                     source="Sensors 2011 sec. 3.3.3 (entire leaves on tree 9)",
                     claim="a curved leaf gives a skewed (|skewness| > 0.3), shifted (|median| > 1 deg) delta-alpha "
                           "distribution", holds=bool(abs(skew) > 0.3 and abs(median) > 1.0),
                     note=f"median {median:+.2f} deg")]
    rows.append(Row("no clear difference between distances", "claim", "deg", float(np.ptp(medians)),
                    source="Sensors 2011 sec. 3.3.2 (flat parts, 15 trees); ours on whole leaves",
                    holds=bool(np.ptp(medians) < 3.0),
                    claim="the distance correction leaves no clear difference between distances (ours: medians "
                          "within 3 deg)"))
    flat = []
    for d in distances:
        delta = leaf_delta_alpha(d, seed, FLAT_PART_RADIUS_M)
        flat.append(float(np.median(delta)))
        rows.append(Row(f"flat part/{d:g} m/median", "median delta alpha, flat part", "deg", flat[-1], x=d,
                        series="flat part", source="ours (paper sec. 3.3.2)",
                        note=f"{len(delta)} pure returns within {100 * FLAT_PART_RADIUS_M:g} cm of the leaf's centre, "
                             f"s.d. {np.std(delta):.2f} deg"))
    judged = [m for d, m in zip(distances, flat) if d <= TABLE3_MAX_DISTANCE_M]
    rows.append(Row("flat parts: no clear difference between distances", "claim", "deg", float(np.ptp(judged)),
                    source="Sensors 2011 sec. 3.3.2 and Table 3 (flat parts of attached leaves, 1.32-4.30 m)",
                    holds=bool(np.ptp(judged) < 3.0),
                    claim="on flat parts the distance correction leaves no clear difference between distances "
                          "(ours: medians within 3 deg at the paper's distances, up to 4.30 m)",
                    note=f"all three distances: spread {np.ptp(flat):.2f} deg (5 m is beyond the paper's range: "
                         f"findings)"))
    attached = []
    for d in ATTACHED_DISTANCES_M:
        parts = attached_flat_parts(d, seed)
        attached.append(float(np.median([m for _, m in parts])) if parts else float("nan"))
        rows += [Row(f"attached leaves/{d:g} m/median", "median delta alpha, flat parts of attached leaves", "deg",
                     attached[-1], x=d, series="attached leaves", source="ours (paper sec. 3.3.2)",
                     note=f"median over the shoot's leaves of each flat part's median; per leaf: "
                          + ", ".join(f"{m:+.1f}" for _, m in parts)),
                 Row(f"attached leaves/{d:g} m/flat parts", "flat parts with a plane of their own", "leaves",
                     float(len(parts)), x=d, series="attached leaves", source="ours (paper Table 3: # data)",
                     note=f"returns per flat part: {np.mean([n for n, _ in parts]):.0f} on average" if parts else "")]
    rows.append(Row("attached leaves: no clear difference between distances", "claim", "deg", float(np.ptp(attached)),
                    source="Sensors 2011 sec. 3.3.2 and Table 3 (flat parts of attached leaves, 1.32-4.30 m)",
                    holds=bool(np.ptp(attached) < 3.0),
                    claim="on flat parts of leaves attached to a shoot the distance correction leaves no clear "
                          "difference between distances (ours: medians over the leaves within 3 deg at 1.5, 3 and "
                          "4.3 m)"))
    for bend in BENDS_DEG:
        delta = bent_leaf_delta_alpha(bend, seed)
        why = "ours: the built-in leaf bent along its midrib only (the paper's 'simple curvature'), 3 m"
        rows += [Row(f"bend {bend:g} deg/skewness", "skewness of delta alpha, leaf bent only", "", skewness(delta),
                     x=bend, series="3 m, no roll", source=why, note=f"{len(delta)} pure returns"),
                 Row(f"bend {bend:g} deg/median", "median delta alpha, leaf bent only", "deg",
                     float(np.median(delta)), x=bend, series="3 m, no roll", source=why)]
    for wrinkle in WRINKLES_M:
        delta = bent_leaf_delta_alpha(0.0, seed, wrinkle_m=wrinkle)
        skew, coefficient, median = skewness(delta), bimodality(delta), float(np.median(delta))
        rows.append(Row(f"wrinkles {1000 * wrinkle:g} mm/skewed or multimodal", "claim", "", coefficient,
                        source="Sensors 2011 sec. 3.3.3 (wrinkled leaves); tls-physics §6 item 11",
                        holds=bool(abs(skew) > 0.3 or coefficient > 5 / 9),
                        claim="a wrinkled leaf gives a skewed or multimodal delta-alpha distribution (ours: "
                              "|skewness| > 0.3 or bimodality coefficient > 5/9)",
                        note=f"flat leaf with wrinkles of {1000 * wrinkle:g} mm, wavelength {10000 * wrinkle:g} "
                             f"mm, 3 m: skewness {skew:+.2f}, bimodality coefficient {coefficient:.3f}, median "
                             f"{median:+.2f} deg, {len(delta)} pure returns"))
    return rows

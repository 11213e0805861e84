"""Thesis ch.5 §3.3-3.4: the synthetic PROP-SFS experiments on analytic surfaces, and the complexity law.

Chapter 5 publishes no result table: its numbers are statements about
figures (prop-sfs.md §5.5). Each statement is a row whose claim is tested
on our reconstructions (``buffer`` variant, percentile quantisation with a
20 % seed, alpha clamp 85 deg, no rim extrapolation: leafsfs' settings for
clean synthetic data); our errors themselves are reported rows for the
plots. Errors are the thesis' eq 3.1 (signed, ``eps_mean``) and eq 3.2
(``abs_eps_mean``), relative to ``h_tot``. The alpha-bias and size studies
run with both domain-alpha rules: ``median`` (ours, clamped median of the
domain's pixels) and ``upper`` (the thesis' literal upper bound alpha_i,
clamped to 85 deg at the shell), see prop-sfs.md A1.
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy import ndimage, stats

from benchmarks.metrics import height_errors
from benchmarks.reproduce.core import Row, register
from leafsfs.engine import reconstruct_heights
from leafsfs.params import SfsParams
from leafsfs.synthetic import sample_surface
from scenes.surfaces import get_surface

SOURCE = "thesis ch.5 §3.3.1"
RULES = ("median", "upper", "lower")
#: Why a rule meets or misses the thesis' statements that rest on its offset (measured in ch5-alpha-bias, seed 0).
RULE_NOTES = {"median": "median rule: no offset at no bias (signed error -0.3 %), so the thesis' statements that "
                        "rest on its positive error (compensated by a bias or by smoothing) cannot hold; a modelling "
                        "choice of ours (ch5-alpha-bias findings)",
              "upper": "upper rule (the thesis' wording): alpha too high at no bias (signed error -16 %), the "
                       "opposite offset to the thesis' (ch5-alpha-bias findings)",
              "lower": "lower rule: the thesis' low alpha (signed error +5 % at no bias), the reading its results "
                       "follow (ch5-alpha-bias findings: an erratum of its text)"}
BIASES_DEG = (-7.0, -3.5, 0.0, 3.5, 7.0)
NOISES_DEG = (1.4, 2.8, 5.7)
PASSES = (0, 1, 2, 3, 4, 5, 10, 20, 30, 40, 50, 60, 70, 80, 90)
SIDES = (25, 34, 41, 47, 53, 58)
EPSILONS = (0.05, 0.10, 0.20)


def reconstruct(surface: str, side: int, *, noise_deg: float = 0.0, bias_deg: float = 0.0, n_smooth: int = 0,
                eps_alpha: float = 0.2, rule: str = "median", seed: int = 0, floor_out: bool = False) -> dict:
    """Reconstruct one analytic surface and score it.

    Parameters
    ----------
    surface : str
        Name in :mod:`scenes.surfaces` (``hemisphere``: radius 20).
    side : int
        Matrix side, pixels.
    noise_deg, bias_deg : float
        Uniform alpha noise amplitude and alpha bias added to the alpha matrix, degrees.
    n_smooth : int
        Smoothing passes.
    eps_alpha : float
        Quantisation percentile (fraction).
    rule : {"median", "upper", "lower"}
        Domain-alpha rule.
    seed : int
        Seed of the noise.
    floor_out : bool
        Leave the flat floor (true height 0, e.g. around the vase body of eq
        3.6) out of the object mask.

    Returns
    -------
    dict
        :func:`benchmarks.metrics.height_errors` plus ``area_rel_err`` (the
        reconstructed height image's area against the true one's, over the
        same fully reconstructed 2 x 2 cells), ``seconds``, ``seed_share``
        (share of the object's pixels in the seed domain), ``seed_on_floor``
        (share of the seed pixels whose true height is 0), ``body_abs_eps_mean``
        (eq 3.2 over the pixels of nonzero true height: the vase without its
        floor), ``levels`` (number of iso-alpha domains) and ``parts``
        (number of watershed parts, one seed each).
    """
    sample = sample_surface(get_surface(surface), side, alpha_noise_deg=noise_deg, alpha_bias_deg=bias_deg, seed=seed)
    mask = sample.mask & (sample.truth != 0) if floor_out else sample.mask
    params = SfsParams(n_smooth=n_smooth, quantization="percentile", eps_alpha=eps_alpha, eps_seed=0.2,
                       alpha_max_deg=85, rim_px=0, alpha_rule=rule)
    start = time.perf_counter()
    result = reconstruct_heights(sample.alpha, sample.height, mask, sample.grid, "buffer", params)
    seconds = time.perf_counter() - start
    scores = height_errors(result.height, sample.truth, mask)
    spacing = np.abs(np.diag(sample.grid.matrix))
    ours, truth = image_area(result.height, spacing), image_area(np.where(np.isfinite(result.height), sample.truth,
                                                                           np.nan), spacing)
    scores["area_rel_err"] = (ours - truth) / truth if truth > 0 else math.nan
    scores["seconds"] = seconds
    seeds = result.seed & mask
    scores["seed_share"] = float(seeds.sum() / mask.sum())
    scores["seed_on_floor"] = float(np.mean(sample.truth[seeds] == 0)) if seeds.any() else math.nan
    scores["body_abs_eps_mean"] = height_errors(result.height, sample.truth, mask & (sample.truth != 0))["abs_eps_mean"]
    scores["levels"] = len(result.thresholds)
    scores["parts"] = int(result.parts.max())
    return scores


def image_area(height: np.ndarray, spacing) -> float:
    """Area of a height image over its 2 x 2 cells whose four corners are finite (two triangles per cell).

    Parameters
    ----------
    height : ndarray, 2-D
        Heights (NaN where missing), in the unit of ``spacing``.
    spacing : array_like
        Pixel size along rows and columns.

    Returns
    -------
    float
        Area, in the square of the unit.
    """
    dy, dx = float(spacing[0]), float(spacing[1])
    a, b, c, d = height[:-1, :-1], height[:-1, 1:], height[1:, :-1], height[1:, 1:]
    ok = np.isfinite(a) & np.isfinite(b) & np.isfinite(c) & np.isfinite(d)
    # triangles (a, b, c) and (b, d, c): cross products of their edge vectors
    t1 = 0.5 * np.sqrt((dy * (b - a)) ** 2 + (dx * (c - a)) ** 2 + (dx * dy) ** 2)
    t2 = 0.5 * np.sqrt((dy * (d - c)) ** 2 + (dx * (d - b)) ** 2 + (dx * dy) ** 2)
    return float(np.sum((t1 + t2)[ok]))


def _monotone(values, decreasing: bool = True) -> bool:
    steps = np.diff(np.asarray(values, float))
    return bool(np.all(steps < 0) if decreasing else np.all(steps > 0))


@register("ch5-alpha-bias", "Thesis ch.5 Fig. 10: hemisphere error and area against an alpha bias of -7..+7 deg, "
          "three domain-alpha rules",
          description="Radius-20 hemisphere, 41 px, no noise, no smoothing, 20 % quantisation; a bias of -7, -3.5, "
                      "0, +3.5, +7 deg added to the alpha matrix; the domain alpha taken as the clamped median of "
                      "its pixels (ours), its upper bound alpha_i (the thesis' literal wording, prop-sfs A1) or its "
                      "lower bound alpha_(i-1), the alpha of the curve it propagates from. Also the combined study: "
                      "+-2.8 deg noise with and without +7 deg bias against smoothing passes.",
          findings="Issue 12 found our trend against the thesis' (a positive bias should lower the error and bring "
                   "the area closer). Measured: the upper-bound rule is not the cause (every slope too steep: "
                   "signed error -16 % at no bias, worse with a positive bias, area +83 %). The median rule is "
                   "unbiased at no bias, so any bias moves it away. The lower-bound rule (each annulus propagated "
                   "with the alpha of its inner curve) reproduces every statement of the thesis: a positive error "
                   "at no bias (+5 %), lowered by a positive bias (|error| 5.3 -> 1.4 % at +7 deg), the area "
                   "brought from -13 % to +0.5 %, the noisy error positive, falling with smoothing, negative with "
                   "+7 deg, the curves a constant apart (under the median rule the noisy unbiased error is -0.5 "
                   "to -1.0 % and the +7 deg curve goes -9.5 -> -8.7 % from 1 to 50 passes; under the upper rule "
                   "-17 to -18 % and -26.5 -> -25.4 %: the statements resting on a positive offset fail under "
                   "both, as in the bias study). So the thesis' code most likely used the lower bound (an erratum "
                   "of its text, which names the upper bound), and its 'positive bias helps' is the "
                   "compensation of that low alpha; our median rule does not need it (a modelling choice, kept "
                   "as the default: it is the most accurate at no bias).")
def alpha_bias(quick: bool, seed: int) -> list[Row]:
    """Rows of the alpha-bias study and the combined noise-and-bias study.

    Parameters
    ----------
    quick : bool
        Side 25 and fewer smoothing passes.
    seed : int
        Seed of the noise.
    """
    side = 25 if quick else 41
    rows = []
    for rule in RULES:
        runs = [reconstruct("hemisphere", side, bias_deg=b, rule=rule, seed=seed) for b in BIASES_DEG]
        for b, s in zip(BIASES_DEG, runs):
            rows.append(Row(f"{rule}/bias {b:+g}/signed", "signed error eps_mean (eq 3.1)", "% of h_tot",
                            100 * s["eps_mean"], x=b, series=rule, source="ours (the thesis' curve is a figure)"))
            rows.append(Row(f"{rule}/bias {b:+g}/area", "area error", "%", 100 * s["area_rel_err"], x=b, series=rule,
                            source="ours (the thesis' curve is a figure)"))
        signed = [s["eps_mean"] for s in runs]
        absolute = [s["abs_eps_mean"] for s in runs]
        area = [abs(s["area_rel_err"]) for s in runs]
        rows += [
            Row(f"{rule}/signed error falls with bias", "claim", "% of h_tot per deg",
                100 * float(np.polyfit(BIASES_DEG, signed, 1)[0]), source=f"{SOURCE} (alpha bias)",
                claim="increasing alpha decreases the average error (signed, eq 3.1)", holds=_monotone(signed),
                series=rule),
            Row(f"{rule}/|error| at +7 below |error| at 0", "claim", "% of h_tot", 100 * absolute[-1],
                source=f"{SOURCE} (alpha bias), issue 12's reading", holds=absolute[-1] < absolute[2], series=rule,
                claim="a positive bias lowers the mean absolute error (eq 3.2) below the unbiased one",
                note=f"mean |error| at 0 deg: {100 * absolute[2]:.2f} %"),
            Row(f"{rule}/area closer with positive bias", "claim", "%", 100 * area[-1], series=rule,
                source=f"{SOURCE} (alpha bias, Fig. 10-4)", holds=area[-1] < area[2] and area[3] < area[2],
                claim="a positive bias brings the reconstructed area closer to the real area",
                note=f"|area error| at 0 deg: {100 * area[2]:.2f} %"),
        ]
    passes = (0, 5, 20, 40) if quick else (0, 1, 2, 5, 10, 20, 30, 40, 50)
    for rule in RULES:
        rows += _combined(rule, side, passes, seed)
    return rows


def _combined(rule: str, side: int, passes, seed: int) -> list[Row]:
    """Rows of the combined study (+-2.8 deg noise with and without +7 deg bias against smoothing) for one rule."""
    rows, curves = [], {}
    for bias in (0.0, 7.0):
        curves[bias] = [reconstruct("hemisphere", side, noise_deg=2.8, bias_deg=bias, n_smooth=n, rule=rule,
                                    seed=seed)["eps_mean"] for n in passes]
        rows += [Row(f"{rule}/noise 2.8/bias {bias:+g}/{n} passes", "signed error with +-2.8 deg noise",
                     "% of h_tot", 100 * e, x=n, series=f"{rule}, bias {bias:+g}",
                     source="ours (thesis Fig. 10 combined)") for n, e in zip(passes, curves[bias])]
    plain, biased = np.array(curves[0.0]), np.array(curves[7.0])
    after20 = np.array(passes) >= 20
    gap = biased - plain
    source = f"{SOURCE} (noise with and without bias)"
    rows += [
        Row(f"{rule}/combined/error falls with smoothing", "claim", "% of h_tot", 100 * float(plain[-1] - plain[1]),
            source=source, holds=bool(plain[-1] < plain[1] and biased[-1] < biased[1]), series=rule,
            claim="the average error decreases with smoothing, with and without bias",
            note=f"{RULE_NOTES[rule]}; unbiased {100 * plain[1]:.2f} -> {100 * plain[-1]:.2f} %, +7 deg "
                 f"{100 * biased[1]:.2f} -> {100 * biased[-1]:.2f} % from {passes[1]} to {passes[-1]} passes"),
        Row(f"{rule}/combined/unbiased error positive", "claim", "% of h_tot", 100 * float(np.mean(plain[1:])),
            source=source, holds=bool(np.all(plain[1:] > 0)), claim="without bias the error is positive", series=rule,
            note=RULE_NOTES[rule]),
        Row(f"{rule}/combined/biased error negative after 20 passes", "claim", "% of h_tot",
            100 * float(np.max(biased[after20])), source=source, holds=bool(np.all(biased[after20] < 0)), series=rule,
            claim="with +7 deg bias the error is negative after 20 passes"),
        Row(f"{rule}/combined/bias translates the error", "claim", "% of h_tot", 100 * float(np.std(gap[1:])),
            source=source, holds=bool(np.std(gap[1:]) < 0.25 * abs(np.mean(gap[1:]))), series=rule,
            claim="the two curves differ by roughly a constant (ours: s.d. of the gap under 25 % of its mean)",
            note=f"mean gap {100 * float(np.mean(gap[1:])):.2f} % of h_tot"),
    ]
    return rows


@register("ch5-smoothing", "Thesis ch.5 Fig. 10: hemisphere error against smoothing passes at +-1.4/2.8/5.7 deg noise",
          description="Radius-20 hemisphere, 41 px, 20 % quantisation, uniform alpha noise of +-1.4, 2.8, 5.7 deg, "
                      "0-90 smoothing passes, median and lower-bound domain-alpha rules; the same passes without "
                      "noise, to separate what smoothing removes (noise) from what it adds (its own distortion).",
          findings="Ends as a modelling assumption of ours (the median domain-alpha rule), measured: with the median "
                   "rule the +-5.7 deg noise is gone after 2 passes (mean |error| with noise 1.14/1.34/1.81/2.46/"
                   "3.27/3.92 % at 2/5/10/20/40/70 passes against 0.97/1.29/1.75/2.42/3.26/3.91 % without noise, "
                   "41 px, seed 0): beyond that every pass only adds the smoothing's own distortion (the masked "
                   "3 x 3 mean lowers the steep alpha near the rim and blurs the rest; signed error -0.3 -> -1.0 %), "
                   "so 20-70 passes cannot beat 2-10. Under the lower-bound rule, the one that reproduces the "
                   "thesis' bias study (ch5-alpha-bias), the same distortion compensates its +5.3 % offset (noise-"
                   "free |error| 5.3/4.7/3.6/3.1 % at 0/5/20/40 passes) and '20-70 better than 2-10' holds, as in "
                   "the thesis: its smoothing benefit is the bias compensation of its low alpha, not noise removal. "
                   "The price is the offset: 57-59 % of the points within 5 % of the radius against the thesis' "
                   "95 %, which the median rule meets. 'No smoothing is poor' holds under the median rule (2.16 % "
                   "at 0 passes against at most 1.34 % at 2-10, round 8) and fails under the lower rule for the "
                   "same offset: unsmoothed, the +-5.7 deg noise partly offsets its low alpha (4.33 % against 5.29 % "
                   "without noise), and from 2 passes on the noisy and noise-free curves agree within 0.05 % (a "
                   "consequence of the rule, no defect). The quick form's 25 px matrix puts the median rule at "
                   "90 % within 5 % of the radius (outside there; 41 px in the full form). The masked boundary mode "
                   "of the smoothing is ours (prop-sfs A13: unspecified in the thesis).")
def smoothing(quick: bool, seed: int) -> list[Row]:
    """Rows of the noise/smoothing study.

    Parameters
    ----------
    quick : bool
        Side 25, four pass counts.
    seed : int
        Seed of the noise.
    """
    side, passes = (25, (0, 5, 20, 80)) if quick else (41, PASSES)
    rows = []
    for rule in ("median", "lower"):
        rows += _smoothing_rows(rule, side, passes, seed)
    return rows


def _smoothing_rows(rule: str, side: int, passes, seed: int) -> list[Row]:
    """Rows of the noise/smoothing study for one domain-alpha rule (with the noise-free curve)."""
    rows = []
    clean = {n: reconstruct("hemisphere", side, n_smooth=n, rule=rule, seed=seed) for n in passes}
    rows += [Row(f"{rule}/no noise/{n} passes/|error|", "mean |error| (eq 3.2)", "% of h_tot",
                 100 * s["abs_eps_mean"], x=n, series=f"{rule} no noise", source="ours (diagnosis: smoothing alone)")
             for n, s in clean.items()]
    runs = {}
    for noise in NOISES_DEG:
        runs = {n: reconstruct("hemisphere", side, noise_deg=noise, n_smooth=n, rule=rule, seed=seed) for n in passes}
        rows += [Row(f"{rule}/noise {noise}/{n} passes/|error|", "mean |error| (eq 3.2)", "% of h_tot",
                     100 * s["abs_eps_mean"], x=n, series=f"{rule} +-{noise} deg", source="ours (thesis Fig. 10)")
                 for n, s in runs.items()]
        few = [n for n in passes if (2 if noise == 5.7 else 1) <= n <= 10]
        within = min(runs[n]["within_5pct"] for n in few) if few else math.nan
        rows.append(Row(f"{rule}/noise {noise}/>95 % within 5 %", "share within 5 % of the radius", "%", 100 * within,
                        source=f"{SOURCE} (noise)", holds=within > 0.95, series=rule,
                        claim=f"with {'2' if noise == 5.7 else '1'}-10 passes more than 95 % of the points have "
                              "|error| < 5 % of the radius (ours: the worst of those pass counts)",
                        note=f"{side} px matrix, passes {', '.join(str(n) for n in few)}"))
    # runs now holds the +-5.7 deg study
    few = [runs[n]["abs_eps_mean"] for n in passes if 2 <= n <= 10]
    mid = [runs[n]["abs_eps_mean"] for n in passes if 20 <= n <= 70]
    many = [runs[n]["abs_eps_mean"] for n in passes if n >= 80]
    if few and mid:
        rows.append(Row(f"{rule}/noise 5.7/20-70 passes better than 2-10", "claim", "% of h_tot",
                        100 * float(np.mean(mid)), source=f"{SOURCE} (noise)", series=rule,
                        holds=float(np.mean(mid)) < float(np.mean(few)),
                        claim="at +-5.7 deg, 20-70 passes are more accurate than 2-10",
                        note=f"mean |error| with 2-10 passes: {100 * float(np.mean(few)):.2f} %"))
    if mid and many:
        rows.append(Row(f"{rule}/noise 5.7/>=80 passes lose accuracy", "claim", "% of h_tot",
                        100 * float(np.mean(many)), source=f"{SOURCE} (noise)", series=rule,
                        holds=float(np.mean(many)) > float(np.min(mid)),
                        claim="80 passes or more lose accuracy (ours: worse than the best of 20-70)"))
    if 0 in runs and few:
        rows.append(Row(f"{rule}/noise 5.7/no smoothing is poor", "claim", "% of h_tot", 100 * runs[0]["abs_eps_mean"],
                        source=f"{SOURCE} (noise)", holds=runs[0]["abs_eps_mean"] > max(few), series=rule,
                        claim="without smoothing the error distribution is poor (worse than with 2-10 passes)",
                        note=f"completeness {runs[0]['completeness']:.2f}; mean |error| with 2-10 passes at most "
                             f"{100 * max(few):.2f} %"))
    smoothed = [n for n in passes if n >= 2]
    if smoothed:
        left = max(abs(runs[n]["abs_eps_mean"] - clean[n]["abs_eps_mean"]) for n in smoothed)
        rows.append(Row(f"{rule}/noise 5.7/noise left after 2+ passes", "diagnosis", "% of h_tot", 100 * left,
                        source="ours (diagnosis)", series=rule,
                        note="largest |error(+-5.7 deg) - error(no noise)| over the pass counts >= 2: what "
                             "smoothing has not removed; no-noise |error| "
                             f"{100 * clean[smoothed[0]]['abs_eps_mean']:.2f}"
                             f" -> {100 * clean[smoothed[-1]]['abs_eps_mean']:.2f} % from {smoothed[0]} to "
                             f"{smoothed[-1]} passes (the smoothing's own distortion)"))
    return rows


@register("ch5-size", "Thesis ch.5 Fig. 11: hemisphere error against matrix size and quantisation percentile",
          description="Radius-20 hemisphere at 25-58 px, 5/10/20 % quantisation, with and without +3.5 deg bias, "
                      "both domain-alpha rules, no noise.",
          findings="Under the lower-bound rule (the one that reproduces the bias study) '10 % unbiased gives the "
                   "errors of 20 % with +3.5 deg' holds (largest gap 0.8 % of h_tot), as it must if the thesis' "
                   "alpha was low by about half a domain; under the median and upper rules it does not. 'A small "
                   "matrix needs a large percentile' ends as a modelling assumption of ours, the error measure: "
                   "eqs 3.1-3.2 average over the points produced, and ours drops the pixels it cannot reach. At "
                   "25 px and 5 % every iso-alpha domain is one pixel wide (no domain pixel has all four "
                   "neighbours in its domain) and 13 % of the matrix is lost (completeness 0.87 against 0.99 at "
                   "20 %; 41 px: 0.90 against 1.00), while the points that are produced are better (mean |error| "
                   "0.84 % against 1.70 %, median rule). Read as 'a small matrix needs a large percentile to be "
                   "reconstructed', the statement holds under every rule; read as an error on the points produced "
                   "it fails under every rule. Our curves are pixel contours with Braquelaire-Vialard tangents, "
                   "defined on one-pixel-wide domains, where the thesis' polygonal iso-alpha curves are not.")
def size(quick: bool, seed: int) -> list[Row]:
    """Rows of the size/percentile study.

    Parameters
    ----------
    quick : bool
        Sides 25 and 41 only.
    seed : int
        Unused (no noise); kept for the common signature.
    """
    sides = (25, 41) if quick else SIDES
    rows = []
    for rule in RULES:
        err, done = {}, {}
        for s in sides:
            for eps in EPSILONS:
                for bias in (0.0, 3.5):
                    scores = reconstruct("hemisphere", s, eps_alpha=eps, bias_deg=bias, rule=rule, seed=seed)
                    err[s, eps, bias], done[s, eps, bias] = scores["abs_eps_mean"], scores["completeness"]
                    rows.append(Row(f"{rule}/side {s}/eps {eps:g}/bias {bias:+g}", f"mean |error|, bias {bias:+g}",
                                    "% of h_tot", 100 * err[s, eps, bias], x=s, series=f"{rule} {100 * eps:g} %",
                                    source="ours (thesis Fig. 11)", note=f"completeness {done[s, eps, bias]:.3f}"))
        small, large = sides[0], sides[-1]
        rows += [
            Row(f"{rule}/small matrix needs a large percentile", "claim", "% of h_tot", 100 * err[small, 0.2, 0.0],
                source="thesis ch.5 §3.3.2", holds=err[small, 0.2, 0.0] < err[small, 0.05, 0.0], series=rule,
                claim=f"at {small} px, 20 % gives a lower error than 5 %",
                note=f"5 %: {100 * err[small, 0.05, 0.0]:.2f} %"),
            Row(f"{rule}/small matrix needs a large percentile (completeness)", "claim", "fraction",
                done[small, 0.2, 0.0], source="thesis ch.5 §3.3.2, read as reconstructed share", series=rule,
                holds=done[small, 0.2, 0.0] > done[small, 0.05, 0.0],
                claim=f"at {small} px, 20 % reconstructs more of the matrix than 5 % (the error rows above count "
                      "only the points produced)", note=f"5 %: {done[small, 0.05, 0.0]:.3f}"),
            Row(f"{rule}/large matrix takes a small percentile", "claim", "% of h_tot", 100 * err[large, 0.05, 0.0],
                source="thesis ch.5 §3.3.2", holds=err[large, 0.05, 0.0] <= err[large, 0.2, 0.0], series=rule,
                claim=f"at {large} px, 5 % gives an error no higher than 20 %",
                note=f"20 %: {100 * err[large, 0.2, 0.0]:.2f} %"),
        ]
        gaps = [abs(err[s, 0.1, 0.0] - err[s, 0.2, 3.5]) for s in sides]
        spread = [abs(err[s, 0.1, 0.0] - err[s, 0.05, 0.0]) for s in sides]
        rows.append(Row(f"{rule}/10 % unbiased like 20 % with +3.5 deg", "claim", "% of h_tot", 100 * float(max(gaps)),
                        source="thesis ch.5 §3.3.2", holds=bool(max(gaps) <= max(spread)), series=rule,
                        claim="for every size, 10 % without bias and 20 % with +3.5 deg bias give the same errors "
                              "(ours: their largest gap no larger than the 10 %-5 % gap)",
                        note=f"{RULE_NOTES[rule]}; largest 10 %-5 % gap {100 * float(max(spread)):.2f} %"))
    return rows


@register("ch5-vase", "Thesis ch.5 Fig. 13: vase col error against the quantisation percentile",
          description="The vase neck (eqs 3.5-3.6, domain divided by 10, prop-sfs A21) at 60 px, 20/10/5 % "
                      "quantisation, 20 % seed, the three domain-alpha rules; then (diagnosis) the same with the flat "
                      "floor around the body (z = 0 of eq 3.6) left out of the object mask.",
          findings="Was a defect of ours in leafsfs seed selection, now fixed (leafsfs.quantize). 41 % of the vase "
                   "matrix is the flat floor of eq 3.6 (z = 0, alpha exactly 0). Before the fix the 20 % seed quantile "
                   "was alpha_0 = 0, so the seed domain was the floor alone (99.5 % of the seed pixels at height 0) "
                   "and the body's crest (alpha above 0, below 20 deg) was no seed: the body became one part seeded by "
                   "the floor and reached only through its vertical walls, in an alpha order running against the "
                   "geometry, and each extra domain added a wrongly ordered annulus (median rule 35.9/60.9/108 % at "
                   "20/10/5 %, upper 439 %, lower 19.9/39.3/68.8 %). The fix follows the method (seeds are the regions "
                   "of locally minimal alpha): a plateau of pixels tied at the lowest alpha (9 or more: more than the "
                   "grid's symmetries can tie) stays in the seed domain but no longer counts in the area fractions, "
                   "which are measured on the pixels above it; whatever its share, so that a floor just under the seed "
                   "fraction cannot starve the crest either. Now the seed domain is the floor and the crest (53 % of "
                   "the object, 77 % of it on the floor), the watershed gives 3 parts (two floors and the body, seeded "
                   "by its crest), and the error at 60 px is median 3.94/4.19/4.14 %, upper 9.72/5.59/4.87 %, lower "
                   "4.74/4.55/4.21 % (over the body alone, before every seed pixel kept its measured height, which "
                   "moved the totals by at most 0.03: 7.0/7.5/7.7, 17.3/10.0/9.0, 8.4/8.1/7.8 %; with the floor "
                   "out of the mask 9.2/9.7/10.0 % under the median rule: the interior is the same, 5.9 against 6.0 % "
                   "at 20 %, and the difference is the body's outer two pixels, 150 of 390 of which go to the floor's "
                   "parts: 12 against 24 %). The thesis' fall of the error with the percentile now holds under its "
                   "literal upper-bound rule and the lower-bound rule (their error falls towards the median rule's as "
                   "the domains narrow), not under our median rule, which is flat within 0.25 % of h_tot: a modelling "
                   "assumption of ours (the median domain alpha, as in ch5-alpha-bias), no longer a defect. What else "
                   "moved: the quick suite (fused) is identical; of the sfs-synthetic suite (buffer, fused) the 6 vase "
                   "rows changed (buffer: points within 5 % of h_tot 0.47 -> 0.90 at 20 %; completeness at 5 % 0.998 "
                   "-> 0.939, as with the floor out of the mask) and the -7 deg hemisphere, whose 21 pixels clipped to "
                   "alpha = 0 are now a plateau (buffer 6.05 -> 5.84 %, fused 0.95 -> 0.92 %; in ch5-alpha-bias the -7 "
                   "deg rows by 0.2-0.5 % of h_tot, no verdict). The thesis blames its 5 % corner divergence on toggle "
                   "points at the col; not looked into here.")
def vase(quick: bool, seed: int) -> list[Row]:
    """Rows of the vase-col study, with the floor in the mask (as eq 3.6) and left out (diagnosis).

    Parameters
    ----------
    quick : bool
        40 px instead of 60.
    seed : int
        Unused (no noise).
    """
    side = 40 if quick else 60
    rows = []
    for floor_out in (False, True):
        for rule in RULES if not floor_out else ("median", "lower"):
            label = f"{rule}, floor out" if floor_out else rule
            runs = {eps: reconstruct("vase", side, eps_alpha=eps, rule=rule, seed=seed, floor_out=floor_out)
                    for eps in (0.2, 0.1, 0.05)}
            rows += [Row(f"{label}/eps {eps:g}/|error|", "mean |error| (eq 3.2)", "% of h_tot",
                         100 * s["abs_eps_mean"], x=100 * eps, series=label,
                         source="ours (diagnosis: floor out of the mask)" if floor_out else "ours (thesis Fig. 13)",
                         note=f"completeness {s['completeness']:.2f}, {s['levels']} domains, "
                              f"body alone {100 * s['body_abs_eps_mean']:.2f} %")
                     for eps, s in runs.items()]
            first = runs[0.2]
            rows.append(Row(f"{label}/seed on the floor", "diagnosis", "% of seed pixels", 100 * first["seed_on_floor"],
                            source="ours (diagnosis)", series=label,
                            note=f"seed domain {100 * first['seed_share']:.0f} % of the object's pixels, "
                                 f"{first['parts']} parts"))
            errors = [runs[eps]["abs_eps_mean"] for eps in (0.2, 0.1, 0.05)]
            rows.append(Row(f"{label}/smaller percentile, lower error", "claim", "% of h_tot", 100 * errors[-1],
                            source="thesis ch.5 §3.3.4" + (", floor out of the mask (ours)" if floor_out else ""),
                            holds=_monotone(errors), series=label,
                            claim="a smaller percentile lowers the local error (20 -> 10 -> 5 %)",
                            note="20 / 10 / 5 %: " + " / ".join(f"{100 * e:.2f}" for e in errors) + " %"
                                 + ("; median rule: its domain alpha gains nothing as the domains narrow, unlike "
                                    "the bounds, so its error does not fall (a modelling choice: ch5-vase findings)"
                                    if label.startswith("median") else "")))
    return rows


def error_matrix(surface: str, side: int, *, noise_deg: float = 0.0, n_smooth: int = 0, eps_alpha: float = 0.2,
                 rule: str = "median", seed: int = 0) -> np.ndarray:
    """The thesis' error matrix: signed ``eps = (d_hat - d) / h_tot`` per pixel (eq 3.1), NaN where not reconstructed.

    Parameters
    ----------
    surface : str
        Name in :mod:`scenes.surfaces`.
    side : int
        Matrix side, pixels.
    noise_deg : float
        Uniform alpha noise amplitude, degrees.
    n_smooth : int
        Smoothing passes.
    eps_alpha : float
        Quantisation percentile (fraction).
    rule : {"median", "upper", "lower"}
        Domain-alpha rule.
    seed : int
        Seed of the noise.

    Returns
    -------
    ndarray, 2-D
        Signed relative error (fraction of h_tot); NaN outside the object or where not reconstructed.
    """
    sample = sample_surface(get_surface(surface), side, alpha_noise_deg=noise_deg, seed=seed)
    params = SfsParams(n_smooth=n_smooth, quantization="percentile", eps_alpha=eps_alpha, eps_seed=0.2,
                       alpha_max_deg=85, rim_px=0, alpha_rule=rule)
    result = reconstruct_heights(sample.alpha, sample.height, sample.mask, sample.grid, "buffer", params)
    h_tot = float(np.ptp(sample.truth[sample.mask]))
    done = sample.mask & np.isfinite(result.height)
    return np.where(done, (result.height - sample.truth) / h_tot, np.nan)


def asymmetry(errors: np.ndarray) -> float:
    """How far an error matrix of a square-symmetric surface departs from the square's symmetries.

    The mean of ``| |e| - |T(e)| |`` over the seven rotations and reflections
    ``T`` of the square (pixels finite in both), divided by the mean ``|e|``:
    0 for an error pattern with the hemisphere's symmetry.

    Parameters
    ----------
    errors : ndarray, 2-D, square
        Error matrix (NaN where missing), centred on the surface's axis.

    Returns
    -------
    float
        Asymmetry index (dimensionless, >= 0); NaN without finite errors.
    """
    a = np.abs(np.asarray(errors, float))
    if not np.isfinite(a).any() or np.nanmean(a) == 0:
        return math.nan if not np.isfinite(a).any() else 0.0
    images = [np.rot90(a, k) for k in (1, 2, 3)] + [np.fliplr(a), np.flipud(a), a.T, np.rot90(a, 2).T]
    return float(np.mean([np.nanmean(np.abs(a - t)) for t in images]) / np.nanmean(a))


#: Thresholds of the cumulative |error| distribution, % of h_tot (5 %: the thesis' criterion).
CUMULATIVE_PCT = (1.0, 2.0, 5.0, 10.0)


def _maps_figures(maps: dict, passes) -> dict:
    """Error matrices (|eps|, one panel per rule and pass count) and their |eps| histograms, as figures."""
    from matplotlib.figure import Figure

    rules = list(dict.fromkeys(rule for rule, _ in maps))
    matrices = Figure(figsize=(2.0 * len(passes) + 0.8, 2.1 * len(rules)), layout="constrained")
    axes = matrices.subplots(len(rules), len(passes), squeeze=False)
    for i, rule in enumerate(rules):
        for j, n in enumerate(passes):
            image = axes[i][j].imshow(100 * np.abs(maps[rule, n]), vmin=0, vmax=10, cmap="magma", origin="lower")
            axes[i][j].set_title(f"{rule}, {n} passes", fontsize=7)
            axes[i][j].set_xticks([])
            axes[i][j].set_yticks([])
    matrices.colorbar(image, ax=axes, shrink=0.8, label="|error|, % of h_tot")
    matrices.suptitle("Thesis ch.5 Fig. 10: error matrices, hemisphere with +-5.7 deg alpha noise", fontsize=9)
    histograms = Figure(figsize=(4.6 * len(rules), 3.2), layout="constrained")
    hist_axes = histograms.subplots(1, len(rules), squeeze=False)[0]
    for axes_, rule in zip(hist_axes, rules):
        for n in passes:
            values = 100 * np.abs(maps[rule, n])
            axes_.hist(values[np.isfinite(values)], bins=np.linspace(0, 15, 31), histtype="step", label=f"{n} passes")
        axes_.axvline(5.0, color="grey", lw=0.8, ls="--")
        axes_.set_title(f"{rule} rule", fontsize=8)
        axes_.set_xlabel("|error|, % of h_tot", fontsize=8)
        axes_.set_ylabel("pixels", fontsize=8)
        axes_.legend(fontsize=6)
    histograms.suptitle("Thesis ch.5 Fig. 10: error distributions, hemisphere with +-5.7 deg alpha noise", fontsize=9)
    return {"error-matrices": matrices, "error-histograms": histograms}


@register("ch5-error-maps", "Thesis ch.5 Fig. 10: error matrices and error distributions against smoothing passes",
          description="Hemisphere (radius 20) at 41 px, +-5.7 deg uniform alpha noise, 20 % quantisation and seed, "
                      "0-20 smoothing passes, median and lower-bound domain-alpha rules: the error matrix |eps| per "
                      "pixel (eq 3.2, shown as images) and its distribution (histograms; the cumulative shares below "
                      "1 / 2 / 5 / 10 % of h_tot as rows), and the error matrix's asymmetry (its mean departure from "
                      "the square's 8 symmetries, relative to its mean |eps|) against the passes.",
          findings="The thesis shows these as figures only (prop-sfs §5.1, §5.5): its one statement on the error "
                   "matrices is that the local error pattern is non-symmetric with 2-4 passes (a bad iso-alpha curve "
                   "extraction) and symmetric from the 5th pass on. 'Symmetric from the 5th pass' is read as: the "
                   "mean asymmetry index at 5 and 10 passes is below its mean at 2-4 passes (an assumption; the "
                   "thesis gives no measure). Measured in development (seed 0; seed 1, not looked at first, in "
                   "brackets): under the median rule the asymmetry falls steadily with the passes (0.70 / 0.64 / 0.61 "
                   "at 2 / 3 / 4 passes, 0.56 / 0.36 at 5 / 10; seed 1: 0.60 / 0.58 / 0.53, 0.58 / 0.39), so there is "
                   "no step at the 5th pass but the claim's comparison holds; under the lower rule the pattern is "
                   "nearly symmetric from 2 passes on (0.15 / 0.14 / 0.14, 0.14 / 0.12; seed 1: 0.13 / 0.14 / 0.13, "
                   "0.15 / 0.14): the comparison holds on seed 0 and fails on seed 1, inside the noise of the index. "
                   "Ours has no 2-4-pass defect of curve extraction to remove. The noise-free hemisphere's own "
                   "asymmetry under the median rule is 0.43 at 0 passes and 0.23 at 10 (lower rule 0.06): the "
                   "median rule's small errors (-0.3 % mean) are not axis-symmetric (a property of the rule on the "
                   "pixel grid, reported, not a claim of the thesis). The distributions (seed 0): under the median "
                   "rule 88.9 / 97.2 / 93.2 % of the pixels are within 5 % of h_tot at 0 / 5 / 20 passes (the "
                   "thesis' '> 95 % within 5 % with 2-10 passes' at 5 passes, and 'no smoothing is poor'); under the "
                   "lower rule 65.3 / 62.2 / 77.0 %, its +5 % offset (ch5-alpha-bias) showing as the bright rim of "
                   "its error matrices.")
def error_maps(quick: bool, seed: int):
    """Rows (cumulative error shares, asymmetry, the symmetry claim) and the error-matrix and histogram figures.

    Parameters
    ----------
    quick : bool
        25 px and passes 0, 2, 4, 5, 20.
    seed : int
        Seed of the alpha noise.

    Returns
    -------
    rows : list of Row
    figures : dict of matplotlib.figure.Figure
        ``error-matrices`` and ``error-histograms``.
    """
    side, passes = (25, (0, 2, 4, 5, 20)) if quick else (41, (0, 2, 3, 4, 5, 10, 20))
    rows, maps = [], {}
    for rule in ("median", "lower"):
        index = {}
        for n in passes:
            maps[rule, n] = errors = error_matrix("hemisphere", side, noise_deg=5.7, n_smooth=n, rule=rule, seed=seed)
            index[n] = asymmetry(errors)
            rows.append(Row(f"{rule}/{n} passes/asymmetry", "asymmetry of the error matrix", "", index[n], x=n,
                            series=rule, source="ours (thesis Fig. 10 error matrices)"))
            if n in (0, 5, 20):
                values = 100 * np.abs(errors[np.isfinite(errors)])
                rows += [Row(f"{rule}/{n} passes/|error| < {c:g} %", "share of pixels with |error| below x",
                             "%", 100 * float(np.mean(values < c)), x=c, series=f"{rule}, {n} passes",
                             source="ours (thesis Fig. 10 error distributions)") for c in CUMULATIVE_PCT]
        few = [index[n] for n in passes if 2 <= n <= 4]
        many = [index[n] for n in passes if 5 <= n <= 10]
        rows.append(Row(f"{rule}/symmetric from the 5th pass", "claim", "", float(np.mean(many)),
                        source="thesis ch.5 §3.3.1 (prop-sfs §5.5)", series=rule,
                        holds=bool(np.mean(many) < np.mean(few)),
                        claim="the local error pattern is non-symmetric with 2-4 passes and symmetric from the 5th "
                              "pass on (ours: mean asymmetry index at 5-10 passes below its mean at 2-4)",
                        note=f"asymmetry at 2-4 passes {np.mean(few):.3f}, at 5-10 passes {np.mean(many):.3f}"
                             + ("; the lower rule's pattern is nearly symmetric from 2 passes on, so this comparison "
                                "is within the index's noise (ch5-error-maps findings)" if rule == "lower" else "")))
    return rows, _maps_figures(maps, passes)


#: Saddle sides (px) and the thesis' seed-curve cutoffs 2/l for their seed perimeters l = 33, 68, 103 px.
SADDLE_SIDES = (25, 50, 75)
SADDLE_CUTOFFS = (0.061, 0.029, 0.019)


def saddle_error(side: int, cutoff, *, rule: str = "median", seed: int = 0) -> dict:
    """Reconstruct the noisy saddle with one seed-curve cutoff; error over the propagated pixels.

    The saddle is ``h = 0.5 (x^2 - y^2)`` on ``[-1, 1]^2`` (prop-sfs A20: the
    thesis gives no equation), with uniform height noise of amplitude 10 % of
    ``h_tot`` (thesis §3.3.3: the distance noise) and noise-free alpha; a 15 %
    seed (the thesis' circular seeds of 88 / 376 / 857 px at 25 / 50 / 75 px:
    ours 95 / 376 / 844), 20 % quantisation, 5 smoothing passes. The seed
    domain keeps its measured (noisy) heights whatever the cutoff, so the
    error is taken over the pixels propagated from the seed curve.

    Parameters
    ----------
    side : int
        Matrix side, pixels.
    cutoff : float or None
        Seed-curve low-pass cutoff, cycles per pixel of arc (``None``: no low-pass).
    rule : {"median", "upper", "lower"}
        Domain-alpha rule.
    seed : int
        Seed of the height noise.

    Returns
    -------
    dict
        ``abs_eps_mean`` and ``eps_mean`` (eqs 3.2 and 3.1 over the propagated pixels, fractions of h_tot),
        ``seed_px`` (seed-domain pixels) and ``completeness`` (share of the non-seed pixels reconstructed).
    """
    sample = sample_surface(get_surface("saddle"), side, height_noise=0.1, seed=seed)
    params = SfsParams(n_smooth=5, quantization="percentile", eps_alpha=0.2, eps_seed=0.15, alpha_max_deg=85,
                       rim_px=0, alpha_rule=rule, seed_cutoff=cutoff)
    result = reconstruct_heights(sample.alpha, sample.height, sample.mask, sample.grid, "buffer", params)
    outside_seed = sample.mask & ~result.seed
    scores = height_errors(result.height, sample.truth, outside_seed)
    scores["eps_mean"], scores["abs_eps_mean"] = (v * float(np.ptp(sample.truth[outside_seed]))
                                                  / float(np.ptp(sample.truth[sample.mask]))
                                                  for v in (scores["eps_mean"], scores["abs_eps_mean"]))
    scores["seed_px"] = int((result.seed & sample.mask).sum())
    return scores


@register("ch5-saddle-cutoff", "Thesis ch.5 Fig. 12: seed-curve low-pass cutoff on noisy saddles of 25, 50 and 75 px",
          description="Saddle h = 0.5 (x^2 - y^2) (prop-sfs A20) at 25 / 50 / 75 px with uniform height noise of "
                      "+-10 % of h_tot, noise-free alpha, a 15 % seed (circular seed curves of about the thesis' "
                      "88 / 376 / 857 px), each reconstructed with the three cutoffs 0.061 / 0.029 / 0.019 cycles "
                      "per pixel of arc (2 / l for l = 33 / 68 / 103 px) and without a low-pass; mean |error| (eq "
                      "3.2, % of the whole saddle's h_tot) over the pixels propagated from the seed curve; median "
                      "and lower-bound domain-alpha rules.",
          findings="The thesis gives figures only; its statements are the claim rows. Our cutoff keeps the "
                   "harmonics up to floor(f_c l) of the seed curve's heights (leafsfs.seed): on the small saddle "
                   "(l about 33 px) 0.029 and 0.019 both keep none, the seed curve becomes flat, and the error is "
                   "the same for both. Measured in development (seed 0; seed 1, not looked at first, in brackets), "
                   "median rule, 0.061 / 0.029 / 0.019 / no low-pass: 25 px 3.9 / 13.8 / 13.8 / 9.2 % (4.1 / 14.1 "
                   "/ 14.1 / 8.0), 50 px 5.1 / 4.3 / 13.6 / 39.6 % (4.3 / 3.5 / 13.4 / 43.1), 75 px 5.8 / 4.9 / 4.9 "
                   "/ 47.4 % (8.0 / 7.9 / 8.1 / 50.2). 'Too small a cutoff flattens the seed curve' (0.019 on the "
                   "small saddle) and 'a larger cutoff perturbs less in absolute error' hold under both rules and "
                   "seeds; each saddle is best near its own 2 / l. 'Too large a cutoff keeps the noise' (0.061 on "
                   "the large saddle) holds by 0.9 points on seed 0 under the median rule and is a tie on seed 1 "
                   "(7.95 against 8.08 %); under the lower rule it fails on seed 0 (5.2 against 7.0 %) and holds on "
                   "seed 1 (8.8 against 7.9 %): at 75 px the "
                   "seed curve is 103 px long and the 6 harmonics that 0.061 keeps carry little of the +-10 % "
                   "noise, so the penalty the thesis saw is within the seed-to-seed spread here (not a defect; the "
                   "thesis' saddle and noise spectrum are not given). Without a low-pass the propagated error is "
                   "8-50 %: the low-pass itself is what the study is about, and it reproduces.")
def saddle_cutoff(quick: bool, seed: int) -> list[Row]:
    """Rows of the cutoff study (error per saddle and cutoff, and the thesis' three statements).

    Parameters
    ----------
    quick : bool
        Unused: the 24 reconstructions take about 7 s.
    seed : int
        Seed of the height noise.
    """
    source = "thesis ch.5 §3.3.3, Fig. 12 (prop-sfs §5.5)"
    rows = []
    for rule in ("median", "lower"):
        err = {}
        for side in SADDLE_SIDES:
            for cutoff in SADDLE_CUTOFFS + (None,):
                s = saddle_error(side, cutoff, rule=rule, seed=seed)
                err[side, cutoff] = 100 * s["abs_eps_mean"]
                name = "no low-pass" if cutoff is None else f"cutoff {cutoff:g}"
                rows.append(Row(f"{rule}/side {side}/{name}", "mean |error| off the seed (eq 3.2)" if cutoff else
                                "mean |error| off the seed, no low-pass", "% of h_tot", err[side, cutoff],
                                x=side if cutoff is None else cutoff, source="ours (thesis Fig. 12)",
                                series=rule if cutoff is None else f"{rule}, side {side}",
                                note=f"seed {s['seed_px']} px, completeness {s['completeness']:.2f}"))
        small, large = SADDLE_SIDES[0], SADDLE_SIDES[-1]
        wide, narrow = SADDLE_CUTOFFS[0], SADDLE_CUTOFFS[-1]
        mean_wide = float(np.mean([err[s, wide] for s in SADDLE_SIDES]))
        mean_narrow = float(np.mean([err[s, narrow] for s in SADDLE_SIDES]))
        rows += [
            Row(f"{rule}/too small a cutoff flattens the small saddle", "claim", "% of h_tot", err[small, narrow],
                source=source, series=rule, holds=bool(err[small, narrow] > err[small, wide]),
                claim=f"too small a cutoff flattens the seed curve: {narrow:g} on the {small} px saddle is worse "
                      f"than {wide:g} (which suits it better)", note=f"{wide:g}: {err[small, wide]:.2f} %"),
            Row(f"{rule}/too large a cutoff keeps the noise on the large saddle", "claim", "% of h_tot",
                err[large, wide], source=source, series=rule, holds=bool(err[large, wide] > err[large, narrow]),
                claim=f"too large a cutoff keeps the noise: {wide:g} on the {large} px saddle is worse than {narrow:g}",
                note=f"{narrow:g}: {err[large, narrow]:.2f} %; a gap within the seed-to-seed spread at this size "
                     "(ch5-saddle-cutoff findings), not a defect"),
            Row(f"{rule}/a larger cutoff perturbs less", "claim", "% of h_tot", mean_wide, source=source,
                series=rule, holds=bool(mean_wide < mean_narrow),
                claim=f"in absolute error a larger cutoff perturbs the result less (ours: mean over the three "
                      f"saddles, {wide:g} below {narrow:g})", note=f"{narrow:g}: {mean_narrow:.2f} %"),
        ]
    return rows


#: The three PROP-SFS variants of thesis ch.5 §2, in the order of the plots.
VARIANTS = ("simple", "sps", "buffer")
#: |error| above which a reconstructed pixel counts as an outlier point, fraction of h_tot (an assumption: the
#: thesis names outlier points in its figures without a threshold).
OUTLIER_EPS = 0.10


def variant_scores(surface: str, variant: str, side: int = 50) -> dict:
    """One noise-free surface reconstructed with one variant (10 % quantisation, 20 % seed): the §3.1-3.2 measures.

    Parameters
    ----------
    surface : str
        Name in :mod:`scenes.surfaces` (``ellipsoid``, ``complex``, ``multi-seed``).
    variant : {"simple", "sps", "buffer"}
        PROP-SFS variant.
    side : int
        Matrix side, pixels.

    Returns
    -------
    dict
        ``completeness`` and ``abs_eps_mean`` (eq 3.2), and over the reconstructed pixels off the seeds:
        ``points_per_pixel`` (mean number of candidate heights), ``outliers`` (share with |eps| above
        :data:`OUTLIER_EPS`), ``distance_rho`` (Spearman correlation of |eps| with the distance to the nearest
        seed pixel) and ``parts`` (watershed parts, one seed each).
    """
    sample = sample_surface(get_surface(surface), side)
    params = SfsParams(n_smooth=0, quantization="percentile", eps_alpha=0.1, eps_seed=0.2, alpha_max_deg=85, rim_px=0)
    result = reconstruct_heights(sample.alpha, sample.height, sample.mask, sample.grid, variant, params)
    scores = height_errors(result.height, sample.truth, sample.mask)
    off_seed = sample.mask & np.isfinite(result.height) & ~result.seed
    error = np.abs(result.height - sample.truth)[off_seed] / float(np.ptp(sample.truth[sample.mask]))
    distance = ndimage.distance_transform_edt(~(result.seed & sample.mask))[off_seed]
    scores["points_per_pixel"] = float(result.count[off_seed].mean())
    scores["outliers"] = float(np.mean(error > OUTLIER_EPS))
    scores["distance_rho"] = float(stats.spearmanr(distance, error).statistic)
    scores["parts"] = int(result.parts.max())
    return scores


@register("ch5-variants", "Thesis ch.5 §3.1-3.2, Figs 6-9: Simple, SPS and Buffer on the ellipsoid, the complex "
          "surface and the multi-seed surface",
          description="Noise-free inclined ellipsoid, complex surface (eq 3.3) and multi-seed surface at 50 px, 10 % "
                      "quantisation, 20 % seed, no smoothing, each reconstructed with the three variants: "
                      "completeness, mean |error| (eq 3.2), candidate points per pixel off the seeds (the redundancy "
                      "map of Fig. 8-6), the share of outlier points (|error| above 10 % of h_tot, an assumption) "
                      "and the rank correlation of |error| with the distance to the nearest seed (Fig. 9-4's "
                      "accumulation).",
          findings="Chapter 5 §3.1-3.2 is qualitative (prop-sfs §5.3-5.4): its statements are the claim rows, with "
                   "thresholds of ours ('complete': at least 95 % of the pixels; 'no significant difference': mean "
                   "|error| within 1 % of h_tot). The Mozart depth map (the thesis' ref. 208) is not in the project, "
                   "so Fig. 7 is not reproduced; its lesson (SPS's outlier points at crossing curves, fewer with "
                   "Buffer) is the complex surface's row here. Measured (seed-free, 50 px): ellipsoid completeness "
                   "0.75 / 1.00 / 0.98 (Simple / SPS / Buffer), mean |error| 0.49 / 0.73 / 0.73 %; complex surface "
                   "outliers 9.2 / 27.2 / 8.0 %, points per pixel 2.28 / 1.80 / 1.01 (Buffer keeps 1 % of its "
                   "pixels with more than one candidate: the redundancy the thesis says remains); multi-seed surface "
                   "(12 parts): |error| rises with the distance from the seeds under every variant (Spearman 0.30 / "
                   "0.34 / 0.40). The thresholds were set after these numbers; at 40 and 64 px (not looked at "
                   "before) every claim holds too (Buffer's ellipsoid completeness 0.973 / 0.987, complex-surface "
                   "outliers 41.2 / 7.0 % against SPS 58.5 / 16.9 %).")
def variants(quick: bool, seed: int) -> list[Row]:
    """Rows of the variant comparison (measures per surface and variant, and the thesis' statements).

    Parameters
    ----------
    quick : bool
        Unused: the nine reconstructions take about 10 s.
    seed : int
        Unused (noise-free surfaces).
    """
    source = "thesis ch.5 §3.1-3.2 (prop-sfs §5.3-5.4)"
    measures = (("completeness", "completeness", "fraction", 1.0), ("abs_eps_mean", "mean |error| (eq 3.2)",
                "% of h_tot", 100.0), ("points_per_pixel", "candidate points per pixel off the seeds", "points", 1.0),
                ("outliers", "outlier points (|error| > 10 % of h_tot)", "%", 100.0),
                ("distance_rho", "rank correlation of |error| with the distance to the seeds", "", 1.0))
    rows, s = [], {}
    for surface in ("ellipsoid", "complex", "multi-seed"):
        for x, variant in enumerate(VARIANTS):
            s[surface, variant] = scores = variant_scores(surface, variant)
            rows += [Row(f"{surface}/{variant}/{key}", quantity, unit, scale * scores[key], x=x, series=surface,
                         source="ours (thesis Figs 6-9)", note=f"variant {variant}, {scores['parts']} parts")
                     for key, quantity, unit, scale in measures]
    ell, cpx, multi = ({v: s[name, v] for v in VARIANTS} for name in ("ellipsoid", "complex", "multi-seed"))
    gap = 100 * abs(ell["sps"]["abs_eps_mean"] - ell["buffer"]["abs_eps_mean"])
    rows += [
        Row("ellipsoid/Simple incomplete, SPS and Buffer complete", "claim", "fraction", ell["simple"]["completeness"],
            source=source, holds=bool(ell["simple"]["completeness"] < 0.95 <= min(ell["sps"]["completeness"],
                                                                                  ell["buffer"]["completeness"])),
            claim="Simple leaves OC points missing (GS divergence); SPS and Buffer are complete (ours: at least 95 % "
                  "of the pixels)", note=f"SPS {ell['sps']['completeness']:.3f}, Buffer "
                                          f"{ell['buffer']['completeness']:.3f}"),
        Row("ellipsoid/SPS and Buffer alike", "claim", "% of h_tot", gap, source=source, holds=bool(gap < 1.0),
            claim="on the ellipsoid there is no significant difference between SPS and Buffer (ours: mean |error| "
                  "within 1 % of h_tot)"),
        Row("complex/Buffer has fewer outlier points than SPS", "claim", "%", 100 * cpx["buffer"]["outliers"],
            source=source, holds=bool(cpx["buffer"]["outliers"] < cpx["sps"]["outliers"]),
            claim="SPS gives many outlier points on the complex surface; Buffer reduces them",
            note=f"SPS {100 * cpx['sps']['outliers']:.1f} %"),
        Row("complex/Buffer has fewer points per pixel than SPS", "claim", "points",
            cpx["buffer"]["points_per_pixel"], source=source,
            holds=bool(cpx["buffer"]["points_per_pixel"] < cpx["sps"]["points_per_pixel"]),
            claim="Buffer gives fewer points per pixel than SPS (Fig. 8-6)",
            note=f"SPS {cpx['sps']['points_per_pixel']:.2f}"),
        Row("multi-seed/error accumulates from each seed", "claim", "", multi["buffer"]["distance_rho"],
            source=source, holds=bool(multi["buffer"]["distance_rho"] > 0),
            claim="the error accumulates with the distance from each seed (ours: |error| rank-correlated positively "
                  "with the distance to the nearest seed, Buffer)"),
    ]
    return rows


def fit_law(area, eps, seconds) -> tuple[float, float]:
    """Exponents ``p, q`` of ``t = A a^p / eps^q + C`` fitted to timings (the form of the thesis' eq 3.10).

    For each trial constant ``C`` below the shortest time, ``log(t - C)`` is
    fitted linearly in ``log a`` and ``log eps``; the ``C`` with the least
    squared error in ``t`` wins.

    Parameters
    ----------
    area : ndarray
        Matrix sizes a_tot, pixels.
    eps : ndarray
        Quantisation percentiles (fractions).
    seconds : ndarray
        Run times, s.

    Returns
    -------
    p, q : float
        Exponents of a_tot and of 1/eps.
    """
    design = np.column_stack([np.ones_like(area), np.log(area), np.log(eps)])
    best = (np.inf, math.nan, math.nan)
    for constant in np.linspace(0.0, 0.95 * float(np.min(seconds)), 40):
        coef = np.linalg.lstsq(design, np.log(seconds - constant), rcond=None)[0]
        error = float(np.sum((np.exp(design @ coef) + constant - seconds) ** 2))
        if error < best[0]:
            best = (error, float(coef[1]), float(-coef[2]))
    return best[1], best[2]


@register("ch5-complexity", "Thesis ch.5 §3.4: complexity law t = 0.022 a_tot^1.37 / eps^1.12 + 14",
          description="Noise-free hemisphere at the thesis' sizes (25-58 px; 75 and 100 px as its validation) and "
                      "percentiles 5/10/15/20 %; the shortest of repeated runs (the thesis kept the shortest of 4); "
                      "log t = c + p log a_tot - q log eps fitted on ours.",
          findings="The law's unit, machine and constant are not stated (prop-sfs A15): only its exponents are "
                   "compared, fitted with a constant term as in the law. Our time grows less than the thesis' with "
                   "the matrix size: the propagation visits each annulus once and the pre-processing is "
                   "vectorised, where the thesis' output (and so its time) grew with point redundancy (ch.7). "
                   "Measured (round 10, shortest of 2 runs, 5 and 20 %): at the thesis' sizes a fixed cost of "
                   "about 0.07 s (20 %) to 0.2 s (5 %) dominates and flattens the fit; beyond them ours is linear "
                   "in the pixels: 0.28 / 0.48 / 1.04 / 2.56 s at 100 / 141 / 200 / 283 px and 20 % (log-log "
                   "slope 1.07 in a_tot from 100 px; the law's fit from 100 px gives 0.96 and 0.71), against the "
                   "law's 1.37. An implementation of lower complexity than the thesis' (an implementation "
                   "difference, not a defect): the row is outside because the law does not describe ours.")
def complexity(quick: bool, seed: int) -> list[Row]:
    """Rows of the complexity law (fitted exponents against the published ones, times against the law's shape).

    Parameters
    ----------
    quick : bool
        Sides 25-41, two percentiles, one repeat.
    seed : int
        Unused (no noise).
    """
    sides, epsilons, repeat = ((25, 34, 41), (0.1, 0.2), 1) if quick else (SIDES + (75, 100), (0.05, 0.1, 0.15, 0.2), 3)
    samples = []
    for s in sides:
        for eps in epsilons:
            t = min(reconstruct("hemisphere", s, eps_alpha=eps, seed=seed)["seconds"] for _ in range(repeat))
            samples.append((s * s, eps, t))
    a, eps, t = (np.array(v, float) for v in zip(*samples))
    p, q = fit_law(a, eps, t)
    tol = ("0.5: the law is a shape target (prop-sfs A15, §9.8: exponents of the same sign and similar size); "
           "its constant 14 and unit are not comparable")
    rows = [Row("exponent of a_tot", "fitted exponent", "", p, 1.37, 0.5, tol, "thesis ch.5 eq 3.10", x=1,
                series="exponents", note="fitted with a constant term, as the law has"),
            Row("exponent of 1/eps", "fitted exponent", "", q, 1.12, 0.5, tol, "thesis ch.5 eq 3.10", x=2,
                series="exponents", note="fitted with a constant term, as the law has")]
    for (area, e, seconds) in samples:
        law = 0.022 * area**1.37 / (100 * e) ** 1.12 + 14
        rows.append(Row(f"side {int(round(math.sqrt(area)))}/eps {e:g}", "time, ours (s) against the law (its unit)",
                        "s", seconds, x=law, series=f"eps {100 * e:g} %", source="ours; x = the law's value",
                        note=f"law: {law:.1f} (unit not stated)"))
    return rows

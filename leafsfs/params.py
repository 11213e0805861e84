"""PROP-SFS parameters with their sources and validation.

Defaults follow the thesis' leaf protocol (ch.7: 20 smoothing passes, shell
rule, LSR radius 5 px, seed-curve cutoff 2/l) and the digest's
recommendations [R] where the thesis is silent; every deviation is named in
the field's description.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from leafsfs.errors import SfsError
from leafsfs.euclid import TANGENT_ESTIMATORS
from leafsfs.quantize import SHELL_SETS

VARIANTS = ("simple", "sps", "buffer", "fused")


@dataclass(frozen=True)
class SfsParams:
    """Parameters of a PROP-SFS reconstruction.

    Attributes
    ----------
    n_smooth : int
        Passes of the masked 3 x 3 mean filter on the alpha image (thesis:
        20 for leaves, >= 5 at 5.7 deg noise; 0 for clean synthetic data).
    quantization : {"shell", "percentile", "fixed"}
        How the iso-alpha thresholds are chosen: the ch.7 shell rule
        (``shell_set``), fixed area fractions (``eps_alpha``, ``eps_seed``),
        or explicit thresholds (``thresholds_deg``).
    shell_set : {"T1", "T2", "T3", "T3*"}
        Shell-rule parameter set (mu, nu) of ch.7.
    eps_alpha, eps_seed : float
        Area fractions of each iso-alpha domain and of the seed domain, in
        ]0, 1[ (percentile mode; the thesis used 0.05-0.2 and 0.2).
    thresholds_deg : tuple of float
        Increasing thresholds alpha_0 .. alpha_(n-1), degrees (fixed mode;
        pi/2 is appended).
    alpha_rule : {"median", "mean", "upper", "lower"}
        Alpha value of a domain: the median or mean of its pixels; the
        thesis' literal rule, its upper bound alpha_i (digest A1: it diverges
        at the shell, so it is clamped to ``alpha_max_deg`` like the others);
        or its lower bound alpha_(i-1), the alpha of the curve it propagates
        from (the rule that reproduces the thesis' ch.5 bias results,
        ``tlsbench reproduce ch5-alpha-bias``).
    alpha_max_deg : float
        Clamp of the domain alpha, degrees (A1: 85 for synthetic data, 60 for
        TLS leaves whose intensity-derived alpha is unreliable above 55-60).
    alpha_bias_deg : float
        Global bias added to every domain alpha, degrees (thesis: 0, +-3.5, +-7).
    min_seed_px : int
        Seed components smaller than this are not used (digest §3.3 [R]).
    orphans : {"merge", "seed"}
        Handling of parts without a seed (digest A22).
    tangents : {"lambda", "thesis"}
        Discrete tangent estimator (:func:`leafsfs.euclid.discrete_tangents`).
    seed_cutoff : "auto", float or None
        Low-pass cutoff of the seed-curve heights in cycles per pixel of arc:
        ``"auto"`` = seed_peaks / l with ``l = 2 sqrt(pi a_seed)`` (thesis eq
        3.4 and ch.7), a number (e.g. 0.061), or None for no filtering.
    seed_peaks : int
        Number of peaks of the seed curve in the auto cutoff (2: saddle, the
        thesis' choice for leaves; 3: monkey saddle).
    lsr_radius_px : float
        Radius of the local least-squares plane on the range image that
        sets the greatest-slope signs, pixels (thesis: 5).
    toggle_window : int
        Curve points on each side searched for a toggle (digest A11: 3).
    fill : {"planar", "ruled", "cone"}
        Sand-pile fill between consecutive lines (digest A7; planar is the
        thesis' choice, see :func:`leafsfs.propagate.fill_heights`).
    buffer_rule : {"prose", "literal"}
        SFS-Buffer replacement rule (digest A5): the last valid outer point
        (prose) or Algorithm 5.1 as printed.
    crossing_window : int
        Number of previous accepted lines tested for crossing (A6: 1).
    rim_px : int
        Object pixels without a candidate within this many pixels of
        reconstructed ones are extrapolated from the nearest reconstructed
        curve point's tangent plane (the outer half of the last contour's
        pixels, and slivers removed by the opening); 0 leaves them as holes
        as in the thesis.
    outlier_threshold_m : float or None
        A measured point is flagged as an outlier when it lies farther than
        this from its corrected distance, m; None (default): ``max(3 sigma,
        2 mm)`` with sigma the leaf's range noise estimated from its pure
        pulses (:func:`leafsfs.reconstruct.outlier_threshold`, the issue's
        outlier rule). Mixed pulses are always outliers. It decides the pure
        pulses' flags under ``inliers="test"``; under ``"refine"`` the pure
        pulses flagged are the noise tails moved onto their neighbours'
        plane.
    inliers : {"auto", "keep", "test", "refine", "replace"}
        Which leaf points keep their measured distance. ``keep``: every pure
        pulse (one surface within the range noise of its neighbours); only
        the mixed pulses take the reconstructed distance. ``test``: the pure
        pulses within the outlier threshold of the reconstruction.
        ``refine``: all but the noise's tails, pure pulses farther from the
        plane of their neighbours' measurements than the noise explains,
        which take that plane's distance
        (:func:`leafsfs.fusion.noise_tails`). ``replace``: none. ``auto``:
        ``refine`` for the fused variant, ``keep`` for the thesis variants,
        whose surface uses the measured heights
        only at the seeds (measured in the benchmark, :mod:`benchmarks.scoring`:
        ``replace`` damaged up to 13 % of the good points of 0.8 m leaves
        where the propagation went astray).
    trait_smoothing_m : float
        Scale of the local planes of the corrected surface that the leaf
        traits are computed from, m (:mod:`leafsfs.traits`; assumption: leaf
        shape varies on centimetre scales, range noise on sub-millimetre
        ones; measured with the benchmark (``tlsbench``): 2 mm leaves the buffer
        variant's crossing cliffs in its areas, +10..+25 % at 0.8 m, 5 mm
        brings them within +-5 % and changes the fused areas by < 1 %).
    sigma_alpha_deg : float
        Standard deviation of the intensity-derived alpha (fused variant),
        degrees (assumption; take it from the calibration residuals).
    sigma_range_m : float
        Range noise of inlier points (fused variant), m (assumption: raw
        FARO LS880-class noise on leaves at 1-2 m, tls-physics §7 item 11,
        rounded up to the 1.8 mm the simulator gives at 1.5 m).
    gate_sigma : float
        Innovation gate of the fused variant in standard deviations.
    unexplained : {"keep", "remove"}
        What becomes of a mixed pulse that no surface explains (no leaf
        region corrects it and no pair of surfaces gives it a distance) and
        whose range proves it mixed (:func:`leafsfs.edges.bracketed`):
        ``keep`` its measured distance, which lies between two surfaces and
        on neither, or ``remove`` it (NaN in the corrected scan, flagged an
        outlier and ``removed``); a pulse whose neighbours share its range
        within the noise (``leafsfs.reconstruct.PIECE_MIN_LINKED``: a piece
        of a surface) is kept. ``remove`` also removes a corrected pulse
        that no surface owns: its two surfaces share its power within
        ``leafsfs.reconstruct.OWNER_MARGIN`` of one half, its range lies
        within ``OWNER_TOLERANCE_M`` of their midpoint and farther than
        ``OWNER_BAND_SIGMA`` noise deviations from both
        (:func:`leafsfs.reconstruct.no_owner`).
    single_surface : {"auto", "move", "keep"}
        What becomes of an edge pulse that nothing moved and whose range lies
        within the range noise of one surface only
        (:meth:`leafsfs.edges.MixedPulses.single_range`): ``move`` it to that
        surface's distance extrapolated to it in the corrected scan (the
        leaves' traits keep its measured range), or ``keep`` its measured
        range. ``auto``: ``move`` when the pure pulses are refined
        (``inliers`` ``refine``, the fused variant), else ``keep``. Variants
        that run the stray-point rule on the pulses PROP-SFS moved keep them
        (:mod:`benchmarks.registry`: moved, such pulses fed the rule and cost
        good points at 0.08 deg).
    """

    n_smooth: int = 20
    quantization: str = "shell"
    shell_set: str = "T3"
    eps_alpha: float = 0.2
    eps_seed: float = 0.2
    thresholds_deg: tuple = ()
    alpha_rule: str = "median"
    alpha_max_deg: float = 60.0
    alpha_bias_deg: float = 0.0
    min_seed_px: int = 4
    orphans: str = "merge"
    tangents: str = "lambda"
    seed_cutoff: object = "auto"
    seed_peaks: int = 2
    lsr_radius_px: float = 5.0
    toggle_window: int = 3
    fill: str = "planar"
    buffer_rule: str = "prose"
    crossing_window: int = 1
    rim_px: int = 2
    outlier_threshold_m: float | None = None
    inliers: str = "auto"
    trait_smoothing_m: float = 0.005
    sigma_alpha_deg: float = 3.0
    sigma_range_m: float = 0.002
    gate_sigma: float = 3.0
    unexplained: str = "remove"
    single_surface: str = "auto"

    def __post_init__(self):
        _choice(self, "quantization", ("shell", "percentile", "fixed"))
        _choice(self, "shell_set", tuple(SHELL_SETS))
        _choice(self, "alpha_rule", ("median", "mean", "upper", "lower"))
        _choice(self, "orphans", ("merge", "seed"))
        _choice(self, "tangents", TANGENT_ESTIMATORS)
        _choice(self, "fill", ("planar", "ruled", "cone"))
        _choice(self, "buffer_rule", ("prose", "literal"))
        _integer(self, "n_smooth", 0, 1000)
        _integer(self, "min_seed_px", 1, 10**6)
        _integer(self, "seed_peaks", 1, 16)
        _integer(self, "toggle_window", 0, 50)
        _integer(self, "crossing_window", 1, 100)
        _integer(self, "rim_px", 0, 50)
        _number(self, "eps_alpha", 0.0, 1.0, open_low=True, open_high=True)
        _number(self, "eps_seed", 0.0, 1.0, open_low=True, open_high=True)
        _number(self, "alpha_max_deg", 1.0, 89.0)
        _number(self, "alpha_bias_deg", -30.0, 30.0)
        _number(self, "lsr_radius_px", 1.0, 50.0)
        if self.outlier_threshold_m is not None:
            _number(self, "outlier_threshold_m", 0.0, 10.0, open_low=True)
        _choice(self, "inliers", ("auto", "keep", "test", "refine", "replace"))
        _choice(self, "unexplained", ("keep", "remove"))
        _choice(self, "single_surface", ("auto", "move", "keep"))
        _number(self, "trait_smoothing_m", 0.0, 1.0, open_low=True)
        _number(self, "sigma_alpha_deg", 0.0, 45.0, open_low=True)
        _number(self, "sigma_range_m", 0.0, 1.0, open_low=True)
        _number(self, "gate_sigma", 0.0, 100.0, open_low=True)
        thresholds = tuple(float(v) for v in self.thresholds_deg)
        if self.quantization == "fixed":
            if not thresholds or any(not (0 <= v < 90) for v in thresholds) \
                    or any(b <= a for a, b in zip(thresholds, thresholds[1:])):
                raise SfsError(f"thresholds_deg must be increasing values in [0, 90) degrees for fixed "
                               f"quantization, got {self.thresholds_deg!r}")
        object.__setattr__(self, "thresholds_deg", thresholds)
        cutoff = self.seed_cutoff
        if not (cutoff is None or cutoff == "auto" or (isinstance(cutoff, (int, float)) and 0 < cutoff < 10)):
            raise SfsError(f"seed_cutoff must be 'auto', None or a number of cycles per pixel in ]0, 10[, got {cutoff!r}")

    def replace(self, **changes) -> "SfsParams":
        """A copy with some fields changed (validated; unknown names raise :class:`SfsError`)."""
        unknown = set(changes) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise SfsError(f"unknown PROP-SFS parameter(s) {sorted(unknown)}; "
                           f"allowed: {', '.join(f.name for f in dataclasses.fields(self))}")
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """JSON-ready parameters."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}


def _choice(params, name, allowed):
    value = getattr(params, name)
    if value not in allowed:
        raise SfsError(f"parameter {name} = {value!r} is not allowed; choose one of {', '.join(map(str, allowed))}")


def _integer(params, name, low, high):
    value = getattr(params, name)
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise SfsError(f"parameter {name} must be an integer in [{low}, {high}], got {value!r}")


def _number(params, name, low, high, open_low=False, open_high=False):
    value = getattr(params, name)
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok:
        ok = (value > low if open_low else value >= low) and (value < high if open_high else value <= high)
    if not ok:
        brackets = ("]" if open_low else "[") + f"{low:g}, {high:g}" + ("[" if open_high else "]")
        raise SfsError(f"parameter {name} must be a number in {brackets}, got {value!r}")

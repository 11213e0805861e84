"""The registry of reconstruction variants: every method the benchmark compares, in one place.

A :class:`Variant` is a named method with default parameters. Leaf variants
return a :class:`VariantOutput`: the output point of every pixel (NaN where
the method dropped it or did not reconstruct it) and, where the method
estimates them, leaf traits. A variant of scope ``leaf`` takes the scan
around one target leaf and the mask of its points (and is run once per
leaf); one of scope ``scan`` takes the whole scan and the label image of
the targets' points, and returns its own leaf regions with their traits. Families:

- ``raw``: no correction (the measured points);
- ``filter``: the outlier-removal baselines of :mod:`leafsfs.baselines`;
- ``prop-sfs``: the PROP-SFS variants of :func:`leafsfs.reconstruct`
  (``simple``, ``sps``, ``buffer``, ``fused`` with the shell-rule set T3, and
  ``buffer-T1``, ``buffer-T2``, ``buffer-T3*``; ``fused-stray``, ``fused`` without the pulses it moved that the
  stray-point rule flags, :mod:`leafsfs.strays`; ``fused-stray5``, for coarse steps, the rule in a 5 px
  window and pulses outside its leaves with no neighbour at their range; ``fused-stray-out``, for coarse steps,
  its changes only within its leaves, the rule on the measured pulses outside them and, within them, on both
  the measured ranges and its own), calibrated by simulating the
  scan's scanner model; they run once on the whole scan, as a user runs
  them, segment it into leaves themselves and return their regions with
  the traits of each (:mod:`benchmarks.scoring` matches the regions to the
  true leaves; parameter ``segmentation: mask`` gives them the targets'
  points as a label image instead);
- ``woody``: ``step`` (:func:`woody.step`) and ``cylinders``
  (:func:`woody.follow_cylinders`) on the points of each woody object,
  registered once the woody package provides them with :func:`woody.score`.

Raw and filtered clouds get their leaf traits from
:func:`leafsfs.baselines.leaf_traits` (range-image mesh with an edge cap).
New variants are added to :func:`_register_builtins` (or, from other code,
with :func:`register_variant`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from benchmarks.errors import BenchError


@dataclass
class VariantOutput:
    """What a leaf variant returns for one leaf (scope ``leaf``) or for a whole scan (scope ``scan``).

    Attributes
    ----------
    xyz : ndarray, (rows, cols, 3)
        Output point of every pixel, world frame, m; NaN where the pixel was
        removed or not reconstructed. Only the leaves' masked pixels are read.
    traits : dict or None
        Leaf traits estimated by a method of scope ``leaf``: ``area_m2``,
        ``elevation_deg``, ``azimuth_deg`` (midrib), optionally ``normal``.
    stats : dict
        Further method-specific numbers stored with the metrics, JSON-ready.
    flags : ndarray of bool or None
        The measured points the method judges to be outliers (removed or
        corrected), for the detection precision and recall.
    labels : ndarray of int or None
        For methods that segment the scan into leaves themselves: the leaf
        region of every pixel (0: none), for the regions they reconstructed.
    regions : dict or None
        With ``labels``: the traits of every region, by label.
    candidates : ndarray of int or None
        With ``labels``: the number of reconstructed values per pixel (the
        thesis' redundancy counts rppp).
    """

    xyz: np.ndarray
    traits: dict | None = None
    stats: dict = field(default_factory=dict)
    flags: np.ndarray | None = None
    labels: np.ndarray | None = None
    regions: dict | None = None
    candidates: np.ndarray | None = None


@dataclass(frozen=True)
class Variant:
    """A named reconstruction method with its default parameters.

    Attributes
    ----------
    name : str
        Registry name (used on the command line and in the store).
    family : str
        ``raw``, ``filter``, ``prop-sfs`` or ``woody``.
    run : callable
        ``run(scan, mask, **params) -> VariantOutput``: ``mask`` is one
        leaf's points (scope ``leaf``) or the label image of the targets'
        points (scope ``scan``).
    params : dict
        Default parameters (JSON-ready).
    description : str
        One line.
    prepare : callable, optional
        ``prepare(scan)``, called once per scan before the timed runs (e.g.
        to build a calibration that every leaf of the scan shares).
    heights : callable, optional
        ``heights(sample, **params) -> leafsfs.HeightResult`` for methods
        that reconstruct height fields (the height-field cases of
        :mod:`benchmarks.heightfields`).
    target : {"leaf", "wood"}
        What the method reconstructs: leaves (and analytic surfaces), or
        woody objects (``run`` then gets the mask of one woody object's
        points and returns its cylinders as ``traits["cylinders"]``).
    scope : {"leaf", "scan"}
        Leaf methods: run on the part of the scan around each target
        (``leaf``), or once on the whole scan (``scan``).
    """

    name: str
    family: str
    run: Callable[..., VariantOutput]
    params: dict
    description: str
    prepare: Callable | None = None
    heights: Callable | None = None
    target: str = "leaf"
    scope: str = "leaf"

    def with_params(self, **changes) -> "Variant":
        """A copy with some parameters changed.

        Raises
        ------
        BenchError
            If a parameter name is unknown (the message lists the allowed ones).
        """
        unknown = sorted(set(changes) - set(self.params))
        if unknown:
            raise BenchError(f"variant {self.name!r} has no parameter(s) {unknown}; "
                             f"allowed: {sorted(self.params) or 'none'}")
        return dataclasses.replace(self, params={**self.params, **changes})

    def __call__(self, scan, mask) -> VariantOutput:
        return self.run(scan, mask, **self.params)

    def reconstruct_heights(self, sample):
        """Run the method on a sampled height field (:class:`leafsfs.synthetic.SyntheticInput`)."""
        return self.heights(sample, **self.params)


_VARIANTS: dict[str, Variant] = {}


def register_variant(variant: Variant) -> Variant:
    """Add ``variant`` to the registry (names are unique)."""
    if variant.name in _VARIANTS:
        raise BenchError(f"variant {variant.name!r} is registered twice")
    _VARIANTS[variant.name] = variant
    return variant


def variant_names() -> list[str]:
    """Names of the registered variants, in registration order."""
    return list(_VARIANTS)


def get_variant(name: str) -> Variant:
    """The registered variant ``name``.

    Raises
    ------
    BenchError
        If no variant has that name (the message lists them).
    """
    if name not in _VARIANTS:
        raise BenchError(f"unknown variant {name!r}; registered: {', '.join(variant_names())}")
    return _VARIANTS[name]


def resolve(names: list[str] | None = None, overrides: dict[str, dict] | None = None) -> list[Variant]:
    """The variants to run, with parameter overrides applied.

    Parameters
    ----------
    names : list of str, optional
        Variant names (default: every registered variant).
    overrides : dict, optional
        ``{variant name: {parameter: value}}``.
    """
    names = variant_names() if not names else list(dict.fromkeys(names))
    overrides = overrides or {}
    stray = sorted(set(overrides) - set(names))
    if stray:
        raise BenchError(f"parameter overrides given for variants that are not run: {stray}")
    return [get_variant(n).with_params(**overrides.get(n, {})) for n in names]


#: Edge cap (None: 1 cm or four sample spacings) and range smoothing of the range-image mesh that gives raw
#: and filtered clouds their leaf traits, m (:func:`leafsfs.baselines.leaf_traits`).
MESH_MAX_EDGE_M = None
MESH_SMOOTHING_M = 0.002


def _removal_variant(name: str, family: str, func: Callable, description: str, **params) -> Variant:
    """A variant that keeps a subset of the measured points (``func(scan, mask, **params) -> kept``)."""

    def run(scan, mask, mesh_max_edge_m, mesh_smoothing_m, **filter_params):
        from leafsfs.baselines import leaf_traits

        kept = func(scan, mask, **filter_params)
        return VariantOutput(np.where(kept[..., None], scan.xyz, np.nan),
                             leaf_traits(scan, kept, mesh_max_edge_m, mesh_smoothing_m), flags=mask & scan.valid & ~kept)

    return Variant(name, family, run, {**params, "mesh_max_edge_m": MESH_MAX_EDGE_M,
                                       "mesh_smoothing_m": MESH_SMOOTHING_M}, description)


def _register_builtins() -> None:
    from leafsfs import baselines

    register_variant(_removal_variant("raw", "raw", lambda scan, mask: mask & scan.valid,
                                      "measured points, no correction"))
    register_variant(_removal_variant("sor", "filter", baselines.statistical_outlier_removal,
                                      "statistical outlier removal (PCL/Open3D), k=8, 2 sd", k=8, std_ratio=2.0))
    register_variant(_removal_variant("radius", "filter", baselines.radius_outlier_removal,
                                      "radius outlier removal: >= 8 neighbours within 3 sample spacings",
                                      radius_spacings=3.0, min_neighbours=8, radius_m=None))
    register_variant(_removal_variant("shadow", "filter", baselines.shadow_filter,
                                      "veiling/shadow angle filter on the range image (ROS/PCL), 10 deg",
                                      min_angle_deg=10.0))
    rule = baselines.STRAY_POINT_RULE
    register_variant(_removal_variant("stray-point", "filter", baselines.stray_point_filter,
                                      f"FARO SCENE stray-point rule: {rule['window_px']}x{rule['window_px']} cell, "
                                      f"{100 * rule['max_range_diff_m']:g} cm, {100 * rule['min_share']:g} %",
                                      **rule))
    register_variant(_removal_variant("intensity", "filter", baselines.intensity_filter,
                                      "dark-point removal: 100 DN below the leaf's median intensity",
                                      below_median_dn=100.0, min_dn=None))
    _register_prop_sfs()
    _register_woody()


def _register_prop_sfs() -> None:
    """PROP-SFS: the four propagation variants with the thesis' leaf parameter set T3 (shell rule), and
    ``buffer`` (the thesis' reference variant) with the other shell-rule sets T1, T2, T3* of thesis ch.7."""
    import leafsfs
    from leafsfs import baselines

    defaults = {"segmentation": "auto", **leafsfs.SfsParams().to_dict()}
    for engine in leafsfs.VARIANTS:
        register_variant(_prop_sfs_variant(engine, engine, defaults))
    for shell in ("T1", "T2", "T3*"):
        register_variant(_prop_sfs_variant(f"buffer-{shell}", "buffer", {**defaults, "shell_set": shell}))
    # ``fused-stray``: the rule on the pulses PROP-SFS moved, with the ``stray-point`` variant's settings; the edge
    # pulses of one surface keep their measured range, which the rule reads as it reads a measured scan
    # (``single_surface``; moved, they cost good points at 0.08 deg: ``fused-stray-out`` on the leafy tree lost
    # 14.89 -> 15.21 %, more than ``stray-point``)
    defaults = {**defaults, "single_surface": "keep"}
    stray = {"scope": "moved", **baselines.STRAY_POINT_RULE}
    register_variant(_prop_sfs_variant("fused-stray", "fused", _with_stray(defaults, stray)))
    # ``fused-stray5``, for coarse steps: the rule in a 5 px window on the moved pulses, and the pulses in no leaf
    # region with no neighbour at their range removed (:func:`leafsfs.strays.remove_strays`, scope ``isolated``)
    stray = {**stray, "scope": "isolated", "window_px": 5}
    register_variant(_prop_sfs_variant("fused-stray5", "fused", _with_stray(defaults, stray)))
    # ``fused-stray-out``, for coarse steps: PROP-SFS's changes kept only within its leaves, and the rule (the
    # ``stray-point`` variant's settings) on every pulse outside them and, within them, on its ranges and the measured
    stray = {"scope": "outside", **baselines.STRAY_POINT_RULE}
    register_variant(_prop_sfs_variant("fused-stray-out", "fused", _with_stray(defaults, stray)))


def _calibration(scan):
    """The intensity calibration of a scan's scanner model (simulated once per model and process)."""
    from benchmarks.experiments.calibration import simulated_calibration

    return simulated_calibration(scan.scanner.model)


#: How a PROP-SFS variant finds the leaves: ``auto``, its own segmentation of the whole scan (as on a real scan), or
#: ``mask``, the targets' points given as a label image (for targets its segmentation does not take for leaves,
#: such as the knife edge's plate, which reaches the window's border).
SEGMENTATIONS = ("auto", "mask")

#: Prefix of a PROP-SFS variant's parameters for the stray-point rule it applies after PROP-SFS
#: (:func:`leafsfs.strays.remove_strays`'s, without the prefix).
STRAY_PREFIX = "stray_"


def _with_stray(params: dict, stray: dict) -> dict:
    """``params`` and the stray-point rule's settings ``stray`` (:func:`leafsfs.strays.remove_strays`'s), prefixed."""
    return {**params, **{STRAY_PREFIX + key: value for key, value in stray.items()}}


def _prop_sfs_variant(name: str, engine: str, params: dict) -> Variant:
    def run(scan, labels, segmentation, **params):
        """PROP-SFS once on the whole scan: its corrected points, outlier flags, and the regions it reconstructed
        with their traits and candidate counts (regions it skipped keep their measured points and are not leaves);
        with the ``stray_*`` parameters, the stray-point rule's outliers among its moved pulses removed."""
        import leafsfs
        from leafsfs.strays import remove_strays

        stray = {key[len(STRAY_PREFIX):]: params.pop(key) for key in list(params) if key.startswith(STRAY_PREFIX)}
        if segmentation not in SEGMENTATIONS:
            raise BenchError(f"PROP-SFS segmentation must be one of {SEGMENTATIONS}, got {segmentation!r}")
        params = leafsfs.SfsParams(**params)
        try:
            result = leafsfs.reconstruct(scan, mask=labels if segmentation == "mask" else None, variant=engine,
                                         params=params, calibration=_calibration(scan))
        except leafsfs.SfsError:  # with valid parameters and calibration: no valid return, or a mask selecting none
            return VariantOutput(scan.xyz, stats={"skipped": 0}, flags=np.zeros(scan.shape, bool),
                                 labels=np.zeros(scan.shape, int), regions={},
                                 candidates=np.zeros(scan.shape, int))
        if stray:
            result = remove_strays(result, **stray)
        regions = {t["leaf"]: t for t in result.traits()}
        labels = np.where(np.isin(result.labels, list(regions)), result.labels, 0)
        return VariantOutput(result.corrected_scan().xyz, stats={"skipped": len(result.skipped)},
                             flags=result.outlier, labels=labels, regions=regions, candidates=result.candidates)

    def heights(sample, segmentation, **params):
        import leafsfs

        params = {key: value for key, value in params.items() if not key.startswith(STRAY_PREFIX)}
        return leafsfs.reconstruct_heights(sample.alpha, sample.height, sample.mask, sample.grid, engine,
                                           leafsfs.SfsParams(**params))

    shell = params["shell_set"]
    extra = {"moved": ", moved pulses the stray-point rule flags removed",
             "isolated": ", moved pulses the stray-point rule flags (5 px window) and isolated pulses outside its "
                         "leaves removed",
             "outside": ", its changes kept only within its leaves; pulses the stray-point rule flags removed: "
                        "outside them on the measured ranges, within them a moved pulse flagged on its measured or "
                        "corrected range, a kept one on both; moves beyond the rule's tolerance of pulses it keeps "
                        "undone"}.get(params.get(STRAY_PREFIX + "scope"), "")
    return Variant(name, "prop-sfs", run, params,
                   f"PROP-SFS {engine} propagation, shell-rule set {shell} (leafsfs.reconstruct, model calibration)"
                   f"{extra}",
                   prepare=_calibration, heights=heights, scope="scan")


def _register_woody() -> None:
    """STEP and cylinder following, with their packages' defaults (scalar parameters are overridable)."""
    import woody

    def step(scan, mask, **params):
        result = woody.step(scan.xyz[mask], viewpoints=scan.pose.position, **params)
        return VariantOutput(scan.xyz, {"cylinders": result.cylinders()}, {"tuboids": len(result.tuboids)})

    def cylinders(scan, mask, **params):
        result = woody.follow_cylinders(scan.xyz[mask], **_scanner_view(scan, mask, params))
        return VariantOutput(scan.xyz, {"cylinders": result.cylinders()}, {"branches": len(result.branches)})

    def cylinders_trunk(scan, mask, **params):
        from woody.trunk import follow_tree

        result = follow_tree(scan.xyz[mask], **_scanner_view(scan, mask, params))
        return VariantOutput(scan.xyz, {"cylinders": result.cylinders()}, {"branches": len(result.branches)})

    # The scan knows its scanner: its position and the beam's footprint bound the radii (woody.footprint), as STEP
    # gets the scanner's position; a number for footprint_m overrides it (0: off).
    follow = {**{k: v for k, v in dataclasses.asdict(woody.FollowParams()).items()
                 if v is None or isinstance(v, (bool, int, float, str))}, "footprint_m": None}
    register_variant(Variant("step", "woody", step, {"cell_m": 0.02, "radius_step_m": 0.01, "r_min_m": 0.02,
                                                     "r_max_m": 0.30},
                             "STEP tuboids (Ravaglia et al. 2017: point-normal Hough, open active contours)",
                             target="wood"))
    register_variant(Variant("cylinders", "woody", cylinders, follow,
                             "cylinder following (Mendez et al.): branch hierarchy of cylinders", target="wood"))
    register_variant(Variant("cylinders-trunk", "woody", cylinders_trunk, follow,
                             "cylinder following with the trunk followed first from the ground up by stacked circle "
                             "fits (woody.trunk.follow_tree)", target="wood"))


def _scanner_view(scan, mask, params: dict) -> dict:
    """``params`` with the scan's scanner position as ``viewpoint`` and, where ``footprint_m`` is None, the scanner
    model's beam diameter (``tlssim.beam.footprint_axes_m`` at normal incidence) at the median range of the
    points, m."""
    from tlssim.beam import footprint_axes_m

    position = np.asarray(scan.pose.position, float)
    out = {**params, "viewpoint": params.get("viewpoint") or tuple(position.tolist())}
    if out.get("footprint_m") is None:
        distance = float(np.median(np.linalg.norm(scan.xyz[mask] - position, axis=1)))
        out["footprint_m"] = float(min(footprint_axes_m(scan.scanner.assumed_model, distance, 0.0)))
    return out


_register_builtins()

"""Height-field cases: the synthetic experiments of the PROP-SFS thesis (ch.5), without a scan.

A case whose scene is ``{"heightfield": NAME, ...}`` samples the analytic
surface ``NAME`` of :mod:`scenes.surfaces` on a ``side x side`` pixel grid
(:func:`leafsfs.synthetic.sample_surface`, seeded by the case seed) with:

- ``alpha_noise_deg``: uniform incidence noise in ``[-A, A]`` (thesis: 1.4, 2.8, 5.7 deg);
- ``alpha_bias_deg``: a global incidence bias (thesis: ±3.5, ±7 deg);
- ``height_noise``: uniform height ("distance") noise as a fraction of
  ``h_max − h_min`` (thesis saddles: 10 %);
- ``surface_params``: parameters of the surface (radians).

The thesis varied the smoothing passes, the quantisation and the seed
cutoff from one experiment to the next: such settings go in the case's
``params`` (``params: {prop-sfs: {n_smooth: 5}}``, see :mod:`benchmarks.suite`).

PROP-SFS variants reconstruct the heights from alpha and the height image
(:func:`leafsfs.reconstruct_heights`); :func:`benchmarks.metrics.height_errors`
scores them with the thesis' relative errors (eqs 3.1–3.2).
"""

from __future__ import annotations

import math

from benchmarks import metrics
from benchmarks.errors import BenchError

_KEYS = {"heightfield", "side", "alpha_noise_deg", "alpha_bias_deg", "height_noise", "surface_params"}


def is_heightfield(spec: dict) -> bool:
    """Whether a case's scene description is a height field."""
    return isinstance(spec, dict) and "heightfield" in spec


def check_heightfield(spec: dict) -> None:
    """Validate a height-field description (raises :class:`BenchError` naming the bad field)."""
    from scenes.surfaces import SURFACE_NAMES

    unknown = sorted(set(spec) - _KEYS)
    if unknown:
        raise BenchError(f"unknown height-field key(s) {unknown}; allowed: {sorted(_KEYS)}")
    if spec["heightfield"] not in SURFACE_NAMES:
        raise BenchError(f"unknown surface {spec['heightfield']!r}; available: {', '.join(SURFACE_NAMES)}")
    side = spec.get("side", 41)
    if not (isinstance(side, int) and side >= 9):
        raise BenchError(f"height-field side must be an integer >= 9 (pixels), got {side!r}")
    for key in ("alpha_noise_deg", "alpha_bias_deg", "height_noise"):
        value = spec.get(key, 0.0)
        if not (isinstance(value, (int, float)) and math.isfinite(value)):
            raise BenchError(f"height-field {key} must be a number, got {value!r}")
    if not isinstance(spec.get("surface_params", {}), dict):
        raise BenchError(f"height-field surface_params must be a mapping, got {spec['surface_params']!r}")


def sample(spec: dict, seed: int):
    """The sampled surface of a height-field case (:class:`leafsfs.synthetic.SyntheticInput`).

    Parameters
    ----------
    spec : dict
        Scene section of a height-field case (``heightfield``, optional
        ``surface_params``, ``side`` in pixels, ``alpha_noise_deg`` and
        ``alpha_bias_deg`` in degrees, ``height_noise`` relative).
    seed : int
        Seed of the noise.

    Returns
    -------
    leafsfs.synthetic.SyntheticInput
        Sampled incidence angles (rad), heights and mask with the true heights.
    """
    from leafsfs.synthetic import sample_surface
    from scenes.surfaces import get_surface

    check_heightfield(spec)
    return sample_surface(get_surface(spec["heightfield"], **spec.get("surface_params", {})), spec.get("side", 41),
                          alpha_noise_deg=spec.get("alpha_noise_deg", 0.0),
                          alpha_bias_deg=spec.get("alpha_bias_deg", 0.0),
                          height_noise=spec.get("height_noise", 0.0), seed=seed)


def score_heights(spec: dict, sampled, result) -> dict:
    """Scores of a height-field reconstruction: the thesis' errors, completeness and redundancy.

    Parameters
    ----------
    spec : dict
        Scene section of the height-field case.
    sampled : leafsfs.synthetic.SyntheticInput
        The sampled surface, with its true heights.
    result : leafsfs.HeightResult
        The reconstruction of ``sampled``.

    Returns
    -------
    dict
        The case's settings, the relative height errors of
        :func:`benchmarks.metrics.height_errors` and the redundancy ratios.
    """
    scores = {"target": spec["heightfield"], "object_type": "heightfield", "side": spec.get("side", 41),
              "alpha_noise_deg": spec.get("alpha_noise_deg", 0.0), "alpha_bias_deg": spec.get("alpha_bias_deg", 0.0),
              "height_noise": spec.get("height_noise", 0.0)}
    scores.update(metrics.height_errors(result.height, sampled.truth, sampled.mask))
    scores.update(result.rppp())
    return scores

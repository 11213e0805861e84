"""PROP-SFS on the analytic surfaces of the thesis' chapter 5 (digest §9 tests 3, 5, 6, 7)."""

import numpy as np
import pytest

from leafsfs.engine import reconstruct_heights, smooth_alpha
from leafsfs.errors import SfsError
from leafsfs.params import SfsParams
from leafsfs.synthetic import sample_surface
from scenes.surfaces import get_surface

SYNTHETIC = SfsParams(n_smooth=0, quantization="percentile", eps_alpha=0.2, eps_seed=0.2, alpha_max_deg=85,
                      seed_cutoff=None, rim_px=0)


def _relative_errors(result, sample):
    reconstructed = result.count > 0
    return np.abs(result.height - sample.truth)[reconstructed] / sample.height_range


def test_hemisphere_with_noise_meets_the_thesis_statement():
    # §5.5: +-2.8 deg uniform alpha noise, 5 smoothing passes, 20 % quantisation:
    # > 95 % of the points within 5 % of the radius.
    sample = sample_surface(get_surface("hemisphere", radius=20.0), 41, alpha_noise_deg=2.8, seed=3)
    result = reconstruct_heights(sample.alpha, sample.height, sample.mask, sample.grid, "buffer",
                                 SYNTHETIC.replace(n_smooth=5))
    error = np.abs(result.height - sample.truth)[result.count > 0] / 20.0
    assert result.completeness > 0.99
    assert np.mean(error < 0.05) > 0.95


@pytest.mark.parametrize("sink", [False, True])
def test_summit_and_sink_propagate_outward(sink):
    # A dome and the same surface upside down (a bowl): the signs from the local planes make the
    # propagation descend (summit) or ascend (sink) outward.
    sample = sample_surface(get_surface("hemisphere", radius=20.0), 41)
    height = -sample.height if sink else sample.height
    truth = -sample.truth if sink else sample.truth
    result = reconstruct_heights(sample.alpha, height, sample.mask, sample.grid, "buffer", SYNTHETIC)
    error = np.abs(result.height - truth)[result.count > 0] / 20.0
    assert np.mean(error < 0.05) > 0.97


@pytest.mark.parametrize("fill,tolerance", [("ruled", 0.012), ("cone", 0.012), ("planar", 0.06)])
def test_cone_is_reconstructed_up_to_discretisation(fill, tolerance):
    # One iso-alpha region around a point seed (thesis §9 test 3): every GS line is straight.
    surface = get_surface("cone", radius=20.0, slope=np.radians(40))
    sample = sample_surface(surface, 41)
    x, y, _, _ = surface.sample(41, 41)
    alpha = np.where(np.hypot(x, y) < 3.0, 0.0, sample.alpha)  # the apex: a small flat seed
    params = SYNTHETIC.replace(quantization="fixed", thresholds_deg=(20.0,), fill=fill)
    result = reconstruct_heights(alpha, sample.height, sample.mask, sample.grid, "buffer", params)
    error = np.abs(result.height - sample.truth)[(result.count > 0) & ~result.seed] / sample.height_range
    assert result.completeness > 0.99
    assert error.max() < tolerance


def test_variant_ordering_on_the_complex_surface():
    sample = sample_surface(get_surface("complex"), 70)
    params = SYNTHETIC.replace(eps_alpha=0.1)
    results = {v: reconstruct_heights(sample.alpha, sample.height, sample.mask, sample.grid, v, params)
               for v in ("simple", "sps", "buffer")}
    assert results["sps"].completeness > results["simple"].completeness + 0.2
    assert results["buffer"].rppp()["rppp_1"] >= results["sps"].rppp()["rppp_1"]
    # The buffer removes many of the SPS outlier triangles (errors relative to h_max - h_min).
    errors = {v: _relative_errors(r, sample) for v, r in results.items()}
    assert np.median(errors["buffer"]) < np.median(errors["sps"])
    assert np.mean(errors["buffer"] > 0.25) < np.mean(errors["sps"] > 0.25)
    assert results["buffer"].stats["buffered"] > 0 and results["buffer"].stats["curve_crossings"] > 0


@pytest.mark.parametrize("side,better,worse", [(25, 0.061, 0.019), (75, 0.019, 0.061)])
def test_saddle_seed_cutoffs(side, better, worse):
    # §5.5: with 10 % height noise, 2/l = 0.061 suits the small saddle (0.019 flattens its seed
    # curve) while on the large saddle 0.061 keeps the noise.
    means = {}
    for cutoff in (better, worse):
        errors = []
        for seed in range(2):
            sample = sample_surface(get_surface("saddle"), side, height_noise=0.1, seed=seed)
            params = SYNTHETIC.replace(eps_alpha=0.1, eps_seed=0.14, seed_cutoff=cutoff)
            result = reconstruct_heights(sample.alpha, sample.height, sample.mask, sample.grid, "buffer", params)
            errors.append(np.abs(result.height - sample.truth)[(result.count > 0) & ~result.seed].mean())
        means[cutoff] = np.mean(errors)
    assert means[better] < 0.8 * means[worse]


def test_masked_smoothing_keeps_background_out():
    alpha = np.full((10, 10), 0.3)
    mask = np.zeros((10, 10), dtype=bool)
    mask[2:8, 2:8] = True
    alpha[~mask] = 1.5
    smoothed = smooth_alpha(alpha, mask, 20)
    assert np.allclose(smoothed[mask], 0.3) and np.all(np.isnan(smoothed[~mask]))


def test_engine_input_errors():
    alpha = np.full((20, 20), 0.2)
    with pytest.raises(SfsError, match="one shape"):
        reconstruct_heights(alpha, np.zeros((20, 21)))
    with pytest.raises(SfsError, match="mask must be a boolean image of shape"):
        reconstruct_heights(alpha, np.zeros((20, 20)), mask=np.ones((5, 5), bool))
    with pytest.raises(SfsError, match="at least 9"):
        reconstruct_heights(np.full((20, 20), np.nan), np.zeros((20, 20)))
    with pytest.raises(SfsError, match="no object pixel has a measured height"):
        reconstruct_heights(alpha, np.full((20, 20), np.nan))
    with pytest.raises(SfsError, match="unknown PROP-SFS variant 'magic'"):
        reconstruct_heights(alpha, np.zeros((20, 20)), variant="magic")
    with pytest.raises(SfsError, match="n_smooth must be an integer"):
        SfsParams(n_smooth=-1)
    with pytest.raises(SfsError, match="unknown PROP-SFS parameter"):
        SfsParams().replace(smoothing=3)


@pytest.mark.parametrize("bias", [-5.0, 5.0])
def test_fused_variant_removes_the_drift_of_a_biased_alpha(bias):
    # A mis-calibrated intensity (alpha biased by 5 deg): the thesis' variants drift with the distance from
    # the seed; the fused variant follows the point cloud's slopes and heights.
    sample = sample_surface(get_surface("hemisphere", radius=20.0), 41, alpha_noise_deg=2.8, alpha_bias_deg=bias,
                            height_noise=0.005, seed=2)
    params = SYNTHETIC.replace(n_smooth=5, eps_alpha=0.1, seed_cutoff="auto", sigma_range_m=0.005 * 20)
    within = {}
    for variant in ("buffer", "fused"):
        result = reconstruct_heights(sample.alpha, sample.height, sample.mask, sample.grid, variant, params)
        within[variant] = np.mean(_relative_errors(result, sample) < 0.05)
    assert within["buffer"] < 0.75 and within["fused"] > 0.85
    assert result.stats["gradient_updates"] > 0 and result.stats["height_updates"] > 0



def test_fused_heights_are_not_locked_out_by_a_drift():
    # Fine pixels under range noise (the point cloud's local slopes are weak) and a biased intensity calibration
    # (alpha off by 8 deg): the propagated heights drift past the innovation gate; they must keep taking the
    # measured heights that agree with their neighbours' surface. With the innovation gate alone 1,391 of 2,774
    # height measurements were rejected and 77 % of the pixels came within 2 % of the radius; now 91 %.
    sample = sample_surface(get_surface("hemisphere", radius=20.0), 121, alpha_noise_deg=1.0, alpha_bias_deg=8.0,
                            height_noise=0.005, seed=3)
    params = SYNTHETIC.replace(n_smooth=5, eps_alpha=0.1, seed_cutoff="auto", sigma_range_m=0.005 * 20)
    result = reconstruct_heights(sample.alpha, sample.height, sample.mask, sample.grid, "fused", params)
    assert np.mean(_relative_errors(result, sample) < 0.02) > 0.85
    assert result.stats["height_rejected"] < 0.2 * result.stats["height_updates"]


def _dome_on_floor(side=41, radius=18.5):
    """Hemisphere of ``radius`` px on a flat floor (alpha 0) filling a ``side`` px square, unit pixels."""
    y, x = np.mgrid[0:side, 0:side] - (side - 1) / 2
    r = np.hypot(x, y)
    truth = np.sqrt(np.maximum(radius**2 - r**2, 0.0))
    return np.where(r < radius, np.arcsin(np.minimum(r / radius, 1.0)), 0.0), truth


@pytest.mark.parametrize("eps_alpha", [0.2, 0.05])
def test_every_piece_of_a_seed_domain_cut_by_the_opening_seeds_a_part(eps_alpha):
    # The floor (35 %, alpha 0) is one seed domain whose four corners are joined only by 1-2 px strips along the
    # border: the 3 x 3 opening of the curve extraction cuts it in four. Every piece seeds a part of its own with its
    # measured heights, so the wall is reached from the floor, not the floor from the wall (before: body 22 / 68 %).
    alpha, truth = _dome_on_floor()
    params = SfsParams(quantization="percentile", eps_alpha=eps_alpha, eps_seed=0.2, alpha_max_deg=85, rim_px=0,
                       n_smooth=0)
    result = reconstruct_heights(alpha, truth, np.ones(alpha.shape, bool), variant="buffer", params=params)
    floor, body = truth == 0, truth > 0
    error = np.abs(result.height - truth) / truth.max()
    assert result.parts.max() == 5  # the dome and the four floor corners
    assert np.nanmean(error[floor]) < 0.01
    assert np.nanmean(error[body]) < 0.05


def test_every_seed_pixel_keeps_its_measured_height():
    # Thesis ch.5 (E): h = Mh on every seed pixel, also the 1-2 px border strips of the floor that the opening of
    # the curve extraction leaves outside every seed curve (before: reached by propagation, 0.3 % of h_tot off).
    alpha, truth = _dome_on_floor()
    params = SfsParams(quantization="percentile", eps_alpha=0.2, eps_seed=0.2, alpha_max_deg=85, rim_px=0, n_smooth=0)
    result = reconstruct_heights(alpha, truth, np.ones(alpha.shape, bool), variant="buffer", params=params)
    seed_domain = result.levels == 0
    assert np.array_equal(result.height[seed_domain], truth[seed_domain])
    assert result.seed[seed_domain].all()


def test_a_stray_pixel_of_the_lowest_domain_does_not_anchor_the_seed():
    # One rim pixel of a hemisphere reads alpha 0 (a noisy rim pulse) among neighbours without a measured height:
    # it belongs to the lowest domain but lies apart from its body at the summit. The seed is anchored in the body,
    # so the whole surface is reached (before: the seed grew from the stray pixel, 59 % of the surface reached).
    sample = sample_surface(get_surface("hemisphere", radius=20.0), 41)
    alpha, height = sample.alpha.copy(), sample.height.copy()
    rows, cols = np.nonzero(sample.mask)
    r, c = rows.min() + 1, cols[np.argmin(rows)]
    height[r - 2:r + 3, c - 2:c + 3] = np.nan
    height[r, c], alpha[r, c] = sample.height[r, c], 0.0
    result = reconstruct_heights(alpha, height, sample.mask, sample.grid, "buffer", SYNTHETIC)
    assert result.completeness > 0.99
    assert np.mean(_relative_errors(result, sample) < 0.02) > 0.85

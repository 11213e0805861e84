"""Seeds from the quantisation when a flat plateau ties at the lowest alpha (a floor beside a crest)."""

import numpy as np
import pytest

from leafsfs.engine import reconstruct_heights
from leafsfs.grid import PixelGrid
from leafsfs.params import SfsParams
from leafsfs.quantize import PLATEAU_PX, assign_levels, quantile_thresholds
from leafsfs.segment import split_parts


def _floor_and_crest(n: int = 30, half_width: int = 5) -> np.ndarray:
    """Alpha (rad): a flat floor (exactly 0) above and below a ridge whose crest, the middle rows, is 0.05 rad."""
    rows = np.abs(np.arange(n) - (n - 1) / 2)[:, None] * np.ones((1, n))
    return np.where(rows < half_width, 0.05 + 0.25 * rows, 0.0)


def test_a_tied_floor_does_not_fill_the_seed():
    alpha = _floor_and_crest()
    mask = np.ones(alpha.shape, bool)
    body = alpha > 0
    assert np.mean(~body) > 0.2  # the tied floor alone is more than the seed fraction
    thresholds = quantile_thresholds(alpha[mask], 0.1, 0.2)
    # the fractions are those of the ridge: its lowest 20 % (the crest rows) join the floor in the seed domain
    assert thresholds[0] == pytest.approx(np.quantile(alpha[body], 0.2))
    levels = assign_levels(alpha, mask, thresholds)
    assert np.all(levels[~body] == 0)
    assert np.all(levels[14:16] == 0) and np.all(levels[body][alpha[body] > thresholds[0]] > 0)
    # so the crest is a seed of its own part, apart from the two floors
    parts = split_parts(alpha, levels)
    assert parts.max() == 3
    crest = parts[15, 0]
    assert body[parts == crest].all()
    for k in range(1, 4):
        assert np.any(levels[parts == k] == 0)


def test_a_plateau_is_left_out_of_the_fractions_whatever_its_share_but_symmetric_ties_are_not():
    spread = np.linspace(0.1, 1.0, 200)
    for share in (0.05, 0.19, 0.2, 0.5):  # a plateau just under the seed fraction must not starve the other seeds
        values = np.concatenate([np.zeros(int(share * 200 / (1 - share))), spread])
        assert np.allclose(quantile_thresholds(values, 0.2, 0.2),
                           np.append(np.quantile(spread, [0.2, 0.4, 0.6, 0.8]), np.pi / 2), rtol=0, atol=1e-12)
    # fewer ties than PLATEAU_PX (the 4 centre pixels of an even-sided dome): the plain quantiles
    values = np.concatenate([np.zeros(PLATEAU_PX - 1), spread])
    assert np.allclose(quantile_thresholds(values, 0.2, 0.2),
                       np.append(np.quantile(values, [0.2, 0.4, 0.6, 0.8]), np.pi / 2), rtol=0, atol=1e-12)
    assert np.array_equal(quantile_thresholds(np.full(50, 0.2), 0.1, 0.2), [0.2, np.pi / 2])


@pytest.mark.parametrize("radius", [8.0, 16.0])
def test_a_half_cylinder_on_a_floor_is_reconstructed_from_its_crest(radius):
    # Height field of a half cylinder lying on a flat floor that covers 60 % or exactly the seed fraction (20 %) of
    # the matrix: seeded by the floor alone, the body would be reached through its vertical walls (mean errors of
    # 67 and 137 % of its height).
    y = np.arange(40.0)[:, None] - 19.5 + np.zeros((1, 40))
    body = np.abs(y) < radius
    height = np.where(body, np.sqrt(np.maximum(radius**2 - y**2, 0.0)), 0.0)
    alpha = np.where(body, np.arctan(np.abs(y) / np.sqrt(np.maximum(radius**2 - y**2, 1e-9))), 0.0)
    params = SfsParams(n_smooth=0, quantization="percentile", eps_alpha=0.1, eps_seed=0.2, alpha_max_deg=85,
                       seed_cutoff=None, rim_px=0)
    result = reconstruct_heights(alpha, height, np.ones(alpha.shape, bool), PixelGrid(), "buffer", params)
    error = np.abs(result.height - height)[body] / radius
    assert result.parts.max() == 3
    done = np.isfinite(error)
    assert np.mean(done) > 0.98 and np.mean(error[done]) < 0.02


def test_seed_pieces_joined_by_a_thin_strip_become_parts_of_their_own():
    # Two 5 x 5 seed blocks joined by a one-pixel strip: one 8-connected seed domain, but two pieces once the
    # 3 x 3 opening of the curve extraction has removed the strip. Each piece seeds its own part.
    levels = np.ones((9, 17), int)
    levels[2:7, 1:6] = 0
    levels[2:7, 11:16] = 0
    levels[4, 6:11] = 0
    alpha = np.where(levels == 0, 0.0, 0.5)
    parts = split_parts(alpha, levels)
    assert parts.max() == 2
    assert parts[4, 3] != parts[4, 13]
    assert set(np.unique(parts[4, 6:11])) <= {parts[4, 3], parts[4, 13]}

"""The fused variant's refine of pure pulses (:func:`leafsfs.fusion.noise_tails`) on surfaces with known heights."""

import numpy as np
import pytest

from leafsfs.fusion import noise_tails
from leafsfs.grid import PixelGrid

SIGMA = 0.001  # range noise, m
GRID = PixelGrid(matrix=0.001 * np.eye(2))  # 1 mm pixels (a leaf at 3 m scanned at 0.018 deg)


def _noisy(truth: np.ndarray, seed: int) -> np.ndarray:
    """Gaussian range noise plus 60 pulses pushed 4-6 sigma off (the noise's tails), m."""
    rng = np.random.default_rng(seed)
    measured = truth + rng.normal(0.0, SIGMA, truth.shape)
    tails = rng.choice(truth.size, 60, replace=False)
    measured.flat[tails] += rng.choice([-1, 1], 60) * rng.uniform(4, 6, 60) * SIGMA
    return measured


def _heights(slopes: tuple[float, float], crease: float = 0.0) -> np.ndarray:
    """A plane (``crease`` 0) or a roof folded along the middle column, m."""
    rows, cols = np.mgrid[0:80, 0:80] * 0.001
    return 0.02 + slopes[0] * rows + slopes[1] * cols + crease * np.abs(cols - 0.04)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_noisy_planar_leaf_has_its_tails_pulled_in_and_no_pulse_pushed_out(seed):
    truth = _heights((0.3, -0.5))
    measured = _noisy(truth, seed)
    tails, plane = noise_tails(measured, np.ones(truth.shape, bool), GRID, SIGMA, SIGMA)
    before, after = np.abs(measured - truth), np.abs(plane - truth)
    # Every moved pulse ends closer to the plane than it was measured, and within 3 sigma of it.
    assert tails.sum() > 60 and np.all(after[tails] < before[tails]) and np.all(after[tails] < 3 * SIGMA)
    # Every pulse measured beyond 3 sigma is pulled in; the neighbours' plane is ~7x more precise than a pulse.
    assert np.all(tails[before > 3 * SIGMA])
    assert np.sqrt(np.mean((plane - truth) ** 2)) < 0.2 * SIGMA


def test_a_fold_pushes_no_pulse_out_and_no_pure_pulse_means_no_move():
    # Across a fold the plane of a pulse's neighbours is biased: at slopes +-1 (a right angle) by up to 3 sigma at
    # the fold, and no moved pulse ends beyond 3 sigma (measured: 2.3); at slopes +-2 the plane misfits its
    # neighbours beyond the RMS guard, and the fold's pulses keep their measurement.
    fold = np.abs(np.arange(80) - 40) <= 2
    for crease in (1.0, 2.0):
        truth = _heights((0.2, 0.0), crease=crease)
        measured = _noisy(truth, 2)
        tails, plane = noise_tails(measured, np.ones(truth.shape, bool), GRID, SIGMA, SIGMA)
        assert tails.sum() > 60 and np.all(np.abs(plane - truth)[tails] < 3 * SIGMA)
    assert not tails[:, fold].any()
    tails, plane = noise_tails(measured, np.zeros(truth.shape, bool), GRID, SIGMA, SIGMA)
    assert not tails.any() and np.isnan(plane).all()


@pytest.mark.parametrize("radius_m", [0.03, 0.007])
@pytest.mark.parametrize("seed", [0, 1])
def test_a_rolled_leaf_has_its_tails_pulled_in_up_to_its_rims_and_no_pulse_pushed_out(radius_m, seed):
    # A leaf rolled about the rows' axis into a circular cylinder of radius 3 cm or 7 mm (a curled margin), seen from
    # its convex side out to 0.9 of the radius (64 deg at the rims, where the plane of the neighbours is one-sided).
    # Without noise the plane of the 5 px disc misses the 7 mm cylinder by up to 0.78 mm (RMS up to 0.60 mm; 3 cm:
    # 0.56 / 0.43 mm), within the RMS guard: the tails are found up to the rims (measured: 7 mm 12 / 11 of 12 / 11
    # beyond 3 sigma, 80 / 69 pulses moved; 3 cm 51 of 51, 238 / 243 moved).
    rows, cols = np.mgrid[0:80, 0:80] * 0.001
    across = cols - 0.04
    truth = 0.02 + 0.2 * rows + radius_m - np.sqrt(np.clip(radius_m**2 - across**2, 0.0, None))
    pure = np.abs(across) <= 0.9 * radius_m
    measured = _noisy(truth, seed)
    tails, plane = noise_tails(measured, pure, GRID, SIGMA, SIGMA)
    before, after = np.abs(measured - truth), np.abs(plane - truth)
    assert np.all(tails[pure & (before > 3 * SIGMA)]) and not tails[~pure].any()
    # no moved pulse ends farther from the leaf than it was measured, nor beyond 3 sigma (measured: at most 1.27 mm)
    assert np.all(after[tails] < before[tails]) and np.all(after[tails] < 3 * SIGMA)

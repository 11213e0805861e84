"""Noise tails off the leaf regions go back to their surface (leafsfs.surfacetails): a noisy branch before a wall."""

import math

import numpy as np

from leafsfs.surfacetails import surface_tails

STEP = math.radians(0.03)  # 1.05 mm between beams at 2 m
ROWS, COLS = 60, 90
DIST, RADIUS, WALL = 2.0, 0.02, 2.5
NOISE, MODELLED = 0.001, 0.0015  # the ranges' noise and the pulses' modelled noise, m
PUSH = 0.03


def _branch():
    """True ranges of a vertical branch (radius 2 cm, axis 2 m away) before a wall at 2.5 m, and the branch's mask.

    The beam at horizontal angle ``phi`` meets the cylinder at ``DIST cos(phi) - sqrt(RADIUS^2 - DIST^2 sin^2(phi))``.
    """
    phi = (np.arange(COLS) - COLS / 2 + 0.3) * STEP
    lateral = DIST * np.sin(phi)
    on = np.abs(lateral) < RADIUS
    depth = DIST * np.cos(phi) - np.sqrt(np.clip(RADIUS ** 2 - lateral ** 2, 0, None))
    true = np.where(on, depth, WALL / np.cos(phi))
    return np.broadcast_to(true, (ROWS, COLS)).copy(), np.broadcast_to(on, (ROWS, COLS)).copy()


def test_pushed_pulses_on_a_branch_go_back_to_its_surface_and_the_rest_keep_their_ranges():
    true, on = _branch()
    rng = np.random.default_rng(3)
    measured = true + rng.normal(0, NOISE, true.shape)
    pushed = np.zeros(true.shape, dtype=bool)
    # A few pulses well inside the branch (away from its silhouettes) pushed 3 cm along the beam.
    cols = np.flatnonzero(on[0])
    pushed[rng.choice(np.arange(8, ROWS - 8), 12, replace=False),
           rng.choice(cols[(cols > cols.min() + 8) & (cols < cols.max() - 8)], 12)] = True
    measured[pushed] += PUSH
    tails, plane = surface_tails(measured, np.ones(true.shape, dtype=bool), MODELLED)
    corrected = np.where(tails, plane, measured)
    assert tails[pushed].all()
    np.testing.assert_allclose(corrected[pushed], true[pushed], atol=1.5 * NOISE)
    # The other pulses: the tails of the noise itself (about the 4.6 % of a normal law beyond 2 deviations) move,
    # away from the silhouettes onto their surface within the noise. Within the window's half-width of a silhouette
    # the refitted plane is one-sided and on the branch's curved flank off by up to 3 deviations (not tested).
    others = tails & ~pushed
    assert others.sum() < 0.06 * (~pushed).sum()
    silhouette = np.abs(np.arange(COLS)[None, :] - np.array([cols.min(), cols.max()])[:, None]).min(axis=0)
    inside = others & (silhouette > 4)[None, :]
    assert inside.sum() > 0.5 * others.sum()
    assert np.all(np.abs(corrected[inside] - true[inside]) < 1.5 * NOISE)


def test_nothing_moves_where_no_plane_fits_enough_pulses():
    true, _ = _branch()
    measured = true + np.random.default_rng(4).normal(0, NOISE, true.shape)
    pure = np.zeros(true.shape, dtype=bool)
    pure[::4, ::4] = True  # 9 of the 81 pulses of a window at most
    measured[20, 20] += PUSH
    tails, plane = surface_tails(measured, pure, MODELLED)
    assert not tails.any()
    assert np.isnan(plane[~pure]).all()


def test_tested_pulses_outside_the_fit_take_the_plane_of_the_fitted_ones_and_do_not_bend_it():
    """Pulses flagged as straddling (tested, not fitted) on a tilted plane: those pushed off it take its range."""
    rows, cols = np.mgrid[0:40, 0:40]
    true = 2.0 + 0.0004 * rows - 0.0007 * cols  # a tilted flat leaf at 2 m, m
    rng = np.random.default_rng(5)
    measured = true + rng.normal(0, NOISE, true.shape)
    lone = np.zeros(true.shape, dtype=bool)
    lone[8:32:3, 8:32:3] = True  # 64 pulses, at most 9 in a window
    pushed = lone & (rng.random(true.shape) < 0.5)
    measured[pushed] += 5 * NOISE  # all the same way: they would tilt a plane fitted to them
    tails, plane = surface_tails(measured, ~lone, MODELLED, tested=lone)
    assert not tails[~lone].any() and np.isnan(plane[~lone]).all()
    assert tails[pushed].all()
    np.testing.assert_allclose(plane[lone], true[lone], atol=0.6 * NOISE)  # 81 - 9 pulses: sigma / sqrt(72) x 3
    # Unpushed lone pulses more than 2 RMS off move too (onto the plane, closer to the truth); the rest keep theirs.
    calm = lone & ~pushed & ~tails
    assert calm.sum() > 0.8 * (lone & ~pushed).sum()
    # A 5 cm step between two surfaces through the window (and lone pulses beside it): the refit keeps the pulse's
    # side, and every pulse that moves lands on its own surface, none on the other one.
    step = np.where(cols >= 20, 0.05, 0.0)
    beside = lone | ((cols == 19) | (cols == 20)) & (rows % 3 == 1)
    tails, plane = surface_tails(measured + step, ~beside, MODELLED, tested=beside)
    assert tails[beside & (np.abs(cols - 20) <= 3)].any()
    np.testing.assert_allclose(plane[tails], (true + step)[tails], atol=1.5 * NOISE)

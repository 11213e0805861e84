"""Mixed pulses of a branch land on its cylinder (leafsfs.woodfit): a leaf edge and a wall around a synthetic branch."""

import math

import numpy as np

from leafsfs.edges import MixedPulses, attribute_mixed
from leafsfs.woodfit import MIN_PULSES, MIN_QUADRIC_PULSES, cylinder_ranges, quadric_ranges, twig_ranges, wood_labels, \
    wood_fitted_range

STEP = math.radians(0.018)
N = 120
DIST, RADIUS, WALL, LEAF = 3.0, 0.01, 3.5, 2.9
NOISE = 0.001
FOOTPRINT_PX = 2.0
BAND = 6


def _profile(rows):
    """Lateral offset of a beam from the branch's axis, m (the axis lies along the columns)."""
    return (rows - N / 2 + 0.3) * STEP * DIST


def _scene(leaf=True, seed=0):
    """A horizontal branch (radius 1 cm, 3 m) before a wall (3.5 m), a leaf (2.9 m) over its left part.

    Each pulse is the power-weighted mean range of 9 x 9 rays across a
    Gaussian footprint (1/e^2 radius 2 px); the wall returns less per ray
    (inverse square). Labels: 1 leaf, 2 branch, 3 wall; pure pulses are
    those whose rays all hit one of them.
    """
    k = 9
    off = np.linspace(-1, 1, k) * 2 * FOOTPRINT_PX
    weight = np.exp(-2 * (off[:, None] ** 2 + off[None] ** 2) / FOOTPRINT_PX ** 2)
    rows, cols = np.mgrid[0:N, 0:N].astype(float)
    total, power = np.zeros((N, N)), np.zeros((N, N, 4))
    for a in range(k):
        for b in range(k):
            r, c = rows + off[a], cols + off[b]
            y = _profile(r)
            on_leaf = leaf & (c < N / 3 + 0.2 * (r - N / 2))
            on_branch = np.abs(y) < RADIUS
            label = np.where(on_leaf, 1, np.where(on_branch, 2, 3))
            z = np.where(on_leaf, LEAF, np.where(on_branch, DIST - np.sqrt(np.clip(RADIUS ** 2 - y ** 2, 0, None)),
                                                 WALL))
            p = weight[a, b] * np.where(label == 3, (DIST / WALL) ** 2, 1.0)
            total += p * z
            for m in (1, 2, 3):
                power[..., m] += p * (label == m)
    range_m = total / power.sum(axis=-1) + np.random.default_rng(seed).normal(0, NOISE, (N, N))
    pure = power.max(axis=-1) >= 0.999 * power.sum(axis=-1)
    surfaces = np.where(pure, power.argmax(axis=-1), 0)
    theta, psi = np.meshgrid(np.arange(N) * STEP, math.pi / 2 + (np.arange(N) - N / 2) * STEP)
    return range_m, surfaces, theta, psi


def _off_branch(range_m, rows):
    """Distance of points at ``range_m`` on the beams of ``rows`` from the branch's surface, m."""
    return np.abs(np.hypot(_profile(rows), range_m - DIST) - RADIUS)


def test_branch_mixed_pulses_land_on_the_cylinder():
    range_m, surfaces, theta, psi = _scene()
    mixed = attribute_mixed(range_m, surfaces, BAND, tolerance_m=3 * NOISE)
    owned = (surfaces == 0) & (mixed.owner == 2)
    assert owned.sum() > 300
    plane = mixed.owner_range()
    fitted = wood_fitted_range(mixed, range_m, theta, psi, None, np.array([1]), BAND, NOISE)
    circle = np.where(np.isfinite(fitted), fitted, plane)
    rows = np.nonzero(owned)[0].astype(float)
    behind = np.where(mixed.pair[..., 1] > 0, mixed.pair_range[..., 0] + mixed.pair_range[..., 1], 0)[owned]
    at_wall = behind > DIST + WALL - 0.05  # the branch's silhouettes against the wall (not the leaf's edge)
    new, old = _off_branch(circle[owned], rows), _off_branch(plane[owned], rows)
    # At its silhouettes the branch turns away from the beam: its plane stops short, its circle does not.
    assert np.median(new[at_wall]) < NOISE
    assert np.median(new[at_wall]) < 0.5 * np.median(old[at_wall])
    # Beside the leaf's edge, on the branch's front, the wood part lands on the branch within the noise.
    assert np.median(new[~at_wall]) < NOISE


def test_edge_pulses_within_the_noise_of_the_branch_land_on_its_cylinder():
    # Unlinked pulses at the branch's edge whose range lies within the noise of its plane are its own (no pair):
    # their circle distance lies nearer the branch than their measured range; pulses of the leaf get none.
    range_m, surfaces, theta, psi = _scene()
    mixed = attribute_mixed(range_m, surfaces, BAND, tolerance_m=3 * NOISE)
    alone = (surfaces == 0) & (mixed.pair[..., 0] == 2) & (mixed.pair[..., 1] == 0)
    fitted = wood_fitted_range(mixed, range_m, theta, psi, None, np.array([1]), BAND, NOISE)
    on = alone & np.isfinite(fitted)
    assert on.sum() >= 0.5 * alone.sum() > 20
    rows = np.nonzero(on)[0].astype(float)
    assert np.median(_off_branch(fitted[on], rows)) < np.median(_off_branch(range_m[on], rows))
    assert np.isnan(fitted[mixed.owner == 1]).all()


def test_flat_strip_keeps_its_plane():
    # A flat strip as wide as the branch: the plane fits its pulses at least as well as a circle: no range given.
    range_m, surfaces, theta, psi = _scene(leaf=False)
    rows = np.arange(N)[:, None] * np.ones((1, N))
    strip = np.abs(_profile(rows)) < RADIUS
    flat = np.where(strip, DIST - 0.3 * _profile(rows), range_m)
    flat[strip] += np.random.default_rng(1).normal(0, NOISE, strip.sum())
    mixed = attribute_mixed(flat, surfaces, BAND, tolerance_m=3 * NOISE)
    targets = (surfaces == 0) & (mixed.owner == 2)
    out = cylinder_ranges(flat, surfaces, mixed.owner, targets, STEP, 8.0, NOISE)
    assert targets.sum() > 100
    assert np.isfinite(out[targets]).mean() < 0.1


def _bowl(curvature, noise, seed=2):
    """A surface curving away from the beam, ``DIST + curvature (x^2 + y^2) / 2`` (x, y across the grid, m), with its
    pure pulses on the rows above ``N / 2`` (label 1), the targets the next 8 rows below them, and the owner image
    (label 1 on both)."""
    rows, cols = np.mgrid[0:N, 0:N].astype(float)
    x, y = (rows - N / 2) * STEP * DIST, (cols - N / 2) * STEP * DIST
    true = DIST + 0.5 * curvature * (x ** 2 + y ** 2)
    range_m = true + np.random.default_rng(seed).normal(0, noise, (N, N))
    surfaces = np.where(rows < N / 2, 1, 0)
    targets = (rows >= N / 2) & (rows < N / 2 + 8) & (np.abs(cols - N / 2) < 20)
    return range_m, true, surfaces, targets, np.where(targets, 1, surfaces)


def _plane_at(range_m, surfaces, row, col, radius):
    """Least-squares plane of the pure pulses within ``radius`` pixels of ``(row, col)``, at that pixel, m."""
    rows, cols = np.nonzero(surfaces > 0)
    near = (rows - row) ** 2 + (cols - col) ** 2 <= radius ** 2
    design = np.stack([np.ones(near.sum()), rows[near] - row, cols[near] - col], axis=1)
    return np.linalg.lstsq(design, range_m[rows[near], cols[near]], rcond=None)[0][0]


def test_quadric_follows_a_surface_curving_away():
    # A 1 cm radius of curvature (a twig seen across): beyond the last pure pulses the surface falls behind their
    # plane by millimetres; the quadric of the pure pulses lands on it within the noise.
    range_m, true, surfaces, targets, owner = _bowl(1 / 0.01, NOISE / 4)
    out = quadric_ranges(range_m, surfaces, owner, targets, 12.0, NOISE)
    fitted = targets & np.isfinite(out)
    assert fitted.sum() >= 40
    rows, cols = np.nonzero(fitted)
    plane = np.array([_plane_at(range_m, surfaces, r, c, 12.0) for r, c in zip(rows, cols)])
    error, plane_error = np.abs(out - true)[fitted], np.abs(plane - true[fitted])
    assert np.median(error) < NOISE / 2
    assert np.median(error) < 0.2 * np.median(plane_error)


def test_quadric_of_a_plane_is_the_plane():
    range_m, true, surfaces, targets, owner = _bowl(0.0, NOISE)
    out = quadric_ranges(range_m, surfaces, owner, targets, 12.0, NOISE)
    error = (out - true)[targets & np.isfinite(out)]
    assert len(error) >= 40
    assert abs(np.median(error)) < NOISE / 2 and np.quantile(np.abs(error), 0.9) < 2.5 * NOISE


def test_quadric_refuses_far_noisy_or_sparse_neighbourhoods():
    # Eight rows beyond four rows of pulses the quadric's own noise exceeds a pulse's: no distance there.
    range_m, _, surfaces, targets, owner = _bowl(0.0, NOISE)
    out = quadric_ranges(range_m, surfaces, owner, targets, 12.0, NOISE)
    assert np.isfinite(out[N // 2]).any() and np.isnan(out[N // 2 + 7][targets[N // 2 + 7]]).all()
    # Residuals beyond twice the noise given, or fewer pulses than the fit needs: no distance.
    range_m, _, surfaces, targets, owner = _bowl(0.0, 5 * NOISE)
    assert np.isnan(quadric_ranges(range_m, surfaces, owner, targets, 12.0, NOISE)[targets]).all()
    range_m, _, surfaces, targets, owner = _bowl(0.0, NOISE)
    sparse = np.where(np.random.default_rng(3).random(surfaces.shape) < (MIN_QUADRIC_PULSES - 2) / 250, surfaces, 0)
    assert np.isnan(quadric_ranges(range_m, sparse, owner, targets, 12.0, NOISE)[targets]).mean() > 0.5


def _twig(pulses, seed=4):
    """A twig seen across at ``DIST`` with ``pulses`` pure pulses (label 1) scattered within 3 px of a target pulse at
    the grid's centre, noise ``NOISE``; returns the range image, the cores, the owner image and the target."""
    rng = np.random.default_rng(seed)
    range_m = DIST + rng.normal(0, NOISE, (N, N))
    cores = np.zeros((N, N), dtype=int)
    ring = [(dr, dc) for dr in range(-3, 4) for dc in range(-3, 4) if 0 < dr * dr + dc * dc <= 9]
    for k in rng.choice(len(ring), pulses, replace=False):
        cores[N // 2 + ring[k][0], N // 2 + ring[k][1]] = 1
    targets = np.zeros((N, N), dtype=bool)
    targets[N // 2, N // 2] = True
    range_m[N // 2, N // 2] = DIST + 0.05  # the target mixes the twig with what lies behind it
    return range_m, cores, np.where(targets, 1, cores), targets


def test_twig_takes_the_median_of_its_few_pulses():
    # 1..MIN_PULSES-1 pulses of the owner around the target: their median (within the noise of the twig's range,
    # not the target's own mixed range).
    for pulses in range(1, MIN_PULSES):
        range_m, cores, owner, targets = _twig(pulses)
        out = twig_ranges(range_m, cores, owner, targets, 4.0)
        assert abs(out[targets][0] - np.median(range_m[cores == 1])) < 1e-12
        assert abs(out[targets][0] - DIST) < 3 * NOISE
        assert np.isnan(out[~targets]).all()


def test_twig_refuses_owners_with_enough_pulses_for_a_fit_or_none():
    # MIN_PULSES or more pulses: a circle or quadric decides there; none within the radius: nothing to take.
    range_m, cores, owner, targets = _twig(MIN_PULSES)
    assert np.isnan(twig_ranges(range_m, cores, owner, targets, 4.0)[targets]).all()
    range_m, cores, owner, targets = _twig(2)
    assert np.isnan(twig_ranges(range_m, cores, owner, targets, 0.5)[targets]).all()


def test_paired_twig_pulse_takes_the_twig_median_a_lone_one_keeps_its_range():
    # A twig of four pure pulses (too few for a circle or a quadric) before a wall: its mixed pulse paired with the
    # wall takes the twig's median range; a pulse within the noise of the twig alone gets nothing (it keeps its
    # measured range in the pipeline).
    rng = np.random.default_rng(5)
    range_m = WALL + rng.normal(0, NOISE, (N, N))
    surfaces = np.full((N, N), 3)  # the wall
    surfaces[55:66, 55:66] = 0  # around the twig: mixed or unlinked
    twig = (slice(60, 62), slice(58, 60))
    surfaces[twig] = 2
    range_m[twig] = DIST + rng.normal(0, NOISE, (2, 2))
    pair, share = np.zeros((N, N, 2), dtype=int), np.full((N, N), np.nan)
    pair_range = np.full((N, N, 2), np.nan)
    owner = np.where(surfaces > 0, surfaces, 0)
    paired, alone = (60, 61), (61, 61)
    range_m[paired] = 0.7 * DIST + 0.3 * WALL
    pair[paired], share[paired], pair_range[paired], owner[paired] = (2, 3), 0.7, (DIST - 0.01, WALL), 2
    range_m[alone] = DIST + 0.002
    pair[alone], share[alone], pair_range[alone], owner[alone] = (2, 0), 1.0, (DIST + 0.002, np.nan), 2
    mixed = MixedPulses(surfaces, pair, share, pair_range, np.full((N, N, 2), np.nan), owner, np.zeros((N, N), bool))
    theta, psi = np.meshgrid(np.arange(N) * STEP, math.pi / 2 + (np.arange(N) - N / 2) * STEP)
    fitted = wood_fitted_range(mixed, range_m, theta, psi, None, np.array([], dtype=int), BAND, NOISE)
    assert abs(fitted[paired] - np.median(range_m[twig])) < 1e-12
    assert np.isnan(fitted[alone])


def test_owner_that_is_no_leaf_and_not_wood_shaped_takes_its_quadric():
    # A wide surface curving away (3 cm radius of curvature: a curled leaf piece), neither elongated, sparse nor narrow,
    # that the segmentation did not take for a leaf owns mixed pulses shared with a wall: they take its quadric,
    # nearer its true surface than its plane; a leaf surface's pulses get nothing.
    range_m, true, surfaces, targets, _ = _bowl(1 / 0.03, NOISE / 4)
    rows = np.arange(N)[:, None] * np.ones((1, N))
    surfaces = np.where(rows >= N / 2 + 8, 2, surfaces)  # the wall's pure pulses below the targets
    range_m = np.where(surfaces == 2, WALL, range_m)
    theta, psi = np.meshgrid(np.arange(N) * STEP, math.pi / 2 + (np.arange(N) - N / 2) * STEP)
    assert not wood_labels(surfaces, range_m, theta, psi, STEP, None)[1]
    share = 0.7
    range_m = np.where(targets, share * true + (1 - share) * WALL, range_m)
    plane = np.full((N, N), np.nan)
    for r, c in zip(*np.nonzero(targets)):
        plane[r, c] = _plane_at(range_m, surfaces == 1, r, c, 12.0)
    pair = np.where(targets[..., None], np.array([1, 2]), 0)
    pair_range = np.where(targets[..., None], np.stack([plane, np.full((N, N), WALL)], axis=-1), np.nan)
    mixed = MixedPulses(surfaces.copy(), pair, np.where(targets, share, np.nan), pair_range,
                        np.full((N, N, 2), np.nan), np.where(targets, 1, surfaces), np.zeros((N, N), bool))
    fitted = wood_fitted_range(mixed, range_m, theta, psi, None, np.array([], dtype=int), BAND, NOISE)
    on = targets & np.isfinite(fitted)
    assert on.sum() >= 0.5 * targets.sum()
    assert np.median(np.abs(fitted - true)[on]) < 0.5 * np.median(np.abs(plane - true)[on])
    assert np.isnan(wood_fitted_range(mixed, range_m, theta, psi, None, np.array([1]), BAND, NOISE)[targets]).all()

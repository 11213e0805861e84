"""Mixed pulses of a branch land on its cylinder (leafsfs.woodfit): a leaf edge and a wall around a synthetic branch."""

import math

import numpy as np

from leafsfs.edges import attribute_mixed
from leafsfs.woodfit import cylinder_ranges, wood_owner_range

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
    circle = wood_owner_range(mixed, range_m, theta, psi, None, np.array([1]), BAND, NOISE)
    plane = mixed.owner_range()
    rows = np.nonzero(owned)[0].astype(float)
    behind = np.where(mixed.pair[..., 1] > 0, mixed.pair_range[..., 0] + mixed.pair_range[..., 1], 0)[owned]
    at_wall = behind > DIST + WALL - 0.05  # the branch's silhouettes against the wall (not the leaf's edge)
    new, old = _off_branch(circle[owned], rows), _off_branch(plane[owned], rows)
    # At its silhouettes the branch turns away from the beam: its plane stops short, its circle does not.
    assert np.median(new[at_wall]) < NOISE
    assert np.median(new[at_wall]) < 0.5 * np.median(old[at_wall])
    # Beside the leaf's edge, on the branch's front, the wood part lands on the branch within the noise.
    assert np.median(new[~at_wall]) < NOISE


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

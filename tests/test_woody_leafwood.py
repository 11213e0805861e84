"""Leaf/wood separation from the geometry alone (woody.leafwood)."""

import numpy as np
import pytest

from woody.errors import WoodyError
from woody.leafwood import REACH_M, separate_wood


def _stem_with_leaves_and_tufts(seed: int):
    """A 1.2 m stem of 3 cm radius (its surface, 4 mm spacing) with 8 flat 8 cm leaf discs touching it and 8
    needle tufts (60 needles of 8 cm, 1 mm apart along each) sprouting from its surface; labels: 1 stem, 2 leaf,
    3 needle."""
    rng = np.random.default_rng(seed)
    count = int(2 * np.pi * 0.03 * 1.2 / 0.004**2)
    angle, z = rng.uniform(0, 2 * np.pi, count), rng.uniform(0, 1.2, count)
    parts, labels = [np.column_stack([0.03 * np.cos(angle), 0.03 * np.sin(angle), z])], [np.full(count, 1)]
    for i in range(8):
        azimuth, height = i * 2.4, 0.2 + 0.1 * i
        out = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
        side = np.array([-out[1], out[0], 0.0])
        tilt = np.cross(out, side)
        if i % 2 == 0:  # a leaf: a disc whose edge touches the stem, tilted 30 deg from horizontal
            r, phi = 0.04 * np.sqrt(rng.uniform(0, 1, 300)), rng.uniform(0, 2 * np.pi, 300)
            u, v = r * np.cos(phi), r * np.sin(phi)
            normal_tilt = np.cos(np.radians(30)) * out + np.sin(np.radians(30)) * tilt
            centre = (0.03 + 0.04) * out + np.array([0, 0, height])
            parts.append(centre + u[:, None] * normal_tilt + v[:, None] * side)
            labels.append(np.full(300, 2))
        else:  # a needle tuft: straight needles from one point of the surface, in every upward direction
            direction = rng.normal(size=(60, 3)) + 1.5 * out
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            along = np.arange(0.005, 0.08, 0.001)
            base = 0.03 * out + np.array([0, 0, height])
            parts.append((base + along[None, :, None] * direction[:, None, :]).reshape(-1, 3))
            labels.append(np.full(60 * len(along), 3))
    points = np.vstack(parts)
    return points + rng.normal(0, 0.0005, points.shape), np.concatenate(labels)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_stem_is_kept_and_its_leaves_and_needle_tufts_left_out(seed):
    points, labels = _stem_with_leaves_and_tufts(seed)
    wood = separate_wood(points)
    stem = labels == 1
    # a stem's tip goes with the leaves (the paths reach less than REACH_M beyond its points, or lead there)
    below_tip = stem & (points[:, 2] < 1.2 - 2 * REACH_M)
    assert wood[below_tip].mean() > 0.97
    # leaves and needles are dead ends of the paths; what lies within the core's margin of the stem stays
    assert wood[labels == 2].mean() < 0.15 and wood[labels == 3].mean() < 0.35


def test_a_bare_stem_is_all_wood_and_a_stray_blob_is_not():
    points, labels = _stem_with_leaves_and_tufts(4)
    stem = points[labels == 1]
    stray = np.array([0.5, 0.0, 0.6]) + np.random.default_rng(5).uniform(-0.03, 0.03, (500, 3))
    wood = separate_wood(np.vstack([stem, stray]))
    assert wood[: len(stem)][stem[:, 2] < 1.2 - 2 * REACH_M].all()
    assert not wood[len(stem):].any()


def test_a_cloud_too_sparse_to_show_a_leaf_is_left_whole():
    points, _ = _stem_with_leaves_and_tufts(1)
    sparse = points[np.random.default_rng(0).choice(len(points), 100, replace=False)]  # some 4 cm apart
    assert separate_wood(sparse).all()


def test_separation_is_deterministic_and_checks_its_settings():
    points, _ = _stem_with_leaves_and_tufts(1)
    assert np.array_equal(separate_wood(points), separate_wood(points))
    with pytest.raises(WoodyError, match="positive"):
        separate_wood(points, reach_m=0.0)
    with pytest.raises(WoodyError, match="too few"):
        separate_wood(points[:5])


def test_follow_tree_reconstructs_only_the_wood_when_asked():
    from woody.trunk import follow_tree

    points, labels = _stem_with_leaves_and_tufts(2)
    wood = separate_wood(points)
    result = follow_tree(points, separate=True)
    assert result.stats["wood_points"] == wood.sum() and len(result.labels) == len(points)
    assert (result.labels[~wood] == -1).all()
    # a stem of 3 cm radius, its leaves and tufts left out: the cylinders hold about its volume (its tip is lost)
    assert 0.7 < result.volume / (np.pi * 0.03**2 * 1.2) < 1.1


def test_follow_tree_says_so_when_the_separation_finds_no_wood():
    from woody.trunk import follow_tree

    blob = np.random.default_rng(0).uniform(-0.03, 0.03, (500, 3))  # 6 cm across: no path runs on for REACH_M
    assert not separate_wood(blob).any()
    with pytest.raises(WoodyError, match="found 0 wood points of 500"):
        follow_tree(blob, separate=True)

"""Greatest-slope formulas (eqs 2.7-2.12), quantisation and the recursive watershed (digest §9 tests 1-2)."""

import numpy as np
import pytest

from leafsfs.quantize import assign_levels, quantile_thresholds, shell_fractions
from leafsfs.segment import split_parts
from leafsfs.slope import (
    cross2, curve_tangent_3d, descending_direction, gs_vector, outward_normal, propagation_direction, sps_normal,
)

# Analytic height fields with exact gradients: (h, grad h).
SURFACES = {
    "plane": (lambda x, y: 0.4 * x - 0.9 * y + 1, lambda x, y: (0.4 + 0 * x, -0.9 + 0 * y)),
    "cone": (lambda x, y: 5 - 0.7 * np.hypot(x, y), lambda x, y: (-0.7 * x / np.hypot(x, y), -0.7 * y / np.hypot(x, y))),
    "dome": (lambda x, y: np.sqrt(9 - x**2 - y**2), lambda x, y: (-x / np.sqrt(9 - x**2 - y**2), -y / np.sqrt(9 - x**2 - y**2))),
    "bowl": (lambda x, y: 0.3 * (x**2 + y**2), lambda x, y: (0.6 * x, 0.6 * y)),
}


def _angle_deg(u, v):
    return np.degrees(np.arccos(np.clip(np.sum(u * v, axis=1), -1, 1)))


@pytest.mark.parametrize("name", sorted(SURFACES))
def test_greatest_slope_formula_matches_minus_gradient_in_all_sign_cases(name):
    rng = np.random.default_rng(1)
    n = 4000
    r, theta = rng.uniform(0.3, 2.5, n), rng.uniform(0, 2 * np.pi, n)
    x, y = r * np.cos(theta), r * np.sin(theta)
    p, q = SURFACES[name][1](x, y)
    grad = np.stack([p, q], axis=1)
    alpha = np.arctan(np.linalg.norm(grad, axis=1))
    t = rng.normal(size=(n, 2))
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    gamma = np.arctan(np.sum(grad * t, axis=1))  # elevation of the curve's 3-D tangent on the surface
    truth = -grad / np.linalg.norm(grad, axis=1, keepdims=True)
    sign = np.sign(cross2(t, truth))
    g = descending_direction(t, gamma, alpha, sign)
    cases = {(s, gm >= 0) for s, gm in zip(sign, gamma)}
    assert cases == {(1.0, True), (1.0, False), (-1.0, True), (-1.0, False)}
    assert _angle_deg(g, truth).max() < 0.5
    # eq 2.9: unit vector of elevation -alpha, normal to the surface normal
    big_g = gs_vector(g, alpha)
    assert np.allclose(np.linalg.norm(big_g, axis=1), 1) and np.allclose(big_g[:, 2], -np.sin(alpha))
    assert np.allclose(np.sum(big_g * sps_normal(grad), axis=1), 0, atol=1e-12)


@pytest.mark.parametrize("name,expected_sign", [("dome", -1), ("cone", -1), ("bowl", 1)])
def test_propagation_points_outward_and_changes_height_by_slope(name, expected_sign):
    height, gradient = SURFACES[name]
    angles = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    x, y = 1.5 * np.cos(angles), 1.5 * np.sin(angles)  # a CCW level curve around the summit / sink
    t = np.stack([-np.sin(angles), np.cos(angles)], axis=1)
    grad = np.stack(gradient(x, y), axis=1)
    alpha = np.arctan(np.linalg.norm(grad, axis=1))
    sign = np.sign(cross2(t, -grad))
    assert np.all(sign == expected_sign)
    g = descending_direction(t, np.zeros(64), alpha, sign)
    d = propagation_direction(t, g, sign)
    assert np.all(np.sum(d * outward_normal(t), axis=1) > 0.999)
    step = 1e-4
    rise = height(x + step * d[:, 0], y + step * d[:, 1]) - height(x, y)
    assert np.allclose(rise / step, sign * np.tan(alpha), rtol=1e-3)


def test_tangent_update_closed_form_equals_the_cross_product_form():
    rng = np.random.default_rng(2)
    n = 500
    t = rng.normal(size=(n, 2))
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    normal = sps_normal(rng.normal(scale=1.5, size=(n, 2)))
    tangent = curve_tangent_3d(t, normal)
    # eq 2.12: T = sgn(x) (k x N), k the principal normal of the projection (either side), sgn = +1 if k left of t
    side = rng.choice([-1.0, 1.0], n)
    k = side[:, None] * np.stack([-t[:, 1], t[:, 0]], axis=1)
    k3 = np.column_stack([k, np.zeros(n)])
    sgn = np.where(cross2(t, k) > 0, 1.0, -1.0)
    crossed = sgn[:, None] * np.cross(k3, normal)
    crossed /= np.linalg.norm(crossed, axis=1, keepdims=True)
    assert np.allclose(tangent, crossed, atol=1e-12)
    assert np.allclose(np.sum(tangent * normal, axis=1), 0, atol=1e-12)  # in the SPS tangent plane
    horizontal = tangent[:, :2] / np.linalg.norm(tangent[:, :2], axis=1, keepdims=True)
    assert np.allclose(horizontal, t)  # projects onto t'


def test_shell_rule_and_quantiles():
    mask = np.ones((60, 80), dtype=bool)
    eps_alpha, eps_seed = shell_fractions(mask, "T3")
    assert eps_alpha == pytest.approx(4 * (2 * 59 + 2 * 79) / 4800)
    assert eps_seed == pytest.approx(2 * eps_alpha)
    assert shell_fractions(mask, "T3*")[1] == pytest.approx(eps_alpha)
    alpha = np.random.default_rng(0).uniform(0, 1.2, mask.shape)
    thresholds = quantile_thresholds(alpha[mask], 0.2, 0.2)
    assert len(thresholds) == 5 and thresholds[-1] == np.pi / 2
    levels = assign_levels(alpha, mask, thresholds)
    assert np.allclose(np.bincount(levels.ravel()) / mask.size, 0.2, atol=0.005)
    assert np.all(alpha[levels == 0] <= thresholds[0])
    assert np.all(alpha[levels == 2] > thresholds[1]) and np.all(alpha[levels == 2] <= thresholds[2])
    flat = quantile_thresholds(np.full(100, 0.3), 0.1, 0.2)
    assert np.array_equal(flat, [0.3, np.pi / 2])


def test_watershed_gives_one_part_per_seed_and_merges_orphans():
    x, y = np.meshgrid(np.linspace(-3, 3, 61), np.linspace(-2, 2, 41))
    # alpha with three minima: two deep ones (seeds) and one shallow one (an orphan above alpha_0)
    alpha = 1.2 - 0.9 * np.exp(-((x + 1.6) ** 2 + y**2)) - 0.9 * np.exp(-((x - 1.6) ** 2 + y**2)) \
        - 0.35 * np.exp(-4 * (x**2 + (y - 1.5) ** 2))
    mask = np.ones_like(alpha, dtype=bool)
    levels = assign_levels(alpha, mask, quantile_thresholds(alpha.ravel(), 0.1, 0.1))
    parts = split_parts(alpha, levels)
    assert parts.max() == 2 and parts.min() == 1
    for k in (1, 2):
        assert np.any(levels[parts == k] == 0)
    assert parts[20, 10] != parts[20, 50]
    kept = split_parts(alpha, levels, orphans="seed")
    assert kept.max() == 3
    assert np.all(levels[kept == kept[40, 30]] > 0)  # the orphan keeps its own lowest domain

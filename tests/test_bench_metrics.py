"""Metric functions of the benchmark on hand-made cases."""

import math

import numpy as np
import pytest
import trimesh

from benchmarks import metrics
from benchmarks.scoring import trait_errors
from benchmarks.summary import headline_columns, headline_table, summarize, summarize_by_scene


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(subdivisions=3, radius=0.5)


def test_surface_distance_matches_brute_force(sphere):
    rng = np.random.default_rng(1)
    # Points on, near and far from the surface, inside and outside.
    directions = rng.normal(size=(600, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    radii = np.concatenate([rng.uniform(0.0, 0.45, 200), rng.uniform(0.49, 0.51, 200), rng.uniform(0.6, 3.0, 200)])
    points = directions * radii[:, None]
    _, expected, _ = trimesh.proximity.closest_point_naive(sphere, points)
    distance = metrics.surface_distance(points, sphere.vertices, sphere.faces)
    np.testing.assert_allclose(distance, expected, atol=1e-12)
    signed = metrics.surface_distance(points, sphere.vertices, sphere.faces, signed=True)
    np.testing.assert_allclose(np.abs(signed), expected, atol=1e-12)
    # Outward face normals: points inside are negative, well-outside ones positive.
    assert np.all(signed[radii < 0.45] < 0) and np.all(signed[radii > 0.6] > 0)


def test_surface_distance_to_a_triangle_is_exact_at_edges_and_corners():
    vertices = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    faces = np.array([[0, 1, 2]])
    points = np.array([[0.2, 0.2, 0.3],     # above the face
                       [-1.0, -1.0, 0.0],   # beyond the corner at the origin
                       [0.5, -2.0, 0.0],    # beyond the edge y = 0
                       [1.0, 1.0, 0.0]])    # beyond the hypotenuse
    expected = [0.3, math.sqrt(2.0), 2.0, math.sqrt(2.0) / 2]
    np.testing.assert_allclose(metrics.surface_distance(points, vertices, faces), expected, atol=1e-12)
    assert metrics.surface_distance(np.zeros((0, 3)), vertices, faces).shape == (0,)


def test_robust_sigma_and_tau():
    rng = np.random.default_rng(2)
    sample = rng.normal(5.0, 0.003, 40_000)
    sample[:2000] = 1.0  # 5 % gross outliers barely move the MAD
    assert metrics.robust_sigma(sample) == pytest.approx(0.003, rel=0.1)
    assert math.isnan(metrics.robust_sigma(np.array([])))
    assert metrics.auto_tau(0.001) == pytest.approx(0.003)
    assert metrics.auto_tau(0.0005) == metrics.TAU_FLOOR_M == 0.002
    assert metrics.auto_tau(math.nan) == 0.002


def test_outlier_scores_for_a_filter_and_a_correction():
    before = np.array([True, True] + [False] * 8)
    # A filter removes outlier 0 and one good point.
    kept = np.ones(10, bool)
    kept[[0, 5]] = False
    s = metrics.outlier_scores(before, kept, before)
    assert s["n_points"] == 10 and s["n_outliers"] == 2
    assert s["rop_before"] == pytest.approx(0.2)
    assert s["rop_after"] == pytest.approx(1 / 8)
    assert s["rop_reduction"] == pytest.approx(1 - (1 / 8) / 0.2)
    assert s["good_points_lost"] == pytest.approx(1 / 8)
    assert s["outliers_removed"] == pytest.approx(0.5)
    assert s["outliers_restored"] == 0.0
    # A correction keeps everything, brings outlier 1 within tau and spoils good point 9.
    after = np.zeros(10, bool)
    after[[0, 9]] = True
    s = metrics.outlier_scores(before, np.ones(10, bool), after)
    assert s["rop_after"] == pytest.approx(0.2)
    assert s["outliers_restored"] == pytest.approx(0.5)
    assert s["good_points_damaged"] == pytest.approx(1 / 8)
    assert s["good_points_lost"] == 0.0
    # Removing everything leaves no outlier, at the cost of every good point.
    s = metrics.outlier_scores(before, np.zeros(10, bool), before)
    assert s["rop_after"] == 0.0 and s["rop_reduction"] == 1.0 and s["good_points_lost"] == 1.0
    # No outlier at all: the reduction is undefined.
    s = metrics.outlier_scores(np.zeros(4, bool), np.ones(4, bool), np.zeros(4, bool))
    assert s["rop_before"] == 0.0 and math.isnan(s["rop_reduction"])


def test_leaf_power_share_from_the_first_and_second_objects():
    truth_id = np.full((5, 12), 1)
    truth_id[:, :4] = 0          # the leaf on the left
    truth_id[0, -1] = -1         # a pulse that hit nothing
    second = np.full((5, 12), -1)
    mixed = np.zeros((5, 12))
    second_fraction = np.zeros((5, 12))
    mixed[:, 3], second[:, 3], second_fraction[:, 3] = 0.3, 1, 0.3     # leaf-dominated edge pulses
    mixed[:, 4], second[:, 4], second_fraction[:, 4] = 0.4, 0, 0.4     # wall-dominated: 40 % from the leaf
    mixed[:, 5], second[:, 5], second_fraction[:, 5] = 0.5, 0, 0.3     # a third object has 20 %
    mixed[:, 10], second[:, 10], second_fraction[:, 10] = 0.2, 2, 0.2  # the minority is someone else
    mixed[0, -1] = np.nan
    share = metrics.leaf_power_share(truth_id, mixed, second, second_fraction, 0)
    np.testing.assert_allclose(share[:, :3], 1.0)
    np.testing.assert_allclose(share[:, 3], 0.7)
    np.testing.assert_allclose(share[:, 4], 0.4)
    np.testing.assert_allclose(share[:, 5], 0.3)
    np.testing.assert_allclose(share[:, 6:], 0.0)
    np.testing.assert_allclose(metrics.leaf_power_share(truth_id, mixed, second, second_fraction, 1)[:, 3:5],
                               [[0.3, 0.6]] * 5)
    assert (share >= metrics.MIN_POWER_SHARE).sum() == 6 * 5


def test_axis_angle_errors_ignore_the_sense_and_wrap_azimuth():
    assert metrics.axis_angle_errors(-30.0, 200.0, 30.0, 20.0) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert metrics.axis_angle_errors(10.0, 359.0, 10.0, 1.0) == pytest.approx((0.0, 2.0), abs=1e-9)
    el, az = metrics.axis_angle_errors(40.0, 90.0, 30.0, 90.0)
    assert el == pytest.approx(10.0) and az == pytest.approx(0.0, abs=1e-9)


def test_trait_errors():
    truth = {"area_m2": 0.002, "elevation_deg": 30.0, "azimuth_deg": 90.0}
    errors = trait_errors(truth, {"area_m2": 0.0019, "elevation_deg": -30.0, "azimuth_deg": 270.0})
    assert errors["area_rel_err"] == pytest.approx(-0.05)
    assert errors["area_abs_err_m2"] == pytest.approx(-0.0001)
    assert errors["elevation_err_deg"] == pytest.approx(0.0, abs=1e-9)
    assert errors["azimuth_err_deg"] == pytest.approx(0.0, abs=1e-9)
    assert trait_errors(truth, None) == {}
    assert trait_errors({"normal": [1, 0, 0]}, {"area_m2": 1.0, "elevation_deg": 0, "azimuth_deg": 0}) == {}


def test_summaries_weigh_cases_equally_and_gate_traits_on_visibility():
    def row(case, variant, leaves, error=None):
        return {"case_name": case, "variant": variant, "family": "raw", "case_spec": {"scene": {"builtin": case}},
                "metrics": {"targets": leaves}, "runtime_s": 1.0, "peak_mem_mb": 2.0, "error": error}

    single = [{"rop_before": 0.2, "rop_after": 0.1, "area_rel_err": -0.1, "visibility": 1.0}]
    tree = [{"rop_before": 0.0, "rop_after": 0.0, "area_rel_err": e, "visibility": v}
            for e, v in ((0.3, 1.0), (0.5, 0.9), (-0.9, 0.2))]
    rows = [row("leaf", "raw", single), row("tree", "raw", tree), row("broken", "raw", [], error="SfsError: x")]
    (summary,) = summarize(rows, "s")
    assert summary["n_cases"] == 3 and summary["n_errors"] == 1 and summary["n_targets"] == 4
    assert summary["rop_before"] == pytest.approx(0.1) and summary["rop_after"] == pytest.approx(0.05)
    assert summary["rop_reduction"] == pytest.approx(0.5)
    # Per case: median |error| of the visible leaves (0.1; 0.4 of 0.3 and 0.5), then the median of the cases.
    assert summary["area_rel_err_median"] == pytest.approx(0.25) and summary["n_leaves_traits"] == 3
    assert summary["diameter_err_median_m"] is None and summary["runtime_s"] == 1.0
    by_scene = summarize_by_scene(rows, "s")
    assert [r["scene"] for r in by_scene] == ["leaf", "tree", "broken"]
    assert by_scene[2]["n_errors"] == 1 and by_scene[2]["rop_before"] is None


def test_pooled_good_points_lost_weighs_leaves_by_their_good_pulses():
    def row(case, leaves):
        return {"case_name": case, "variant": "fused", "family": "prop-sfs", "case_spec": {"scene": {"builtin": case}},
                "metrics": {"targets": leaves}, "runtime_s": 1.0, "peak_mem_mb": 2.0, "error": None}

    # A leaf of 100 good pulses losing 1, and a grazing sliver whose one good pulse (of 5) is removed.
    tree = [{"n_points": 100, "n_outliers": 0, "good_points_lost": 0.01},
            {"n_points": 5, "n_outliers": 4, "good_points_lost": 1.0},
            {"n_points": 3, "n_outliers": 3, "good_points_lost": None}]  # no good pulse: not scored
    single = [{"n_points": 50, "n_outliers": 10, "good_points_lost": 0.0}]
    (summary,) = summarize([row("tree", tree), row("leaf", single)], "s")
    assert summary["good_points_lost_pooled"] == pytest.approx((2 / 101 + 0.0) / 2)
    assert summary["good_points_lost"] == pytest.approx((0.505 + 0.0) / 2)


def test_height_errors_follow_the_thesis_definition():
    truth = np.array([[0.0, 1.0], [2.0, 4.0]])
    mask = np.array([[True, True], [True, False]])  # h_tot = 2 on the mask
    estimate = np.array([[0.1, np.nan], [1.8, 99.0]])
    errors = metrics.height_errors(estimate, truth, mask)
    assert errors["completeness"] == pytest.approx(2 / 3)
    assert errors["eps_mean"] == pytest.approx((0.05 - 0.1) / 2)
    assert errors["abs_eps_mean"] == pytest.approx(0.075)
    assert errors["within_5pct"] == 0.0  # 5 % and 10 %: neither is strictly below 5 %
    assert metrics.height_errors(np.full((2, 2), np.nan), truth, mask)["completeness"] == 0.0


def test_headline_shows_woody_columns_only_when_woody_objects_were_scored():
    def row(case, variant, targets, runtime_s=1.0):
        return {"case_name": case, "variant": variant, "family": "woody", "case_spec": {"scene": {"builtin": case}},
                "metrics": {"targets": targets}, "runtime_s": runtime_s, "peak_mem_mb": 2.0, "error": None}

    wood = [{"diameter_err_mae_m": 0.004, "volume_rel_err": -0.2, "dbh_err_m": -0.003}]
    leaf = [{"rop_before": 0.2, "rop_after": 0.1}]
    # Leaf cases give a woody method nothing to do: they do not count for its runtime.
    woody_only = summarize([row("tree", "step", wood)] + [row(f"leaf{i}", "step", [], 0.0) for i in range(3)], "s")
    assert woody_only[0]["runtime_s"] == 1.0
    titles = [title for title, _, _ in headline_columns(woody_only)]
    assert titles == ["variant", "diam err med", "|vol err| med", "|DBH err| med", "runtime/case", "errors"]
    assert woody_only[0]["dbh_err_median_m"] == 0.003
    assert "|vol err| med" in headline_table(woody_only) and "20.0%" in headline_table(woody_only)
    mixed = summarize([row("tree", "step", wood), row("leaf", "raw", leaf)], "s")
    assert [t for t, _, _ in headline_columns(mixed)][:2] == ["variant", "ROP after"]
    assert "|vol err| med" in [t for t, _, _ in headline_columns(mixed)]
    assert "|vol err| med" not in [t for t, _, _ in headline_columns(summarize([row("leaf", "raw", leaf)], "s"))]

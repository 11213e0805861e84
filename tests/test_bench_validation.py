"""The thesis' validation table (ch.7) on hand-made numbers: regression, eq 2.1 BIAS, precision, groups, counts."""

import math

import numpy as np
import pytest

from benchmarks import metrics, summary


def test_linear_fit_of_estimates_against_truth():
    exact = metrics.linear_fit([1.0, 2.0, 3.0, 4.0], [3.0, 5.0, 7.0, 9.0])
    assert exact == pytest.approx({"slope": 2.0, "intercept": 1.0, "r2": 1.0})
    # y = (1, 3, 2) on x = (1, 2, 3): line 0.5 x + 1, residuals (-0.5, 1, -0.5): R² = 1 - 1.5 / 2.
    assert metrics.linear_fit([1.0, 2.0, 3.0], [1.0, 3.0, 2.0]) == pytest.approx(
        {"slope": 0.5, "intercept": 1.0, "r2": 0.25})
    assert math.isnan(metrics.linear_fit([1.0], [2.0])["slope"])
    assert math.isnan(metrics.linear_fit([2.0, 2.0], [1.0, 3.0])["r2"])


def test_area_bias_zeroes_the_mean_relative_error():
    # Estimates 20 % and 10 % low on 10 and 20 cm²: adding 2 cm² makes both exact (eq 2.1).
    assert metrics.area_bias([8.0, 18.0], [10.0, 20.0]) == pytest.approx(2.0)
    # Errors that cancel in relative terms need no bias.
    assert metrics.area_bias([9.0, 22.0], [10.0, 20.0]) == pytest.approx(0.0, abs=1e-12)
    bias = metrics.area_bias([12.0, 15.0], [10.0, 20.0])
    assert bias == pytest.approx(1 / 3)
    assert np.mean((np.array([12.0, 15.0]) + bias - [10.0, 20.0]) / [10.0, 20.0]) == pytest.approx(0.0, abs=1e-12)
    assert math.isnan(metrics.area_bias([], []))


def test_precision_and_aligned_angles():
    assert metrics.precision([1.0, 2.0, 3.0], [0.0, 0.0, 0.0]) == pytest.approx(1.0)
    assert metrics.precision([5.0, 5.0], [1.0, 1.0]) == 0.0  # a constant offset is bias, not imprecision
    assert math.isnan(metrics.precision([1.0], [0.0]))
    # An axis given with the opposite sense is the same axis; the azimuth is unwrapped next to the truth.
    assert metrics.aligned_axis_angles(-30.0, 200.0, 30.0, 20.0) == pytest.approx((30.0, 20.0))
    assert metrics.aligned_axis_angles(10.0, 359.0, 10.0, 1.0) == pytest.approx((10.0, -1.0))


def leaf(area_true_cm2, area_cm2, found=1, visibility=1.0, elevation=(30.0, 30.0), azimuth=(10.0, 10.0),
         pixels=1000, rppp_1=0.9):
    scores = {"object_type": "leaf", "area_true_m2": area_true_cm2 * 1e-4, "area_m2": area_cm2 * 1e-4,
              "visible_area_m2": area_true_cm2 * 1e-4,
              "visibility": visibility, "found": found, "region_pixels": pixels, "rppp_0": 0.0, "rppp_1": rppp_1,
              "rppp_2": 1 - rppp_1, "rppp_3": 0.0, "rppp_more": 0.0}
    if found:
        scores.update({"elevation_true_deg": elevation[0], "elevation_deg": elevation[1],
                       "azimuth_true_deg": azimuth[0], "azimuth_deg": azimuth[1]})
    return scores


def row(case, variant, leaves, counts=None, runtime=2.0):
    return {"case_name": case, "variant": variant, "family": "prop-sfs", "case_spec": {"scene": {"builtin": case}},
            "metrics": {"targets": leaves, "case": counts or {}}, "runtime_s": runtime, "peak_mem_mb": 100.0,
            "error": None}


def test_validation_table_over_all_scored_leaves():
    a = [leaf(10, 8, elevation=(10, 12), azimuth=(0, 5)), {**leaf(20, 18, elevation=(30, 28), azimuth=(90, 85)),
                                                           "merged": 1, "visible_area_m2": 18e-4},
         leaf(30, 0, found=0), leaf(40, 99, visibility=0.5)]
    b = [leaf(40, 38, elevation=(50, 50), azimuth=(45, 45), pixels=7000, rppp_1=0.5)]
    counts = {"n_regions": 5, "n_false": 2, "n_visible": 3, "n_found_visible": 2, "n_found": 3, "n_missed": 1,
              "n_pulses": 1000}
    rows = [row("tree", "fused", a, {**counts, "cpu_s": 1.5}), row("leaf", "fused", b, {**counts, "n_false": 0})]
    (table,) = summary.validation_table(rows)
    # Visible leaves: 10, 20, 30 (missed), 40 cm²; reconstructed: 10, 20, 40 -> 8, 18, 38: y = x - 2 exactly.
    assert table["n_leaves"] == 4 and table["n_success"] == 3 and table["success"] == pytest.approx(0.75)
    assert table["area_slope"] == pytest.approx(1.0) and table["area_intercept_cm2"] == pytest.approx(-2.0)
    assert table["area_r2"] == pytest.approx(1.0)
    expected_bias = -((-0.2) + (-0.1) + (-0.05)) / (1 / 10 + 1 / 20 + 1 / 40)
    assert table["area_bias_cm2"] == pytest.approx(expected_bias)
    assert table["area_rel_err_median"] == pytest.approx(0.1)
    # Against the visible area (the 20 cm² leaf hides 2 cm² behind its curl): 8 / 18 / 38 on 10 / 18 / 40.
    assert table["area_seen_r2"] == pytest.approx(metrics.linear_fit([10, 18, 40], [8, 18, 38])["r2"])
    assert table["elevation_r2"] == pytest.approx(metrics.linear_fit([10, 30, 50], [12, 28, 50])["r2"])
    assert table["elevation_precision_deg"] == pytest.approx(np.std([2, -2, 0], ddof=1))
    assert table["azimuth_precision_deg"] == pytest.approx(np.std([5, -5, 0], ddof=1))
    assert (table["n_found"], table["n_merged"], table["n_missed"], table["n_false"]) == (3, 1, 1, 2)
    # rppp by leaf group: the 1000-pixel leaves in group A, the 7000-pixel one in D.
    groups = summary.rppp_groups(rows)
    assert [(g["group"], g["n_leaves"]) for g in groups] == [("A", 3), ("D", 1)]
    assert groups[0]["rppp_1"] == pytest.approx(0.9) and groups[1]["rppp_2"] == pytest.approx(0.5)
    # Per case: pulses, throughput and peak memory; found / missed / false in the summary row.
    cases = summary.case_table(rows)
    assert cases[0]["pulses_per_s"] == 500.0 and cases[0]["peak_mem_mb"] == 100.0 and cases[1]["n_false"] == 0
    assert cases[0]["cpu_s"] == 1.5 and cases[1]["cpu_s"] is None  # runs before cpu_s was recorded have none
    (row_summary,) = summary.summarize(rows, "s")
    assert (row_summary["n_found"], row_summary["n_missed"], row_summary["n_false"]) == (6, 2, 2)
    assert row_summary["found_visible"] == pytest.approx(4 / 6) and row_summary["pulses_per_s"] == 500.0
    text = summary.leaf_printout(rows)
    assert "validation" in text and "rppp" in text and "500" in text


def test_variants_without_segmentation_have_no_found_counts():
    rows = [row("leaf", "raw", [{k: v for k, v in leaf(10, 11).items() if k != "found"}])]
    (table,) = summary.validation_table(rows)
    assert table["n_success"] == 1 and table["n_found"] is None and table["n_false"] is None
    assert summary.case_table(rows) == [] and summary.rppp_groups(rows) == []

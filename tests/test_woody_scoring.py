"""Scores against truth on hand-made cylinder lists: perfect match, missed branch, false positive, radius bias."""

import copy

import numpy as np
import pytest

from woody import WoodyError, score
from woody.geometry import cylinders_volume


def _cyl(cid, parent, order, branch, start, end, r0, r1=None):
    return {"id": cid, "parent": parent, "order": order, "branch": branch, "start": list(start), "end": list(end),
            "radius_m": r0, "radius_end_m": r0 if r1 is None else r1}


TRUTH = [_cyl(0, -1, 1, 0, (0, 0, 0), (0, 0, 1), 0.05),
         _cyl(1, 0, 2, 1, (0, 0, 1), (0.6, 0, 1.8), 0.02),
         _cyl(2, 0, 2, 2, (0, 0, 1), (-0.6, 0, 1.8), 0.02)]


def test_perfect_reconstruction_scores_perfectly():
    s = score({"cylinders": TRUTH, "volume_m3": cylinders_volume(TRUTH)}, copy.deepcopy(TRUTH))
    assert s["radius_error_m"]["mae"] == 0 and s["diameter_error_m"]["max"] == 0
    assert s["completeness"] == pytest.approx(1.0) and s["precision"] == pytest.approx(1.0)
    assert s["volume_error"] == pytest.approx(0.0)
    assert s["detection_rate"] == 1.0 and s["length_error"]["max"] == pytest.approx(0.0, abs=1e-9)
    topo = s["topology"]
    assert topo["edge_precision"] == 1.0 and topo["edge_recall"] == 1.0 and topo["order_accuracy"] == 1.0
    assert topo["fragmentation"] == 1.0 and topo["max_order_rec"] == topo["max_order_true"] == 2
    assert s["taper"]["taper_ok_height_m"] == pytest.approx(1.0)


def test_missed_branch_lowers_completeness_detection_recall_and_volume():
    s = score(TRUTH, copy.deepcopy(TRUTH[:2]))
    assert s["completeness"] == pytest.approx(2.0 / 3.0, abs=0.005)  # junction overlaps are not visible
    assert s["branches_detected"] == 2 and s["detection_rate"] == pytest.approx(2.0 / 3.0)
    missing = np.pi * 0.02 ** 2 * 1.0
    assert s["volume_error"] == pytest.approx(-missing / cylinders_volume(TRUTH))
    assert s["topology"]["edge_recall"] == 0.5 and s["topology"]["edge_precision"] == 1.0
    assert s["precision"] == pytest.approx(1.0)


def test_seen_completeness_leaves_out_the_truth_no_point_lies_on():
    # points on the stem's and the first branch's surfaces only: the second branch was not seen by the scan
    t = np.linspace(0, 1, 200)[:, None]
    stem = np.column_stack([0.05 + 0 * t, 0 * t, t])
    branch = np.array([0, 0, 1]) + t * np.array([0.6, 0, 0.8]) + np.array([0, 0.02, 0])
    s = score(TRUTH, copy.deepcopy(TRUTH[:2]), points=np.vstack([stem, branch]))
    assert s["completeness"] == pytest.approx(2.0 / 3.0, abs=0.005)
    assert s["seen_completeness"] == pytest.approx(1.0, abs=0.015)
    assert s["seen_length_m"] == pytest.approx(2.0, abs=0.02)
    assert "seen_completeness" not in score(TRUTH, copy.deepcopy(TRUTH[:2]))


def test_false_positive_is_counted_as_unmatched_reconstructed_length():
    extra = _cyl(3, -1, 1, 3, (5, 5, 0), (5, 5, 1), 0.02)
    s = score(TRUTH, copy.deepcopy(TRUTH) + [extra])
    assert s["false_positive_length_m"] == pytest.approx(1.0)
    assert s["reconstructed_length_m"] == pytest.approx(4.0, abs=0.05)
    assert s["precision"] == pytest.approx(1.0 - 1.0 / s["reconstructed_length_m"])
    assert s["completeness"] == pytest.approx(1.0)


def test_radius_bias_is_reported_exactly_for_radius_diameter_volume_and_taper():
    rec = copy.deepcopy(TRUTH)
    for c in rec:
        c["radius_m"] += 0.002
        c["radius_end_m"] += 0.002
    s = score(TRUTH, rec)
    assert s["radius_error_m"]["bias"] == pytest.approx(0.002)
    assert s["radius_error_m"]["sd"] == pytest.approx(0.0, abs=1e-12)
    assert s["diameter_error_m"]["bias"] == pytest.approx(0.004)
    expected = (cylinders_volume(rec) - cylinders_volume(TRUTH)) / cylinders_volume(TRUTH)
    assert s["volume_error"] == pytest.approx(expected)
    assert s["taper"]["taper_ok_height_m"] == pytest.approx(1.0)  # 4 mm diameter error is within 1 cm
    for c in rec:
        c["radius_m"] += 0.004
        c["radius_end_m"] += 0.004
    assert score(TRUTH, rec)["taper"]["taper_ok_height_m"] == 0.0  # 12 mm is not


def test_frustum_radius_is_interpolated_along_the_axis():
    rec = [_cyl(0, -1, 1, 0, (0, 0, 0), (0, 0, 1), 0.06, 0.04)]
    s = score([TRUTH[0]], rec)
    assert s["radius_error_m"]["bias"] == pytest.approx(0.0, abs=1e-9)
    assert s["radius_error_m"]["mae"] == pytest.approx(0.005, rel=1e-3)
    assert s["radius_error_m"]["max"] == pytest.approx(0.01, rel=0.02)


def test_axis_angle_and_distance_limit_matches():
    tilted = [_cyl(0, -1, 1, 0, (0, 0, 0), (0.8, 0, 0.6), 0.05)]  # 53 deg off the truth axis
    assert score([TRUTH[0]], tilted)["completeness"] < 0.1
    shifted = [_cyl(0, -1, 1, 0, (0.2, 0, 0), (0.2, 0, 1), 0.05)]  # 20 cm beside it
    assert score([TRUTH[0]], shifted)["completeness"] == 0.0


def test_buried_child_base_is_not_counted():
    child = _cyl(1, 0, 2, 1, (0, 0, 0.5), (0.5, 0, 0.5), 0.02)  # starts on the trunk axis
    s = score([TRUTH[0], child], [TRUTH[0], child])
    assert s["truth_length_m"] == pytest.approx(1.0 + 0.45, abs=0.011)


def test_step_output_without_orders_has_no_topology_and_bad_input_is_refused():
    rec = [dict(c, order=None) for c in TRUTH]
    assert score(TRUTH, rec)["topology"] is None
    with pytest.raises(WoodyError, match="no cylinders"):
        score([], TRUTH)
    with pytest.raises(WoodyError, match="lacks"):
        score(TRUTH, [{"start": [0, 0, 0]}])


def _budget_class(s, diameter_m):
    return next(c for c in s["volume_budget"]["by_diameter_class"]
                if c["diameter_from_m"] <= diameter_m < (c["diameter_to_m"] or np.inf))


def test_volume_budget_splits_the_error_into_wider_missed_and_spurious_volume():
    branch = np.pi * 0.02 ** 2 * 1.0  # each side branch: r 2 cm, 1 m long
    perfect = score(TRUTH, copy.deepcopy(TRUTH))
    for diameter, true in ((0.1, np.pi * 0.05 ** 2), (0.04, 2 * branch)):
        cls = _budget_class(perfect, diameter)
        assert cls["true_m3"] == pytest.approx(true, rel=1e-6)
        assert cls["reconstructed_m3"] == pytest.approx(true, rel=0.02) and cls["missed_m3"] == 0
    assert perfect["volume_budget"]["false_positive_m3"] == 0

    wider = copy.deepcopy(TRUTH)
    wider[1]["radius_m"] = wider[1]["radius_end_m"] = 0.04  # one branch twice as wide: 4x its volume
    cls = _budget_class(score(TRUTH, wider), 0.04)
    assert cls["reconstructed_m3"] == pytest.approx(5 * branch, rel=0.02) and cls["missed_m3"] == 0

    extra = _cyl(3, -1, 1, 3, (5, 5, 0), (5, 5, 1), 0.02)
    s = score(TRUTH, copy.deepcopy(TRUTH[:2]) + [extra])  # one branch missed, one spurious
    assert _budget_class(s, 0.04)["missed_m3"] == pytest.approx(branch, rel=0.05)
    assert _budget_class(s, 0.04)["reconstructed_m3"] == pytest.approx(branch, rel=0.02)
    assert s["volume_budget"]["false_positive_m3"] == pytest.approx(branch, rel=1e-6)


def test_breast_height_diameter_is_scored_on_the_stem_at_1_3_m():
    stem = [_cyl(0, -1, 1, 0, (0, 0, 0), (0, 0, 2), 0.06, 0.04)]  # tapers: 9.4 cm across at 1.3 m
    wider = [_cyl(0, -1, 1, 0, (0, 0, 0), (0, 0, 2), 0.063, 0.043)]
    dbh = score(stem, wider)["taper"]["dbh"]
    assert dbh["diameter_true_m"] == pytest.approx(0.094, abs=2e-4)
    assert dbh["diameter_error_m"] == pytest.approx(0.006, abs=1e-6)
    short = [_cyl(0, -1, 1, 0, (0, 0, 0), (0, 0, 1), 0.06)]  # the reconstruction stops below breast height
    assert score(stem, short)["taper"]["dbh"]["diameter_error_m"] is None
    assert score([TRUTH[0]], [TRUTH[0]])["taper"]["dbh"] is None  # a 1 m stem has no breast height

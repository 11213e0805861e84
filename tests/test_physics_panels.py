"""The panel series of Balduzzi et al. 2011: intensity against distance and its correction (Table 2)."""

import math

import numpy as np
import pytest

import scenes
from leafsfs.calibration import (ReferenceCurve, correct_distance, fit_reference_curve, panel_statistics,
                                 reference_curve_from_table)
from leafsfs.errors import SfsError
from tlssim.calibration import panel_table
from tlssim.errors import ScanError
from tlssim.simulate import setup_from_section, simulate

#: Table 2 of the Sensors 2011 paper: mean shift below the 99 % curve (DN).
TABLE_2_SHIFT = {0.48: 169.55, 0.22: 399.30, 0.03: 884.93}


@pytest.fixture(scope="module")
def panels(llvm):
    scene = scenes.build("panel-series")
    setup = setup_from_section(scene.scanner)
    scan = simulate(scene, setup, seed=0, progress=False, backend="llvm")
    table = panel_table(scan)
    return scan, table, reference_curve_from_table(table), setup.model


def _series(table, rho):
    chosen = np.isclose(table["reflectance"], rho)
    return table["distance_m"][chosen], table["intensity_dn"][chosen]


def test_every_panel_has_unmixed_returns(panels):
    scan, table, _, _ = panels
    assert len(table["name"]) == 7 * 14
    assert table["count"].min() >= 50
    assert np.allclose(table["distance_m"], table["nominal_distance_m"], rtol=1e-3, atol=3e-3)


def test_reference_panel_at_3_56_m_gives_1781_dn(panels):
    _, _, curve, _ = panels
    assert curve.reference_dn == pytest.approx(1781.45, abs=5)


@pytest.mark.parametrize("rho", sorted(TABLE_2_SHIFT))
def test_mean_shifts_match_table_2(panels, rho):
    _, table, curve, _ = panels
    stats = panel_statistics(table, curve)
    assert stats[rho]["mean_shift_dn"] == pytest.approx(TABLE_2_SHIFT[rho], rel=0.15)


def test_corrected_intensity_no_longer_depends_on_distance(panels):
    _, table, curve, _ = panels
    stats = panel_statistics(table, curve)
    for rho, values in stats.items():
        if rho >= 0.48:
            assert values["corrected_rmse_dn"] < 4.0  # the sources: < 4 DN for rho >= 48 % beyond 1 m
        # vertical shifts of one curve: the offset hardly varies with distance, even below 1 m
        assert values["shift_std_dn"] < (3.0 if rho >= 0.48 else 6.0)


def test_ratio_correction_restores_the_reference_curve(panels):
    _, table, curve, _ = panels
    distance, intensity = _series(table, 0.99)
    far = distance > 1
    ratio = correct_distance(intensity[far], distance[far], curve, mode="ratio")
    assert np.allclose(ratio, curve.reference_dn, atol=1e-6)
    with pytest.raises(SfsError, match="correction mode"):
        correct_distance(intensity, distance, curve, mode="log")


def test_near_range_attenuator_shapes_the_curve(panels):
    scan, table, curve, model = panels
    distance, intensity = _series(table, 0.99)
    i_1m = intensity[np.isclose(distance, 1.0, rtol=0.01)][0]
    full_inverse_square = 2 * model.log_gain_dn * math.log(3.56 / 1.0)
    assert i_1m - curve.reference_dn < full_inverse_square  # not brighter by the full 1/d² amount
    assert i_1m < curve.reference_dn  # the attenuator even makes it darker
    # not saturated anywhere, in particular at 0.6 m and closer
    assert np.nanmax(scan.intensity) < model.intensity_max_dn
    assert intensity[np.isclose(distance, 0.6, rtol=0.01)][0] < 0.9 * model.intensity_max_dn
    # beyond a few metres the curve is 1/d²-like: slope of -2k per unit ln d (7.5 -> 10 m)
    far = distance > 7
    slope = np.diff(intensity[far]) / np.diff(np.log(distance[far]))
    assert slope[0] == pytest.approx(-2 * model.log_gain_dn, rel=0.1)


def test_curve_round_trips_through_json(panels):
    import json
    from dataclasses import asdict

    _, _, curve, _ = panels
    again = ReferenceCurve.from_dict(json.loads(json.dumps(asdict(curve))))
    d = np.geomspace(0.4, 10, 50)
    assert np.array_equal(again(d), curve(d))
    assert curve.distance_range_m == pytest.approx((0.35, 10.0), rel=3e-3)


def test_reference_curve_interpolates_its_nodes_in_ln_d():
    d = np.array([0.5, 1.0, 2.0, 4.0, 8.0])
    dn = 1500 + 100 * np.log(d) - 40 * np.log(d) ** 2  # a quadratic in ln d is reproduced exactly
    curve = fit_reference_curve(d, dn)
    x = np.geomspace(0.5, 8, 40)
    assert np.allclose(curve(x), 1500 + 100 * np.log(x) - 40 * np.log(x) ** 2, atol=1e-6)
    with pytest.raises(SfsError, match="3 distinct distances"):
        fit_reference_curve([1.0, 1.0, 2.0], [1, 2, 3])


def test_panel_table_needs_panels(llvm):
    scene = scenes.build("knife-edge")
    scan = simulate(scene, setup_from_section(scene.scanner), progress=False, backend="llvm")
    with pytest.raises(ScanError, match="panel-series"):
        panel_table(scan)

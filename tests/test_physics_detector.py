"""Detector chain: attenuator, log amplifier, amplitude and range noise, dropouts, range filter."""

import math

import numpy as np
import pytest
from scipy.stats import norm

from tlssim.detector import PulseReturns, average_along_psi, detect, detection_threshold, log_amplifier_dn
from tlssim.errors import ScanError
from tlssim.noise import amplitude_noise_std, fit_range_noise, panel_amplitude, range_noise_std
from tlssim.radiometry import near_filter, range_gain, reference_power
from tlssim.scanner import FARO_LS880_FILTERED_PRECISION, FARO_LS880_RAW_PRECISION, ScannerModel, get_preset

MODEL = get_preset("faro-ls880")


def test_attenuator_form_and_limits():
    d = np.array([0.35, 1.0, 3.0, 10.0, 76.0])
    expected = 1.0 / (1.0 + (3.0 / d) ** 3)
    assert np.allclose(near_filter(MODEL, d), expected)
    assert near_filter(MODEL, 3.0) == pytest.approx(0.5)
    assert np.allclose(range_gain(MODEL, d), expected / d**2)
    assert np.allclose(range_gain(MODEL.replace(near_filter_range_m=0.0), d), 1.0 / d**2)


def test_attenuator_table_interpolates_linearly_on_numpy_and_drjit(llvm):
    import mitsuba as mi

    nodes = ((0.5, 0.01), (1.0, 0.05), (3.0, 0.5), (10.0, 1.0))
    model = MODEL.replace(near_filter_table=nodes)
    d = np.array([0.2, 0.5, 0.75, 2.0, 3.0, 6.5, 10.0, 50.0])
    expected = np.interp(d, *zip(*nodes))  # constant beyond the ends
    assert np.allclose(near_filter(model, d), expected, atol=1e-12)
    on_device = np.asarray(near_filter(model, mi.Float(d.astype(np.float32))))
    assert np.allclose(on_device, expected, atol=1e-6)


@pytest.mark.parametrize("table", [((1.0, 0.5),), ((1.0, 0.5), (1.0, 0.6)), ((1.0, 0.5), (2.0, 1.5)),
                                   ((2.0, 0.5), (1.0, 0.6)), "x"])
def test_bad_attenuator_table_is_refused(table):
    with pytest.raises(ScanError, match="near_filter_table"):
        MODEL.replace(near_filter_table=table)


def test_reference_target_includes_the_attenuator():
    assert reference_power(MODEL) == pytest.approx(0.99 * near_filter(MODEL, 3.56) / 3.56**2)
    assert log_amplifier_dn(MODEL, np.array([reference_power(MODEL)]))[0] == round(MODEL.intensity_ref_dn)


def test_reflectances_are_vertical_shifts_of_k_ln_rho():
    d = np.geomspace(0.4, 20, 30)
    dn = {rho: log_amplifier_dn(MODEL.replace(intensity_max_dn=100000), panel_amplitude(MODEL, rho, d))
          for rho in (0.99, 0.48, 0.03)}
    for rho in (0.48, 0.03):
        shift = dn[0.99].astype(float) - dn[rho]
        assert np.all(np.abs(shift - MODEL.log_gain_dn * math.log(0.99 / rho)) <= 1.0)  # quantisation only


def test_range_noise_constants_are_the_fit_of_the_datasheet_points():
    s0, gamma = fit_range_noise(MODEL, FARO_LS880_RAW_PRECISION)
    assert MODEL.range_noise_m == pytest.approx(s0, rel=1e-3)
    assert MODEL.range_noise_exponent == pytest.approx(gamma, abs=5e-4)
    for rho, d, sigma in FARO_LS880_RAW_PRECISION:
        assert range_noise_std(MODEL, panel_amplitude(MODEL, rho, d)) == pytest.approx(sigma, rel=0.10)


def test_filtered_preset_averages_to_the_published_filtered_precision():
    filtered = get_preset("faro-ls880-filtered")
    for rho, d, sigma in FARO_LS880_FILTERED_PRECISION:
        raw = range_noise_std(filtered, panel_amplitude(filtered, rho, d))
        assert raw / math.sqrt(filtered.range_filter_length) == pytest.approx(sigma, rel=0.15)


def _returns(amplitude, distance=5.0):
    amplitude = np.asarray(amplitude, dtype=float)
    return PulseReturns(np.full(amplitude.shape, distance), amplitude, amplitude)


def test_intensity_and_range_noise_follow_the_signal():
    rng = np.random.default_rng(1)
    ref = reference_power(MODEL)
    for ratio in (1.0, 0.1, 0.02):
        amplitude = np.full((400, 100), ratio * ref)
        range_m, intensity = detect(MODEL, _returns(amplitude), rng)
        sigma_dn = MODEL.intensity_noise_dn * ratio ** -MODEL.intensity_noise_exponent
        # Gaussian noise on the amplitude: the log amplifier's mean sits k·s²/2 low (s = sigma_dn / k).
        expected_dn = MODEL.intensity_ref_dn + MODEL.log_gain_dn * (math.log(ratio) - 0.5 * (sigma_dn / MODEL.log_gain_dn) ** 2)
        assert np.all(np.isfinite(range_m))
        assert np.mean(intensity) == pytest.approx(expected_dn, abs=0.3)
        assert np.std(intensity) == pytest.approx(math.hypot(sigma_dn, 1 / math.sqrt(12)), rel=0.05)
        assert np.std(range_m) == pytest.approx(range_noise_std(MODEL, ratio * ref), rel=0.03)
        assert np.mean(range_m) == pytest.approx(5.0, abs=3 * np.std(range_m) / 200)


def test_dropouts_follow_the_noisy_signal_against_the_threshold():
    threshold = detection_threshold(MODEL)
    assert log_amplifier_dn(MODEL, np.array([threshold * 1.0001]))[0] == MODEL.min_signal_dn
    ratios = np.array([0.5, 1.0, 1.5, 2.0, 3.0])
    amplitude = np.repeat(ratios[:, None] * threshold, 20000, axis=1)
    range_m, intensity = detect(MODEL, _returns(amplitude), np.random.default_rng(2))
    kept = np.isfinite(range_m).mean(axis=1)
    sigma = amplitude_noise_std(MODEL, ratios * threshold)
    expected = norm.cdf((ratios * threshold - threshold) / sigma)
    assert np.allclose(kept, expected, atol=0.01)
    assert np.all(np.diff(kept) > 0)  # less signal, more dropouts
    assert np.array_equal(np.isfinite(range_m), np.isfinite(intensity))
    assert np.nanmin(intensity) >= MODEL.min_signal_dn


def test_no_signal_no_return_and_range_limits():
    ref = reference_power(MODEL)
    returns = PulseReturns(np.array([[5.0, 0.59, 77.0, 5.0]]), np.array([[0.0, ref, ref, ref]]),
                           np.array([[0.0, ref, ref, ref]]))
    range_m, intensity = detect(MODEL.noise_free(), returns, np.random.default_rng(0))
    assert np.isnan(range_m[0, :3]).all() and np.isnan(intensity[0, :3]).all()
    assert range_m[0, 3] == 5.0 and intensity[0, 3] == round(MODEL.intensity_ref_dn)


def test_intensity_signal_choice():
    ref = reference_power(MODEL)
    returns = PulseReturns(np.array([[5.0]]), np.array([[0.5 * ref]]), np.array([[ref]]))
    _, phasor = detect(MODEL.noise_free(), returns, np.random.default_rng(0))
    _, power = detect(MODEL.noise_free().replace(intensity_signal="power"), returns, np.random.default_rng(0))
    assert power[0, 0] - phasor[0, 0] == pytest.approx(MODEL.log_gain_dn * math.log(2), abs=1)


def test_range_filter_is_a_centred_mean_of_returned_samples():
    column = np.array([1.0, 2.0, np.nan, 4.0, 5.0, 6.0, 7.0])[:, None]
    out = average_along_psi(column, 3)[:, 0]
    expected = [1.5, 1.5, np.nan, 4.5, 5.0, 6.0, 6.5]
    assert np.allclose(out, expected, equal_nan=True)
    assert average_along_psi(column, 1) is column
    rng = np.random.default_rng(3)
    noisy = 10.0 + rng.normal(0, 1e-3, (3000, 20))
    assert np.std(average_along_psi(noisy, 15)[20:-20]) == pytest.approx(1e-3 / math.sqrt(15), rel=0.06)


def test_detector_is_deterministic_per_stream():
    amplitude = np.full((50, 40), 0.01 * reference_power(MODEL))
    a = detect(MODEL, _returns(amplitude), np.random.default_rng(7))
    b = detect(MODEL, _returns(amplitude), np.random.default_rng(7))
    c = detect(MODEL, _returns(amplitude), np.random.default_rng(8))
    assert all(np.array_equal(x, y, equal_nan=True) for x, y in zip(a, b))
    assert not np.array_equal(a[0], c[0], equal_nan=True)


@pytest.mark.parametrize("field,value", [("intensity_noise_dn", -1.0), ("range_noise_m", float("nan")),
                                         ("smear_fraction", 1.5), ("range_filter_length", 0),
                                         ("intensity_signal", "log"), ("intensity_noise_exponent", 2.0),
                                         ("leaf_transmission", "yes"), ("bsdf", "shiny"), ("min_signal_dn", None)])
def test_bad_detector_parameters_are_refused(field, value):
    with pytest.raises(ScanError, match=field):
        MODEL.replace(**{field: value})


def test_every_preset_value_has_a_source():
    import dataclasses

    from tlssim.scanner import FARO_LS880_SOURCES

    assert set(FARO_LS880_SOURCES) == {f.name for f in dataclasses.fields(ScannerModel)} - {"name"}
    assert all(text.strip() for text in FARO_LS880_SOURCES.values())


def test_model_round_trips_through_its_dictionary():
    model = MODEL.replace(near_filter_table=((1.0, 0.1), (4.0, 1.0)), bsdf={"type": "roughplastic", "alpha": 0.2},
                          range_filter_length=5)
    assert ScannerModel.from_dict(model.to_dict()) == model
    assert model.bsdf_plugin == {"type": "roughplastic", "alpha": 0.2}

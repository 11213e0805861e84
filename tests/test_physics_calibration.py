"""Goniometer calibration: plane-fit incidence, the intensity-incidence relation, the Calibration bundle, CLI."""

import json
import math

import numpy as np
import pytest

import scenes
from benchmarks.experiments.calibration import simulated_calibration
from leafsfs.calibration import (Calibration, IncidenceRelation, fit_calibration, fit_incidence_relation,
                                 station_intensities)
from leafsfs.cli import main as leafsfs_main
from leafsfs.errors import SfsError
from leafsfs.preprocess import resolve_calibration
from scenes.calibration_scenes import GONIOMETER_ANGLES_DEG
from tlssim.calibration import fit_plane, goniometer_table, load_table, panel_table, patch_incidence, save_table
from tlssim.cli import main
from tlssim.scanner import get_preset
from tlssim.simulate import setup_from_section, simulate


@pytest.fixture(scope="module")
def calibration(llvm):
    return simulated_calibration(get_preset("faro-ls880"))


@pytest.fixture(scope="module")
def goniometer_scan(llvm):
    scene = scenes.build("goniometer")
    return simulate(scene, setup_from_section(scene.scanner), seed=1, progress=False, backend="llvm")


def test_simulated_calibration_is_cached(calibration, tmp_path, monkeypatch):
    from benchmarks.experiments import calibration as experiment

    model = get_preset("faro-ls880")
    assert simulated_calibration(model) is calibration  # in memory, no second simulation
    # the disk cache, on cheap stand-in tables (a second simulation may differ in the last bit)
    alpha = np.radians(np.arange(0, 81, 10.0))
    panels = {"reflectance": np.full(4, 0.99), "distance_m": np.array([1.0, 2.0, 4.0, 8.0]),
              "intensity_dn": np.array([1900.0, 1850.0, 1700.0, 1520.0])}
    goniometer = {"name": np.array([f"s{i}" for i in range(len(alpha))]), "alpha_rad": alpha,
                  "sample_station": np.arange(len(alpha)), "sample_range_m": np.full(len(alpha), 2.16),
                  "sample_intensity_dn": (1800 + 263 * np.log(np.cos(alpha))).astype(np.float32)}
    calls = []
    monkeypatch.setattr(experiment, "simulate_tables", lambda m, seed: calls.append(seed) or (panels, goniometer))
    monkeypatch.setattr(experiment, "_MEMORY", {})
    first = simulated_calibration(model, seed=3, cache_dir=tmp_path)
    assert calls == [3] and len(list(tmp_path.glob("calibration-*.json"))) == 1
    monkeypatch.setattr(experiment, "_MEMORY", {})
    again = simulated_calibration(model, seed=3, cache_dir=tmp_path)  # read back from the file
    assert calls == [3] and again == first
    assert simulated_calibration(model, seed=3, cache_dir=tmp_path) is again


def test_plane_fit_incidence_follows_the_goniometer(goniometer_scan):
    table = goniometer_table(goniometer_scan)
    error = np.degrees(table["alpha_rad"]) - table["nominal_deg"]
    # both rotation axes; the horizontal one loses its narrowest (largest-angle) stations
    assert len(table["name"]) >= 30
    assert np.max(np.abs(error[table["nominal_deg"] <= 60])) < 1.5
    assert set(table["nominal_deg"][table["rotation_axis"] == "vertical"]) >= set(range(0, 85, 5))


def test_lambertian_leaf_follows_k_ln_cos(calibration, goniometer_scan):
    table = goniometer_table(goniometer_scan)
    corrected, _ = station_intensities(table, calibration.curve)
    k = get_preset("faro-ls880").log_gain_dn
    top = corrected[table["nominal_deg"] == 0].mean()
    # pure-leaf samples: the 48 % leaf keeps its Table 2 offset below the 99 % curve, and k·ln cos(alpha)
    assert top == pytest.approx(calibration.curve.reference_dn + k * math.log(0.48 / 0.99), abs=3)
    expected = top + k * np.log(np.cos(np.radians(table["nominal_deg"])))
    assert np.max(np.abs(corrected - expected)) < 4


def test_relation_is_monotone_and_inverts(calibration):
    relation = calibration.incidence
    assert np.all(np.diff(relation.lut_dn) < 0) and np.all(np.diff(relation.lut_alpha_rad) > 0)
    assert len(relation.polynomial) == 5
    alpha = np.radians(np.arange(5, 76, 5.0))
    for method in ("lut", "polynomial"):
        chosen = IncidenceRelation(**{**relation.__dict__, "method": method})
        back = chosen.alpha(chosen.intensity(alpha))
        assert np.max(np.abs(np.degrees(back - alpha))) < 0.5
    # clamps and flags
    dn = np.array([2047.0, relation.intensity(math.radians(40)), relation.intensity(math.radians(70)), 0.0])
    a = relation.alpha(dn)
    assert a[0] == 0.0 and a[-1] == pytest.approx(math.pi / 2)
    assert list(relation.reliable(dn)) == [True, True, False, False]


def test_calibration_bundle_round_trips(calibration, tmp_path):
    path = calibration.save(tmp_path / "cal.json")
    again = Calibration.load(path)
    assert again == calibration
    intensity, distance = np.array([1500.0, 1300.0]), np.array([2.0, 5.0])
    assert np.array_equal(again.alpha(intensity, distance), calibration.alpha(intensity, distance))
    # d < 1 m is outside the distance correction; 1550 DN at 2 m is ~45 deg
    assert list(calibration.reliable(np.array([1550.0, 1550.0]), np.array([0.5, 2.0]))) == [False, True]


def test_broken_calibration_files_name_the_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(SfsError, match="bad.json"):
        Calibration.load(bad)
    bad.write_text(json.dumps({"format": "something else"}))
    with pytest.raises(SfsError, match="bad.json.*not a tlssim calibration"):
        Calibration.load(bad)


def test_fit_incidence_relation_on_a_known_curve():
    alpha = np.radians(np.arange(0, 81, 5.0))
    dn = 1600 + 263 * np.log(np.cos(alpha))
    relation = fit_incidence_relation(alpha, dn)
    assert np.allclose(relation.lut_dn, dn)
    probe = np.radians([3.0, 33.0, 61.0])
    assert np.allclose(relation.alpha(1600 + 263 * np.log(np.cos(probe))), probe, atol=np.radians(0.6))
    with pytest.raises(SfsError, match="distinct angles"):
        fit_incidence_relation([0.1, 0.1, 0.2], [1, 2, 3])


def test_range_aware_plane_fit_removes_the_orthogonal_fit_bias():
    """A narrow patch with range noise along the line of sight: the orthogonal fit tilts away, 1/r regression does not."""
    rng = np.random.default_rng(1)
    a = math.radians(45)
    normal, centre = np.array([-math.cos(a), 0, math.sin(a)]), np.array([2.16, 0, 0])
    u = np.array([0.0, 1.0, 0.0])
    v = np.cross(normal, u)
    patch = centre + rng.uniform(-0.03, 0.03, (4000, 1)) * u + rng.uniform(-0.011, 0.011, (4000, 1)) * v
    r = np.linalg.norm(patch, axis=1)
    noisy = patch / r[:, None] * (r + rng.normal(0, 0.0017, len(r)))[:, None]
    centroid, fitted, _ = fit_plane(noisy)
    orthogonal = math.degrees(math.acos(abs(fitted @ centroid) / np.linalg.norm(centroid)))
    assert orthogonal > 46.0
    assert math.degrees(patch_incidence(noisy)) == pytest.approx(45.0, abs=0.4)


def test_goniometer_scene_spans_the_published_angles():
    scene = scenes.build("goniometer")
    leaves = [o for o in scene.objects if o.type == "leaf"]
    assert len(leaves) == 2 * len(GONIOMETER_ANGLES_DEG) and GONIOMETER_ANGLES_DEG[-1] == 85
    for leaf in leaves:
        centre = 0.5 * (leaf.vertices.min(axis=0) + leaf.vertices.max(axis=0))
        sight = leaf.vertices[0] / np.linalg.norm(leaf.vertices[0])  # the fan's centre vertex
        incidence = math.degrees(math.acos(abs(np.dot(leaf.face_normals()[0], sight))))
        assert incidence == pytest.approx(leaf.truth["incidence_deg"], abs=1e-6)
        assert np.linalg.norm(leaf.vertices[0]) == pytest.approx(2.16, abs=1e-9)
        assert np.linalg.norm(centre) == pytest.approx(2.16, abs=0.04)
        assert leaf.face_areas().sum() == pytest.approx(math.pi / 4 * 0.0647 * 0.0219, rel=0.01)


def test_tables_round_trip_through_their_files_exactly(calibration, goniometer_scan, tmp_path):
    table = goniometer_table(goniometer_scan)
    again, model = load_table(save_table(table, tmp_path / "g.json", "goniometer", {"name": "x"}), "goniometer")
    assert model == {"name": "x"} and set(again) == set(table)
    for key, value in table.items():
        assert np.array_equal(again[key], value) and again[key].dtype.kind == value.dtype.kind
    assert np.array_equal(station_intensities(again, calibration.curve)[0], station_intensities(table, calibration.curve)[0])
    with pytest.raises(ValueError, match="g.json: not a panels table"):
        load_table(tmp_path / "g.json", "panels")


def test_calibration_workflow_from_scans_to_reconstruction(calibration, goniometer_scan, tmp_path, capsys):
    """tlssim calibrate measures both tables, leafsfs calibrate fits them, leafsfs reconstruct takes the result."""
    scene = scenes.build("panel-series")
    panel_scan = simulate(scene, setup_from_section(scene.scanner), progress=False, backend="llvm")
    panel_scan.save(tmp_path / "panels.npz")
    goniometer_scan.save(tmp_path / "gonio.npz")
    assert main(["calibrate", str(tmp_path / "panels.npz")]) == 0
    assert main(["calibrate", str(tmp_path / "gonio.npz"), "-o", str(tmp_path / "out" / "gonio")]) == 0
    assert (tmp_path / "panels.png").stat().st_size > 10_000 and (tmp_path / "out" / "gonio.png").is_file()
    assert leafsfs_main(["calibrate", str(tmp_path / "panels.json"), str(tmp_path / "out" / "gonio.json"),
                         "-o", str(tmp_path / "cal.json")]) == 0
    assert "f99(3.56 m) = 178" in capsys.readouterr().out
    loaded = resolve_calibration(str(tmp_path / "cal.json"))  # what leafsfs reconstruct --calibration does
    assert loaded.curve.reference_dn == pytest.approx(1781.45, abs=5)
    assert loaded == fit_calibration(panel_table(panel_scan), goniometer_table(goniometer_scan))  # files are exact
    assert loaded.incidence.alpha(1500.0) == pytest.approx(calibration.incidence.alpha(1500.0), abs=math.radians(1))
    assert (tmp_path / "cal.png").is_file()
    capsys.readouterr()
    assert leafsfs_main(["calibrate", str(tmp_path / "out" / "gonio.json"), str(tmp_path / "panels.json")]) == 2
    assert "not a panels table" in capsys.readouterr().err
    with pytest.raises(SfsError, match="measured table.*leafsfs calibrate"):  # a table is not a calibration
        resolve_calibration(str(tmp_path / "panels.json"))

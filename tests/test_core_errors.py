"""Bad input gets a clear one-line error, never a traceback."""

import numpy as np
import pytest

import scenes
from scenes.scene import Material, Scene, SceneError, SceneObject
from tlssim.cli import main as tlssim_main
from tlssim.errors import ScanError
from tlssim.scanner import get_preset
from tlssim.simulate import setup_from_section, simulate


@pytest.mark.parametrize("value", [0.0, -0.01])
def test_divergence_must_be_positive(value):
    with pytest.raises(ScanError, match="divergence_deg must be a positive"):
        get_preset("faro-ls880", divergence_deg=value)


def test_unknown_preset_and_parameter():
    with pytest.raises(ScanError, match="unknown scanner preset 'faro-x'; available: faro-ls880"):
        get_preset("faro-x")
    with pytest.raises(ScanError, match="unknown scanner parameter"):
        get_preset("faro-ls880", beam_colour="red")


def test_frequency_must_cover_the_range():
    with pytest.raises(ScanError, match="unambiguous range"):
        get_preset("faro-ls880", mod_freqs_hz=(10e6,))


def test_window_outside_the_field_of_view():
    section = {"window": {"theta_deg": [0, 1], "psi_deg": [150, 170]}}
    with pytest.raises(ScanError, match=r"leaves the field of view.*\[0, 160\]"):
        setup_from_section(section)
    with pytest.raises(ScanError, match="theta_deg and psi_deg"):
        setup_from_section({"window": {"theta_deg": [0, 1]}})


def test_empty_scene(llvm):
    setup = setup_from_section({"window": {"theta_deg": [0, 1], "psi_deg": [89, 90]}})
    with pytest.raises(SceneError, match="no objects"):
        simulate(Scene(objects=[], name="void"), setup, progress=False)


def test_nan_vertices_and_degenerate_meshes():
    with pytest.raises(SceneError, match="NaN"):
        SceneObject("bad", "mesh", [[0, 0, 0], [1, 0, np.nan], [0, 1, 0]], [[0, 1, 2]], Material("m", 0.5))
    with pytest.raises(SceneError, match="degenerate"):
        SceneObject("flat", "mesh", [[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], Material("m", 0.5))


def test_unknown_scene_name():
    with pytest.raises(SceneError, match="unknown built-in scene 'no-such'; available: .*knife-edge"):
        scenes.load("no-such")


@pytest.mark.parametrize(
    "argv, message",
    [
        (["scan", "no-such", "-o", "x.npz"], "unknown built-in scene"),
        (["scan", "knife-edge", "-o", "x.npz", "--scanner", "faro-x"], "unknown scanner preset"),
        (["scan", "knife-edge", "-o", "x.npz", "--subrays", "0"], "n_subrays must be a positive integer"),
    ],
)
def test_cli_reports_one_line_errors(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert tlssim_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("tlssim: error:") and message in err and "Traceback" not in err
    assert len(err.splitlines()) == 1


def test_scan_memory_is_refused_or_warned_before_allocating():
    from tlssim.simulate import BYTES_PER_PULSE, WARN_SCAN_BYTES, check_scan_memory

    with pytest.raises(ScanError, match=r"1000 x 2000 = 2,000,000 pulses needs about 0.4 GB.*larger step_deg"):
        check_scan_memory((1000, 2000), available_bytes=10**8)
    rows = WARN_SCAN_BYTES // BYTES_PER_PULSE // 1000 + 1
    with pytest.warns(UserWarning, match="will hold about"):
        assert check_scan_memory((rows, 1000), available_bytes=10**12) == rows * 1000 * BYTES_PER_PULSE
    assert check_scan_memory((10, 10), available_bytes=10**12) == 100 * BYTES_PER_PULSE


def test_a_tiny_step_is_refused_in_one_line(tmp_path, capsys):
    scene = tmp_path / "wall.yaml"
    scene.write_text("scanner:\n  window: {theta_deg: [-10, 10], psi_deg: [80, 100], step_deg: 0.000001}\n"
                     "objects:\n  - {type: plane, name: wall, size: [2, 2], pose: {center: [3, 0, 0], "
                     "facing: scanner}, material: spectralon-99}\n")
    assert tlssim_main(["scan", str(scene), "-o", str(tmp_path / "s.npz"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pulses needs about" in err[0]

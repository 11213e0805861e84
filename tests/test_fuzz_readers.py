"""Fuzzing the file readers: any bytes give the package's one error type (or a result), never another exception.

Each reader gets random byte strings and valid files with bytes flipped, cut or
inserted (Hypothesis). A reader may accept a damaged file when what is left
still parses; what it may not do is raise anything but its package's error,
or hang (every example has a deadline).
"""

from datetime import timedelta

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import scenes
from benchmarks.errors import BenchError
from benchmarks.suite import load_suite
from scenes.scene import SceneError
from tlssim.errors import ScanError
from tlssim.formats import export_scan, import_scan
from tlssim.scan import Scan

FUZZ = settings(max_examples=100, deadline=timedelta(seconds=5), derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _small_scan() -> Scan:
    rng = np.random.default_rng(0)
    theta, psi = np.meshgrid(np.radians(np.linspace(-1, 1, 6)), np.radians(np.linspace(89, 91, 5)))
    range_m = 3.0 + rng.normal(0, 0.01, theta.shape)
    range_m[0, 0] = np.nan
    direction = np.stack([np.sin(psi) * np.cos(theta), np.sin(psi) * np.sin(theta), np.cos(psi)], axis=-1)
    return Scan(range=range_m, intensity=np.full(theta.shape, 900.0, np.float32), theta=theta, psi=psi,
                xyz=range_m[..., None] * direction, meta={"scene": "fuzz"})


@st.composite
def damaged(draw, valid: bytes):
    """A valid file's bytes with a few flipped, cut off, or inserted."""
    data = bytearray(valid)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "cut", "insert"]))
        at = draw(st.integers(0, max(len(data) - 1, 0)))
        if kind == "flip" and data:
            data[at] ^= draw(st.integers(1, 255))
        elif kind == "cut":
            data = data[:at]
        else:
            data[at:at] = draw(st.binary(min_size=1, max_size=16))
    return bytes(data)


def _inputs(valid: bytes):
    return st.one_of(st.binary(max_size=512), damaged(valid))


@pytest.fixture(scope="module")
def valid_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("valid")
    scan = _small_scan()
    files = {"npz": scan.save(folder / "s.npz")}
    for ext in ("ptx", "las", "laz", "e57"):
        files[ext] = export_scan(scan, folder / f"s.{ext}")
    return {ext: path.read_bytes() for ext, path in files.items()}


def _check_scan_reader(tmp_path, ext, data):
    path = tmp_path / f"fuzz.{ext}"
    path.write_bytes(data)
    try:
        scan = Scan.load(path) if ext == "npz" else import_scan(path)
    except ScanError as exc:
        assert str(exc)
    else:
        assert scan.range.ndim == 2


@pytest.mark.parametrize("ext", ["npz", "ptx", "las", "laz", "e57"])
def test_scan_readers(valid_files, tmp_path, ext):
    @FUZZ
    @given(data=_inputs(valid_files[ext]))
    def run(data):
        _check_scan_reader(tmp_path, ext, data)

    run()


SCENE = yaml.safe_dump({"name": "fuzz", "scanner": {"window": {"theta_deg": [-2, 2], "psi_deg": [88, 92]}},
                        "objects": [{"type": "plane", "name": "wall", "size": [2, 2],
                                     "pose": {"center": [3, 0, 0], "facing": "scanner"}, "material": "spectralon-99"}]})
SUITE = yaml.safe_dump({"name": "fuzz", "cases": [{"name": "leaf-{distance_m}m", "scene": {"generator": "plate-leaf"},
                                                   "vary": {"distance_m": [3.0, 5.0]}}]})


def test_scene_files(tmp_path):
    @FUZZ
    @given(data=_inputs(SCENE.encode()))
    def run(data):
        path = tmp_path / "scene.yaml"
        path.write_bytes(data)
        try:
            scenes.load(path)
        except SceneError as exc:
            assert str(exc)

    run()


def test_suite_files(tmp_path):
    @FUZZ
    @given(data=_inputs(SUITE.encode()))
    def run(data):
        path = tmp_path / "suite.yaml"
        path.write_bytes(data)
        try:
            load_suite(str(path))
        except BenchError as exc:
            assert str(exc)

    run()

"""The Scan type: NPZ and PLY round trips, determinism, and the scan CLI."""

import json
import threading

import numpy as np
import pytest
import trimesh

import scenes
import tlssim
from tlssim.cli import main as tlssim_main
from tlssim.compare import compare_scans
from tlssim.errors import ScanError
from tlssim.scan import GRID_KEYS, TRUTH_KEYS, Scan, write_npz
from tlssim.simulate import setup_from_section, simulate


@pytest.fixture(scope="module")
def knife(llvm):
    scene = scenes.build("knife-edge")
    return simulate(scene, setup_from_section(scene.scanner), seed=3, progress=False, backend="llvm")


def test_scan_arrays_and_world_frame(knife):
    rows, cols = knife.shape
    assert knife.xyz.shape == (rows, cols, 3) and knife.truth_normal.shape == (rows, cols, 3)
    assert knife.truth_id.dtype == np.int32
    assert knife.object_names == ["plate", "wall"]
    # xyz = position + range * direction(theta, psi)
    direction = np.stack([np.sin(knife.psi) * np.cos(knife.theta), np.sin(knife.psi) * np.sin(knife.theta),
                          np.cos(knife.psi)], axis=-1)
    assert np.allclose(knife.xyz, knife.pose.position + knife.range[..., None] * direction)
    # truth: the central sub-ray distance to the plate or the wall, normals facing the scanner
    assert np.all(np.isin(np.round(knife.truth_range * np.sin(knife.psi) * np.cos(knife.theta), 6), [1.5, 2.0]))
    assert np.allclose(knife.truth_normal, [-1, 0, 0], atol=1e-6)
    assert np.allclose(knife.incidence, np.arccos(np.sin(knife.psi) * np.cos(knife.theta)), atol=1e-3)


def test_npz_round_trip(knife, tmp_path):
    knife.layers["outlier"] = np.zeros(knife.shape, bool)
    try:
        path = knife.save(tmp_path / "scan.npz")
    finally:
        del knife.layers["outlier"]
    with np.load(path, allow_pickle=False) as data:
        keys = set(data.files)
    assert set(GRID_KEYS + TRUTH_KEYS) | {"object_names", "scanner_position", "scanner_rotation",
                                          "scanner", "meta", "outlier", "truth_second_id",
                                          "second_fraction"} == keys
    back = Scan.load(path)
    for key in GRID_KEYS + TRUTH_KEYS:
        assert np.array_equal(getattr(back, key), getattr(knife, key), equal_nan=True)
    assert back.object_names == knife.object_names
    assert back.scanner == knife.scanner and back.meta == knife.meta
    assert back.scanner.model.name == "faro-ls880" and back.scanner.window.step_deg[0] > 0
    assert np.array_equal(back.pose.rotation, knife.pose.rotation)
    assert back.layers["outlier"].shape == knife.shape


def test_scans_written_with_the_scanner_model_dict_still_load(knife, tmp_path):
    """Files from before the typed description: the model's parameters under ``scanner_model``, the window in meta."""
    from tlssim.scan import write_npz

    path = knife.save(tmp_path / "new.npz")
    with np.load(path, allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files if key != "scanner"}
    arrays["scanner_model"] = np.array(json.dumps(knife.scanner.model.to_dict()))
    arrays["meta"] = np.array(json.dumps({**knife.meta, "window": knife.scanner.window.to_dict()}))
    old = Scan.load(write_npz(tmp_path / "old.npz", arrays))
    assert old.scanner == knife.scanner and old.meta == knife.meta
    del arrays["scanner_model"]
    arrays["meta"] = np.array(json.dumps(knife.meta))
    real = Scan.load(write_npz(tmp_path / "bare.npz", arrays))  # e.g. converted from a real scan
    assert real.scanner.model is None and real.scanner.window is None
    assert real.scanner.assumed_model == tlssim.get_preset("faro-ls880")


def test_same_seed_same_bytes_different_seed_differs(backend, tmp_path):
    scene = scenes.build("knife-edge")
    setup = setup_from_section(scene.scanner)
    paths = []
    for i, seed in enumerate((5, 5, 6)):
        scan = simulate(scene, setup, seed=seed, progress=False, backend=backend)
        paths.append(scan.save(tmp_path / f"s{i}.npz"))
    data = [p.read_bytes() for p in paths]
    assert data[0] == data[1]
    assert data[0] != data[2]


def test_cuda_scan_matches_llvm_scan(cuda_and_llvm):
    """Both backends trace the same sub-rays: the same seed gives the same knife-edge scan to within float rounding."""
    scene = scenes.build("knife-edge")
    setup = setup_from_section(scene.scanner)
    cuda, cpu = (simulate(scene, setup, seed=5, progress=False, backend=name) for name in ("cuda", "llvm"))
    layers = compare_scans(cuda, cpu, tolerance_m=1e-4)["layers"]
    for name in ("range", "truth_range", "truth_id"):
        assert layers[name]["only_a"] == layers[name]["only_b"] == 0
        # a sub-ray grazing a triangle edge may hit on one backend only (Embree's and OptiX's intersection tests)
        assert layers[name]["differing"] <= 1e-3 * layers[name]["compared"]
    assert layers["range"]["median"] < 1e-6


def test_ply_export(knife, tmp_path):
    path = knife.to_ply(tmp_path / "cloud.ply")
    cloud = trimesh.load(path)
    assert len(cloud.vertices) == int(knife.valid.sum())
    assert np.allclose(np.asarray(cloud.vertices), knife.points())


def test_malformed_scan_files_are_rejected(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip at all")
    with pytest.raises(ScanError, match="bad.npz.*not a readable NPZ"):
        Scan.load(bad)
    np.savez(tmp_path / "partial.npz", range=np.zeros((2, 2)))
    with pytest.raises(ScanError, match="missing scan arrays"):
        Scan.load(tmp_path / "partial.npz")
    with pytest.raises(ScanError, match="no such scan file"):
        Scan.load(tmp_path / "absent.npz")


def test_scan_cli_writes_scan_and_cloud(llvm, tmp_path, capsys):
    out, ply = tmp_path / "k.npz", tmp_path / "k.ply"
    assert tlssim_main(["scan", "knife-edge", "-o", str(out), "--ply", str(ply), "--subrays", "7",
                        "--seed", "1", "--quiet", "--backend", "llvm"]) == 0
    summary = json.loads(capsys.readouterr().out)
    scan = Scan.load(out)
    assert summary["returns"] == int(scan.valid.sum()) > 0
    assert scan.scanner.model.n_subrays == 7 and ply.exists()


def test_scenes_cli_lists_the_library(capsys):
    assert tlssim_main(["scenes"]) == 0
    listed = [line.split()[0] for line in capsys.readouterr().out.splitlines()]
    assert set(scenes.names()) == set(listed) and "knife-edge" in listed and "tilted-plane" in listed


def test_two_writers_of_one_npz_do_not_collide(tmp_path):
    """A second writer that finishes while the first is still writing (a shared tile cache) leaves both intact."""
    path = tmp_path / "tile.npz"

    def first_members():
        yield "a", np.arange(1000.0)
        other = threading.Thread(target=write_npz, args=(path, {"a": np.arange(1000.0), "b": np.ones(3)}))
        other.start()  # another writer of the same file, done meanwhile
        other.join()
        yield "b", np.ones(3)

    write_npz(path, first_members())
    with np.load(path, allow_pickle=False) as data:
        assert np.array_equal(data["a"], np.arange(1000.0)) and np.array_equal(data["b"], np.ones(3))
    assert [p.name for p in tmp_path.iterdir()] == ["tile.npz"]

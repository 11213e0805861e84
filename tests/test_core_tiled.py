"""Tiled scans: same bytes whatever the tile size, resume after an interrupted write, lazy reads, streamed export."""

import json

import numpy as np
import pytest

import scenes
from tlssim.cli import main as tlssim_main
from tlssim.errors import ScanError
from tlssim.formats import export_scan, import_scan
from tlssim.scan import GRID_KEYS, TRUTH_KEYS, Scan
from tlssim.simulate import check_scan_memory, setup_from_section, simulate, simulate_tiled, tile_columns
from tlssim.tiled import INDEX, open_scan, open_tiled

SEED = 11


@pytest.fixture(scope="module")
def knife(llvm):
    scene = scenes.build("knife-edge")
    setup = setup_from_section(scene.scanner)
    return scene, setup, simulate(scene, setup, seed=SEED, progress=False, backend="llvm")


def _same(a: Scan, b: Scan) -> bool:
    arrays = all(np.array_equal(getattr(a, k), getattr(b, k), equal_nan=True) for k in GRID_KEYS + TRUTH_KEYS)
    return arrays and a.layers.keys() == b.layers.keys() and all(
        np.array_equal(a.layers[k], b.layers[k], equal_nan=True) for k in a.layers)


@pytest.fixture(scope="module")
def tiled_dir(knife, tmp_path_factory):
    scene, setup, _ = knife
    path = tmp_path_factory.mktemp("tiled") / "knife"
    simulate_tiled(scene, setup, path, seed=SEED, tile_cols=9, progress=False, backend="llvm")
    return path


@pytest.mark.parametrize("tile_cols", [1, 9, 23])
def test_tiles_hold_the_bytes_of_the_whole_scan(knife, tmp_path, tile_cols):
    scene, setup, whole = knife
    tiled = simulate_tiled(scene, setup, tmp_path / "t", seed=SEED, tile_cols=tile_cols, progress=False,
                           backend="llvm")
    assert tiled.complete and tiled.shape == whole.shape
    assert len(tiled.tiles) == -(-whole.shape[1] // tile_cols)
    assert _same(tiled.load(), whole)
    # another seed gives other noise: the comparison can fail
    other = simulate_tiled(scene, setup, tmp_path / "o", seed=SEED + 1, tile_cols=tile_cols, progress=False,
                           backend="llvm")
    assert not np.array_equal(other.load().range, whole.range, equal_nan=True)


def test_wavefront_size_changes_no_byte(knife):
    """Wavefronts of 3 columns, each traced while the previous one is post-processed, give the one-wavefront bytes."""
    scene, setup, whole = knife
    rows = setup.window.shape[0]
    small = simulate(scene, setup, seed=SEED, progress=False, backend="llvm", chunk_subrays=3 * rows * 19)
    assert _same(whole, small)


def test_mixed_pulses_carry_their_subray_rows(knife):
    """The rows handed with the reductions are those of the pulses that see two objects, read from the device."""
    from tlssim.simulate import prepare_scan

    scene, setup, _ = knife
    job = prepare_scan(scene, setup, "llvm")
    theta, psi = (np.ravel(a) for a in np.meshgrid(*setup.window.angles()))
    hits = job.traced.trace(setup.model, job.beam, setup.pose, theta, psi, np.zeros(len(theta)))
    returned = (hits.object_id >= 0) & (hits.power > 0)
    seen = [set(row[ok]) for row, ok in zip(hits.object_id, returned)]
    assert np.array_equal(hits.mixed, np.nonzero([len(objects) > 1 for objects in seen])[0])
    assert len(hits.mixed) > 0
    for name, full in (("object_id", hits.object_id), ("power", hits.power), ("prim", hits.prim)):
        assert np.array_equal(getattr(hits, "mixed_" + name), full[hits.mixed])


def test_resume_keeps_checked_tiles_and_rewrites_the_others(knife, tiled_dir, tmp_path):
    scene, setup, whole = knife
    import shutil

    path = tmp_path / "resume"
    shutil.copytree(tiled_dir, path)
    index = json.loads((path / INDEX).read_text())
    tiles = index["tiles"]
    kept, corrupted, deleted, unlisted = (path / t["file"] for t in tiles[:4])
    kept_stamp = kept.stat().st_mtime_ns
    data = bytearray(corrupted.read_bytes())
    data[len(data) // 2] ^= 0xFF
    corrupted.write_bytes(bytes(data))
    deleted.unlink()
    # a write killed before the last tiles were listed
    index["tiles"] = [t for t in tiles if t["file"] != unlisted.name]
    index["complete"] = False
    (path / INDEX).write_text(json.dumps(index))
    assert not open_tiled(path).complete
    with pytest.raises(ScanError, match="incomplete"):
        open_tiled(path).load()

    resumed = simulate_tiled(scene, setup, path, seed=SEED, progress=False, backend="llvm")
    assert resumed.complete and resumed.tile_cols == 9
    assert kept.stat().st_mtime_ns == kept_stamp  # checked and kept, not simulated again
    assert corrupted.read_bytes() == (tiled_dir / corrupted.name).read_bytes()
    assert deleted.is_file() and unlisted.is_file()
    assert _same(resumed.load(), whole)


def test_resume_refuses_another_scan_or_tile_size(knife, tiled_dir, tmp_path):
    scene, setup, _ = knife
    with pytest.raises(ScanError, match="another scan"):
        simulate_tiled(scene, setup, tiled_dir, seed=SEED + 1, progress=False, backend="llvm")
    with pytest.raises(ScanError, match="tiles of 9 columns"):
        simulate_tiled(scene, setup, tiled_dir, seed=SEED, tile_cols=5, progress=False, backend="llvm")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "x.txt").write_text("x")
    with pytest.raises(ScanError, match="not empty"):
        simulate_tiled(scene, setup, tmp_path / "other", seed=SEED, tile_cols=5, progress=False, backend="llvm")


def test_lazy_reads(knife, tiled_dir):
    _, _, whole = knife
    tiled = open_scan(tiled_dir)
    assert tiled.has_truth and tiled.object_names == whole.object_names
    assert np.array_equal(tiled.theta_columns, whole.theta[0]) and np.array_equal(tiled.psi_rows, whole.psi[:, 0])
    window = tiled.load_columns(5, 30)  # spans four tiles
    assert _same(window, whole.crop(slice(None), slice(5, 30))) and window.meta["columns"] == [5, 30]
    # every tile is a plain NPZ that numpy reads without pickle
    first = tiled.tiles[0]
    with np.load(tiled_dir / first.file, allow_pickle=False) as data:
        assert np.array_equal(data["range"], whole.range[:, :first.col1], equal_nan=True)
    # overlapping windows cover every column, consecutive ones share the overlap
    starts, ends = [], []
    for col0, part in tiled.windows(width=20, overlap=6):
        assert _same(part, whole.crop(slice(None), slice(col0, col0 + part.shape[1])))
        starts.append(col0)
        ends.append(col0 + part.shape[1])
    assert starts[0] == 0 and ends[-1] == whole.shape[1]
    assert all(e - s == 6 for s, e in zip(starts[1:], ends[:-1]))
    with pytest.raises(ScanError, match="width > overlap"):
        next(tiled.windows(width=4, overlap=4))


@pytest.mark.parametrize("ext", ["las", "laz", "ptx"])
def test_export_of_a_tiled_scan_equals_that_of_the_scan_in_memory(knife, tiled_dir, tmp_path, ext):
    _, _, whole = knife
    streamed = export_scan(open_tiled(tiled_dir), tmp_path / f"tiled.{ext}")
    in_memory = export_scan(whole, tmp_path / f"memory.{ext}")
    assert streamed.read_bytes() == in_memory.read_bytes()


def test_e57_of_a_tiled_scan_reads_back_as_that_of_the_scan_in_memory(knife, tiled_dir, tmp_path):
    # E57 files differ only by the file's random GUID (pye57 writes uuid4): compare what they hold.
    _, _, whole = knife
    streamed = import_scan(export_scan(open_tiled(tiled_dir), tmp_path / "tiled.e57"))
    in_memory = import_scan(export_scan(whole, tmp_path / "memory.e57"))
    assert streamed.shape == whole.shape
    for key in ("range", "intensity", "xyz", "theta", "psi"):
        assert np.array_equal(getattr(streamed, key), getattr(in_memory, key), equal_nan=True), key
    assert np.array_equal(streamed.valid, whole.valid)


def test_scan_and_export_commands(tmp_path, capsys, llvm):
    out = tmp_path / "scan"
    args = ["scan", "knife-edge", "-o", str(out), "--tile-cols", "20", "--seed", str(SEED), "--quiet",
            "--backend", "llvm"]
    assert tlssim_main(args) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["tile_cols"] == 20 and summary["tiles"] == open_tiled(out).shape[1] // 20 + 1
    assert tlssim_main(args) == 0  # a finished scan is checked and kept
    assert tlssim_main(["export", str(out), str(tmp_path / "scan.laz")]) == 0
    assert (tmp_path / "scan.laz").stat().st_size > 0
    assert tlssim_main(["scan", "knife-edge", "-o", str(out), "--memory-budget", "-1", "--quiet"]) == 2
    assert "--memory-budget must be positive" in capsys.readouterr().err


def test_tile_size_from_a_memory_budget():
    rows = 8900  # the full 360 x 160 deg scan at 0.018 deg
    cols = tile_columns((rows, 20000), budget_bytes=2 * 1024**3)
    assert 1 <= cols < 20000
    assert cols * rows * 200 + 100 * (1 << 21) <= 2 * 1024**3 < (cols + 1) * rows * 200 + 100 * (1 << 21)
    with pytest.raises(ScanError, match="cannot hold one column"):
        tile_columns((rows, 20000), budget_bytes=10**6)


def test_memory_check_points_to_tiles():
    with pytest.raises(ScanError, match="in tiles on disk"):
        check_scan_memory((8900, 20000), available_bytes=24 * 1024**3)

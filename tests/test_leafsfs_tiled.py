"""PROP-SFS on a tiled scan: a leaf cut by tile borders is reconstructed once, as on the whole scan; resume."""

import json

import numpy as np
import pytest

import scenes
import tlssim
from benchmarks.experiments.calibration import simulated_calibration
from leafsfs import SfsError, reconstruct
from leafsfs.cli import main
from leafsfs.strays import remove_strays
from leafsfs import tiled as leafsfs_tiled
from leafsfs.tiled import GUARD_COLS, is_full_circle, margin_columns, margin_rows, reconstruct_tiled
from tlssim.simulate import simulate_tiled
from tlssim.tiled import add_tile, open_tiled, start_tiled

# The 9 cm pear leaf 1.5 m from the scanner spans columns 25-213 of the 309 of its scan (0.018 deg).
LEAF_SIZE_M = 0.06  # smaller than the leaf: the margin that follows from it must grow (and does)


@pytest.fixture(scope="module")
def tiled_leaf(tmp_path_factory, llvm):
    scene = scenes.build("leaf-1.5m")
    path = tmp_path_factory.mktemp("tiled-leaf") / "scan"
    tiled = simulate_tiled(scene, tlssim.setup_from_section(scene.scanner), path, seed=3, tile_cols=50,
                           progress=False, backend="llvm")
    calibration = simulated_calibration(tiled.scanner.model)
    whole = reconstruct(tiled.load(), variant="buffer", calibration=calibration)
    return tiled, calibration, whole


@pytest.fixture(scope="module")
def whole_fused(tiled_leaf):
    tiled, calibration, _ = tiled_leaf
    return reconstruct(tiled.load(), variant="fused", calibration=calibration)


@pytest.fixture(scope="module")
def by_core(tiled_leaf, tmp_path_factory):
    tiled, calibration, _ = tiled_leaf
    out = tmp_path_factory.mktemp("tiled-out")
    return {core: reconstruct_tiled(tiled, out / str(core), "buffer", calibration=calibration, core_cols=core,
                                    leaf_size_m=LEAF_SIZE_M) for core in (77, 120)}


def test_a_leaf_cut_by_tile_borders_is_reconstructed_once_as_on_the_whole_scan(tiled_leaf, by_core):
    tiled, _, whole = tiled_leaf
    leaf_pixels = tiled.load().truth_id == tiled.object_names.index("leaf")
    (expected,) = whole.traits()
    for core, result in by_core.items():
        cols = np.nonzero(leaf_pixels.any(axis=0))[0]
        assert len({int(c) // core for c in cols}) >= 2, "the leaf must straddle a core border"
        (leaf,) = result.traits  # one leaf, not one per window
        assert leaf["area_m2"] == pytest.approx(expected["area_m2"], rel=0.02)
        assert leaf["elevation_deg"] == pytest.approx(expected["elevation_deg"], abs=0.5)
        assert leaf["n_points"] == pytest.approx(expected["n_points"], rel=0.02)
        assert not leaf["cut_by_border"]
        corrected = result.scan.load()
        assert set(np.unique(corrected.layers["leaf"][leaf_pixels])) <= {0, leaf["leaf"]}
        assert np.mean(corrected.layers["leaf"][whole.labels > 0] == leaf["leaf"]) > 0.98
        # the distances the whole-scan run corrected are corrected alike
        same = np.isclose(corrected.range, whole.range, atol=1e-4, equal_nan=True)
        assert np.mean(same[whole.corrected]) > 0.9
        # traits.json gathers the leaves of all tiles
        report = json.loads((result.scan.path.parent / "traits.json").read_text())
        assert [entry["leaf"] for entry in report["leaves"]] == [leaf["leaf"]]


def test_a_leaf_cut_by_band_and_core_borders_is_one_leaf(tiled_leaf, tmp_path):
    tiled, calibration, whole = tiled_leaf
    leaf_pixels = tiled.load().truth_id == tiled.object_names.index("leaf")
    rows, cols = (np.nonzero(leaf_pixels.any(axis=axis))[0] for axis in (1, 0))
    assert rows.min() < 85 <= rows.max() and cols.min() < 160 <= cols.max(), "the leaf must straddle both borders"
    (expected,) = whole.traits()
    result = reconstruct_tiled(tiled, tmp_path, "buffer", calibration=calibration, core_cols=160, band_rows=85,
                               leaf_size_m=0.12)
    (leaf,) = result.traits  # one leaf, not one per window
    assert leaf["area_m2"] == pytest.approx(expected["area_m2"], rel=0.02)
    assert leaf["n_points"] == pytest.approx(expected["n_points"], rel=0.02)
    assert not leaf["cut_by_border"] and leaf["margin_rows"] > 0
    labels = result.scan.load().layers["leaf"]
    assert np.mean(labels[whole.labels > 0] == leaf["leaf"]) > 0.98


def test_margin_grows_with_the_leaf_size_and_nearness(tiled_leaf):
    tiled, _, _ = tiled_leaf
    core = tiled.load_columns(100, 150)
    small, large = margin_columns(core, 0.03, 4096), margin_columns(core, 0.12, 4096)
    # at 1.5 m a column is 1.5 m x 0.018 deg = 0.47 mm wide: 0.03 m spans about 64 columns
    assert small - GUARD_COLS == pytest.approx(0.03 / (1.5 * np.radians(0.018)), rel=0.1)
    assert large - GUARD_COLS == pytest.approx(4 * (small - GUARD_COLS), rel=0.05)
    assert margin_columns(core, 0.12, 100) == 100
    # a row is r dpsi tall: at 1.5 m and 0.018 deg, 0.03 m spans about 64 rows too
    assert margin_rows(core, 0.03, 4096) - GUARD_COLS == pytest.approx(0.03 / (1.5 * np.radians(0.018)), rel=0.1)


def test_resume_rewrites_only_the_missing_tiles(tiled_leaf, by_core):
    tiled, calibration, _ = tiled_leaf
    result = by_core[77]
    out = result.scan.path.parent
    before = {t.file: t.sha256 for t in result.scan.tiles}
    last = result.scan.tiles[-1]
    (result.scan.path / last.file).unlink()
    calls = []
    again = reconstruct_tiled(tiled, out, "buffer", calibration=calibration, core_cols=77, leaf_size_m=LEAF_SIZE_M,
                              progress=lambda done, total: calls.append((done, total)))
    assert again.windows == 2  # the last core's window and its neighbour's, not all five
    assert calls == [(0, 2), (1, 2), (2, 2)]  # the progress counts the windows this run reconstructs
    assert again.pulses == tiled.shape[0] * (last.col1 - last.col0)
    assert {t.file: t.sha256 for t in open_tiled(out / "corrected").tiles} == before
    assert [t["leaf"] for t in again.traits] == [t["leaf"] for t in result.traits]
    with pytest.raises(SfsError, match="another scan"):
        reconstruct_tiled(tiled, out, "fused", calibration=calibration, core_cols=77, leaf_size_m=LEAF_SIZE_M)


def test_reconstruct_command_on_a_tiled_scan(tiled_leaf, whole_fused, tmp_path, capsys):
    tiled, calibration, _ = tiled_leaf
    cal = calibration.save(tmp_path / "calibration.json")
    assert main(["reconstruct", str(tiled.path), "--calibration", str(cal), "-o", str(tmp_path / "out"),
                 "--core-cols", "150"]) == 0
    out = capsys.readouterr().out
    assert "1 leaves in 3 tiles of 150 columns" in out and "pulses/s" in out
    assert open_tiled(tmp_path / "out" / "corrected").complete
    # the stray-point rule after fused, window by window: the pulses the whole scan's run removes, but for
    # background pulses that the last core's window (no leaf in it) gives back as measured, with fused alone too
    assert main(["reconstruct", str(tiled.path), "--calibration", str(cal), "-o", str(tmp_path / "stray"),
                 "--variant", "fused-stray", "--core-cols", "150"]) == 0
    corrected = open_tiled(tmp_path / "stray" / "corrected").load()
    whole = remove_strays(whole_fused)
    removed = corrected.layers["removed"]
    assert removed.sum() > 1000 and not (removed & ~whole.removed).any()
    assert (removed & whole.removed).sum() > 0.85 * whole.removed.sum()
    kept = ~whole.removed
    assert np.mean(np.isclose(corrected.range, whole.range, atol=1e-4)[kept]) > 0.99
    assert main(["reconstruct", str(tiled.path), "--calibration", str(cal), "-o", str(tmp_path / "scope"),
                 "--stray-scope", "outside"]) == 2
    assert "--stray-scope needs --variant fused-stray" in capsys.readouterr().err


def test_background_corrections_stay_where_a_window_holds_the_leaf(tiled_leaf, whole_fused, tmp_path):
    # fused moves background pulses (noise tails, mixed pulses given to the wall); a window keeps those in its
    # core also when their nearest leaf is another core's (on main before round 15: 76 of them given back as
    # measured in the cores holding the leaf), and the last core, whose window holds no leaf, corrects its own
    # (before round 16 it gave them all back)
    tiled, calibration, _ = tiled_leaf
    measured = tiled.load()
    result = reconstruct_tiled(tiled, tmp_path / "fused", "fused", calibration=calibration, core_cols=150,
                               leaf_size_m=LEAF_SIZE_M)
    moved = ~np.isclose(whole_fused.range, measured.range, atol=1e-6)
    given_back = moved & np.isclose(result.scan.load().range, measured.range, atol=1e-6)
    assert moved.sum() > 1000
    assert given_back.sum() < 0.002 * moved.sum()


def test_same_output_for_any_worker_count_and_input_tiling(tiled_leaf, by_core, tmp_path):
    tiled, calibration, _ = tiled_leaf
    retiled = _retiled(tiled, tmp_path / "scan", 130)
    assert retiled.tile_cols != tiled.tile_cols and retiled.load().range.tobytes() == tiled.load().range.tobytes()
    runs = [by_core[77], reconstruct_tiled(retiled, tmp_path / "out", "buffer", calibration=calibration, core_cols=77,
                                           leaf_size_m=LEAF_SIZE_M, workers=2)]
    assert runs[1].windows == 5
    (a, b) = (run.scan.load() for run in runs)
    for key in ("range", "intensity", "xyz", "truth_id"):
        assert getattr(a, key).tobytes() == getattr(b, key).tobytes(), key
    assert a.layers.keys() == b.layers.keys()
    for key in a.layers:
        assert a.layers[key].tobytes() == b.layers[key].tobytes(), key
    assert runs[0].traits == runs[1].traits and len(runs[0].traits) == 1
    with pytest.raises(SfsError, match="workers >= 1"):
        reconstruct_tiled(tiled, tmp_path / "none", "buffer", calibration=calibration, workers=0)


def _retiled(tiled, path, tile_cols):
    """The same scan written again in tiles of ``tile_cols`` columns."""
    header = {key: tiled.index[key] for key in ("shape", "scanner", "scanner_position", "scanner_rotation",
                                                "object_names", "meta", "theta_columns", "psi_rows", "has_truth")}
    index, todo = start_tiled(path, header, tiled.index["fingerprint"], tile_cols)
    for c0, c1 in todo:
        add_tile(path, index, c0, tiled.load_columns(c0, c1))
    return open_tiled(path)


@pytest.fixture(scope="module")
def full_circle(tmp_path_factory, llvm):
    scene = scenes.build("leaf-1.5m")  # the leaf spans azimuths -2.2 to 3.3 deg: the seam at 0 deg cuts it
    section = {**scene.scanner, "window": {"theta_deg": [0.0, 359.964], "psi_deg": [88.5, 91.6], "step_deg": 0.036}}
    return simulate_tiled(scene, tlssim.setup_from_section(section), tmp_path_factory.mktemp("circle") / "scan",
                          seed=3, tile_cols=2500, progress=False, backend="llvm")


def test_a_leaf_cut_by_the_seam_of_a_360_deg_scan_is_one_leaf(tiled_leaf, full_circle, tmp_path):
    _, calibration, whole = tiled_leaf
    scan = full_circle
    assert is_full_circle(scan.theta_columns) and not is_full_circle(scan.theta_columns[:-2])
    result = reconstruct_tiled(scan, tmp_path / "out", "buffer", calibration=calibration, core_cols=2500)
    (leaf,) = result.traits  # one leaf, not its two halves
    (expected,) = whole.traits()  # the leaf in the middle of a window at half the step
    assert leaf["area_m2"] == pytest.approx(expected["area_m2"], rel=0.05)
    assert leaf["n_points"] == pytest.approx(expected["n_points"] / 4, rel=0.05)
    assert not leaf["cut_by_border"] and leaf["core"] in (0, 3)
    labels = result.scan.load().layers["leaf"]
    assert labels[:, :80].max() == labels[:, -80:].max() == leaf["leaf"]  # both halves carry its label


def test_a_resumed_360_deg_run_reconstructs_first_the_windows_of_the_first_core_it_writes(tiled_leaf, full_circle,
                                                                                         tmp_path, monkeypatch):
    _, calibration, _ = tiled_leaf
    out = tmp_path / "out"
    first = reconstruct_tiled(full_circle, out, "buffer", calibration=calibration, core_cols=1250)
    for tile in first.scan.tiles:
        if tile.col0 in (0, 3750):  # cores 0 and 3 of 8 are missing: core 3 is written first, core 0 last
            (first.scan.path / tile.file).unlink()
    computed, assembled = [], {}
    window, assemble = leafsfs_tiled._reconstruct_window, leafsfs_tiled._assemble_core

    def counted_window(scan, band, core, *args):
        computed.append(core[0] // 1250)
        return window(scan, band, core, *args)

    def noted_assembly(k, *args):
        assembled[k] = sorted(computed)
        return assemble(k, *args)

    monkeypatch.setattr(leafsfs_tiled, "_reconstruct_window", counted_window)
    monkeypatch.setattr(leafsfs_tiled, "_assemble_core", noted_assembly)
    again = reconstruct_tiled(full_circle, out, "buffer", calibration=calibration, core_cols=1250)
    # Core 3 needs its neighbours' windows and core 0's (whose leaf count numbers the others), not every window
    # up to core 0's neighbours (7 and 1), which the run would hold in memory at once.
    assert assembled == {3: [0, 2, 3, 4], 0: [0, 1, 2, 3, 4, 7]}
    assert again.windows == 6 and [t["leaf"] for t in again.traits] == [t["leaf"] for t in first.traits]


def test_a_core_written_member_by_member_is_the_file_scan_save_writes(tiled_leaf, tmp_path, monkeypatch):
    import dataclasses

    from leafsfs import tiled as tiled_module
    from tlssim.scan import grid_to_xyz

    tiled, _, _ = tiled_leaf
    monkeypatch.setattr(tiled_module, "_POINT_ROWS", 16)  # the points of the 169 rows in several bands
    c0, c1 = 30, 120  # across the input's tiles of 50 columns
    scan = tiled.load_columns(c0, c1)
    rng = np.random.default_rng(0)
    grids = {"range": scan.range + rng.normal(0, 1e-3, scan.shape), "outlier": rng.random(scan.shape) < 0.1,
             "candidates": rng.integers(0, 5, scan.shape, dtype=np.int32), "background": rng.random(scan.shape) < 0.2,
             "spread": rng.random(scan.shape).astype(np.float32),
             "leaf": rng.integers(0, 3, scan.shape, dtype=np.int32)}
    meta = {**tiled.meta, "columns": [c0, c1], "leafsfs": {"leaves": []}}
    streamed = tiled_module._write_core(tiled, c0, c1, grids, meta, tmp_path / "streamed.npz")
    layers = {**scan.layers, "outlier": grids["outlier"], "candidates": grids["candidates"], "leaf": grids["leaf"],
              "background": grids["background"], "removed": grids["outlier"] & np.isnan(grids["range"]),
              "range_spread": grids["spread"]}
    whole = dataclasses.replace(scan, range=grids["range"], layers=layers, meta=meta,
                                xyz=grid_to_xyz(grids["range"], scan.theta, scan.psi, scan.pose))
    assert streamed.read_bytes() == whole.save(tmp_path / "whole.npz").read_bytes()


def test_the_window_plan_fits_its_budget_whatever_the_tiling(tiled_leaf, tmp_path):
    from leafsfs.tiled import plan_windows

    tiled, _, _ = tiled_leaf
    rows, cols = tiled.shape
    whole = plan_windows(tiled, 1e12, leaf_size_m=0.06)  # a budget that holds the whole scan as one core
    assert whole.fits and whole.core_cols == cols and whole.band_rows == rows  # 169 rows: one band
    small, large = (plan_windows(tiled, budget, leaf_size_m=0.06) for budget in (whole.peak_bytes - 1e6,
                                                                                 whole.peak_bytes))
    assert small.fits and large.fits and small.peak_bytes <= whole.peak_bytes - 1e6
    assert 1 < small.core_cols < large.core_cols == cols and small.band_rows == rows
    budget = plan_windows(tiled, 1e12, workers=2, leaf_size_m=0.06).peak_bytes - 1e6
    one, two = (plan_windows(tiled, budget, workers=workers, leaf_size_m=0.06) for workers in (1, 2))
    assert two.fits and two.core_cols < one.core_cols  # two windows at once, and one more process
    assert plan_windows(_retiled(tiled, tmp_path / "scan", 130), whole.peak_bytes, leaf_size_m=0.06) == large
    assert not plan_windows(tiled, 0.1e9, leaf_size_m=0.06).fits  # less than the imports of one process


def test_a_tile_member_read_by_rows_is_the_rows_of_the_whole_member(tmp_path):
    import zipfile

    from leafsfs.tiled import _member_rows
    from tlssim.scan import write_npz

    rng = np.random.default_rng(1)
    arrays = {"grid": rng.normal(size=(300, 7)), "points": rng.normal(size=(300, 7, 3)),
              "flags": rng.random((300, 7)) < 0.5, "fortran": np.asfortranarray(rng.normal(size=(300, 7)))}
    path = write_npz(tmp_path / "tile.npz", arrays)
    with zipfile.ZipFile(path) as data:
        for key, whole in arrays.items():
            for rows in (slice(None), slice(0, 10), slice(123, 301), slice(299, 300), slice(50, 50), slice(5, 40, 3)):
                part = _member_rows(data, key, rows)
                assert part.dtype == whole.dtype and part.shape == whole[rows].shape, (key, rows)
                assert part.tobytes() == np.ascontiguousarray(whole[rows]).tobytes(), (key, rows)
                assert part.flags.writeable and part.flags.c_contiguous


def test_the_window_plan_tries_bands_taller_than_the_default(tiled_leaf, monkeypatch):
    from leafsfs import tiled as tiled_module

    tiled, _, _ = tiled_leaf
    rows, cols = tiled.shape
    # bands of 32 rows by default, 16 to 128 tried: on a scan of 169 rows the tallest bands repeat the fewest row
    # margins (at 1.5 m a 6 cm leaf spans about 130 rows), so the plan that holds whole cores takes them
    monkeypatch.setattr(tiled_module, "BAND_ROWS", 32)
    monkeypatch.setattr(tiled_module, "MAX_BAND_ROWS", 128)
    monkeypatch.setattr(tiled_module, "MIN_BAND_ROWS", 16)
    plan = tiled_module.plan_windows(tiled, 1e12, leaf_size_m=0.06)
    assert plan.fits and plan.core_cols == cols and plan.band_rows == 128

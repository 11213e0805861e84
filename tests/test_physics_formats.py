"""Scan file formats: round trips of E57, PTX and LAS/LAZ, and clear errors on broken files."""

import json

import numpy as np
import pytest

import scenes
from scenes.scene import Scene
from tlssim.cli import main
from tlssim.errors import ScanError
from tlssim.formats import export_scan, import_scan
from tlssim.scan import Scan
from tlssim.simulate import setup_from_section, simulate

#: Precision each format keeps: coordinates (m), intensity (DN), angles (rad).
PRECISION = {"e57": (2e-6, 0.0, 2e-7), "ptx": (1e-6, 2e-3, 1e-5), "las": (1e-5, 0.0, 0.0), "laz": (1e-5, 0.0, 0.0)}


@pytest.fixture(scope="module")
def scan(llvm):
    """The knife-edge plate (no wall) seen from a turned, shifted scanner; the window crosses azimuth 180 deg."""
    scene = scenes.build("knife-edge")
    scene = Scene(objects=scene.objects[:1], name="plate")
    position = np.array([0.3, -0.2, 0.1])
    scene.objects[0].vertices = scene.objects[0].vertices + position
    section = {"position": position.tolist(), "orientation": {"yaw_deg": 180.0, "pitch_deg": 1.0, "roll_deg": -1.0},
               "window": {"theta_deg": [178.0, 183.0], "psi_deg": [87.0, 93.0], "step_deg": 0.05}}
    result = simulate(scene, setup_from_section(section), seed=5, progress=False, backend="llvm")
    assert 0 < result.valid.sum() < result.valid.size
    return result


@pytest.mark.parametrize("ext", sorted(PRECISION))
def test_round_trip(scan, tmp_path, ext):
    coords, dn, angle = PRECISION[ext]
    back = import_scan(export_scan(scan, tmp_path / f"scan.{ext}"))
    assert back.shape == scan.shape
    assert np.array_equal(back.valid, scan.valid)
    valid = scan.valid
    assert np.max(np.abs(back.range[valid] - scan.range[valid])) <= 2 * coords
    assert np.max(np.abs(back.xyz[valid] - scan.xyz[valid])) <= 2 * coords
    assert np.max(np.abs(back.intensity[valid] - scan.intensity[valid])) <= dn
    wrapped = np.angle(np.exp(1j * (back.theta - scan.theta)))  # azimuths agree modulo 2 pi
    assert np.max(np.abs(wrapped)) <= angle + 1e-12
    assert np.max(np.abs(back.psi - scan.psi)) <= angle + 1e-12
    assert np.allclose(back.pose.position, scan.pose.position, atol=1e-12)
    assert np.allclose(back.pose.rotation, scan.pose.rotation, atol=1e-12)
    if ext in ("las", "laz"):  # truth of the returned points comes along
        for key in ("truth_id", "truth_range", "mixed_fraction", "incidence", "truth_normal"):
            assert np.array_equal(getattr(back, key)[valid], getattr(scan, key)[valid], equal_nan=True)
        assert back.object_names == scan.object_names and back.scanner == scan.scanner
    else:
        assert not back.has_truth  # real-scan formats: ready for reconstruction, no truth


def test_laz_is_compressed(scan, tmp_path):
    las, laz = export_scan(scan, tmp_path / "a.las"), export_scan(scan, tmp_path / "a.laz")
    assert laz.stat().st_size < 0.6 * las.stat().st_size


def test_unknown_format(scan, tmp_path):
    with pytest.raises(ScanError, match=r"unknown scan format '\.xyz'"):
        export_scan(scan, tmp_path / "a.xyz")
    with pytest.raises(ScanError, match="no such scan file"):
        import_scan(tmp_path / "missing.e57")


def _broken(tmp_path, scan, ext, damage):
    path = export_scan(scan, tmp_path / f"good.{ext}")
    bad = tmp_path / f"bad.{ext}"
    bad.write_bytes(damage(path.read_bytes()))
    return bad


@pytest.mark.parametrize("ext,damage,message", [
    ("ptx", lambda b: b[: len(b) // 2], "truncated PTX file"),
    ("ptx", lambda b: b"12\n" + b, "PTX header line"),
    ("ptx", lambda b: b.replace(b"\n", b"\nx ", 1), "PTX header must start"),
    ("ptx", lambda b: b[:5], "truncated PTX header"),
    ("ptx", lambda b: b"\xff\xfe" + b, "not a PTX file"),
    ("e57", lambda b: b[: len(b) // 2], "E57"),
    ("e57", lambda b: b"not an e57 file at all", "not a readable E57 file"),
    ("las", lambda b: b[:200], "LAS/LAZ"),
    ("laz", lambda b: b[: len(b) // 2], "LAS/LAZ"),
])
def test_broken_files_get_clear_errors(scan, tmp_path, ext, damage, message):
    bad = _broken(tmp_path, scan, ext, damage)
    with pytest.raises(ScanError, match=message) as error:
        import_scan(bad)
    assert str(bad) in str(error.value)


def test_ptx_malformed_point_line(scan, tmp_path):
    bad = _broken(tmp_path, scan, "ptx", lambda b: b.replace(b"0.000000 0.000000 0.000000 0.000000", b"0 0 zero 0", 1))
    with pytest.raises(ScanError, match="malformed PTX point line"):
        import_scan(bad)


def test_plain_las_point_cloud_is_not_a_scan(tmp_path):
    import laspy

    points = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
    points.x, points.y, points.z = np.zeros(3), np.ones(3), np.arange(3.0)
    points.write(str(tmp_path / "cloud.las"))
    with pytest.raises(ScanError, match="without tlssim grid metadata"):
        import_scan(tmp_path / "cloud.las")


def test_unstructured_e57_is_refused(tmp_path):
    import pye57

    with pye57.E57(str(tmp_path / "cloud.e57"), mode="w") as e57:
        e57.write_scan_raw({"cartesianX": np.zeros(4), "cartesianY": np.ones(4), "cartesianZ": np.arange(4.0)})
    with pytest.raises(ScanError, match="no rowIndex / columnIndex and its points cannot be gridded"):
        import_scan(tmp_path / "cloud.e57")


def test_export_and_import_commands(scan, tmp_path, capsys):
    scan.save(tmp_path / "scan.npz")
    assert main(["export", str(tmp_path / "scan.npz"), str(tmp_path / "scan.e57")]) == 0
    assert main(["import", str(tmp_path / "scan.e57"), "-o", str(tmp_path / "back.npz")]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert json.loads(lines[-1])["truth"] is False
    back = Scan.load(tmp_path / "back.npz")
    assert np.array_equal(back.valid, scan.valid)
    assert main(["import", str(tmp_path / "scan.npz"), "-o", str(tmp_path / "x.npz")]) == 2
    assert "unknown scan format" in capsys.readouterr().err


def test_unstructured_e57_is_gridded_from_its_angles(scan, tmp_path):
    """An E57 export without row/column indices (as many are) comes back on the same grid."""
    import pye57

    structured = export_scan(scan, tmp_path / "grid.e57")
    with pye57.E57(str(structured)) as e57:
        data = e57.read_scan_raw(0)
        header = e57.get_header(0)
        rotation, translation = header.rotation, header.translation
    rng = np.random.default_rng(3)
    order = rng.permutation(len(data["cartesianX"]))  # exporters need not keep the scan order
    cloud = {k: v[order] for k, v in data.items() if k not in ("rowIndex", "columnIndex")}
    path = tmp_path / "cloud.e57"
    with pye57.E57(str(path), mode="w") as e57:
        e57.write_scan_raw(cloud, rotation=rotation, translation=translation)
    back = import_scan(path)
    assert back.shape == scan.shape and np.array_equal(back.valid, scan.valid)
    assert np.max(np.abs(back.xyz[scan.valid] - scan.xyz[scan.valid])) <= 4e-6


E57_SAMPLES = __import__("pathlib").Path(__file__).parent / "data" / "e57"


@pytest.mark.parametrize("name,message", [
    ("bad-crc.e57", r"not a readable E57 file \(checksum mismatch, file is corrupted \(ErrorBadChecksum\)\)$"),
    ("empty.e57", "holds no scan$"),
    ("ZeroPoints.e57", "holds no points$"),
    ("InvalidCVHeader.e57", "holds no points$"),
    ("ZeroPointsInvalid.e57", r"malformed or truncated E57 scan \(.*ErrorInvalidZeroRecordsData3D\)\)$"),
    ("ColourRepresentation.e57", r"malformed or truncated E57 scan \(.*ErrorValueNotRepresentable\)\)$"),
    ("ColouredCubeFloat.e57", "do not lie on one station's regular angular grid .* read it as a point cloud"),
])
def test_libe57_samples_give_one_line_errors(name, message, tmp_path, capsys):
    path = E57_SAMPLES / name
    with pytest.raises(ScanError, match=message):
        import_scan(path)
    assert main(["import", str(path), "-o", str(tmp_path / "out.npz")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "out.npz").exists()


def test_e57_streamed_into_tiles_holds_the_arrays_of_the_whole_import(scan, tmp_path, capsys, monkeypatch):
    from tlssim.formats import e57
    from tlssim.formats.e57 import read_tiled

    monkeypatch.setattr(e57, "_BAND_CELLS", 500)  # the on-disk grids filled and read in bands of 4 rows

    path = export_scan(scan, tmp_path / "scan.e57")
    whole = import_scan(path)
    # chunks of 1,000 points cut the 121-row columns; the window crosses azimuth 180 deg (unwrapped across tiles)
    tiled = read_tiled(path, tmp_path / "tiles", tile_cols=23, chunk_points=1000)
    assert len(tiled.tiles) == 5 and not (tmp_path / ".tiles.import-grids").exists()
    back = tiled.load()
    for key in ("range", "intensity", "theta", "psi", "xyz"):
        assert np.array_equal(getattr(back, key), getattr(whole, key), equal_nan=True), key
    assert np.array_equal(back.pose.rotation, whole.pose.rotation)
    before = {t.file: t.sha256 for t in tiled.tiles}
    (tiled.path / tiled.tiles[2].file).unlink()  # an interrupted import resumes with the tiles that check
    assert {t.file: t.sha256 for t in read_tiled(path, tmp_path / "tiles", chunk_points=1000).tiles} == before
    assert main(["import", str(path), "-o", str(tmp_path / "cmd"), "--tile-cols", "40"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["tiles"] == 3


def _same_scans(back, whole, keys=("range", "intensity", "theta", "psi", "xyz")):
    for key in keys:
        assert np.array_equal(getattr(back, key), getattr(whole, key), equal_nan=True), key
    assert np.array_equal(back.pose.rotation, whole.pose.rotation)
    assert np.array_equal(back.pose.position, whole.pose.position)


def _blank_ptx(path, rows, empty_rows, empty_cols):
    """Rewrite a PTX file with the given rows and columns without a return (``0 0 0 0`` lines)."""
    lines = path.read_text().splitlines()
    for i in range(10, len(lines)):
        col, row = divmod(i - 10, rows)
        if row in empty_rows or col in empty_cols:
            lines[i] = "0 0 0 0"
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("blank", [False, True])
def test_ptx_streamed_into_tiles_holds_the_bytes_of_the_whole_import(scan, tmp_path, monkeypatch, blank):
    from tlssim.formats import grid, import_tiled, ptx

    path = export_scan(scan, tmp_path / "scan.ptx")
    if blank:  # empty rows and columns: filled from the grid-wide straight lines, as the whole import fills them
        _blank_ptx(path, scan.shape[0], {0, 1, 60}, {0, 50, scan.shape[1] - 1})
    whole = import_scan(path)
    monkeypatch.setattr(grid, "MEDIAN_SORT_VALUES", 50)  # the median azimuth found by narrowing passes
    monkeypatch.setattr(ptx, "_BAND_CELLS", 500)  # the rows' zeniths read in bands of 4 rows
    for tile_cols in (23, 64):  # blocks of 1,000 lines cut the 121-row columns
        tiled = ptx.read_tiled(path, tmp_path / f"t{tile_cols}", tile_cols=tile_cols, block_lines=1000)
        assert len(tiled.tiles) == -(-scan.shape[1] // tile_cols)
        assert not (tmp_path / f".t{tile_cols}.import-grids").exists()
        back = tiled.load()
        _same_scans(back, whole)
        assert back.meta["format"] == "ptx" and not tiled.has_truth
    before = {t.file: t.sha256 for t in tiled.tiles}
    (tiled.path / tiled.tiles[0].file).unlink()  # an interrupted import resumes with the tiles that check
    assert {t.file: t.sha256 for t in import_tiled(path, tmp_path / "t64").tiles} == before


def test_ptx_streamed_import_refuses_a_truncated_file(scan, tmp_path):
    from tlssim.formats import import_tiled

    path = export_scan(scan, tmp_path / "scan.ptx")
    path.write_text("\n".join(path.read_text().splitlines()[:-5]) + "\n")
    with pytest.raises(ScanError, match="truncated PTX file"):
        import_tiled(path, tmp_path / "tiles")
    assert not (tmp_path / ".tiles.import-grids").exists()


@pytest.mark.parametrize("ext", ["las", "laz"])
def test_las_streamed_into_tiles_holds_the_arrays_of_the_whole_import(scan, tmp_path, ext):
    from tlssim.formats import las

    path = export_scan(scan, tmp_path / f"scan.{ext}")
    whole = import_scan(path)
    keys = ("range", "intensity", "theta", "psi", "xyz", "truth_range", "truth_id", "mixed_fraction", "incidence",
            "truth_normal")
    for tile_cols in (23, 64):  # chunks of 500 points cut the tiles
        tiled = las.read_tiled(path, tmp_path / f"t{tile_cols}", tile_cols=tile_cols, chunk_points=500)
        assert len(tiled.tiles) == -(-scan.shape[1] // tile_cols) and tiled.has_truth
        back = tiled.load()
        _same_scans(back, whole, keys)
        assert back.object_names == whole.object_names and back.scanner == whole.scanner
        assert {k: v for k, v in back.meta.items() if k != "columns"} == whole.meta
    before = {t.file: t.sha256 for t in tiled.tiles}
    (tiled.path / tiled.tiles[1].file).unlink()
    assert {t.file: t.sha256 for t in las.read_tiled(path, tmp_path / "t64", chunk_points=500).tiles} == before


def test_streamed_las_import_needs_points_in_column_order(scan, tmp_path):
    import laspy

    from tlssim.formats import import_tiled

    data = laspy.read(str(export_scan(scan, tmp_path / "scan.las")))
    data.points = data.points[np.arange(len(data.points))[::-1]]  # last column first
    path = tmp_path / "reversed.las"
    data.write(str(path))
    _same_scans(import_scan(path), import_scan(tmp_path / "scan.las"))  # the whole import takes any order
    with pytest.raises(ScanError, match="not in column order .* import the file whole"):
        import_tiled(path, tmp_path / "tiles", tile_cols=23)


def test_streamed_las_import_needs_the_grid_index(tmp_path, capsys):
    import laspy

    cloud = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
    cloud.x, cloud.y, cloud.z = np.arange(3.0), np.ones(3), np.zeros(3)
    path = tmp_path / "cloud.las"
    cloud.write(str(path))
    assert main(["import", str(path), "-o", str(tmp_path / "tiles")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "only files written by tlssim, with the row, col, theta and psi" in err


def test_import_command_streams_ptx_and_las(scan, tmp_path, capsys):
    for ext in ("ptx", "las"):
        path = export_scan(scan, tmp_path / f"scan.{ext}")
        assert main(["import", str(path), str(tmp_path / ext), "--tile-cols", "40"]) == 0
        out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        assert out["tiles"] == 3 and out["truth"] == (ext == "las")


def test_las_metadata_longer_than_one_vlr(scan, tmp_path, monkeypatch):
    import laspy

    from tlssim.formats import las
    from tlssim.formats.points import read_points

    whole = import_scan(export_scan(scan, tmp_path / "one.las"))
    monkeypatch.setattr(las, "VLR_MAX_BYTES", 1000)  # a large grid's axes: the JSON spans several VLRs
    path = export_scan(scan, tmp_path / "many.las")
    assert len(las.metadata_records(laspy.read(str(path)).header.vlrs)) > 3
    _same_scans(import_scan(path), whole)
    _same_scans(las.read_tiled(path, tmp_path / "tiles", tile_cols=40).load(), whole)
    assert np.array_equal(read_points(path).viewpoints, scan.pose.position)

"""E57 export and import of structured scans (via ``pye57``)."""

from __future__ import annotations

import uuid
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from tlssim.errors import ScanError
from tlssim.formats.grid import (angles_of, complete_angles, grid_indices, local_points, scan_from_local,
                                 unwrap_columns)
from tlssim.pattern import ScannerPose
from tlssim.scan import Scan
from tlssim.tiled import TiledScan, scan_tiles

#: Row and column indices are stored as 16-bit unsigned integers by pye57.
MAX_INDEX = 65535


#: Points handed to libE57 per write call (the writer's buffers hold this many of each field).
CHUNK_POINTS = 1 << 20
#: Namespace of the scans' GUIDs (uuid5 of the scan's name and shape: the same scan gives the same file).
_GUID_NAMESPACE = uuid.UUID("6f1c1b8e-2d0e-4f4b-9a59-0c6a1e2f7a57")


def write(scan: Scan | TiledScan, path: Path) -> None:
    """Write the whole grid as one structured E57 scan (scanner frame, with the pose), tile by tile.

    Points are written column by column (``columnIndex``, then ``rowIndex``)
    through libE57's compressed-vector writer in chunks of
    :data:`CHUNK_POINTS`, so a tiled scan is read twice (bounds, then points)
    but never held whole: the file is the same for a scan in memory and for
    any tiling of it.

    Parameters
    ----------
    scan : Scan or TiledScan
        The scan to write; coordinates in m.
    path : Path
        Output ``.e57`` file.
    """
    import pye57
    from pye57 import libe57

    rows, cols = scan.shape
    if max(rows, cols) - 1 > MAX_INDEX:
        raise ScanError(f"{path}: a {rows} x {cols} grid exceeds the E57 writer's {MAX_INDEX + 1} rows or columns")
    name = str(scan.meta.get("scene") or "tlssim scan")
    local_lo, local_hi = np.full(3, np.inf), np.full(3, -np.inf)
    world_lo, world_hi = np.full(3, np.inf), np.full(3, -np.inf)
    i_lo, i_hi, invalid_states = np.inf, -np.inf, set()
    for _, tile in scan_tiles(scan):
        fields = _tile_fields(tile, 0)
        local = np.stack([fields["cartesianX"], fields["cartesianY"], fields["cartesianZ"]], axis=1)
        local_lo, local_hi = np.minimum(local_lo, local.min(axis=0)), np.maximum(local_hi, local.max(axis=0))
        if tile.valid.any():
            world = tile.xyz[tile.valid]
            world_lo, world_hi = np.minimum(world_lo, world.min(axis=0)), np.maximum(world_hi, world.max(axis=0))
        i_lo, i_hi = min(i_lo, float(fields["intensity"].min())), max(i_hi, float(fields["intensity"].max()))
        invalid_states |= set(np.unique(fields["cartesianInvalidState"]).tolist())
    if not np.all(np.isfinite(world_lo)):
        world_lo = world_hi = np.asarray(scan.pose.position, float)
    x, y, z, w = Rotation.from_matrix(scan.pose.rotation).as_quat()
    with pye57.E57(str(path), mode="w") as e57:
        image = e57.image_file
        node = libe57.StructureNode(image)
        node.set("guid", libe57.StringNode(image, "{%s}" % uuid.uuid5(_GUID_NAMESPACE, f"{name} {rows} {cols}")))
        node.set("name", libe57.StringNode(image, name))
        node.set("description", libe57.StringNode(image, "tlssim"))
        bounds = libe57.StructureNode(image)
        for key, value in (("rowMinimum", 0), ("rowMaximum", rows - 1), ("columnMinimum", 0),
                           ("columnMaximum", cols - 1), ("returnMinimum", 0), ("returnMaximum", 0)):
            bounds.set(key, libe57.IntegerNode(image, int(value)))
        node.set("indexBounds", bounds)
        limits = libe57.StructureNode(image)
        limits.set("intensityMinimum", libe57.FloatNode(image, i_lo))
        limits.set("intensityMaximum", libe57.FloatNode(image, i_hi))
        node.set("intensityLimits", limits)
        box = libe57.StructureNode(image)
        for axis, k in (("x", 0), ("y", 1), ("z", 2)):
            box.set(f"{axis}Minimum", libe57.FloatNode(image, float(world_lo[k])))
            box.set(f"{axis}Maximum", libe57.FloatNode(image, float(world_hi[k])))
        node.set("cartesianBounds", box)
        pose = libe57.StructureNode(image)
        rotation = libe57.StructureNode(image)
        for key, value in (("w", w), ("x", x), ("y", y), ("z", z)):
            rotation.set(key, libe57.FloatNode(image, float(value)))
        translation = libe57.StructureNode(image)
        for key, value in zip("xyz", np.asarray(scan.pose.position, float)):
            translation.set(key, libe57.FloatNode(image, float(value)))
        pose.set("rotation", rotation)
        pose.set("translation", translation)
        node.set("pose", pose)
        prototype = libe57.StructureNode(image)
        # Bounds widened by a few single-precision steps: libE57 checks the stored (rounded) values against them.
        pad = 1e-6 * np.maximum(np.abs(local_lo), np.abs(local_hi)) + 1e-9
        lo, hi = local_lo - pad, local_hi + pad
        for k, key in enumerate(("cartesianX", "cartesianY", "cartesianZ")):
            prototype.set(key, libe57.FloatNode(image, float(0.5 * (lo[k] + hi[k])), libe57.E57_SINGLE, float(lo[k]),
                                                float(hi[k])))
        prototype.set("intensity", libe57.FloatNode(image, i_lo, libe57.E57_SINGLE, i_lo, i_hi))
        prototype.set("rowIndex", libe57.IntegerNode(image, 0, 0, rows - 1))
        prototype.set("columnIndex", libe57.IntegerNode(image, 0, 0, cols - 1))
        prototype.set("cartesianInvalidState", libe57.IntegerNode(image, 0, min(invalid_states), max(invalid_states)))
        names = ["cartesianX", "cartesianY", "cartesianZ", "intensity", "rowIndex", "columnIndex",
                 "cartesianInvalidState"]
        arrays, buffers = e57.make_buffers(names, CHUNK_POINTS)
        points = libe57.CompressedVectorNode(image, prototype, libe57.VectorNode(image, True))
        node.set("points", points)
        e57.data3d.append(node)
        writer = points.writer(buffers)
        for col0, tile in scan_tiles(scan):
            fields = _tile_fields(tile, col0)
            for a in range(0, len(fields["rowIndex"]), CHUNK_POINTS):
                n = min(CHUNK_POINTS, len(fields["rowIndex"]) - a)
                for key in names:
                    arrays[key][:n] = fields[key][a:a + n]
                writer.write(n)
        writer.close()


def _tile_fields(tile: Scan, col0: int) -> dict[str, np.ndarray]:
    """The E57 point fields of a tile whose first column is ``col0``, column by column (column-major)."""
    local = np.swapaxes(local_points(tile), 0, 1).reshape(-1, 3)
    col, row = np.indices(tile.shape[::-1])
    return {
        "cartesianX": local[:, 0], "cartesianY": local[:, 1], "cartesianZ": local[:, 2],
        "intensity": np.nan_to_num(tile.intensity.T, nan=0.0).ravel().astype(np.float32),
        "rowIndex": row.ravel().astype(np.uint16), "columnIndex": (col.ravel() + col0).astype(np.uint16),
        # 0: valid point; 1: the cartesian vector is only a direction (no return)
        "cartesianInvalidState": np.where(tile.valid.T.ravel(), 0, 1).astype(np.int8),
    }


def read(path: Path, intensity_max_dn: float = 2047.0) -> Scan:
    """Read the first scan of an E57 file as a truth-less :class:`Scan`.

    A structured scan (``rowIndex`` and ``columnIndex``) keeps its grid; an
    unstructured one is gridded from its angles when it is one station's scan
    on a regular angular grid (:func:`~tlssim.formats.grid.grid_indices`), and
    refused with the reason otherwise. Cartesian or spherical coordinates are
    accepted. Intensities normalised to [0, 1]
    (``intensityLimits`` maximum <= 1) are scaled to ``0..intensity_max_dn``.

    Parameters
    ----------
    path : Path
        Input ``.e57`` file.
    intensity_max_dn : float
        Full scale that normalised intensities are scaled to, DN.

    Returns
    -------
    Scan
        The scan (range in m, angles in rad, intensity in DN), without truth.
    """
    with opened(path) as e57:
        if e57.scan_count < 1:
            raise ScanError(f"{path}: the E57 file holds no scan")
        header = e57.get_header(0)
        data = e57.read_scan_raw(0, ignore_unsupported_fields=True)
        rotation, translation = header.rotation, header.translation
        limit = _intensity_limit(header)
    local, invalid = _coordinates(path, data)
    intensity_dn = data.get("intensity")
    if not len(local):
        raise ScanError(f"{path}: the E57 scan holds no points")
    if "rowIndex" in data and "columnIndex" in data:
        row, col = data["rowIndex"].astype(np.int64), data["columnIndex"].astype(np.int64)
        row, col = row - row.min(), col - col.min()
    else:
        located = invalid < 2  # points with a direction
        local, invalid = local[located], invalid[located]
        intensity_dn = None if intensity_dn is None else intensity_dn[located]
        try:
            row, col = grid_indices(local)
        except ScanError as exc:
            raise ScanError(f"{path}: the E57 scan has no rowIndex / columnIndex and {exc}") from None
    shape = (int(row.max()) + 1, int(col.max()) + 1)
    grid = np.full(shape + (3,), np.nan)
    grid[row, col] = local
    valid = np.zeros(shape, dtype=bool)
    valid[row, col] = invalid == 0
    intensity = np.full(shape, np.nan)
    if intensity_dn is not None:
        scale = intensity_max_dn if limit is not None and limit <= 1.0 else 1.0
        intensity[row, col] = intensity_dn * scale
    has_direction = np.zeros(shape, dtype=bool)
    has_direction[row, col] = invalid < 2
    theta, psi = angles_of(np.where(has_direction[..., None], grid, np.nan))
    theta, psi = complete_angles(theta, psi)
    try:
        pose = ScannerPose(translation, Rotation.from_quat(np.roll(rotation, -1)).as_matrix())
    except (ScanError, ValueError) as exc:
        raise ScanError(f"{path}: invalid scanner pose ({exc})") from None
    return scan_from_local(grid, valid, intensity, pose, theta, psi, {"source": str(path), "format": "e57"})


def _coordinates(path: Path, data: dict) -> tuple[np.ndarray, np.ndarray]:
    """Scanner-frame points and their invalid state (0 valid, 1 direction only, 2 nothing)."""
    if all(k in data for k in ("cartesianX", "cartesianY", "cartesianZ")):
        local = np.stack([data["cartesianX"], data["cartesianY"], data["cartesianZ"]], axis=1)
        invalid = data.get("cartesianInvalidState", np.zeros(len(local), np.int8))
    elif all(k in data for k in ("sphericalRange", "sphericalAzimuth", "sphericalElevation")):
        r, azimuth, elevation = data["sphericalRange"], data["sphericalAzimuth"], data["sphericalElevation"]
        invalid = data.get("sphericalInvalidState", np.zeros(len(r), np.int8))
        r = np.where(invalid == 0, r, 1.0)  # a direction-only point keeps its angles
        local = np.stack([r * np.cos(elevation) * np.cos(azimuth), r * np.cos(elevation) * np.sin(azimuth),
                          r * np.sin(elevation)], axis=1)
    else:
        raise ScanError(f"{path}: the E57 scan has neither cartesian nor spherical coordinates")
    return local.astype(np.float64), np.asarray(invalid).astype(np.int64)


def _first_line(exc: Exception) -> str:
    """The first non-empty line of a libE57 message (the rest is the library's debug dump)."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return lines[0] if lines else type(exc).__name__


@contextmanager
def opened(path: Path, what: str = "scan"):
    """An E57 file open for reading, closed on exit; libE57's own exceptions become one-line ScanErrors.

    Parameters
    ----------
    path : Path
        The ``.e57`` file.
    what : str
        What the caller reads, for the message of a read that fails ("malformed or truncated E57 {what}").
    """
    import pye57

    try:
        e57 = pye57.E57(str(path))
    except Exception as exc:  # libE57 raises its own exception types
        raise ScanError(f"{path}: not a readable E57 file ({_first_line(exc)})") from None
    try:
        yield e57
    except ScanError:
        raise
    except Exception as exc:
        raise ScanError(f"{path}: malformed or truncated E57 {what} ({_first_line(exc)})") from None
    finally:
        e57.close()


def _intensity_limit(header) -> float | None:
    """Upper intensity limit of a scan header, if it states one."""
    if "intensityLimits" not in header.scan_fields:
        return None
    return float(header["intensityLimits"]["intensityMaximum"].value())


def read_tiled(path: Path, outdir, tile_cols: int | None = None, budget_bytes: int = 2 * 1024**3,
               chunk_points: int = CHUNK_POINTS) -> TiledScan:
    """Stream the first scan of a structured E57 file into a tiled scan directory (:mod:`tlssim.tiled`).

    The points are read in chunks of ``chunk_points`` through libE57's
    compressed-vector reader: a first pass finds the grid from ``rowIndex``
    and ``columnIndex``, a second scatters the points into on-disk grids
    (NumPy memory maps beside ``outdir``, removed at the end) in whatever order
    the file holds them; the tiles are then cut from those grids. So memory
    holds one chunk and one tile, and the tiles hold the arrays of
    :func:`read` on the same file (the azimuths are unwrapped along each row
    across the tiles as on the whole grid). An interrupted import resumes
    with the tiles that check.

    Parameters
    ----------
    path : Path
        Input ``.e57`` file, a structured scan whose every grid cell holds a point or a direction.
    outdir : str or Path
        Output directory of the tiled scan.
    tile_cols : int, optional
        Columns per tile (default: from ``budget_bytes``).
    budget_bytes : int
        Memory for one tile when ``tile_cols`` is not given, bytes (about 150 bytes per pulse).
    chunk_points : int
        Points read per call.

    Returns
    -------
    TiledScan
        The imported scan, opened lazily, without truth.

    Raises
    ------
    ScanError
        If the file is unreadable, not structured, or has grid cells without a direction (read it whole
        with :func:`read`, which fills them from the grid's rows and columns).
    """
    import shutil

    import pye57

    from tlssim.tiled import earlier_import, import_tile_cols

    outdir = Path(outdir)
    scratch = outdir.parent / f".{outdir.name}.import-grids"
    with opened(path) as e57:
        if e57.scan_count < 1:
            raise ScanError(f"{path}: the E57 file holds no scan")
        header = e57.get_header(0)
        if not {"rowIndex", "columnIndex"} <= set(header.point_fields):
            raise ScanError(f"{path}: a streamed import needs a structured E57 scan (rowIndex and columnIndex); "
                            "import it whole (-o FILE.npz)")
        fields = [f for f in header.point_fields if f in pye57.e57.SUPPORTED_POINT_FIELDS]
        low, high = np.full(2, np.iinfo(np.int64).max), np.full(2, -1)
        for chunk in _chunks(e57, header, ["rowIndex", "columnIndex"], chunk_points):
            index = np.stack([chunk["rowIndex"], chunk["columnIndex"]]).astype(np.int64)
            low, high = np.minimum(low, index.min(axis=1)), np.maximum(high, index.max(axis=1))
        if high[0] < 0:
            raise ScanError(f"{path}: the E57 scan holds no points")
        shape = (int(high[0] - low[0]) + 1, int(high[1] - low[1]) + 1)
        rows, cols = shape
        limit = _intensity_limit(header)
        rotation, translation = header.rotation, header.translation
        try:
            pose = ScannerPose(translation, Rotation.from_quat(np.roll(rotation, -1)).as_matrix())
        except (ScanError, ValueError) as exc:
            raise ScanError(f"{path}: invalid scanner pose ({exc})") from None
        fingerprint, earlier, done = earlier_import(path, outdir)
        if done:
            return earlier
        tile_cols = import_tile_cols(tile_cols, earlier, rows, cols, budget_bytes, 150)
        try:
            grids = _scatter_grids(path, e57, header, fields, shape, low, limit, scratch, chunk_points)
        except BaseException:
            shutil.rmtree(scratch, ignore_errors=True)
            raise
    try:
        return _write_tiles(outdir, grids, pose, tile_cols, fingerprint, {"source": str(path), "format": "e57"})
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _write_tiles(outdir: Path, grids: dict, pose: ScannerPose, tile_cols: int, fingerprint: str,
                 meta: dict) -> TiledScan:
    """Cut the on-disk grids of :func:`_scatter_grids` into the tiles of a tiled scan (those not yet written)."""
    from tlssim.scan import ScannerDescription
    from tlssim.tiled import add_tile, open_tiled, start_tiled

    rows, cols = _part(grids, "psi", ()).shape
    column_theta, carry = np.empty(cols), None
    for c0 in range(0, cols, tile_cols):  # the columns' azimuths for the index, one tile at a time
        theta, carry = unwrap_columns(_part(grids, "theta", (slice(None), slice(c0, c0 + tile_cols))), carry)
        column_theta[c0:c0 + tile_cols] = np.median(theta, axis=0)
    band_rows = max(1, _BAND_CELLS // cols)
    psi_rows = [float(np.median(row)) for r0 in range(0, rows, band_rows)
                for row in _part(grids, "psi", slice(r0, r0 + band_rows))]
    first = {"shape": [rows, cols], "scanner": ScannerDescription().to_dict(),
             "scanner_position": np.asarray(pose.position, float).tolist(),
             "scanner_rotation": np.asarray(pose.rotation, float).tolist(), "object_names": None,
             "theta_columns": column_theta.tolist(), "psi_rows": psi_rows, "has_truth": False, "meta": meta}
    index, todo = start_tiled(outdir, first, fingerprint, tile_cols)
    carry = None
    for c0 in range(0, cols, tile_cols):
        c1 = min(cols, c0 + tile_cols)
        window = (slice(None), slice(c0, c1))
        theta, carry = unwrap_columns(_part(grids, "theta", window), carry)
        if (c0, c1) in todo:
            tile = scan_from_local(_part(grids, "local", window), _part(grids, "valid", window),
                                   _part(grids, "intensity", window), pose, theta, _part(grids, "psi", window),
                                   dict(meta))
            add_tile(outdir, index, c0, tile)
    return open_tiled(outdir)


#: Cells of an on-disk grid handled at once (a band of whole rows) by a streamed import.
_BAND_CELLS = 1 << 20


def _part(grids: dict, key: str, index) -> np.ndarray:
    """A copy of ``grids[key][index]`` from its ``.npy`` file, mapped only for the read.

    The grids are mapped for each read or write and unmapped after it, so that their pages do not stay in
    the process's resident memory.
    """
    mapped = np.load(grids[key], mmap_mode="r")
    try:
        return np.array(mapped[index])
    finally:
        del mapped


def _store(grids: dict, key: str, index, values) -> None:
    """Write ``values`` into ``grids[key][index]`` (its ``.npy`` file mapped only for the write)."""
    mapped = np.load(grids[key], mmap_mode="r+")
    mapped[index] = values
    del mapped


def _chunks(e57, header, fields: list[str], chunk_points: int):
    """Yield the points of the first scan ``chunk_points`` at a time, as dicts of the ``fields``' arrays."""
    data, buffers = e57.make_buffers(fields, chunk_points)
    reader = header.points.reader(buffers)
    try:
        while True:
            count = reader.read()
            if count == 0:
                return
            yield {key: value[:count] for key, value in data.items()}
    finally:
        reader.close()


def _scatter_grids(path, e57, header, fields, shape, low, limit, scratch: Path, chunk_points: int) -> dict:
    """Scatter the points into on-disk grids: scanner-frame points, validity, intensity (DN) and the angles.

    Returns the ``.npy`` file of each grid (``local``, ``valid``, ``direction``, ``intensity``, ``theta``,
    ``psi``); each is mapped only for one chunk's or one band's read or write.
    """
    scratch.mkdir(parents=True, exist_ok=True)
    grids = {}
    band_rows = max(1, _BAND_CELLS // shape[1])
    for key, trailing, dtype, fill in (("local", (3,), np.float64, np.nan), ("valid", (), bool, False),
                                       ("direction", (), bool, False), ("intensity", (), np.float64, np.nan),
                                       ("theta", (), np.float64, 0.0), ("psi", (), np.float64, 0.0)):
        grids[key] = scratch / f"{key}.npy"
        created = np.lib.format.open_memmap(grids[key], "w+", dtype, shape + trailing)
        del created
        for r0 in range(0, shape[0], band_rows):
            _store(grids, key, slice(r0, r0 + band_rows), fill)
    scale = 1.0
    for chunk in _chunks(e57, header, fields, chunk_points):
        local, invalid = _coordinates(path, chunk)
        cells = (chunk["rowIndex"].astype(np.int64) - low[0], chunk["columnIndex"].astype(np.int64) - low[1])
        _store(grids, "local", cells, local)
        _store(grids, "valid", cells, invalid == 0)
        _store(grids, "direction", cells, invalid < 2)
        if "intensity" in chunk:
            scale = 2047.0 if limit is not None and limit <= 1.0 else 1.0
            _store(grids, "intensity", cells, chunk["intensity"] * scale)
    for r0 in range(0, shape[0], band_rows):  # band by band: the angles, and every cell must have a direction
        band = slice(r0, r0 + band_rows)
        if not _part(grids, "direction", band).all():
            raise ScanError(f"{path}: grid cells without a point or a direction; a streamed import cannot fill "
                            "them from the whole grid: import it whole (-o FILE.npz)")
        local = _part(grids, "local", band)
        _store(grids, "theta", band, np.arctan2(local[..., 1], local[..., 0]))
        _store(grids, "psi", band, np.arccos(np.clip(local[..., 2] / np.linalg.norm(local, axis=-1), -1.0, 1.0)))
    return grids



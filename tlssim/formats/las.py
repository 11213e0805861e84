"""LAS/LAZ export and import of the returned points with their grid position and truth (via ``laspy``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tlssim.errors import ScanError
from tlssim.pattern import ScannerPose
from tlssim.scan import TRUTH_KEYS, Scan, ScannerDescription
from tlssim.tiled import TiledScan, scan_tiles

#: Coordinate resolution of the written files, m.
SCALE_M = 1e-5
#: Bits of an extra-bytes descriptor's ``options`` that say its min and max statistics are set (LAS 1.4).
_STATS_OPTIONS = 0b110
#: VLR that carries the scan's metadata as JSON (continued in the VLRs of the next record ids when longer than
#: :data:`VLR_MAX_BYTES`).
VLR_USER_ID, VLR_RECORD_ID = "tlslab", 1
#: Largest payload of one VLR, bytes (its length is a 16-bit field in the LAS specification).
VLR_MAX_BYTES = 65535
#: Extra dimensions: grid position and angles, then the truth arrays (normals split per axis).
_GRID_DIMS = (("row", np.int32), ("col", np.int32), ("theta", np.float64), ("psi", np.float64))
_TRUTH_DIMS = (("truth_range", np.float64), ("truth_id", np.int32), ("mixed_fraction", np.float32),
               ("incidence", np.float32), ("truth_normal_x", np.float32), ("truth_normal_y", np.float32),
               ("truth_normal_z", np.float32))


def write(scan: Scan | TiledScan, path: Path) -> None:
    """Write the returned points (world frame) as LAS, or LAZ for a ``.laz`` path, tile by tile.

    A :class:`~tlssim.tiled.TiledScan` is streamed: one tile in memory at a
    time, and the file has the same bytes as that of the scan in memory.

    Parameters
    ----------
    scan : Scan or TiledScan
        The scan to write; coordinates in m.
    path : Path
        Output ``.las`` or ``.laz`` file.
    """
    import laspy

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.offsets = scan.pose.position
    header.scales = np.full(3, SCALE_M)
    dims = _GRID_DIMS + (_TRUTH_DIMS if scan.has_truth else ())
    header.add_extra_dims([laspy.ExtraBytesParams(name=name, type=dtype) for name, dtype in dims])
    for descriptor in header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs:
        # No min/max statistics: laspy 2.7 takes them from the first point of each written chunk
        # (wrong values that would also depend on the tile size).
        descriptor.options &= ~_STATS_OPTIONS
    rows, cols = scan.shape
    if isinstance(scan, TiledScan):
        theta_columns, psi_rows = scan.theta_columns, scan.psi_rows
    else:
        theta_columns, psi_rows = np.nanmedian(scan.theta, axis=0), np.nanmedian(scan.psi, axis=1)
    meta = {"shape": [rows, cols], "theta_columns": theta_columns.tolist(),
            "psi_rows": psi_rows.tolist(), "scanner_position": scan.pose.position.tolist(),
            "scanner_rotation": scan.pose.rotation.tolist(), "scanner": scan.scanner.to_dict(),
            "meta": scan.meta, "object_names": scan.object_names}
    data = json.dumps(meta).encode()
    for part, start in enumerate(range(0, len(data), VLR_MAX_BYTES)):  # a large grid's axes span several VLRs
        header.vlrs.append(laspy.VLR(user_id=VLR_USER_ID, record_id=VLR_RECORD_ID + part, description="tlssim scan",
                                     record_data=data[start:start + VLR_MAX_BYTES]))
    with laspy.open(str(path), mode="w", header=header) as writer:
        for col0, tile in scan_tiles(scan):
            writer.write_points(_tile_points(tile, col0, header, dims))


def _tile_points(tile: Scan, col0: int, header, dims) -> "laspy.ScaleAwarePointRecord":
    """The returned points of one tile (whose first column is ``col0`` of the scan) as LAS records, column-major."""
    import laspy

    col, row = np.nonzero(tile.valid.T)  # column by column, as the scanner records them
    cells = (row, col)
    points = laspy.ScaleAwarePointRecord.zeros(len(row), header=header)
    points.x, points.y, points.z = tile.xyz[cells].T
    points.intensity = np.round(tile.intensity[cells]).astype(np.uint16)
    values = {"row": row, "col": col + col0, "theta": tile.theta[cells], "psi": tile.psi[cells]}
    if tile.has_truth:
        values.update({key: getattr(tile, key)[cells] for key in TRUTH_KEYS if key != "truth_normal"})
        values.update({f"truth_normal_{a}": tile.truth_normal[cells][:, i] for i, a in enumerate("xyz")})
    for name, dtype in dims:
        points[name] = values[name].astype(dtype)
    return points


#: Sizes in the LAS public header (LAS 1.0-1.4 specifications): the header, a VLR's and an EVLR's own header, bytes.
_LAS_HEADER_MIN, _VLR_HEADER, _EVLR_HEADER = 227, 54, 60


def _check_header(path: Path) -> None:
    """Refuse a LAS/LAZ file whose header promises more records than the file holds.

    laspy trusts the header's record counts: a damaged count makes it read
    billions of empty records instead of failing.
    """
    size = path.stat().st_size
    with open(path, "rb") as handle:
        head = handle.read(247)
    if len(head) < _LAS_HEADER_MIN or head[:4] != b"LASF":
        raise ScanError(f"{path}: not a LAS/LAZ file (no LASF header)")
    header_size = int.from_bytes(head[94:96], "little")
    n_vlrs = int.from_bytes(head[100:104], "little")
    n_evlrs = int.from_bytes(head[243:247], "little") if header_size >= 247 and len(head) >= 247 else 0
    if header_size + n_vlrs * _VLR_HEADER + n_evlrs * _EVLR_HEADER > size:
        raise ScanError(f"{path}: truncated or damaged LAS/LAZ header ({n_vlrs} variable-length records "
                        f"and {n_evlrs} extended ones announced, {size} bytes in the file)")


#: Truth arrays of a file written with truth: fill value of the cells without a return and dtype.
_TRUTH_FILL = (("truth_range", np.nan, np.float64), ("truth_id", -1, np.int32),
               ("mixed_fraction", np.nan, np.float32), ("incidence", np.nan, np.float32))
#: Points read per chunk by a streamed import.
CHUNK_POINTS = 1 << 20


def metadata_records(vlrs) -> list:
    """The VLRs that carry a tlssim scan's JSON metadata, in order; empty if none."""
    return sorted((v for v in vlrs if v.user_id == VLR_USER_ID and v.record_id >= VLR_RECORD_ID),
                  key=lambda v: v.record_id)


def metadata_json(records: list) -> dict:
    """The JSON metadata joined from the VLRs of :func:`metadata_records` (raises ValueError if malformed)."""
    return json.loads(b"".join(bytes(v.record_data) for v in records))


def _metadata(path: Path, header) -> dict:
    """The scan's grid and metadata from a LAS header written by :func:`write`.

    Returns a dict of ``rows``, ``cols``, ``pose``, ``theta_columns`` and
    ``psi_rows`` (rad), ``scanner``, ``object_names``, ``meta`` and
    ``has_truth``; a file without the grid raises a one-line ScanError
    saying which files are allowed.
    """
    records = metadata_records(header.vlrs)
    names = set(header.point_format.extra_dimension_names)
    if not records or not {n for n, _ in _GRID_DIMS} <= names:
        raise ScanError(f"{path}: LAS/LAZ without tlssim grid metadata (only files written by tlssim, with the "
                        "row, col, theta and psi extra dimensions and the tlslab VLR, can be imported as scans; "
                        "point clouds have no scan grid)")
    try:
        meta = metadata_json(records)
        rows, cols = (int(n) for n in meta["shape"])
        pose = ScannerPose(meta["scanner_position"], meta["scanner_rotation"])
        scan_meta = dict(meta.get("meta") or {})
        if "scanner" in meta:
            scanner = ScannerDescription.from_dict(meta["scanner"])
        else:  # files written before the description: the model's parameters, the window in the scan's meta
            scanner = ScannerDescription.from_dict({"model": meta.get("scanner_model"),
                                                    "window": scan_meta.pop("window", None)})
        theta_columns = np.asarray(meta["theta_columns"], float).reshape(cols)
        psi_rows = np.asarray(meta["psi_rows"], float).reshape(rows)
    except (KeyError, TypeError, ValueError, json.JSONDecodeError) as exc:
        raise ScanError(f"{path}: malformed tlssim metadata in the LAS/LAZ file ({exc!r})") from None
    return {"rows": rows, "cols": cols, "pose": pose, "theta_columns": theta_columns, "psi_rows": psi_rows,
            "scanner": scanner, "object_names": meta.get("object_names"),
            "meta": {**scan_meta, "source": str(path), "format": "las"},
            "has_truth": {n for n, _ in _TRUTH_DIMS} <= names}


def _empty_grid(grid: dict, cols: int) -> dict:
    """The arrays of ``cols`` columns before any point is placed: axes from the metadata, no return, no truth."""
    rows = grid["rows"]
    arrays = {"theta": np.broadcast_to(grid["theta_columns"][None, :cols], (rows, cols)).copy(),
              "psi": np.broadcast_to(grid["psi_rows"][:, None], (rows, cols)).copy(),
              "xyz": np.full((rows, cols, 3), np.nan), "intensity": np.full((rows, cols), np.nan, np.float32)}
    if grid["has_truth"]:
        for key, fill, dtype in _TRUTH_FILL:
            arrays[key] = np.full((rows, cols), fill, dtype)
        arrays["truth_normal"] = np.full((rows, cols, 3), np.nan, np.float32)
    return arrays


def _place(path: Path, grid: dict, arrays: dict, points, col0: int = 0) -> None:
    """Put LAS points (columns from ``col0`` of the scan) into their cells of ``arrays``."""
    row, col = np.asarray(points["row"], np.int64), np.asarray(points["col"], np.int64) - col0
    cols = arrays["psi"].shape[1]
    if len(row) and (row.min() < 0 or col.min() < 0 or row.max() >= grid["rows"] or col.max() >= cols):
        raise ScanError(f"{path}: point grid positions lie outside the {grid['rows']} x {grid['cols']} grid")
    arrays["theta"][row, col], arrays["psi"][row, col] = points["theta"], points["psi"]
    arrays["xyz"][row, col] = np.stack([points.x, points.y, points.z], axis=1)
    arrays["intensity"][row, col] = points.intensity
    if grid["has_truth"]:
        for key, _, _ in _TRUTH_FILL:
            arrays[key][row, col] = points[key]
        arrays["truth_normal"][row, col] = np.stack([points[f"truth_normal_{a}"] for a in "xyz"], axis=1)


def _scan(grid: dict, arrays: dict, meta: dict) -> Scan:
    """The :class:`Scan` of placed arrays (range from the points and the scanner position)."""
    range_m = np.linalg.norm(arrays["xyz"] - grid["pose"].position, axis=-1)
    return Scan(range=range_m, pose=grid["pose"], scanner=grid["scanner"], object_names=grid["object_names"],
                meta=meta, **arrays)


def read(path: Path) -> Scan:
    """Read a LAS/LAZ file written by :func:`write` back into a :class:`Scan`.

    No-return cells get NaN range and intensity, the grid's axes from the
    metadata, and no truth (the file holds returned points only).
    """
    import laspy

    _check_header(path)
    try:
        points = laspy.read(str(path))
    except Exception as exc:  # laspy raises LaspyException, ValueError, OSError...
        raise ScanError(f"{path}: not a readable LAS/LAZ file ({exc})") from None
    grid = _metadata(path, points.header)
    arrays = _empty_grid(grid, grid["cols"])
    _place(path, grid, arrays, points)
    return _scan(grid, arrays, dict(grid["meta"]))


def read_tiled(path: Path, outdir, tile_cols: int | None = None, budget_bytes: int = 2 * 1024**3,
               chunk_points: int = CHUNK_POINTS) -> TiledScan:
    """Stream a LAS/LAZ file written by :func:`write` into a tiled scan directory (:mod:`tlssim.tiled`).

    The points are read ``chunk_points`` at a time (``laspy``'s chunk
    iterator) and placed into the tile of their ``col`` extra dimension;
    :func:`write` stores them column by column, so one tile is in memory at
    a time and a tile is written when the points move past it. The tiles
    hold the arrays of :func:`read` on the same file, with the truth of the
    returned points. An interrupted import resumes with the tiles that check.

    Parameters
    ----------
    path : Path
        Input ``.las`` or ``.laz`` file written by tlssim (grid index in its extra dimensions).
    outdir : str or Path
        Output directory of the tiled scan.
    tile_cols : int, optional
        Columns per tile (default: from ``budget_bytes``).
    budget_bytes : int
        Memory for one tile when ``tile_cols`` is not given, bytes (about :data:`tlssim.tiled.LOADED_BYTES_PER_PULSE`
        per pulse).
    chunk_points : int
        Points read at once.

    Returns
    -------
    TiledScan
        The imported scan, opened lazily.

    Raises
    ------
    ScanError
        If the file is unreadable, has no tlssim grid, or its points are not in column order (read it whole
        with :func:`read`).
    """
    import laspy

    from tlssim.tiled import (LOADED_BYTES_PER_PULSE, add_tile, earlier_import, import_tile_cols, open_tiled,
                              start_tiled)

    outdir = Path(outdir)
    _check_header(path)
    fingerprint, earlier, done = earlier_import(path, outdir)
    if done:
        return earlier
    try:
        reader = laspy.open(str(path))
    except Exception as exc:  # laspy raises LaspyException, ValueError, OSError...
        raise ScanError(f"{path}: not a readable LAS/LAZ file ({exc})") from None
    with reader:
        grid = _metadata(path, reader.header)
        rows, cols = grid["rows"], grid["cols"]
        tile_cols = import_tile_cols(tile_cols, earlier, rows, cols, budget_bytes, LOADED_BYTES_PER_PULSE)
        header = {"shape": [rows, cols], "scanner": grid["scanner"].to_dict(),
                  "scanner_position": np.asarray(grid["pose"].position, float).tolist(),
                  "scanner_rotation": np.asarray(grid["pose"].rotation, float).tolist(),
                  "object_names": grid["object_names"], "theta_columns": grid["theta_columns"].tolist(),
                  "psi_rows": grid["psi_rows"].tolist(), "has_truth": grid["has_truth"], "meta": grid["meta"]}
        index, todo = start_tiled(outdir, header, fingerprint, tile_cols)
        tile_cols = int(index["tile_cols"])
        todo = set(todo)
        current, arrays = 0, None

        def finish(number: int) -> None:
            c0 = number * tile_cols
            c1 = min(cols, c0 + tile_cols)
            if (c0, c1) in todo:
                tile_arrays = arrays if arrays is not None else _empty_grid(_shifted(grid, c0), c1 - c0)
                add_tile(outdir, index, c0, _scan(grid, tile_arrays, dict(grid["meta"])))

        try:
            for points in reader.chunk_iterator(chunk_points):
                col = np.asarray(points["col"], np.int64)
                if len(col) and (col.min() < 0 or col.max() >= cols):
                    raise ScanError(f"{path}: point grid positions lie outside the {rows} x {cols} grid")
                tile_of = col // tile_cols
                if len(tile_of) and (tile_of[0] < current or np.any(np.diff(tile_of) < 0)):
                    raise ScanError(f"{path}: the points are not in column order (as tlssim writes them); "
                                    "import the file whole (-o FILE.npz)")
                for number in np.unique(tile_of):
                    while current < number:
                        finish(current)
                        current, arrays = current + 1, None
                    c0 = int(number) * tile_cols
                    if (c0, min(cols, c0 + tile_cols)) in todo:
                        if arrays is None:
                            arrays = _empty_grid(_shifted(grid, c0), min(cols, c0 + tile_cols) - c0)
                        _place(path, grid, arrays, points[tile_of == number], c0)
        except ScanError:
            raise
        except Exception as exc:  # laspy raises LaspyException, ValueError, OSError...
            raise ScanError(f"{path}: malformed or truncated LAS/LAZ points ({exc})") from None
        while current * tile_cols < cols:
            finish(current)
            current, arrays = current + 1, None
    return open_tiled(outdir)


def _shifted(grid: dict, col0: int) -> dict:
    """``grid`` with its column azimuths starting at column ``col0``."""
    return {**grid, "theta_columns": grid["theta_columns"][col0:]}

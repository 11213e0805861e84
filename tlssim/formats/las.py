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
#: VLR that carries the scan's metadata as JSON.
VLR_USER_ID, VLR_RECORD_ID = "tlslab", 1
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
    header.vlrs.append(laspy.VLR(user_id=VLR_USER_ID, record_id=VLR_RECORD_ID, description="tlssim scan",
                                 record_data=json.dumps(meta).encode()))
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
    records = [v for v in points.header.vlrs if v.user_id == VLR_USER_ID and v.record_id == VLR_RECORD_ID]
    names = set(points.point_format.extra_dimension_names)
    if not records or not {n for n, _ in _GRID_DIMS} <= names:
        raise ScanError(f"{path}: LAS/LAZ without tlssim grid metadata (only files written by tlssim can be "
                        "imported as scans; point clouds have no scan grid)")
    try:
        meta = json.loads(records[0].record_data)
        rows, cols = meta["shape"]
        pose = ScannerPose(meta["scanner_position"], meta["scanner_rotation"])
        theta = np.broadcast_to(np.asarray(meta["theta_columns"], float)[None, :], (rows, cols)).copy()
        psi = np.broadcast_to(np.asarray(meta["psi_rows"], float)[:, None], (rows, cols)).copy()
        scan_meta = dict(meta.get("meta") or {})
        if "scanner" in meta:
            scanner = ScannerDescription.from_dict(meta["scanner"])
        else:  # files written before the description: the model's parameters, the window in the scan's meta
            scanner = ScannerDescription.from_dict({"model": meta.get("scanner_model"),
                                                    "window": scan_meta.pop("window", None)})
    except (KeyError, TypeError, ValueError, json.JSONDecodeError) as exc:
        raise ScanError(f"{path}: malformed tlssim metadata in the LAS/LAZ file ({exc!r})") from None
    row, col = np.asarray(points["row"], np.int64), np.asarray(points["col"], np.int64)
    if len(row) and (row.min() < 0 or col.min() < 0 or row.max() >= rows or col.max() >= cols):
        raise ScanError(f"{path}: point grid positions lie outside the {rows} x {cols} grid")
    theta[row, col], psi[row, col] = points["theta"], points["psi"]
    xyz = np.full((rows, cols, 3), np.nan)
    xyz[row, col] = np.stack([points.x, points.y, points.z], axis=1)
    intensity = np.full((rows, cols), np.nan, np.float32)
    intensity[row, col] = points.intensity
    truth = {}
    if {n for n, _ in _TRUTH_DIMS} <= names:
        for key, fill, dtype in (("truth_range", np.nan, np.float64), ("truth_id", -1, np.int32),
                                 ("mixed_fraction", np.nan, np.float32), ("incidence", np.nan, np.float32)):
            truth[key] = np.full((rows, cols), fill, dtype)
            truth[key][row, col] = points[key]
        truth["truth_normal"] = np.full((rows, cols, 3), np.nan, np.float32)
        truth["truth_normal"][row, col] = np.stack([points[f"truth_normal_{a}"] for a in "xyz"], axis=1)
    range_m = np.linalg.norm(xyz - pose.position, axis=-1)
    return Scan(range=range_m, intensity=intensity, theta=theta, psi=psi, xyz=xyz, pose=pose,
                scanner=scanner, object_names=meta.get("object_names"),
                meta={**scan_meta, "source": str(path), "format": "las"}, **truth)

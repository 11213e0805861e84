"""Point clouds as they come: the points of any supported file, with what the file says about how they were seen.

Unlike :func:`tlssim.formats.import_scan`, which needs a scan grid, this
reads every format as a plain cloud (format by extension):

- ``.npz``: a scan written by :meth:`tlssim.Scan.save` (its returned points,
  the scanner position and, for simulated scans, the truth normals) or an
  archive with ``points`` (n, 3) and optional ``normals`` (n, 3) and
  ``scanner_position`` ((3,) or (n, 3));
- ``.ply``: binary or ASCII, the vertex element's ``x, y, z`` and optional
  ``nx, ny, nz``;
- ``.las``, ``.laz``: any LAS/LAZ file (scaled x, y, z); files written by
  tlssim also give their scanner position and truth normals;
- ``.e57``: every scan of the file, structured or not, cartesian or
  spherical, in world coordinates, each point with its scan's position;
- ``.ptx``: the returned points and the scanner position;
- ``.xyz``, ``.txt``, ``.csv``, ``.pts``, ``.asc``: ASCII columns separated
  by spaces, tabs, commas or semicolons, ``x y z`` first; an optional header
  line names the columns (``nx ny nz`` are then read as normals); a ``.pts``
  file's first line may be the point count.

Unreadable, truncated or malformed files raise
:class:`~tlssim.errors.ScanError` naming the file and the problem.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tlssim.errors import ScanError

#: Extensions of ASCII column files.
ASCII_SUFFIXES = (".xyz", ".txt", ".csv", ".pts", ".asc")


@dataclass
class PointCloud:
    """Points with what the file says about how they were seen.

    Attributes
    ----------
    points : ndarray, (n, 3), float64
        Coordinates, m.
    viewpoints : ndarray, (n, 3) or (3,), or None
        Position of the scanner that measured each point (or of the one
        scanner), m; ``None`` when the file does not say.
    normals : ndarray, (n, 3), or None
        Normals given in the file (not necessarily unit), ``None`` if none.
    """

    points: np.ndarray
    viewpoints: np.ndarray | None = None
    normals: np.ndarray | None = None


def read_points(path) -> PointCloud:
    """Read the points of a point-cloud or scan file (format by extension, see the module).

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    PointCloud

    Raises
    ------
    ScanError
        If the file is missing, of an unknown format, or cannot be read.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    readers = {".npz": _read_npz, ".ply": _read_ply, ".las": _read_las, ".laz": _read_las, ".e57": _read_e57,
               ".ptx": _read_ptx, **{s: _read_ascii for s in ASCII_SUFFIXES}}
    if suffix not in readers:
        raise ScanError(f"{path}: unknown point-cloud format {path.suffix!r}; supported: {', '.join(readers)}")
    if not path.is_file():
        raise ScanError(f"{path}: no such point-cloud file")
    return readers[suffix](path)


def _read_npz(path: Path) -> PointCloud:
    from tlssim.scan import Scan

    try:
        with np.load(path, allow_pickle=False) as data:
            names = set(data.files)
            if not ({"range", "xyz"} <= names):
                if "points" not in names:
                    raise ScanError(f"{path}: NPZ holds neither a tlssim scan (range, xyz) nor a 'points' array; "
                                    f"found {sorted(names)}")
                return PointCloud(np.asarray(data["points"]), _optional(data, "scanner_position"),
                                  _optional(data, "normals"))
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
        raise ScanError(f"{path}: not a readable NPZ archive ({exc})") from None
    scan = Scan.load(path)
    normals = None if scan.truth_normal is None else scan.truth_normal[scan.valid]
    if normals is not None and not np.isfinite(normals).all():
        normals = None
    return PointCloud(scan.points(), scan.pose.position, normals)


def _optional(data, key: str):
    return np.asarray(data[key]) if key in data.files else None


def _read_ply(path: Path) -> PointCloud:
    import trimesh

    try:
        with open(path, "rb") as handle:
            loaded = trimesh.exchange.ply.load_ply(handle)
        vertex = loaded["metadata"]["_ply_raw"]["vertex"]["data"]
        names = set(vertex.dtype.names or ()) if hasattr(vertex, "dtype") else set(vertex)

        def column(name):
            return np.asarray(vertex[name], dtype=float).reshape(-1)

        points = np.column_stack([column(a) for a in "xyz"])
        normals = np.column_stack([column(a) for a in ("nx", "ny", "nz")]) if {"nx", "ny", "nz"} <= names else None
    except Exception as exc:  # trimesh raises KeyError, ValueError, IndexError... on damaged files
        raise ScanError(f"{path}: not a readable PLY point cloud with x, y, z vertex properties "
                        f"({type(exc).__name__}: {exc})") from None
    return PointCloud(points, None, normals)


def _read_las(path: Path) -> PointCloud:
    import laspy

    from tlssim.formats.las import _check_header, metadata_json, metadata_records

    _check_header(path)
    try:
        las = laspy.read(str(path))
        points = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)]).astype(float)
        extra = set(las.point_format.extra_dimension_names)
        normals = np.column_stack([np.asarray(las[f"truth_normal_{a}"], float) for a in "xyz"]) \
            if {f"truth_normal_{a}" for a in "xyz"} <= extra else None
        records = metadata_records(las.header.vlrs)
    except Exception as exc:  # laspy raises LaspyException, ValueError, OSError...
        raise ScanError(f"{path}: not a readable LAS/LAZ file ({exc})") from None
    viewpoint = None
    if records:
        try:
            meta = metadata_json(records)
            viewpoint = np.asarray(meta["scanner_position"], float)
        except (KeyError, TypeError, ValueError):
            viewpoint = None
    if normals is not None and not np.isfinite(normals).all():
        normals = None
    return PointCloud(points, viewpoint, normals)


def _read_e57(path: Path) -> PointCloud:
    from scipy.spatial.transform import Rotation

    from tlssim.formats.e57 import _coordinates, opened

    points, viewpoints = [], []
    with opened(path, "file") as e57:
        for index in range(e57.scan_count):
            header = e57.get_header(index)
            data = e57.read_scan_raw(index, ignore_unsupported_fields=True)
            local, invalid = _coordinates(path, data)
            local = local[invalid == 0]
            rotation = Rotation.from_quat(np.roll(np.asarray(header.rotation, float), -1)).as_matrix()
            translation = np.asarray(header.translation, float)
            points.append(local @ rotation.T + translation)
            viewpoints.append(np.broadcast_to(translation, local.shape))
    if not points:
        raise ScanError(f"{path}: the E57 file holds no scan")
    return PointCloud(np.concatenate(points), np.concatenate(viewpoints))


def _read_ptx(path: Path) -> PointCloud:
    from tlssim.formats import ptx

    scan = ptx.read(path)
    return PointCloud(scan.points(), scan.pose.position)


def _read_ascii(path: Path) -> PointCloud:
    try:
        lines = path.read_text(encoding="utf-8", errors="strict").splitlines()
    except (UnicodeDecodeError, OSError) as exc:
        raise ScanError(f"{path}: not a readable ASCII point file ({exc})") from None
    rows = [line.replace(",", " ").replace(";", " ").split() for line in lines]
    rows = [r for r, line in zip(rows, lines) if r and not line.lstrip().startswith(("#", "//"))]
    names = None
    if rows and not _numeric(rows[0]):
        names = [n.lower().lstrip("/").strip("\"'") for n in rows[0]]
        rows = rows[1:]
    elif rows and len(rows[0]) == 1 and path.suffix.lower() == ".pts":
        rows = rows[1:]  # the point count
    if not rows:
        raise ScanError(f"{path}: the ASCII point file holds no points")
    width = len(rows[0])
    if width < 3:
        raise ScanError(f"{path}: the ASCII point file needs at least three columns (x y z), found {width}")
    bad = next((i for i, r in enumerate(rows) if len(r) != width or not _numeric(r)), None)
    if bad is not None:
        raise ScanError(f"{path}: line {bad + 1 + (names is not None)} of the point data is not {width} numbers: "
                        f"{' '.join(rows[bad])[:80]!r}")
    table = np.array(rows, dtype=float)
    xyz = [names.index(a) for a in "xyz"] if names and set("xyz") <= set(names) else [0, 1, 2]
    normals = None
    if names and {"nx", "ny", "nz"} <= set(names):
        normals = table[:, [names.index(a) for a in ("nx", "ny", "nz")]]
    return PointCloud(table[:, xyz], None, normals)


def _numeric(row: list[str]) -> bool:
    try:
        [float(v) for v in row]
    except ValueError:
        return False
    return True

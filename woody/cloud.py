"""Point clouds for woody: validation and readers for NPZ, PLY, LAS and E57 files.

A :class:`Cloud` holds the points and, where the file says so, the position
of the scanner that saw each point (used to orient normals) and given
normals. Readers choose the format by file extension:

- ``.npz``: either a scan written by :meth:`tlssim.Scan.save` (its valid
  ``xyz``, the scanner position, and the truth normals as ``normals`` when the
  scan is simulated), or a plain archive with ``points`` (n, 3) and optional
  ``normals`` (n, 3) and ``scanner_position`` ((3,) or (n, 3));
- ``.ply``: binary or ASCII vertex element with ``x, y, z`` and optional
  ``nx, ny, nz``;
- ``.las`` (and ``.laz`` when a LAZ backend is installed): scaled x, y, z;
- ``.e57``: every scan of the file in world coordinates, each point with the
  position of its own scan.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from woody.errors import WoodyError


@dataclass
class Cloud:
    """Points with what is known about how they were seen.

    Attributes
    ----------
    points : ndarray, (n, 3), float64
        Coordinates, m.
    viewpoints : ndarray, (n, 3), float64, or None
        Position of the scanner that measured each point, m; ``None`` when
        unknown.
    normals : ndarray, (n, 3), float64, or None
        Unit normals given with the cloud (e.g. a simulated scan's truth
        normals); ``None`` when the file has none.
    """

    points: np.ndarray
    viewpoints: np.ndarray | None = None
    normals: np.ndarray | None = None


def check_points(points, name: str = "points") -> np.ndarray:
    """Validate a point array and return it as ``(n, 3)`` float64.

    Raises
    ------
    WoodyError
        If the array is not ``(n, 3)``, is empty, or holds NaN or infinite values.
    """
    try:
        array = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        raise WoodyError(f"{name} must be a numeric (n, 3) array") from None
    if array.ndim != 2 or array.shape[1] != 3:
        raise WoodyError(f"{name} must be an (n, 3) array of x, y, z in metres, got shape {array.shape}")
    if len(array) == 0:
        raise WoodyError(f"{name} is empty: at least one point is needed")
    bad = ~np.isfinite(array).all(axis=1)
    if bad.any():
        raise WoodyError(f"{name} holds {int(bad.sum())} point(s) with NaN or infinite coordinates "
                         f"(first at index {int(np.argmax(bad))}); drop them first")
    return array


def check_normals(normals, count: int) -> np.ndarray:
    """Validate normals for ``count`` points and return them as unit ``(n, 3)`` float64.

    Raises
    ------
    WoodyError
        If the shape does not match, or a normal is NaN, infinite or zero.
    """
    array = check_points(normals, "normals")
    if len(array) != count:
        raise WoodyError(f"normals has {len(array)} rows but there are {count} points")
    length = np.linalg.norm(array, axis=1)
    if (length < 1e-12).any():
        raise WoodyError(f"normals holds {int((length < 1e-12).sum())} zero vector(s)")
    return array / length[:, None]


def check_viewpoints(viewpoints, count: int) -> np.ndarray | None:
    """Scanner positions as ``(n, 3)`` float64 (a single ``(3,)`` position is broadcast), or ``None``."""
    if viewpoints is None:
        return None
    array = np.asarray(viewpoints, dtype=float)
    if array.shape == (3,):
        array = np.broadcast_to(array, (count, 3))
    if array.shape != (count, 3) or not np.isfinite(array).all():
        raise WoodyError(f"scanner_position must be a finite (3,) or ({count}, 3) array, got shape {array.shape}")
    return np.ascontiguousarray(array)


def read_cloud(path) -> Cloud:
    """Read a point cloud file (format by extension: .npz, .ply, .las, .laz, .e57).

    Raises
    ------
    WoodyError
        If the file is missing, has an unknown extension, or cannot be read
        (the message names the file and the problem).
    """
    path = Path(path)
    if not path.is_file():
        raise WoodyError(f"{path}: no such point-cloud file")
    readers = {".npz": _read_npz, ".ply": _read_ply, ".las": _read_las, ".laz": _read_las, ".e57": _read_e57}
    reader = readers.get(path.suffix.lower())
    if reader is None:
        raise WoodyError(f"{path}: unknown point-cloud format {path.suffix!r}; allowed: {', '.join(readers)}")
    cloud = reader(path)
    try:
        points = check_points(cloud.points)
        return Cloud(points, check_viewpoints(cloud.viewpoints, len(points)),
                     None if cloud.normals is None else check_normals(cloud.normals, len(points)))
    except WoodyError as exc:
        raise WoodyError(f"{path}: {exc}") from None


def _read_npz(path: Path) -> Cloud:
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
        raise WoodyError(f"{path}: not a readable NPZ archive ({exc})") from None
    if "range" in arrays and "xyz" in arrays:
        from tlssim.scan import Scan
        from tlssim.errors import ScanError

        try:
            scan = Scan.load(path)
        except ScanError as exc:
            raise WoodyError(str(exc)) from None
        valid = scan.valid
        normals = None if scan.truth_normal is None else scan.truth_normal[valid]
        if normals is not None and not np.isfinite(normals).all():
            normals = None
        return Cloud(scan.points(), scan.pose.position, normals)
    if "points" not in arrays:
        raise WoodyError(f"{path}: NPZ holds neither a tlssim scan (range, xyz) nor a 'points' array; "
                         f"found {sorted(arrays)}")
    return Cloud(arrays["points"], arrays.get("scanner_position"), arrays.get("normals"))


def _read_ply(path: Path) -> Cloud:
    import trimesh

    try:
        with open(path, "rb") as handle:
            loaded = trimesh.exchange.ply.load_ply(handle)
        vertex = loaded["metadata"]["_ply_raw"]["vertex"]["data"]
        points = np.column_stack([vertex[axis] for axis in "xyz"]).astype(float)
    except (KeyError, ValueError, IndexError, TypeError) as exc:
        raise WoodyError(f"{path}: not a readable PLY point cloud with x, y, z vertex properties ({exc!r})") from None
    names = vertex.dtype.names
    normals = np.column_stack([vertex[a] for a in ("nx", "ny", "nz")]).astype(float) \
        if {"nx", "ny", "nz"} <= set(names) else None
    return Cloud(points, None, normals)


def _read_las(path: Path) -> Cloud:
    import laspy

    try:
        las = laspy.read(path)
    except (laspy.errors.LaspyException, OSError, ValueError) as exc:
        raise WoodyError(f"{path}: not a readable LAS/LAZ file ({exc})") from None
    return Cloud(np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)]))


def _read_e57(path: Path) -> Cloud:
    import pye57

    points, viewpoints = [], []
    try:
        e57 = pye57.E57(str(path))
        try:
            for index in range(e57.scan_count):
                data = e57.read_scan(index, ignore_missing_fields=True)
                xyz = np.column_stack([data["cartesianX"], data["cartesianY"], data["cartesianZ"]])
                points.append(xyz)
                viewpoints.append(np.broadcast_to(e57.scan_position(index).reshape(3), xyz.shape))
        finally:
            e57.close()
    except Exception as exc:  # libE57 raises its own exception types for malformed files
        raise WoodyError(f"{path}: not a readable E57 file ({exc})") from None
    if not points:
        raise WoodyError(f"{path}: the E57 file holds no scan")
    return Cloud(np.concatenate(points), np.concatenate(viewpoints))

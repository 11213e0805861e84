"""PTX (Leica ASCII grid) export and import.

Layout: the number of columns, the number of rows, the scanner position, its
three axes (one per line), the 4 x 4 transformation matrix (row-vector
convention: three lines of ``axis 0`` and a line ``position 1``), then one
``x y z intensity`` line per cell, column by column, in the scanner frame.
Intensity is normalised to [0, 1] by the scanner's largest digital number; a
cell without a return is ``0 0 0 0``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tlssim.errors import ScanError
from tlssim.formats.grid import angles_of, complete_angles, local_points, scan_from_local
from tlssim.pattern import ScannerPose
from tlssim.scan import Scan
from tlssim.tiled import TiledScan, scan_tiles

HEADER_LINES = 10


def write(scan: Scan | TiledScan, path: Path) -> None:
    """Write the grid as PTX (coordinates to 1 µm, intensity to 1e-6 of the full scale), tile by tile.

    PTX lists the grid column by column, so a :class:`~tlssim.tiled.TiledScan`
    is streamed one tile in memory at a time, with the bytes of the scan in memory.

    Parameters
    ----------
    scan : Scan or TiledScan
        The scan to write; coordinates in m, intensity in DN.
    path : Path
        Output ``.ptx`` file.
    """
    rows, cols = scan.shape
    full_scale = float(scan.scanner.assumed_model.intensity_max_dn)
    rotation, position = scan.pose.rotation, scan.pose.position
    header = [f"{cols}", f"{rows}", _row(position)] + [_row(rotation[:, i]) for i in range(3)]
    header += [_row(np.append(rotation[:, i], 0.0)) for i in range(3)] + [_row(np.append(position, 1.0))]
    with open(path, "w") as handle:
        handle.write("\n".join(header) + "\n")
        for _, tile in scan_tiles(scan):
            local = np.where(tile.valid[..., None], local_points(tile), 0.0)
            intensity = np.where(tile.valid, tile.intensity / full_scale, 0.0)
            table = np.concatenate([local, intensity[..., None]], axis=-1).transpose(1, 0, 2).reshape(-1, 4)
            np.savetxt(handle, table, fmt="%.6f")


def read(path: Path, intensity_max_dn: float = 2047.0) -> Scan:
    """Read the first scan of a PTX file as a truth-less :class:`Scan`.

    Intensity is scaled from [0, 1] to ``0..intensity_max_dn``; points at the
    origin are cells without a return. Extra columns (colour) are ignored.

    Parameters
    ----------
    path : Path
        Input ``.ptx`` file.
    intensity_max_dn : float
        Full scale that the [0, 1] intensities are scaled to, DN.

    Returns
    -------
    Scan
        The scan (range in m, angles in rad, intensity in DN), without truth.
    """
    with open(path, "rb") as handle:
        try:
            header = [next(handle).decode("ascii").split() for _ in range(HEADER_LINES)]
        except StopIteration:
            raise ScanError(f"{path}: truncated PTX header (expected {HEADER_LINES} lines)") from None
        except UnicodeDecodeError:
            raise ScanError(f"{path}: not a PTX file (the header is not ASCII text)") from None
        cols, rows = _count(path, header[0], "columns"), _count(path, header[1], "rows")
        matrix = np.array([_numbers(path, line, 4, HEADER_LINES - 3 + i) for i, line in enumerate(header[6:])])
        try:
            table = np.loadtxt(handle, max_rows=rows * cols, ndmin=2, usecols=(0, 1, 2, 3))
        except ValueError as exc:
            raise ScanError(f"{path}: malformed PTX point line ({exc})") from None
    if len(table) != rows * cols:
        raise ScanError(f"{path}: truncated PTX file: {rows} x {cols} = {rows * cols} points expected, "
                        f"{len(table)} found")
    try:
        pose = ScannerPose(matrix[3, :3], matrix[:3, :3].T)
    except ScanError as exc:
        raise ScanError(f"{path}: invalid PTX transformation matrix ({exc})") from None
    grid = table.reshape(cols, rows, 4).transpose(1, 0, 2)
    local = grid[..., :3]
    valid = np.any(local != 0.0, axis=-1)
    theta, psi = angles_of(np.where(valid[..., None], local, np.nan))
    theta, psi = complete_angles(theta, psi)
    return scan_from_local(local, valid, grid[..., 3] * intensity_max_dn, pose, theta, psi,
                           {"source": str(path), "format": "ptx"})


def _row(values) -> str:
    return " ".join(f"{v:.15g}" for v in values)


def _count(path: Path, line: list[str], what: str) -> int:
    try:
        (value,) = line
        count = int(value)
    except ValueError:
        raise ScanError(f"{path}: PTX header must start with the number of columns and rows, got {line!r}") from None
    if count < 1:
        raise ScanError(f"{path}: the PTX number of {what} must be positive, got {count}")
    return count


def _numbers(path: Path, line: list[str], count: int, number: int) -> list[float]:
    try:
        values = [float(v) for v in line]
    except ValueError:
        values = []
    if len(values) != count:
        raise ScanError(f"{path}: PTX header line {number} must hold {count} numbers, got {' '.join(line)!r}")
    return values

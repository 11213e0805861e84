"""PTX (Leica ASCII grid) export and import.

Layout: the number of columns, the number of rows, the scanner position, its
three axes (one per line), the 4 x 4 transformation matrix (row-vector
convention: three lines of ``axis 0`` and a line ``position 1``), then one
``x y z intensity`` line per cell, column by column, in the scanner frame.
Intensity is normalised to [0, 1] by the scanner's largest digital number; a
cell without a return is ``0 0 0 0``.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from pathlib import Path

import numpy as np

from tlssim.errors import ScanError
from tlssim.formats.grid import (angles_of, complete_angles, fill_line, local_points, scan_from_local,
                                 streamed_median, unwrap_columns)
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
        cols, rows, matrix = _header(path, handle)
        try:
            table = np.loadtxt(handle, max_rows=rows * cols, ndmin=2, usecols=(0, 1, 2, 3))
        except ValueError as exc:
            raise ScanError(f"{path}: malformed PTX point line ({exc})") from None
    _check_count(path, rows, cols, len(table))
    pose = _pose(path, matrix)
    grid = table.reshape(cols, rows, 4).transpose(1, 0, 2)
    local = grid[..., :3]
    valid = np.any(local != 0.0, axis=-1)
    theta, psi = angles_of(np.where(valid[..., None], local, np.nan))
    theta, psi = complete_angles(theta, psi)
    return scan_from_local(local, valid, grid[..., 3] * intensity_max_dn, pose, theta, psi,
                           {"source": str(path), "format": "ptx"})


def _header(path: Path, handle) -> tuple[int, int, np.ndarray]:
    """Read the header of a PTX file open in binary mode: columns, rows and the 4 x 4 transformation matrix."""
    try:
        header = [next(handle).decode("ascii").split() for _ in range(HEADER_LINES)]
    except StopIteration:
        raise ScanError(f"{path}: truncated PTX header (expected {HEADER_LINES} lines)") from None
    except UnicodeDecodeError:
        raise ScanError(f"{path}: not a PTX file (the header is not ASCII text)") from None
    cols, rows = _count(path, header[0], "columns"), _count(path, header[1], "rows")
    matrix = np.array([_numbers(path, line, 4, HEADER_LINES - 3 + i) for i, line in enumerate(header[6:])])
    return cols, rows, matrix


def _check_count(path: Path, rows: int, cols: int, found: int) -> None:
    if found != rows * cols:
        raise ScanError(f"{path}: truncated PTX file: {rows} x {cols} = {rows * cols} points expected, "
                        f"{found} found")


def _pose(path: Path, matrix: np.ndarray) -> ScannerPose:
    try:
        return ScannerPose(matrix[3, :3], matrix[:3, :3].T)
    except ScanError as exc:
        raise ScanError(f"{path}: invalid PTX transformation matrix ({exc})") from None


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


#: Point lines parsed per block of a streamed import.
BLOCK_LINES = 1 << 18
#: Cells of the on-disk zenith grid read at once (a band of whole rows) by a streamed import.
_BAND_CELLS = 1 << 20


def read_tiled(path: Path, outdir, tile_cols: int | None = None, budget_bytes: int = 2 * 1024**3,
               block_lines: int = BLOCK_LINES, intensity_max_dn: float = 2047.0) -> TiledScan:
    """Stream the first scan of a PTX file into a tiled scan directory (:mod:`tlssim.tiled`).

    The point lines are parsed ``block_lines`` at a time into an on-disk
    table beside ``outdir`` (removed at the end); the tiles of whole columns
    are then cut from it. The grid-wide steps of :func:`read` (the median
    azimuth that stands in for cells without a return while the rows are
    unwrapped, each row's median zenith, the straight-line fill of empty
    rows and columns) are done in passes over that table with one tile or
    one band of about a million cells in memory, so the tiles hold the bytes of :func:`read`
    on the same file whatever the tile size. An interrupted import resumes
    with the tiles that check.

    Parameters
    ----------
    path : Path
        Input ``.ptx`` file.
    outdir : str or Path
        Output directory of the tiled scan.
    tile_cols : int, optional
        Columns per tile (default: from ``budget_bytes``).
    budget_bytes : int
        Memory for one tile when ``tile_cols`` is not given, bytes (about 150 bytes per pulse).
    block_lines : int
        Point lines parsed at once.
    intensity_max_dn : float
        Full scale that the [0, 1] intensities are scaled to, DN.

    Returns
    -------
    TiledScan
        The imported scan, opened lazily, without truth.
    """
    import shutil

    from tlssim.tiled import earlier_import, import_tile_cols

    outdir = Path(outdir)
    fingerprint, earlier, done = earlier_import(path, outdir)
    if done:
        return earlier
    scratch = outdir.parent / f".{outdir.name}.import-grids"
    scratch.mkdir(parents=True, exist_ok=True)
    try:
        with open(path, "rb") as handle:
            cols, rows, matrix = _header(path, handle)
            _parse_table(path, handle, rows, cols, scratch / "table.f8", block_lines)
        pose = _pose(path, matrix)
        tile_cols = import_tile_cols(tile_cols, earlier, rows, cols, budget_bytes, 150)
        table = _Table(scratch / "table.f8", rows, cols, tile_cols)
        median = streamed_median(lambda: (theta[np.isfinite(theta)] for *_, theta, _ in _tiles(table, None)))
        median = 0.0 if np.isnan(median) else median  # no return at all: as read's unwrapping
        fill = _fill_values(table, median, scratch / "psi.f8")
        return _write_tiles(table, outdir, pose, median, fill, fingerprint, intensity_max_dn,
                            {"source": str(path), "format": "ptx"})
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _parse_table(path: Path, handle, rows: int, cols: int, table: Path, block_lines: int) -> None:
    """Parse the ``rows * cols`` point lines (``x y z intensity``) into a raw float64 file, a block at a time."""
    import itertools

    count, done = rows * cols, 0
    with open(table, "wb") as out:
        while done < count:
            lines = list(itertools.islice(handle, min(block_lines, count - done)))
            if not lines:
                break
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", UserWarning)  # a block of empty lines
                    block = np.loadtxt(lines, ndmin=2, usecols=(0, 1, 2, 3))
            except ValueError as exc:
                raise ScanError(f"{path}: malformed PTX point line ({exc})") from None
            out.write(np.ascontiguousarray(block, dtype=np.float64).tobytes())
            done += len(block)
    _check_count(path, rows, cols, done)


@dataclasses.dataclass(frozen=True)
class _Table:
    """The parsed point table on disk (PTX order: column by column) and the tiling of its columns."""

    file: Path
    rows: int
    cols: int
    tile_cols: int

    def read(self, c0: int, c1: int) -> np.ndarray:
        """Columns ``c0:c1`` as a ``(rows, c1 - c0, 4)`` grid of ``x y z intensity``."""
        count = (c1 - c0) * self.rows * 4
        block = np.fromfile(self.file, np.float64, count, offset=c0 * self.rows * 32)
        return block.reshape(c1 - c0, self.rows, 4).transpose(1, 0, 2)


def _tiles(table: _Table, median: float | None):
    """Yield ``(c0, c1, grid, valid, theta, psi)`` per tile, as :func:`read` computes them before the fill.

    ``theta`` is the raw azimuth when ``median`` is None, otherwise the
    azimuth unwrapped along the rows with ``median`` standing in for the
    cells without a return (NaN there), carried across the tiles.
    """
    carry = None
    for c0 in range(0, table.cols, table.tile_cols):
        c1 = min(table.cols, c0 + table.tile_cols)
        grid = table.read(c0, c1)
        valid = np.any(grid[..., :3] != 0.0, axis=-1)
        local = np.where(valid[..., None], grid[..., :3], np.nan)
        theta = np.arctan2(local[..., 1], local[..., 0])
        psi = np.arccos(np.clip(local[..., 2] / np.linalg.norm(local, axis=-1), -1.0, 1.0))
        if median is not None:
            missing = np.isnan(theta)
            theta, carry = unwrap_columns(np.where(missing, median, theta), carry)
            theta = np.where(missing, np.nan, theta)
        yield c0, c1, grid, valid, theta, psi


def _fill_values(table: _Table, median: float, psi_file: Path) -> dict:
    """The grid-wide values of :func:`~tlssim.formats.grid.complete_angles` and the index's axes, in passes.

    Returns a dict of ``column_theta`` and ``row_psi`` (the fill of cells
    without a direction, rad), ``theta_columns`` and ``psi_rows`` (median
    azimuth of every filled column and zenith of every filled row, rad).
    """
    rows, cols = table.rows, table.cols
    column_median, theta_columns = np.empty(cols), np.empty(cols)
    with open(psi_file, "wb") as handle:  # the zeniths, row by row (file reads and writes: no mapped pages)
        handle.truncate(rows * cols * 8)
    with np.errstate(all="ignore"), warnings.catch_warnings(), open(psi_file, "r+b") as handle:
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns or rows
        for c0, c1, _, _, theta, psi in _tiles(table, median):
            column_median[c0:c1] = np.nanmedian(theta, axis=0)
            theta_columns[c0:c1] = np.median(np.where(np.isnan(theta), column_median[None, c0:c1], theta), axis=0)
            for row in range(rows):
                os.pwrite(handle.fileno(), psi[row].tobytes(), (row * cols + c0) * 8)
        row_median, psi_rows = np.empty(rows), np.empty(rows)
        band_rows = max(1, _BAND_CELLS // cols)
        for r0 in range(0, rows, band_rows):
            band_slice = slice(r0, r0 + band_rows)
            count = min(rows, r0 + band_rows) - r0
            band = np.fromfile(psi_file, np.float64, count * cols, offset=r0 * cols * 8).reshape(count, cols)
            row_median[band_slice] = np.nanmedian(band, axis=1)
            filled = np.where(np.isnan(band), row_median[band_slice, None], band)
            psi_rows[band_slice] = np.median(filled, axis=1)
    column_theta, row_psi = fill_line(column_median), fill_line(row_median)
    # an empty column or row takes its fitted value everywhere: that is its median
    theta_columns = np.where(np.isnan(column_median), column_theta, theta_columns)
    psi_rows = np.where(np.isnan(row_median), row_psi, psi_rows)
    return {"column_theta": column_theta, "row_psi": row_psi, "theta_columns": theta_columns, "psi_rows": psi_rows}


def _write_tiles(table: _Table, outdir: Path, pose: ScannerPose, median: float, fill: dict, fingerprint: str,
                 intensity_max_dn: float, meta: dict) -> TiledScan:
    """Write the tiles not yet written (:func:`tlssim.tiled.start_tiled`), filled as :func:`read` fills them."""
    from tlssim.scan import ScannerDescription
    from tlssim.tiled import add_tile, open_tiled, start_tiled

    header = {"shape": [table.rows, table.cols], "scanner": ScannerDescription().to_dict(),
              "scanner_position": np.asarray(pose.position, float).tolist(),
              "scanner_rotation": np.asarray(pose.rotation, float).tolist(), "object_names": None,
              "theta_columns": fill["theta_columns"].tolist(), "psi_rows": fill["psi_rows"].tolist(),
              "has_truth": False, "meta": meta}
    index, todo = start_tiled(outdir, header, fingerprint, table.tile_cols)
    for c0, c1, grid, valid, theta, psi in _tiles(table, median):
        if (c0, c1) in todo:
            theta = np.where(np.isnan(theta), fill["column_theta"][None, c0:c1], theta)
            psi = np.where(np.isnan(psi), fill["row_psi"][:, None], psi)
            tile = scan_from_local(grid[..., :3], valid, grid[..., 3] * intensity_max_dn, pose, theta, psi,
                                   dict(meta))
            add_tile(outdir, index, c0, tile)
    return open_tiled(outdir)

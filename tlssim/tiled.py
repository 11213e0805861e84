"""Tiled scans on disk: a scan larger than memory, stored and read tile by tile.

A tiled scan is a directory with one NPZ per tile of whole columns (each a
:class:`~tlssim.scan.Scan` file: ``Scan.load`` or ``numpy.load`` read it,
no pickle) and an ``index.json``:

- ``format`` ``"tlssim-tiled-scan"``, ``version`` 1;
- ``shape`` ``[rows, cols]`` of the whole grid, ``tile_cols`` (columns per
  tile; the last tile may be narrower), ``complete`` (every tile written);
- ``fingerprint``: SHA-256 of what the scan was made from (scene, scanner,
  pose, window, seed), so that a resumed write never mixes two scans;
- ``scanner`` (the :class:`~tlssim.scan.ScannerDescription`),
  ``scanner_position``, ``scanner_rotation``, ``object_names``, ``meta``,
  ``theta_columns`` and ``psi_rows`` (the grid's axes, rad);
- ``tiles``: per finished tile ``file``, ``col0``, ``col1``, ``bytes`` and
  ``sha256`` of the file, so that a resumed write keeps only tiles that check.

Tiles are cut along the azimuth (columns): the scanner records column by
column, the detector's range filter runs along the zenith within a column,
and the simulator draws every column's noise from its own stream, so a tile
holds exactly the bytes of those columns of the whole scan.

:func:`open_tiled` gives a lazy :class:`TiledScan` (iterate tiles, load a
window of columns, iterate overlapping windows); :func:`scan_tiles` lets
exporters treat an in-memory :class:`Scan` and a tiled one alike.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from tlssim.errors import ScanError
from tlssim.pattern import ScannerPose
from tlssim.scan import GRID_KEYS, TRUTH_KEYS, Scan, ScannerDescription, partial_path

FORMAT = "tlssim-tiled-scan"
VERSION = 1
INDEX = "index.json"
#: Memory of a loaded scan with truth, bytes per pulse (grid, points, truth and the two-object layers).
LOADED_BYTES_PER_PULSE = 100


@dataclasses.dataclass(frozen=True)
class TileEntry:
    """One finished tile: its file (relative to the scan directory), its columns and its checks."""

    file: str
    col0: int
    col1: int
    bytes: int
    sha256: str


class TiledScan:
    """A scan stored as tiles of whole columns, read lazily (:func:`open_tiled`).

    Attributes
    ----------
    path : Path
        The scan directory.
    shape : (int, int)
        Grid shape ``(rows, cols)`` of the whole scan.
    pose : ScannerPose
        Scanner position (m) and orientation.
    scanner : ScannerDescription
        Scanner model and window.
    object_names : list of str or None
        Names of the scene objects, indexed by ``truth_id``.
    meta : dict
        Metadata of the scan (scene, seed, backend...).
    theta_columns, psi_rows : ndarray
        Azimuth of every column and zenith of every row, rad.
    tiles : list of TileEntry
        The finished tiles, in column order.
    tile_cols : int
        Columns per tile.
    complete : bool
        Whether every column has been written.
    """

    def __init__(self, path: Path, index: dict):
        self.path = Path(path)
        self.index = index
        self.shape = tuple(int(n) for n in index["shape"])
        self.tile_cols = int(index["tile_cols"])
        self.pose = ScannerPose(index["scanner_position"], index["scanner_rotation"])
        self.scanner = ScannerDescription.from_dict(index["scanner"])
        self.object_names = index.get("object_names")
        self.meta = dict(index.get("meta") or {})
        self.theta_columns = np.asarray(index["theta_columns"], dtype=np.float64)
        self.psi_rows = np.asarray(index["psi_rows"], dtype=np.float64)
        self.tiles = [TileEntry(**t) for t in index["tiles"]]
        self.complete = bool(index.get("complete")) and _covered(self.tiles) == self.shape[1]
        self.has_truth = bool(index.get("has_truth"))

    def __repr__(self) -> str:
        return (f"TiledScan({str(self.path)!r}, shape={self.shape}, tiles={len(self.tiles)}, "
                f"complete={self.complete})")

    def _require_complete(self) -> None:
        if not self.complete:
            raise ScanError(f"{self.path}: the tiled scan is incomplete ({_covered(self.tiles)} of {self.shape[1]} "
                            "columns written); resume the scan first")

    def read_tile(self, tile: TileEntry) -> Scan:
        """Load one tile as a :class:`Scan` (its ``rows x (col1 - col0)`` pulses)."""
        return Scan.load(self.path / tile.file)

    def iter_tiles(self) -> Iterator[tuple[int, Scan]]:
        """Yield ``(col0, tile)`` for every tile in column order, one tile in memory at a time."""
        self._require_complete()
        for tile in self.tiles:
            yield tile.col0, self.read_tile(tile)

    def load_columns(self, col0: int, col1: int, rows: slice = slice(None)) -> Scan:
        """Load the columns ``col0:col1`` of the scan (reads only the tiles that overlap them).

        Parameters
        ----------
        col0, col1 : int
            First and past-the-last column, ``0 <= col0 < col1 <= cols``.
        rows : slice
            Rows to keep (default all): each tile is cut as it is read, so
            only the window's rows are held.

        Returns
        -------
        Scan
            The window; ``meta["columns"]`` is ``[col0, col1]``.
        """
        self._require_complete()
        if not 0 <= col0 < col1 <= self.shape[1]:
            raise ScanError(f"columns {col0}:{col1} outside the scan's 0:{self.shape[1]}")
        parts = []
        for tile in self.tiles:
            if tile.col1 > col0 and tile.col0 < col1:
                scan = self.read_tile(tile)
                parts.append(scan.crop(rows, slice(max(col0, tile.col0) - tile.col0, min(col1, tile.col1) - tile.col0)))
        window = concat_columns(parts)
        window.meta = {**self.meta, "columns": [int(col0), int(col1)]}
        return window

    def windows(self, width: int, overlap: int = 0) -> Iterator[tuple[int, Scan]]:
        """Yield ``(col0, window)`` over the whole scan in windows of ``width`` columns overlapping by ``overlap``.

        Consecutive windows share ``overlap`` columns, so an object cut by one
        window's border lies whole in the next one when it is at most
        ``overlap`` columns wide; a consumer keeps what it finds in a
        window's own part (e.g. objects whose first column lies before the
        next window's start).

        Parameters
        ----------
        width : int
            Columns per window, ``> overlap``.
        overlap : int
            Columns shared by consecutive windows, ``>= 0``.
        """
        if width <= overlap or overlap < 0:
            raise ScanError(f"windows need width > overlap >= 0, got width {width}, overlap {overlap}")
        cols = self.shape[1]
        col0 = 0
        while True:
            col1 = min(cols, col0 + width)
            yield col0, self.load_columns(col0, col1)
            if col1 == cols:
                return
            col0 = col1 - overlap

    def load(self) -> Scan:
        """The whole scan in memory.

        Raises
        ------
        ScanError
            If its arrays (about :data:`LOADED_BYTES_PER_PULSE` per pulse) exceed the available memory.
        """
        need, available = self.shape[0] * self.shape[1] * LOADED_BYTES_PER_PULSE, available_memory_bytes()
        if available is not None and need > available:
            raise ScanError(f"{self.path}: loading the whole {self.shape[0]} x {self.shape[1]} scan needs about "
                            f"{need / 1e9:.1f} GB, more than the {available / 1e9:.1f} GB available; read it tile by "
                            "tile (iter_tiles, windows) or export it to LAS/LAZ or PTX, which stream")
        window = self.load_columns(0, self.shape[1])
        window.meta = dict(self.meta)
        return window


def _covered(tiles: list[TileEntry]) -> int:
    """Columns covered without a gap from column 0 by ``tiles``."""
    end = 0
    for tile in sorted(tiles, key=lambda t: t.col0):
        if tile.col0 != end:
            break
        end = tile.col1
    return end


def concat_columns(parts: list[Scan]) -> Scan:
    """Join scans of the same rows side by side (left to right) into one scan.

    Parameters
    ----------
    parts : list of Scan
        Scans with the same rows, pose, scanner and layers, in column order.

    Returns
    -------
    Scan
        The joined scan (the first part's pose, scanner, names and meta).
    """
    if len(parts) == 1:
        return parts[0]
    first = parts[0]
    arrays = {key: np.concatenate([getattr(p, key) for p in parts], axis=1)
              for key in GRID_KEYS + TRUTH_KEYS if getattr(first, key) is not None}
    layers = {key: np.concatenate([p.layers[key] for p in parts], axis=1) for key in first.layers}
    return dataclasses.replace(first, **arrays, layers=layers, meta=dict(first.meta))


def open_tiled(path) -> TiledScan:
    """Open a tiled scan directory (reads only its index).

    Raises
    ------
    ScanError
        If the directory has no readable index of a tiled scan.
    """
    path = Path(path)
    index_path = path / INDEX
    if not index_path.is_file():
        raise ScanError(f"{path}: not a tiled scan (no {INDEX})")
    try:
        index = json.loads(index_path.read_text(encoding="utf-8"))
        if index.get("format") != FORMAT:
            raise ScanError(f"{index_path}: format {index.get('format')!r} is not {FORMAT!r}")
        if index.get("version") != VERSION:
            raise ScanError(f"{index_path}: version {index.get('version')!r} of the tiled scan format is not "
                            f"supported (only {VERSION})")
        return TiledScan(path, index)
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, ScanError):
            raise
        raise ScanError(f"{index_path}: malformed tiled-scan index ({exc!r})") from None


def open_scan(path) -> Scan | TiledScan:
    """A scan file (``.npz``, loaded) or a tiled scan directory (opened lazily)."""
    path = Path(path)
    return open_tiled(path) if path.is_dir() else Scan.load(path)


def scan_tiles(scan: Scan | TiledScan) -> Iterator[tuple[int, Scan]]:
    """Yield ``(col0, tile)``: the tiles of a tiled scan, or an in-memory scan as one tile at column 0."""
    if isinstance(scan, TiledScan):
        yield from scan.iter_tiles()
    else:
        yield 0, scan


def file_sha256(path: Path) -> str:
    """SHA-256 of a file's bytes, hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 22), b""):
            digest.update(block)
    return digest.hexdigest()


def file_fingerprint(path) -> str:
    """Identity of an input file for a resumed import: SHA-256 of its resolved path, size and modification time."""
    path = Path(path)
    stat = path.stat()
    return hashlib.sha256(json.dumps([str(path.resolve()), stat.st_size, stat.st_mtime_ns]).encode()).hexdigest()


def earlier_import(path, outdir) -> tuple[str, TiledScan | None, bool]:
    """What an earlier streamed import of ``path`` left in ``outdir``.

    Parameters
    ----------
    path : str or Path
        The input scan file.
    outdir : str or Path
        Output directory of the tiled scan.

    Returns
    -------
    fingerprint : str
        :func:`file_fingerprint` of ``path``.
    earlier : TiledScan or None
        The tiled scan in ``outdir`` (None if there is none).
    done : bool
        Whether ``earlier`` is complete and imported from this very file (nothing left to do).
    """
    fingerprint = file_fingerprint(path)
    earlier = open_tiled(outdir) if (Path(outdir) / INDEX).is_file() else None
    done = earlier is not None and earlier.complete and earlier.index.get("fingerprint") == fingerprint
    return fingerprint, earlier, done


def import_tile_cols(tile_cols: int | None, earlier: TiledScan | None, rows: int, cols: int, budget_bytes: float,
                     bytes_per_pulse: float) -> int:
    """Columns per tile of a streamed import.

    Parameters
    ----------
    tile_cols : int, optional
        Columns asked for (used if given).
    earlier : TiledScan, optional
        The tiled scan an earlier import left (a resumed import keeps its tiles).
    rows, cols : int
        Shape of the scan.
    budget_bytes : float
        Memory for one tile, bytes.
    bytes_per_pulse : float
        Memory of the import per pulse of a tile, bytes.

    Returns
    -------
    int
        ``tile_cols``, else the earlier import's, else as many as ``budget_bytes`` holds (at least one, at most
        ``cols``).
    """
    if tile_cols:
        return tile_cols
    if earlier is not None:
        return earlier.tile_cols
    return max(1, min(cols, int(budget_bytes // (bytes_per_pulse * rows))))


def _write_index(path: Path, index: dict) -> None:
    """Write the index atomically (temporary file, then rename)."""
    tmp = partial_path(path / INDEX)
    tmp.write_text(json.dumps(index), encoding="utf-8")
    tmp.replace(path / INDEX)


def start_tiled(path, header: dict, fingerprint: str, tile_cols: int | None) -> tuple[dict, list[tuple[int, int]]]:
    """Create a tiled scan directory, or take up an interrupted one: the index and the tiles still to write.

    Tiles already listed in the index are kept when their file has the
    recorded size and SHA-256; the others are written again.

    Parameters
    ----------
    path : str or Path
        The scan directory (created when missing).
    header : dict
        ``shape``, ``scanner``, ``scanner_position``, ``scanner_rotation``,
        ``object_names``, ``meta``, ``theta_columns``, ``psi_rows``, ``has_truth``.
    fingerprint : str
        Identity of the scan being written; an existing directory with
        another fingerprint is refused.
    tile_cols : int or None
        Columns per tile (``None``: the existing directory's).

    Returns
    -------
    index : dict
        The index (to pass to :func:`add_tile`).
    todo : list of (int, int)
        Column ranges of the tiles still to write.

    Raises
    ------
    ScanError
        If the directory holds another scan or tiles of another size, or is not a tiled scan.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ScanError(f"{path}: exists and is not a directory; a tiled scan is written to a directory")
    done: list[TileEntry] = []
    if (path / INDEX).is_file():
        old = open_tiled(path)
        if old.index.get("fingerprint") != fingerprint:
            raise ScanError(f"{path}: holds another scan (different scene, scanner, window or seed); "
                            "remove it or write to another directory")
        if tile_cols is not None and tile_cols != old.tile_cols:
            raise ScanError(f"{path}: holds tiles of {old.tile_cols} columns; resume with that tile size "
                            "or remove the directory")
        tile_cols = old.tile_cols
        done = [t for t in old.tiles if _tile_ok(path, t)]
    elif path.is_dir() and any(path.iterdir()):
        raise ScanError(f"{path}: directory is not empty and holds no tiled scan; choose an empty or new directory")
    if tile_cols is None or tile_cols < 1:
        raise ScanError(f"tile size must be at least 1 column, got {tile_cols}")
    path.mkdir(parents=True, exist_ok=True)
    cols = int(header["shape"][1])
    kept = {(t.col0, t.col1) for t in done}
    todo = [(c0, min(cols, c0 + tile_cols)) for c0 in range(0, cols, tile_cols)
            if (c0, min(cols, c0 + tile_cols)) not in kept]
    index = {"format": FORMAT, "version": VERSION, **header, "tile_cols": int(tile_cols), "fingerprint": fingerprint,
             "complete": not todo, "tiles": [dataclasses.asdict(t) for t in sorted(done, key=lambda t: t.col0)]}
    _write_index(path, index)
    return index, todo


def _tile_ok(path: Path, tile: TileEntry) -> bool:
    file = path / tile.file
    return file.is_file() and file.stat().st_size == tile.bytes and file_sha256(file) == tile.sha256


def add_tile(path, index: dict, col0: int, tile: Scan) -> None:
    """Write one finished tile and record it in the index (both atomically).

    Parameters
    ----------
    path : str or Path
        The scan directory (:func:`start_tiled`).
    index : dict
        The index returned by :func:`start_tiled`; updated in place.
    col0 : int
        First column of the tile in the whole scan.
    tile : Scan
        The tile (all rows).
    """
    add_tile_members(path, index, col0, col0 + tile.shape[1], tile.save)


def add_tile_members(path, index: dict, col0: int, col1: int, write) -> None:
    """Write one finished tile with ``write(file)`` and record it in the index (as :func:`add_tile`).

    For a tile written member by member (:func:`tlssim.scan.write_npz` of a generator), so that it need not
    be in memory whole.

    Parameters
    ----------
    path : str or Path
        The scan directory (:func:`start_tiled`).
    index : dict
        The index returned by :func:`start_tiled`; updated in place.
    col0, col1 : int
        First and past-the-last column of the tile in the whole scan.
    write : callable
        Writes the tile's NPZ to the path it is given and returns that path.
    """
    path = Path(path)
    name = f"tile-{col0:06d}-{col1:06d}.npz"
    file = write(path / name)
    entry = TileEntry(name, int(col0), int(col1), file.stat().st_size, file_sha256(file))
    tiles = [t for t in index["tiles"] if t["col0"] != col0] + [dataclasses.asdict(entry)]
    index["tiles"] = sorted(tiles, key=lambda t: t["col0"])
    index["complete"] = _covered([TileEntry(**t) for t in index["tiles"]]) == int(index["shape"][1])
    _write_index(path, index)


def available_memory_bytes() -> int | None:
    """Memory available to the process (``MemAvailable`` of ``/proc/meminfo``), bytes; ``None`` where unknown."""
    try:
        for line in open("/proc/meminfo", encoding="ascii"):
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None

"""Scan file formats: E57, PTX and LAS/LAZ, chosen by file extension.

- **E57** (ASTM E2807, via ``pye57``): one structured scan with row and
  column indices, intensity and the scanner pose; points in the scanner
  frame as single-precision floats. Pulses without a return are kept as
  directions (``cartesianInvalidState = 1``), so the whole grid survives.
- **PTX** (Leica ASCII): the grid column by column with the scanner pose in
  the header; points in the scanner frame (1 µm), intensity normalised to
  [0, 1]; pulses without a return are written as ``0 0 0 0``.
- **LAS/LAZ** (ASPRS LAS 1.4, point format 6, via ``laspy``): the returned
  points in the world frame (10 µm), intensity in DN, the grid position and
  angles and every truth array as extra dimensions, and the scan's metadata
  (grid shape and axes, pose, scanner model, object names) as JSON in
  ``tlslab`` VLRs (one, or several in a row when longer than 65,535 bytes).

:func:`import_tiled` streams a scan larger than memory (a structured E57, a
PTX, or a LAS/LAZ written by tlssim) into a tiled scan directory.
:func:`import_scan` of an E57 or PTX file gives a :class:`~tlssim.scan.Scan`
without truth, ready for reconstruction; a LAS/LAZ file written by
:func:`export_scan` comes back with the truth of its returned points.
Unreadable, truncated or malformed files raise :class:`~tlssim.errors.ScanError`
naming the file and the problem.
"""

from __future__ import annotations

from pathlib import Path

from tlssim.errors import ScanError
from tlssim.formats import e57, las, ptx
from tlssim.scan import Scan
from tlssim.tiled import TiledScan

#: Writer and reader of every supported extension.
FORMATS = {".e57": (e57.write, e57.read), ".ptx": (ptx.write, ptx.read),
           ".las": (las.write, las.read), ".laz": (las.write, las.read)}

#: Extensions whose writer streams a tiled scan tile by tile.
STREAMED = (".e57", ".ptx", ".las", ".laz")


def _codec(path: Path):
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ScanError(f"{path}: unknown scan format {suffix!r}; supported: {', '.join(sorted(FORMATS))}")
    return FORMATS[suffix]


def export_scan(scan: Scan | TiledScan, path) -> Path:
    """Write ``scan`` in the format of ``path``'s extension (``.e57``, ``.ptx``, ``.las``, ``.laz``).

    A tiled scan (:mod:`tlssim.tiled`) is streamed tile by tile to every
    format, with the bytes of the same scan in memory.

    Parameters
    ----------
    scan : Scan or TiledScan
        The scan to write.
    path : str or Path
        Output file; its extension picks the format. Missing folders are created.

    Returns
    -------
    Path
        The written file.
    """
    path = Path(path)
    writer, _ = _codec(path)
    if isinstance(scan, TiledScan) and path.suffix.lower() not in STREAMED:
        scan = scan.load()
    path.parent.mkdir(parents=True, exist_ok=True)
    writer(scan, path)
    return path


def import_tiled(path, outdir, tile_cols: int | None = None) -> TiledScan:
    """Stream a scan file into a tiled scan directory, tile by tile (resumable).

    A structured E57 scan (:func:`tlssim.formats.e57.read_tiled`), a PTX
    file (:func:`tlssim.formats.ptx.read_tiled`) or a LAS/LAZ file written by
    tlssim (:func:`tlssim.formats.las.read_tiled`); the tiles hold the arrays
    of :func:`import_scan` on the same file.

    Parameters
    ----------
    path : str or Path
        Input ``.e57``, ``.ptx``, ``.las`` or ``.laz`` file.
    outdir : str or Path
        Output directory (an interrupted import into it resumes).
    tile_cols : int, optional
        Columns per tile (default: tiles of about 2 GB).

    Returns
    -------
    TiledScan
        The imported scan (with the truth of its returned points for a LAS/LAZ written with truth).
    """
    path = Path(path)
    readers = {".e57": e57.read_tiled, ".ptx": ptx.read_tiled, ".las": las.read_tiled, ".laz": las.read_tiled}
    if path.suffix.lower() not in readers:
        raise ScanError(f"{path}: unknown scan format {path.suffix.lower()!r}; supported: {', '.join(sorted(readers))}")
    if not path.is_file():
        raise ScanError(f"{path}: no such scan file")
    return readers[path.suffix.lower()](path, outdir, tile_cols)


def import_scan(path) -> Scan:
    """Read a scan file (``.e57``, ``.ptx``, ``.las``, ``.laz``; the first scan of multi-scan files)."""
    path = Path(path)
    _, reader = _codec(path)
    if not path.is_file():
        raise ScanError(f"{path}: no such scan file")
    return reader(path)

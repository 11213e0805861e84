"""The :class:`Scan` type: the contract between simulation and reconstruction.

A scan is a set of 2-D arrays on the scanner's (psi, theta) grid (rows =
zenith ``psi``, columns = azimuth ``theta``), plus optional ground-truth
arrays of the same shape. Reconstruction code must work when the truth is
absent (real scans).

Files
-----
``save``/``load`` use NPZ without pickle. Keys:

- ``range`` (m, float64, NaN = no return), ``intensity`` (DN, float32, NaN =
  no return), ``theta`` and ``psi`` (rad, float64), ``xyz`` (rows x cols x 3,
  m, **world frame**);
- truth (simulated scans only): ``truth_range`` (m, distance of the central
  sub-ray), ``truth_id`` (int32, object carrying most of the returned power,
  -1 = none), ``mixed_fraction`` (share of returned power not from that
  object), ``incidence`` (rad, on that object), ``truth_normal`` (unit normal
  facing the scanner);
- ``object_names`` (string array, index = truth id), ``scanner_position``
  (3,), ``scanner_rotation`` (3 x 3, scanner to world), ``scanner`` (JSON
  text of the :class:`ScannerDescription`: ``{"model": parameters or null,
  "window": window or null}``), ``meta`` (JSON text); files written before
  the description existed carry ``scanner_model`` (the parameters) and the
  window in ``meta`` instead, and still load;
- any further per-pixel layer under its own name; simulated scans carry
  ``truth_second_id`` (int32, object with the next largest returned power,
  -1 = none) and ``second_fraction`` (its power share), and reconstructions
  add e.g. ``outlier``.
"""

from __future__ import annotations

import json
import os
import threading
import zipfile
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tlssim.errors import ScanError
from tlssim.pattern import ScannerPose, ScanWindow, beam_frame
from tlssim.scanner import ScannerModel, get_preset

GRID_KEYS = ("range", "intensity", "theta", "psi", "xyz")
TRUTH_KEYS = ("truth_range", "truth_id", "mixed_fraction", "incidence", "truth_normal")
META_KEYS = ("object_names", "scanner_position", "scanner_rotation", "scanner", "scanner_model", "meta")


@dataclass(frozen=True)
class ScannerDescription:
    """The scanner behind a scan: its model and the window it scanned.

    Attributes
    ----------
    model : ScannerModel or None
        The scanner model's parameters (simulated scans); ``None`` where
        they are unknown, as for most real scans.
    window : ScanWindow or None
        The scanned window (angles and steps, degrees); ``None`` where unknown.
    """

    model: ScannerModel | None = None
    window: ScanWindow | None = None

    @property
    def assumed_model(self) -> ScannerModel:
        """The recorded model, or the default model (the ``faro-ls880`` preset) where none is recorded.

        For real scans this is an assumption: their scanner is taken to be
        an LS880-class instrument.
        """
        return self.model if self.model is not None else get_preset("faro-ls880")

    def to_dict(self) -> dict:
        """JSON-ready description (:meth:`from_dict` reads it back)."""
        return {"model": None if self.model is None else self.model.to_dict(),
                "window": None if self.window is None else self.window.to_dict()}

    @classmethod
    def from_dict(cls, data: dict) -> "ScannerDescription":
        """Read :meth:`to_dict` output back.

        Raises
        ------
        ScanError
            If the data is not a mapping with valid ``model`` and ``window`` entries.
        """
        if not isinstance(data, dict):
            raise ScanError(f"a scanner description must be a mapping, got {type(data).__name__}")
        model, window = data.get("model"), data.get("window")
        try:
            return cls(ScannerModel.from_dict(model) if model else None, ScanWindow(**window) if window else None)
        except TypeError as exc:
            raise ScanError(f"malformed scanner window ({exc})") from None


@dataclass
class Scan:
    """A phase-shift scan on its (psi, theta) grid.

    Attributes
    ----------
    range : ndarray, (rows, cols), float64
        Measured distance, m; NaN where there is no return.
    intensity : ndarray, (rows, cols), float32
        Intensity, DN; NaN where there is no return.
    theta, psi : ndarray, (rows, cols), float64
        Azimuth and zenith of each pulse, rad.
    xyz : ndarray, (rows, cols, 3), float64
        Measured points in the world frame, m; NaN where there is no return.
    pose : ScannerPose
        Scanner position and orientation.
    scanner : ScannerDescription
        The scanner model and window that produced the scan (empty when unknown).
    object_names : list of str or None
        Names of the scene objects, indexed by ``truth_id``.
    truth_range, truth_id, mixed_fraction, incidence, truth_normal : ndarray or None
        Ground truth (see the module docstring); ``None`` for real scans.
    layers : dict of str to ndarray
        Further per-pixel layers (e.g. ``outlier`` flags), saved under their names.
    meta : dict
        JSON-ready metadata (scene, seed, backend...).
    """

    range: np.ndarray
    intensity: np.ndarray
    theta: np.ndarray
    psi: np.ndarray
    xyz: np.ndarray
    pose: ScannerPose = field(default_factory=ScannerPose)
    scanner: ScannerDescription = field(default_factory=ScannerDescription)
    object_names: list[str] | None = None
    truth_range: np.ndarray | None = None
    truth_id: np.ndarray | None = None
    mixed_fraction: np.ndarray | None = None
    incidence: np.ndarray | None = None
    truth_normal: np.ndarray | None = None
    layers: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        shape = np.shape(self.range)
        if len(shape) != 2:
            raise ScanError(f"scan range must be a 2-D (psi, theta) grid, got shape {shape}")
        for key in GRID_KEYS + TRUTH_KEYS + tuple(self.layers):
            value = self.layers[key] if key in self.layers else getattr(self, key)
            if value is None:
                continue
            expected = shape + (3,) if key in ("xyz", "truth_normal") else shape
            if key in self.layers:
                ok = np.shape(value)[:2] == shape
            else:
                ok = np.shape(value) == expected
            if not ok:
                raise ScanError(f"scan array {key!r} has shape {np.shape(value)}, expected {expected}")
        clash = sorted(set(self.layers) & set(GRID_KEYS + TRUTH_KEYS + META_KEYS))
        if clash:
            raise ScanError(f"extra layers may not reuse reserved scan keys: {clash}")

    @property
    def shape(self) -> tuple[int, int]:
        """Grid shape ``(rows, cols)``."""
        return self.range.shape

    @property
    def valid(self) -> np.ndarray:
        """Boolean grid of pulses with a return."""
        return np.isfinite(self.range)

    @property
    def has_truth(self) -> bool:
        """Whether the scan carries ground-truth arrays (simulated scans do)."""
        return self.truth_id is not None

    def crop(self, rows: slice, cols: slice) -> "Scan":
        """The part ``[rows, cols]`` of the grid as a scan (grid, truth and layers are views, not copies).

        Parameters
        ----------
        rows : slice
            Grid rows (zenith) to keep.
        cols : slice
            Grid columns (azimuth) to keep.

        Returns
        -------
        Scan
            The cropped scan, with the same pose, scanner, names and meta.
        """
        window = (rows, cols)
        arrays = {key: getattr(self, key)[window] for key in GRID_KEYS + TRUTH_KEYS if getattr(self, key) is not None}
        return replace(self, **arrays, layers={k: v[window] for k, v in self.layers.items()}, meta=dict(self.meta))

    def points(self) -> np.ndarray:
        """Returned points as an ``(n, 3)`` array, world frame, m."""
        return self.xyz[self.valid]

    def save(self, path) -> Path:
        """Write the scan as NPZ (compressed, no pickle); returns the path."""
        path = Path(path)
        arrays = {key: getattr(self, key) for key in GRID_KEYS + TRUTH_KEYS if getattr(self, key) is not None}
        arrays.update(self.layers)
        arrays["scanner_position"] = self.pose.position
        arrays["scanner_rotation"] = self.pose.rotation
        arrays["scanner"] = np.array(json.dumps(self.scanner.to_dict()))
        arrays["meta"] = np.array(json.dumps(self.meta))
        if self.object_names is not None:
            arrays["object_names"] = np.array(self.object_names, dtype=str)
        return write_npz(path, arrays)

    @classmethod
    def load(cls, path) -> "Scan":
        """Read a scan written by :meth:`save`.

        Raises
        ------
        ScanError
            If the file is missing, not an NPZ archive, or lacks or misshapes
            required arrays (the message names the file and the problem).
        """
        path = Path(path)
        if path.is_dir():
            raise ScanError(f"{path}: is a directory; a tiled scan is opened with tlssim.tiled.open_tiled "
                            "(or open_scan, which takes either)")
        if not path.is_file():
            raise ScanError(f"{path}: no such scan file")
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {key: data[key] for key in data.files}
        except (zipfile.BadZipFile, zlib.error, ValueError, OSError, EOFError) as exc:
            raise ScanError(f"{path}: not a readable NPZ scan ({exc})") from None
        missing = [key for key in GRID_KEYS if key not in arrays]
        if missing:
            raise ScanError(f"{path}: missing scan arrays {missing}")
        try:
            meta = json.loads(str(arrays.pop("meta", "{}")))
            legacy = json.loads(str(arrays.pop("scanner_model", "{}")))  # files written before the description
            if "scanner" in arrays:
                scanner = ScannerDescription.from_dict(json.loads(str(arrays.pop("scanner"))))
            else:
                scanner = ScannerDescription.from_dict({"model": legacy, "window": meta.pop("window", None)})
            pose = ScannerPose(arrays.pop("scanner_position", np.zeros(3)), arrays.pop("scanner_rotation", np.eye(3)))
            names = arrays.pop("object_names", None)
            fields = {key: arrays.pop(key) for key in GRID_KEYS + TRUTH_KEYS if key in arrays}
            return cls(**fields, pose=pose, scanner=scanner, meta=meta,
                       object_names=None if names is None else [str(n) for n in names], layers=arrays)
        except (json.JSONDecodeError, TypeError) as exc:
            raise ScanError(f"{path}: malformed scan metadata ({exc})") from None
        except ScanError as exc:
            raise ScanError(f"{path}: {exc}") from None

    def to_ply(self, path) -> Path:
        """Write the returned points as a binary PLY point cloud (world frame).

        Vertex properties: ``x, y, z`` (float64, m), ``intensity`` (float32,
        DN), ``row, col`` (int32, grid position) and, for simulated scans,
        ``truth_id`` (int32) and ``mixed_fraction`` (float32).
        """
        valid = self.valid
        rows, cols = np.nonzero(valid)
        columns = [("x", "<f8", self.xyz[valid, 0]), ("y", "<f8", self.xyz[valid, 1]), ("z", "<f8", self.xyz[valid, 2]),
                   ("intensity", "<f4", self.intensity[valid]), ("row", "<i4", rows), ("col", "<i4", cols)]
        if self.has_truth:
            columns += [("truth_id", "<i4", self.truth_id[valid]), ("mixed_fraction", "<f4", self.mixed_fraction[valid])]
        return write_ply_points(path, columns)


#: DEFLATE level of the NPZ members. Level 1 instead of zlib's default 6: a 9 M-pulse tile of the orchard row
#: (752 MB of arrays) is written in 3.8 instead of 9.9 CPU-s, 105.6 instead of 101.8 MB; the arrays are the same.
NPZ_COMPRESS_LEVEL = 1


def partial_path(path: Path) -> Path:
    """The temporary name beside ``path`` that this process and thread write before renaming onto ``path``.

    ``<name>.<process id>-<thread id>.partial``: each writer has its own,
    so that writers of the same file at once (two processes filling one
    cache) never write into each other's file.
    """
    return path.with_name(f"{path.name}.{os.getpid()}-{threading.get_ident()}.partial")


def write_npz(path, arrays) -> Path:
    """Write arrays as a compressed NPZ (:data:`NPZ_COMPRESS_LEVEL`) whose bytes depend only on the arrays.

    ``numpy.savez`` stamps the current time into the archive; here every
    member gets a fixed date so that the same data gives the same file. The
    file is written under a temporary name of its own and renamed, so an
    interrupted write never leaves a truncated scan behind and two writers
    of the same file (e.g. two benchmark runs filling one tile cache) do not
    collide.

    Parameters
    ----------
    path : str or Path
        Output ``.npz`` file; missing folders are created.
    arrays : dict of str to ndarray, or iterable of (str, ndarray)
        Arrays to store, by member name, in order; an iterable (e.g. a generator) is consumed one member at
        a time, so that only the member being written need be in memory.

    Returns
    -------
    Path
        The written file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = partial_path(path)
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, value in (arrays.items() if isinstance(arrays, dict) else arrays):
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info._compresslevel = NPZ_COMPRESS_LEVEL  # ZipFile.open takes the level from the member's info
            with archive.open(info, "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
    tmp.replace(path)
    return path


_PLY_TYPES = {"<f8": "double", "<f4": "float", "<i4": "int", "<u1": "uchar"}


def write_ply_points(path, columns) -> Path:
    """Write a binary little-endian PLY point cloud.

    Parameters
    ----------
    path : str or Path
        Output file.
    columns : list of (name, numpy dtype string, ndarray)
        Vertex properties, each a 1-D array of the same length; dtypes among
        ``<f8, <f4, <i4, <u1``.
    """
    path = Path(path)
    count = len(columns[0][2])
    table = np.empty(count, dtype=[(name, dtype) for name, dtype, _ in columns])
    for name, _, values in columns:
        table[name] = values
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {count}"]
    header += [f"property {_PLY_TYPES[dtype]} {name}" for name, dtype, _ in columns]
    header.append("end_header\n")
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as handle:
        handle.write("\n".join(header).encode("ascii"))
        handle.write(table.tobytes())
    return path


def grid_to_xyz(range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray, pose: ScannerPose) -> np.ndarray:
    """World coordinates of grid measurements, m (NaN where ``range_m`` is NaN).

    Parameters
    ----------
    range_m : ndarray
        Measured range per cell, m (NaN without return).
    theta : ndarray
        Azimuth per cell, rad.
    psi : ndarray
        Zenith angle per cell, rad.
    pose : ScannerPose
        Scanner position (m) and orientation in the world frame.

    Returns
    -------
    ndarray
        World coordinates, m, shape ``range_m.shape + (3,)``.
    """
    axis, _, _ = beam_frame(theta, psi)
    local = axis * range_m[..., None]
    return local @ pose.rotation.T + pose.position

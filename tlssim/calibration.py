"""Calibration tables measured from scans of calibration targets.

The calibrations of Balduzzi et al. 2011 (Sensors 11:1657, sec. 2.2-2.3;
thesis ch.6) start from two experiments, here the built-in scenes
``panel-series`` (Spectralon-like panels of seven reflectances at distances
from 0.35 to 10 m) and ``goniometer`` (a pear leaf turned from 0 to 85 deg
about two axes). This module reduces their scans, simulated or real, to
tables:

- :func:`panel_table`: mean intensity and distance of every panel;
- :func:`goniometer_table`: the plane-fit incidence of every goniometer
  leaf (:func:`patch_incidence`, decision 7.14 of the digest: the
  orientation-free ``alpha = acos(|n·x|/(|n||x|))`` of a plane fitted in the
  scanner's error geometry, instead of the sources' best of three axis
  regressions) and the intensity and range of its interior returns;
- :func:`save_table` / :func:`load_table`: the tables as JSON files
  (``tlssim calibrate``).

Fitting the inverse model to these tables (reference curve, distance
correction, intensity-to-incidence relation) is reconstruction's job:
:mod:`leafsfs.calibration` (``leafsfs calibrate``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from scipy import ndimage

from tlssim.errors import ScanError
from tlssim.scan import Scan

#: Format tags of the table files, by kind of table.
TABLE_FORMATS = {"panels": "tlssim-panel-table", "goniometer": "tlssim-goniometer-table"}


# --------------------------------------------------------------------------- panels

def panel_table(scan: Scan, margin: float = 2.5) -> dict[str, np.ndarray]:
    """Mean intensity and distance of every calibration panel of a scan.

    Panels are the objects named like ``panel-rho0.99-d3.60m`` (see
    :mod:`scenes.calibration_scenes`); only returns whose footprint lies
    wholly on the panel count: the panel's pixels (by ``truth_id``) farther
    than ``margin`` beam radii plus half the smear from the outline of those
    pixels, which itself reaches about one radius beyond the panel (where
    part of the beam misses it).

    Parameters
    ----------
    scan : Scan
        A simulated scan of a calibration scene, with truth (``truth_id``).
    margin : float
        Clearance kept from a panel's outline, in beam radii (dimensionless).

    Returns
    -------
    dict of ndarray
        ``name``, ``reflectance``, ``nominal_distance_m``, ``distance_m``
        (median measured range), ``intensity_dn`` (mean), ``intensity_std_dn``
        and ``count``, one entry per panel with interior returns, sorted by
        reflectance (descending) and distance.

    Raises
    ------
    ScanError
        If the scan has no truth or no calibration panels.
    """
    from scenes.calibration_scenes import parse_panel_name

    panels = _named_objects(scan, parse_panel_name, "calibration panels (scan the built-in scene 'panel-series')")
    rows = []
    for index, (rho, nominal) in panels.items():
        inside = _interior(scan, scan.truth_id == index, nominal, margin) & scan.valid
        values = scan.intensity[inside]
        if len(values):
            rows.append((scan.object_names[index], rho, nominal, float(np.median(scan.range[inside])),
                         float(values.mean()), float(values.std()), len(values)))
    rows.sort(key=lambda r: (-r[1], r[2]))
    keys = ("name", "reflectance", "nominal_distance_m", "distance_m", "intensity_dn", "intensity_std_dn", "count")
    return {key: np.array(column) for key, column in zip(keys, zip(*rows))}


# --------------------------------------------------------------------------- incidence from geometry

def fit_plane(points) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares (orthogonal) plane through points.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        At least three points, m.

    Returns
    -------
    centroid : ndarray, shape (3,)
    normal : ndarray, shape (3,)
        Unit normal (sign arbitrary).
    rms : float
        Root-mean-square orthogonal distance of the points to the plane, m.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 3:
        raise ScanError(f"a plane fit needs an (n >= 3, 3) array of points, got shape {points.shape}")
    centroid = points.mean(axis=0)
    _, singular, vt = np.linalg.svd(points - centroid, full_matrices=False)
    return centroid, vt[2], float(singular[2] / math.sqrt(len(points)))


def patch_incidence(points, scanner_position=(0.0, 0.0, 0.0)) -> float:
    """Incidence angle of a flat patch seen from the scanner, rad in [0, pi/2].

    ``alpha = acos(|n·x| / |x|)``, with ``x`` the vector from the scanner to
    the patch's centroid and ``n`` the normal of the patch's plane. The plane
    ``n·p = c`` is fitted in the scanner's error geometry: along each beam of
    unit direction ``u`` the range is ``r = c / (n·u)``, so ``1/r`` is linear
    in ``u`` and a least-squares fit of ``1/r`` against ``u`` gives ``n/c``.
    Range noise lies along the line of sight; an orthogonal fit
    (:func:`fit_plane`) would treat it as isotropic and tilt the normal away
    from the line of sight on narrow, noisy patches (by ~2 deg for a 2 cm
    wide leaf at 2 m and 45 deg).

    Parameters
    ----------
    points : array_like, shape (n, 3)
        At least three points of the patch, m.
    scanner_position : array_like, shape (3,)
        Optical centre of the scanner in the points' frame, m.
    """
    points = np.asarray(points, dtype=np.float64) - np.asarray(scanner_position, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 3:
        raise ScanError(f"a patch incidence needs an (n >= 3, 3) array of points, got shape {points.shape}")
    distance = np.linalg.norm(points, axis=1)
    plane, *_ = np.linalg.lstsq(points / distance[:, None], 1.0 / distance, rcond=None)
    sight = points.mean(axis=0)
    cosine = abs(float(plane @ sight)) / (float(np.linalg.norm(plane)) * float(np.linalg.norm(sight)))
    return float(math.acos(min(1.0, cosine)))


# --------------------------------------------------------------------------- goniometer

def goniometer_table(scan: Scan, margin: float = 2.5, plane_margin: float = 1.0, max_mixed_fraction: float = 0.05,
                     min_points: int = 10) -> dict[str, np.ndarray]:
    """Plane-fit incidence and the interior returns of every goniometer leaf of a scan.

    Leaves are the objects named like ``leaf-vertical-45deg`` (see
    :mod:`scenes.calibration_scenes`). The plane through the returns of a
    leaf (``truth_id``) farther than ``plane_margin`` beam radii from the
    outline of its pixels (whose beam centre lies on the leaf) gives its
    incidence (the sources' LSR angle, :func:`patch_incidence`); pixels
    beyond the leaf's edge carry the edge's range and would flatten the
    plane. The intensity samples are the leaf's interior returns: pixels
    farther than ``margin`` beam radii (plus half the smear) from the
    outline of the leaf's pixels, with at most ``max_mixed_fraction`` of
    their power from other surfaces. Edge returns, whose footprint reaches
    the dark platform, fall below the leaf's curve (the sources' large-angle
    effect); they are the outliers a reconstruction must treat, not part of
    the relation. The samples are kept pixel by pixel, so that the distance
    correction (:func:`leafsfs.calibration.station_intensities`) applies to
    each return's own range.

    Parameters
    ----------
    scan : Scan
        A scan of the ``goniometer`` scene, with truth.
    margin, plane_margin : float
        Interior margins of the intensity samples and of the plane fit, in
        beam radii at the goniometer's distance.
    max_mixed_fraction : float
        Largest share of a sample's power from other surfaces.
    min_points : int
        Fewest samples of a leaf that is kept.

    Returns
    -------
    dict of ndarray
        Per station (leaf), sorted by angle: ``name``, ``rotation_axis``,
        ``nominal_deg``, ``alpha_rad`` (plane fit), ``intensity_dn`` (mean
        raw intensity), ``count``; per sample: ``sample_station`` (index of
        its station), ``sample_intensity_dn`` (raw, DN) and
        ``sample_range_m`` (m), stations in order, pixels in grid order.

    Raises
    ------
    ScanError
        If the scan has no truth, no goniometer leaves, or none with
        ``min_points`` samples.
    """
    from scenes.calibration_scenes import GONIOMETER_DISTANCE_M, parse_leaf_name

    leaves = _named_objects(scan, parse_leaf_name, "goniometer leaves (scan the built-in scene 'goniometer')")
    rows = []
    for index, (axis, nominal) in leaves.items():
        leaf = scan.truth_id == index
        plane = _interior(scan, leaf, GONIOMETER_DISTANCE_M, plane_margin)
        chosen = _interior(scan, leaf, GONIOMETER_DISTANCE_M, margin)
        chosen &= scan.valid & (scan.mixed_fraction <= max_mixed_fraction)
        if chosen.sum() >= min_points:
            rows.append((scan.object_names[index], axis, nominal,
                         patch_incidence(scan.xyz[plane & scan.valid], scan.pose.position),
                         float(scan.intensity[chosen].mean()), int(chosen.sum()),
                         scan.intensity[chosen], scan.range[chosen]))
    if not rows:
        raise ScanError(f"no goniometer leaf has >= {min_points} interior returns")
    rows.sort(key=lambda r: r[3])
    keys = ("name", "rotation_axis", "nominal_deg", "alpha_rad", "intensity_dn", "count")
    table = {key: np.array(column) for key, column in zip(keys, zip(*(r[:6] for r in rows)))}
    table["sample_station"] = np.repeat(np.arange(len(rows)), [r[5] for r in rows])
    table["sample_intensity_dn"] = np.concatenate([r[6] for r in rows])
    table["sample_range_m"] = np.concatenate([r[7] for r in rows])
    return table


# --------------------------------------------------------------------------- files

def save_table(table: dict, path, kind: str, scanner_model: dict | None = None) -> Path:
    """Write a calibration table as JSON; returns the path.

    Parameters
    ----------
    table : dict of ndarray
        :func:`panel_table` or :func:`goniometer_table` output.
    path : str or Path
        Output file.
    kind : {"panels", "goniometer"}
        Which table it is.
    scanner_model : dict, optional
        Parameters of the scanner that measured it (``scan.scanner.model.to_dict()``).
    """
    if kind not in TABLE_FORMATS:
        raise ScanError(f"table kind must be one of {sorted(TABLE_FORMATS)}, got {kind!r}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    document = {"format": TABLE_FORMATS[kind], "scanner_model": scanner_model or {},
                "table": {key: np.asarray(value).tolist() for key, value in table.items()}}
    path.write_text(json.dumps(document, indent=1))
    return path


def load_table(path, kind: str) -> tuple[dict[str, np.ndarray], dict]:
    """Read a table written by :func:`save_table`.

    Parameters
    ----------
    path : str or Path
        The JSON file.
    kind : {"panels", "goniometer"}
        The kind of table expected.

    Returns
    -------
    table : dict of ndarray
    scanner_model : dict
        Parameters of the scanner that measured it (empty when unknown).

    Raises
    ------
    ScanError
        If the file is missing, not JSON, or not a table of that kind (the
        message names the file).
    """
    path = Path(path)
    try:
        document = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ScanError(f"{path}: not a readable calibration table ({exc})") from None
    expected = TABLE_FORMATS.get(kind)
    if not isinstance(document, dict) or document.get("format") != expected or not isinstance(
            document.get("table"), dict):
        raise ScanError(f"{path}: not a {kind} table (expected format {expected!r}; write one with "
                        "'tlssim calibrate SCAN')")
    table = {key: np.asarray(value) for key, value in document["table"].items()}
    if kind == "goniometer":
        table["sample_intensity_dn"] = table["sample_intensity_dn"].astype(np.float32)
    model = document.get("scanner_model") or {}
    return table, model if isinstance(model, dict) else {}


# --------------------------------------------------------------------------- helpers

def _named_objects(scan: Scan, parse, what: str) -> dict:
    if not scan.has_truth or scan.object_names is None:
        raise ScanError(f"the scan has no ground truth: cannot find its {what}")
    found = {i: parse(name) for i, name in enumerate(scan.object_names)}
    found = {i: value for i, value in found.items() if value is not None}
    if not found:
        raise ScanError(f"the scan has no {what}")
    return found


def _interior(scan: Scan, mask: np.ndarray, distance_m: float, margin: float) -> np.ndarray:
    """Pixels of ``mask`` farther than ``margin`` beam radii (plus half the smear) from its outline.

    Angular distances on the grid (the window's border counts as outline),
    with the beam radius of the scan's model at ``distance_m``.
    """
    model = scan.scanner.assumed_model
    rows, cols = scan.shape
    d_psi = abs(float(scan.psi[-1, 0] - scan.psi[0, 0])) / max(rows - 1, 1)
    d_theta = abs(float(scan.theta[0, -1] - scan.theta[0, 0])) / max(cols - 1, 1) * float(np.sin(np.median(scan.psi)))
    radius = margin * model.beam_radius_m(distance_m) / distance_m + 0.5 * model.smear_fraction * d_psi
    inside = np.zeros_like(mask)
    if not mask.any():
        return inside
    box = ndimage.find_objects(mask.astype(np.int8))[0]  # the distance is computed on the mask's bounding box,
    # padded: beyond the window's border nothing is known, so it bounds the interior too
    distance = ndimage.distance_transform_edt(np.pad(mask[box], 1), sampling=(d_psi, d_theta))[1:-1, 1:-1]
    inside[box] = distance > radius
    return inside

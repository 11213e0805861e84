"""Intensity calibration: distance correction and the intensity-to-incidence relation.

These are the calibrations of Balduzzi et al. 2011 (Sensors 11:1657, sec.
2.2-2.3; thesis ch.6), usable on simulated and on real scans:

1. **Distance effect.** :func:`fit_reference_curve` fits the 99 % reference
   curve ``f99(d)`` (piecewise quadratic, interpolating the panel means in
   ``ln d``) and :func:`correct_distance` removes the distance effect. The
   default is the additive log-domain form with the sign of the digest's
   decision 7.1, ``I_c = I(d) - f99(d) + f99(d_ref)`` (the printed eq. 1.7
   has the sign the other way); ``mode="ratio"`` gives the multiplicative
   eq. 1.6, ``I_c = I(d)·(f99(d_ref) - c)/(f99(d) - c)``.
2. **Incidence from geometry.** :func:`patch_incidence` estimates a patch's
   incidence from a least-squares plane fitted in the scanner's error
   geometry (noise along the line of sight), with the orientation-free form
   ``alpha = acos(|n·x|/(|n||x|))`` of decision 7.14, instead of the
   sources' best of three axis regressions; :func:`fit_plane` is the
   orthogonal fit (plane RMS, e.g. range precision on a panel).
3. **Intensity to incidence.** :func:`fit_incidence_relation` fits corrected
   intensity against incidence with a 4th-order polynomial (as the sources
   do) and a monotone lookup table (isotonic regression, decision 7.13);
   :meth:`IncidenceRelation.alpha` inverts either, clamped to [0, pi/2],
   and :meth:`IncidenceRelation.reliable` flags angles beyond the validity
   limit (60 deg: above ~55-60 deg the footprint is comparable to the leaf
   and the sources consider the inversion unusable).

:func:`panel_table` and :func:`goniometer_table` reduce scans of the built-in
``panel-series`` and ``goniometer`` scenes to the samples these fits need;
:func:`calibrate_model` simulates both experiments for a scanner model and
returns a :class:`Calibration` (cached in memory, and on disk under
``TLSSIM_CACHE_DIR`` when that variable is set).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.interpolate import PPoly, make_interp_spline
from scipy.optimize import isotonic_regression

from tlssim.errors import ScanError
from tlssim.scan import Scan
from tlssim.scanner import ScannerModel

#: Reference distance and validity limit of the distance correction (Sensors 2011), m.
REFERENCE_DISTANCE_M, CORRECTION_VALID_FROM_M = 3.56, 1.0
#: Incidence beyond which the intensity inversion is flagged unreliable (digest 7.13), rad.
VALIDITY_LIMIT_RAD = math.radians(60.0)
#: Order of the intensity-incidence polynomial of the sources.
POLYNOMIAL_ORDER = 4
CORRECTION_MODES = ("additive", "ratio")
_FORMAT = "tlssim-calibration"


# --------------------------------------------------------------------------- distance effect

@dataclass(frozen=True)
class ReferenceCurve:
    """The 99 % reference curve ``f99(d)``: piecewise polynomials in ``x = ln(d / 1 m)``.

    Attributes
    ----------
    breakpoints : tuple of float
        Piece boundaries in ``ln d`` (increasing).
    coefficients : tuple of tuple of float
        Polynomial coefficients, shape ``(order + 1, pieces)``, highest power
        first, in powers of ``x - breakpoints[i]`` (``scipy.interpolate.PPoly``
        convention); values in DN.
    reference_distance_m : float
        ``d_ref`` of the correction, m.
    valid_from_m : float
        Smallest distance at which the correction is trusted, m.
    """

    breakpoints: tuple[float, ...]
    coefficients: tuple[tuple[float, ...], ...]
    reference_distance_m: float = REFERENCE_DISTANCE_M
    valid_from_m: float = CORRECTION_VALID_FROM_M

    def __call__(self, distance_m) -> np.ndarray:
        """``f99`` at ``distance_m`` (m), DN; the end pieces extrapolate."""
        with np.errstate(invalid="ignore", divide="ignore"):
            x = np.log(np.asarray(distance_m, dtype=np.float64))
        return PPoly(np.array(self.coefficients), np.array(self.breakpoints))(x)

    @property
    def reference_dn(self) -> float:
        """``f99(d_ref)``, DN."""
        return float(self(self.reference_distance_m))

    @property
    def distance_range_m(self) -> tuple[float, float]:
        """Distances spanned by the fitted pieces, m."""
        return float(np.exp(self.breakpoints[0])), float(np.exp(self.breakpoints[-1]))

    @classmethod
    def from_dict(cls, data: dict) -> "ReferenceCurve":
        """Read :func:`dataclasses.asdict` output back."""
        return cls(tuple(data["breakpoints"]), tuple(tuple(c) for c in data["coefficients"]),
                   float(data["reference_distance_m"]), float(data["valid_from_m"]))


def fit_reference_curve(distance_m, intensity_dn, reference_distance_m: float = REFERENCE_DISTANCE_M,
                        valid_from_m: float = CORRECTION_VALID_FROM_M) -> ReferenceCurve:
    """Fit ``f99(d)`` through the mean intensities of a reference panel at several distances.

    The curve is the quadratic spline interpolating the points in ``ln d``
    (pieces of order two, as in the sources).

    Parameters
    ----------
    distance_m, intensity_dn : array_like
        Distance (m) and mean intensity (DN) of the reference panel at each
        position; at least three distinct distances.
    reference_distance_m, valid_from_m : float
        Stored with the curve (see :class:`ReferenceCurve`).

    Raises
    ------
    ScanError
        With fewer than three distinct finite distances.
    """
    distance = np.asarray(distance_m, dtype=np.float64)
    intensity = np.asarray(intensity_dn, dtype=np.float64)
    keep = np.isfinite(distance) & np.isfinite(intensity) & (distance > 0)
    distance, intensity = distance[keep], intensity[keep]
    order = np.argsort(distance)
    distance, intensity = distance[order], intensity[order]
    if len(np.unique(distance)) != len(distance) or len(distance) < 3:
        raise ScanError(f"the reference curve needs >= 3 distinct distances, got {np.round(distance, 3).tolist()}")
    pieces = PPoly.from_spline(make_interp_spline(np.log(distance), intensity, k=2))
    proper = np.nonzero(np.diff(pieces.x) > 0)[0]
    breakpoints = np.append(pieces.x[proper], pieces.x[proper[-1] + 1])
    return ReferenceCurve(tuple(breakpoints.tolist()), tuple(map(tuple, pieces.c[:, proper].tolist())),
                          float(reference_distance_m), float(valid_from_m))


def correct_distance(intensity_dn, range_m, curve: ReferenceCurve, mode: str = "additive",
                     offset_dn: float = 0.0) -> np.ndarray:
    """Remove the distance effect from intensities.

    Parameters
    ----------
    intensity_dn : array_like
        Raw intensity, DN.
    range_m : array_like
        Measured range of the same points, m.
    curve : ReferenceCurve
        The 99 % reference curve.
    mode : {"additive", "ratio"}
        ``additive`` (default): ``I - f99(d) + f99(d_ref)``, exact for the
        log amplifier, whose reflectance curves are vertical shifts of each
        other. ``ratio``: ``I·(f99(d_ref) - c)/(f99(d) - c)`` with ``c =
        offset_dn``, the material's offset below the reference curve.
    offset_dn : float
        ``c`` of the ratio form (0 treats every material like the reference).

    Returns
    -------
    ndarray
        Intensity as if measured at ``d_ref``, DN.
    """
    if mode not in CORRECTION_MODES:
        raise ScanError(f"correction mode must be one of {CORRECTION_MODES}, got {mode!r}")
    intensity = np.asarray(intensity_dn, dtype=np.float64)
    reference = curve(range_m)
    if mode == "additive":
        return intensity - reference + curve.reference_dn
    return intensity * (curve.reference_dn - offset_dn) / (reference - offset_dn)


def panel_table(scan: Scan, margin: float = 2.5) -> dict[str, np.ndarray]:
    """Mean intensity and distance of every calibration panel of a scan.

    Panels are the objects named like ``panel-rho0.99-d3.60m`` (see
    :mod:`scenes.calibration_scenes`); only returns whose footprint lies
    wholly on the panel count: the panel's pixels (by ``truth_id``) farther
    than ``margin`` beam radii plus half the smear from the outline of those
    pixels, which itself reaches about one radius beyond the panel (where
    part of the beam misses it).

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


def panel_statistics(table: dict, curve: ReferenceCurve, mode: str = "additive",
                     min_distance_m: float = CORRECTION_VALID_FROM_M) -> dict[float, dict[str, float]]:
    """The columns of the sources' Table 2 for every reflectance of a :func:`panel_table`.

    Returns
    -------
    dict
        For every reflectance: ``mean_shift_dn`` and ``shift_std_dn`` (offset
        ``f99(d) - I(d)`` averaged over distances beyond ``min_distance_m``,
        and its spread over all distances), ``raw_at_reference_dn`` (the
        material's intensity at ``d_ref``, interpolated linearly in ``ln d``)
        and ``corrected_rmse_dn`` (RMS spread of the corrected intensity
        about its mean beyond ``min_distance_m``: what remains of the
        distance effect).
    """
    stats = {}
    for rho in np.unique(table["reflectance"])[::-1]:
        chosen = np.isclose(table["reflectance"], rho)
        distance, intensity = table["distance_m"][chosen], table["intensity_dn"][chosen]
        far = distance > min_distance_m
        shift = curve(distance) - intensity
        corrected = correct_distance(intensity[far], distance[far], curve, mode)
        stats[float(rho)] = {
            "mean_shift_dn": float(shift[far].mean()), "shift_std_dn": float(shift.std()),
            "raw_at_reference_dn": float(np.interp(np.log(curve.reference_distance_m), np.log(distance), intensity)),
            "corrected_rmse_dn": float(np.sqrt(np.mean((corrected - corrected.mean()) ** 2))),
        }
    return stats


def reference_curve_from_scan(scan: Scan, reflectance: float = 0.99) -> ReferenceCurve:
    """Fit ``f99`` from the panels of reflectance ``reflectance`` in a ``panel-series`` scan."""
    table = panel_table(scan)
    chosen = np.isclose(table["reflectance"], reflectance)
    if chosen.sum() < 3:
        raise ScanError(f"the scan has {int(chosen.sum())} panels of reflectance {reflectance}; the curve needs >= 3")
    return fit_reference_curve(table["distance_m"][chosen], table["intensity_dn"][chosen])


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


# --------------------------------------------------------------------------- intensity -> incidence

@dataclass(frozen=True)
class IncidenceRelation:
    """Corrected intensity against incidence, and its inverse.

    Attributes
    ----------
    lut_alpha_rad, lut_dn : tuple of float
        Monotone lookup table: incidence (increasing) and corrected
        intensity (strictly decreasing).
    polynomial : tuple of float
        4th-order polynomial ``dn(alpha)``, alpha in rad, highest power first
        (``numpy.polyval`` order; the linear coefficient is zero).
    fit_range_rad : (float, float)
        Incidences covered by the calibration data.
    validity_limit_rad : float
        Beyond this incidence the inversion is flagged unreliable.
    method : {"lut", "polynomial"}
        Which of the two :meth:`alpha` inverts.
    """

    lut_alpha_rad: tuple[float, ...]
    lut_dn: tuple[float, ...]
    polynomial: tuple[float, ...]
    fit_range_rad: tuple[float, float]
    validity_limit_rad: float = VALIDITY_LIMIT_RAD
    method: str = "lut"

    def __post_init__(self):
        if self.method not in ("lut", "polynomial"):
            raise ScanError(f"incidence relation method must be 'lut' or 'polynomial', got {self.method!r}")

    def intensity(self, alpha_rad) -> np.ndarray:
        """Corrected intensity expected at incidence ``alpha_rad``, DN.

        The table is interpolated linearly in ``alpha²``: near normal
        incidence intensity varies as ``1 - cos(alpha) ~ alpha²/2``, so that
        this is the interpolation the inversion can follow.
        """
        if self.method == "polynomial":
            return np.polyval(self.polynomial, alpha_rad)
        return _interp_extrapolate(np.square(alpha_rad), np.square(self.lut_alpha_rad), self.lut_dn)

    def alpha(self, corrected_dn) -> np.ndarray:
        """Incidence of a corrected intensity, rad, clamped to [0, pi/2].

        The table (or the polynomial sampled over the calibrated range and made
        monotone) is inverted by linear interpolation of ``alpha²`` against
        intensity, which stays well conditioned near normal incidence where
        intensity hardly changes with the angle; beyond the table's ends the
        end segments extrapolate before the clamp.
        """
        alpha, dn = self._table()
        square = _interp_extrapolate(corrected_dn, dn[::-1], np.square(alpha[::-1]))
        return np.sqrt(np.clip(square, 0.0, 0.25 * math.pi**2))

    def reliable(self, corrected_dn) -> np.ndarray:
        """Whether the inverted incidence lies within the validity limit."""
        return self.alpha(corrected_dn) <= self.validity_limit_rad

    def _table(self) -> tuple[np.ndarray, np.ndarray]:
        if self.method == "lut":
            return np.array(self.lut_alpha_rad), np.array(self.lut_dn)
        alpha = np.linspace(*self.fit_range_rad, 512)
        return _strictly_decreasing(alpha, np.minimum.accumulate(np.polyval(self.polynomial, alpha)))

    @classmethod
    def from_dict(cls, data: dict) -> "IncidenceRelation":
        """Read :func:`dataclasses.asdict` output back."""
        return cls(tuple(data["lut_alpha_rad"]), tuple(data["lut_dn"]), tuple(data["polynomial"]),
                   tuple(data["fit_range_rad"]), float(data["validity_limit_rad"]), data.get("method", "lut"))


def fit_incidence_relation(alpha_rad, corrected_dn, validity_limit_rad: float = VALIDITY_LIMIT_RAD,
                           method: str = "lut") -> IncidenceRelation:
    """Fit corrected intensity against incidence.

    Parameters
    ----------
    alpha_rad, corrected_dn : array_like
        Incidence (rad, e.g. from :func:`patch_incidence`) and distance-corrected
        intensity (DN) of calibration samples; at least five distinct angles.
    validity_limit_rad : float
        Stored with the relation (see :class:`IncidenceRelation`).
    method : {"lut", "polynomial"}
        Default inversion of the relation.

    Returns
    -------
    IncidenceRelation
        Least-squares 4th-order polynomial without a linear term (intensity
        depends on ``cos(alpha)``, so its slope vanishes at normal incidence,
        which keeps the polynomial invertible there), and the isotonic
        (non-increasing) regression of the samples sorted by angle as the
        lookup table, with tied plateaus merged so that it is strictly
        decreasing.
    """
    alpha = np.asarray(alpha_rad, dtype=np.float64)
    dn = np.asarray(corrected_dn, dtype=np.float64)
    keep = np.isfinite(alpha) & np.isfinite(dn)
    alpha, dn = alpha[keep], dn[keep]
    if len(np.unique(alpha)) <= POLYNOMIAL_ORDER:
        raise ScanError(f"the incidence relation needs > {POLYNOMIAL_ORDER} distinct angles, got {len(np.unique(alpha))}")
    order = np.argsort(alpha)
    alpha, dn = alpha[order], dn[order]
    lut_alpha, lut_dn = _strictly_decreasing(alpha, isotonic_regression(dn, increasing=False).x)
    # No linear term: intensity is even in alpha (it depends on cos alpha), so its slope vanishes at normal incidence.
    powers = [p for p in range(POLYNOMIAL_ORDER, -1, -1) if p != 1]
    coefficients, *_ = np.linalg.lstsq(alpha[:, None] ** np.array(powers), dn, rcond=None)
    polynomial = np.zeros(POLYNOMIAL_ORDER + 1)
    polynomial[[POLYNOMIAL_ORDER - p for p in powers]] = coefficients
    return IncidenceRelation(tuple(lut_alpha.tolist()), tuple(lut_dn.tolist()), tuple(polynomial.tolist()),
                             (float(alpha[0]), float(alpha[-1])), float(validity_limit_rad), method)


def goniometer_table(scan: Scan, curve: ReferenceCurve, mode: str = "additive", margin: float = 2.5,
                     plane_margin: float = 1.0, max_mixed_fraction: float = 0.05,
                     min_points: int = 10) -> dict[str, np.ndarray]:
    """Plane-fit incidence and mean corrected intensity of every goniometer leaf of a scan.

    Leaves are the objects named like ``leaf-vertical-45deg`` (see
    :mod:`scenes.calibration_scenes`). The plane through the returns of a
    leaf (``truth_id``) farther than ``plane_margin`` beam radii from the
    outline of its pixels (whose beam centre lies on the leaf) gives its
    incidence (the sources' LSR angle, :func:`patch_incidence`); pixels
    beyond the leaf's edge carry the edge's range and would flatten the
    plane. The intensity is the mean distance-corrected
    intensity of the leaf's interior returns: pixels farther than ``margin``
    beam radii (plus half the smear) from the outline of the leaf's pixels,
    with at most ``max_mixed_fraction`` of their power from other surfaces.
    Edge returns, whose footprint reaches the dark platform, fall below the
    leaf's curve (the sources' large-angle effect); they are the outliers a
    reconstruction must treat, not part of the relation.

    Returns
    -------
    dict of ndarray
        ``name``, ``rotation_axis``, ``nominal_deg``, ``alpha_rad`` (plane
        fit), ``corrected_dn`` (mean), ``corrected_std_dn`` and ``count``,
        for leaves with at least ``min_points`` samples, sorted by angle.
    """
    from scenes.calibration_scenes import GONIOMETER_DISTANCE_M, parse_leaf_name

    leaves = _named_objects(scan, parse_leaf_name, "goniometer leaves (scan the built-in scene 'goniometer')")
    corrected = correct_distance(scan.intensity, scan.range, curve, mode)
    rows = []
    for index, (axis, nominal) in leaves.items():
        leaf = scan.truth_id == index
        plane = _interior(scan, leaf, GONIOMETER_DISTANCE_M, plane_margin)
        chosen = _interior(scan, leaf, GONIOMETER_DISTANCE_M, margin)
        chosen &= scan.valid & (scan.mixed_fraction <= max_mixed_fraction)
        if chosen.sum() >= min_points:
            values = corrected[chosen]
            rows.append((scan.object_names[index], axis, nominal,
                         patch_incidence(scan.xyz[plane & scan.valid], scan.pose.position),
                         float(values.mean()), float(values.std()), int(chosen.sum())))
    if not rows:
        raise ScanError(f"no goniometer leaf has >= {min_points} interior returns")
    rows.sort(key=lambda r: r[3])
    keys = ("name", "rotation_axis", "nominal_deg", "alpha_rad", "corrected_dn", "corrected_std_dn", "count")
    return {key: np.array(column) for key, column in zip(keys, zip(*rows))}


# --------------------------------------------------------------------------- the bundle

@dataclass(frozen=True)
class Calibration:
    """Distance correction and intensity-incidence relation of one scanner.

    Attributes
    ----------
    curve : ReferenceCurve
    incidence : IncidenceRelation
    mode : {"additive", "ratio"}
        Distance-correction form used for the relation and by :meth:`corrected`.
    scanner_model : dict
        Parameters of the scanner model the calibration belongs to.
    """

    curve: ReferenceCurve
    incidence: IncidenceRelation
    mode: str = "additive"
    scanner_model: dict = field(default_factory=dict, compare=False)

    def corrected(self, intensity_dn, range_m) -> np.ndarray:
        """Distance-corrected intensity, DN."""
        return correct_distance(intensity_dn, range_m, self.curve, self.mode)

    def alpha(self, intensity_dn, range_m) -> np.ndarray:
        """Incidence from raw intensity and range, rad in [0, pi/2]."""
        return self.incidence.alpha(self.corrected(intensity_dn, range_m))

    def reliable(self, intensity_dn, range_m) -> np.ndarray:
        """Whether :meth:`alpha` lies within the validity limit (and the range within the correction's)."""
        return self.incidence.reliable(self.corrected(intensity_dn, range_m)) & (
            np.asarray(range_m) >= self.curve.valid_from_m)

    def to_dict(self) -> dict:
        """JSON-ready description (:meth:`from_dict` reads it back)."""
        return {"format": _FORMAT, "version": 1, "mode": self.mode, "reference_curve": asdict(self.curve),
                "incidence_relation": asdict(self.incidence), "scanner_model": self.scanner_model}

    @classmethod
    def from_dict(cls, data: dict) -> "Calibration":
        """Read :meth:`to_dict` output back.

        Raises
        ------
        ScanError
            If the data is not a tlssim calibration.
        """
        if not isinstance(data, dict) or data.get("format") != _FORMAT:
            raise ScanError(f"not a tlssim calibration (expected format {_FORMAT!r})")
        try:
            return cls(ReferenceCurve.from_dict(data["reference_curve"]),
                       IncidenceRelation.from_dict(data["incidence_relation"]),
                       data.get("mode", "additive"), data.get("scanner_model", {}))
        except (KeyError, TypeError, ValueError) as exc:
            raise ScanError(f"malformed tlssim calibration ({exc!r})") from None

    def save(self, path) -> Path:
        """Write the calibration as JSON; returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.to_dict(), indent=1))
        return path

    @classmethod
    def load(cls, path) -> "Calibration":
        """Read a calibration written by :meth:`save` (errors name the file)."""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ScanError(f"{path}: not a readable calibration file ({exc})") from None
        try:
            return cls.from_dict(data)
        except ScanError as exc:
            raise ScanError(f"{path}: {exc}") from None


def calibrate_scans(panel_scan: Scan, goniometer_scan: Scan, mode: str = "additive") -> Calibration:
    """Fit a :class:`Calibration` from scans of the ``panel-series`` and ``goniometer`` scenes."""
    curve = reference_curve_from_scan(panel_scan)
    table = goniometer_table(goniometer_scan, curve, mode)
    return Calibration(curve, fit_incidence_relation(table["alpha_rad"], table["corrected_dn"]), mode,
                       goniometer_scan.scanner_model)


def calibrate_model(model: ScannerModel, seed: int = 0, cache_dir=None) -> Calibration:
    """Simulate both calibration experiments with ``model`` and fit them.

    Results are cached in memory per ``(model, seed)``, and as JSON in
    ``cache_dir`` (default: the ``TLSSIM_CACHE_DIR`` environment variable,
    none if unset) under a key that also covers the simulator's source code.

    Parameters
    ----------
    model : ScannerModel
        The scanner to calibrate; the scenes' set-ups (pose, window, the
        panel series' shorter minimum range) apply on top of it.
    seed : int
        Seed of both simulations.
    cache_dir : str or Path, optional
        Directory of the on-disk cache.
    """
    cache_dir = cache_dir or os.environ.get("TLSSIM_CACHE_DIR")
    if not cache_dir:
        return _calibrate_cached(model, int(seed))
    path = Path(cache_dir) / f"calibration-{_cache_key(model, seed)}.json"
    if path.is_file():
        return Calibration.load(path)
    calibration = _calibrate_cached(model, int(seed))
    calibration.save(path)
    return calibration


@functools.lru_cache(maxsize=16)
def _calibrate_cached(model: ScannerModel, seed: int) -> Calibration:
    import scenes
    from tlssim.simulate import setup_from_section, simulate

    scans = []
    for name in ("panel-series", "goniometer"):
        scene = scenes.build(name)
        scans.append(simulate(scene, setup_from_section(scene.scanner, model=model), seed=seed, progress=False))
    return calibrate_scans(*scans)


def _cache_key(model: ScannerModel, seed: int) -> str:
    digest = hashlib.sha256(json.dumps([model.to_dict(), int(seed)], sort_keys=True).encode())
    package = Path(__file__).resolve().parent
    for source in sorted(package.rglob("*.py")) + sorted((package.parent / "scenes").glob("*.py")):
        digest.update(source.read_bytes())
    return digest.hexdigest()[:20]


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
    model = ScannerModel.from_dict(scan.scanner_model)
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


def _strictly_decreasing(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge runs of equal ``y`` (a non-increasing sequence) into one node at their mean ``x``."""
    values, start = np.unique(-y, return_index=True)
    counts = np.diff(np.append(start, len(y)))
    return np.add.reduceat(x, start) / counts, -values


def _interp_extrapolate(x, xp, fp) -> np.ndarray:
    """Linear interpolation with linear extrapolation of the end segments (``xp`` increasing)."""
    x = np.asarray(x, dtype=np.float64)
    xp, fp = np.asarray(xp, dtype=np.float64), np.asarray(fp, dtype=np.float64)
    if len(xp) == 1:
        return np.full_like(x, fp[0])
    result = np.interp(x, xp, fp)
    low_slope = (fp[1] - fp[0]) / (xp[1] - xp[0])
    high_slope = (fp[-1] - fp[-2]) / (xp[-1] - xp[-2])
    result = np.where(x < xp[0], fp[0] + (x - xp[0]) * low_slope, result)
    return np.where(x > xp[-1], fp[-1] + (x - xp[-1]) * high_slope, result)

"""The inverse intensity calibration: distance correction and the intensity-to-incidence relation.

These are the calibrations of Balduzzi et al. 2011 (Sensors 11:1657, sec.
2.2-2.3; thesis ch.6), fitted from measured tables and applied to simulated
and real scans alike:

1. **Distance effect.** :func:`fit_reference_curve` fits the 99 % reference
   curve ``f99(d)`` (piecewise quadratic, interpolating the panel means in
   ``ln d``) and :func:`correct_distance` removes the distance effect. The
   default is the additive log-domain form with the sign of the digest's
   decision 7.1, ``I_c = I(d) - f99(d) + f99(d_ref)`` (the printed eq. 1.7
   has the sign the other way); ``mode="ratio"`` gives the multiplicative
   eq. 1.6, ``I_c = I(d)·(f99(d_ref) - c)/(f99(d) - c)``.
2. **Intensity to incidence.** :func:`fit_incidence_relation` fits corrected
   intensity against incidence with a 4th-order polynomial (as the sources
   do) and a monotone lookup table (isotonic regression, decision 7.13);
   :meth:`IncidenceRelation.alpha` inverts either, clamped to [0, pi/2],
   and :meth:`IncidenceRelation.reliable` flags angles beyond the validity
   limit (60 deg: above ~55-60 deg the footprint is comparable to the leaf
   and the sources consider the inversion unusable).

The tables come from scans of calibration targets, measured by
:func:`tlssim.calibration.panel_table` and
:func:`tlssim.calibration.goniometer_table` (``tlssim calibrate``);
:func:`fit_calibration` turns them into a :class:`Calibration`
(``leafsfs calibrate``). Simulating the targets to get those tables is an
experiment of the benchmarks (``tlsbench experiment calibration``):
reconstruction never simulates.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import PPoly, make_interp_spline
from scipy.optimize import isotonic_regression

from leafsfs.errors import SfsError

#: Reference distance and validity limit of the distance correction (Sensors 2011), m.
REFERENCE_DISTANCE_M, CORRECTION_VALID_FROM_M = 3.56, 1.0
#: Incidence beyond which the intensity inversion is flagged unreliable (digest 7.13), rad.
VALIDITY_LIMIT_RAD = math.radians(60.0)
#: Order of the intensity-incidence polynomial of the sources.
POLYNOMIAL_ORDER = 4
CORRECTION_MODES = ("additive", "ratio")
#: Format tag of calibration files (the name they had when the model lived in tlssim; files stay readable).
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
    SfsError
        With fewer than three distinct finite distances.
    """
    distance = np.asarray(distance_m, dtype=np.float64)
    intensity = np.asarray(intensity_dn, dtype=np.float64)
    keep = np.isfinite(distance) & np.isfinite(intensity) & (distance > 0)
    distance, intensity = distance[keep], intensity[keep]
    order = np.argsort(distance)
    distance, intensity = distance[order], intensity[order]
    if len(np.unique(distance)) != len(distance) or len(distance) < 3:
        raise SfsError(f"the reference curve needs >= 3 distinct distances, got {np.round(distance, 3).tolist()}")
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
        raise SfsError(f"correction mode must be one of {CORRECTION_MODES}, got {mode!r}")
    intensity = np.asarray(intensity_dn, dtype=np.float64)
    reference = curve(range_m)
    if mode == "additive":
        return intensity - reference + curve.reference_dn
    return intensity * (curve.reference_dn - offset_dn) / (reference - offset_dn)


def panel_statistics(table: dict, curve: ReferenceCurve, mode: str = "additive",
                     min_distance_m: float = CORRECTION_VALID_FROM_M) -> dict[float, dict[str, float]]:
    """The columns of the sources' Table 2 for every reflectance of a panel table.

    Parameters
    ----------
    table : dict of ndarray
        :func:`tlssim.calibration.panel_table` output.
    curve : ReferenceCurve
        The 99 % reference curve.
    mode : {"additive", "ratio"}
        Distance-correction form of ``corrected_rmse_dn``.
    min_distance_m : float
        Distances beyond which the mean shift and the corrected spread are taken, m.

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
            raise SfsError(f"incidence relation method must be 'lut' or 'polynomial', got {self.method!r}")

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
        Incidence (rad, e.g. from :func:`tlssim.calibration.patch_incidence`) and distance-corrected
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
        raise SfsError(f"the incidence relation needs > {POLYNOMIAL_ORDER} distinct angles, got {len(np.unique(alpha))}")
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
        """Distance-corrected intensity, DN.

        Parameters
        ----------
        intensity_dn : array_like
            Raw intensity, DN.
        range_m : array_like
            Measured range of the same returns, m.
        """
        return correct_distance(intensity_dn, range_m, self.curve, self.mode)

    def alpha(self, intensity_dn, range_m) -> np.ndarray:
        """Incidence from raw intensity and range, rad in [0, pi/2].

        Parameters
        ----------
        intensity_dn : array_like
            Raw intensity, DN.
        range_m : array_like
            Measured range of the same returns, m.
        """
        return self.incidence.alpha(self.corrected(intensity_dn, range_m))

    def reliable(self, intensity_dn, range_m) -> np.ndarray:
        """Whether :meth:`alpha` lies within the validity limit (and the range within the correction's).

        Parameters
        ----------
        intensity_dn : array_like
            Raw intensity, DN.
        range_m : array_like
            Measured range of the same returns, m.
        """
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
        SfsError
            If the data is not a tlssim calibration.
        """
        if isinstance(data, dict) and str(data.get("format", "")).startswith("tlssim-") and \
                str(data["format"]).endswith("-table"):
            raise SfsError(f"not a tlssim calibration but a measured table ({data['format']}): fit the panel and "
                           "goniometer tables with 'leafsfs calibrate PANELS.json GONIOMETER.json -o calibration.json'")
        if not isinstance(data, dict) or data.get("format") != _FORMAT:
            raise SfsError(f"not a tlssim calibration (expected format {_FORMAT!r})")
        try:
            return cls(ReferenceCurve.from_dict(data["reference_curve"]),
                       IncidenceRelation.from_dict(data["incidence_relation"]),
                       data.get("mode", "additive"), data.get("scanner_model", {}))
        except (KeyError, TypeError, ValueError) as exc:
            raise SfsError(f"malformed tlssim calibration ({exc!r})") from None

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
            raise SfsError(f"{path}: not a readable calibration file ({exc})") from None
        try:
            return cls.from_dict(data)
        except SfsError as exc:
            raise SfsError(f"{path}: {exc}") from None


def reference_curve_from_table(table: dict, reflectance: float = 0.99) -> ReferenceCurve:
    """Fit ``f99`` from the panels of reflectance ``reflectance`` of a panel table.

    Parameters
    ----------
    table : dict of ndarray
        :func:`tlssim.calibration.panel_table` of a ``panel-series`` scan
        (columns ``reflectance``, ``distance_m`` in m, ``intensity_dn`` in DN).
    reflectance : float
        Reflectance of the reference panels.

    Raises
    ------
    SfsError
        With fewer than three panels of that reflectance.
    """
    chosen = np.isclose(table["reflectance"], reflectance)
    if chosen.sum() < 3:
        raise SfsError(f"the table has {int(chosen.sum())} panels of reflectance {reflectance}; the curve needs >= 3")
    return fit_reference_curve(table["distance_m"][chosen], table["intensity_dn"][chosen])


def station_intensities(table: dict, curve: ReferenceCurve, mode: str = "additive") -> tuple[np.ndarray, np.ndarray]:
    """Mean and spread of the distance-corrected intensity of every station of a goniometer table, DN.

    Parameters
    ----------
    table : dict of ndarray
        :func:`tlssim.calibration.goniometer_table`: its per-pixel samples
        (``sample_station``, ``sample_intensity_dn``, ``sample_range_m``).
    curve : ReferenceCurve
        The 99 % reference curve of the distance correction.
    mode : {"additive", "ratio"}
        Distance-correction form (see :func:`correct_distance`).

    Returns
    -------
    mean, std : ndarray
        One value per station, DN.
    """
    station = np.asarray(table["sample_station"])
    corrected = correct_distance(table["sample_intensity_dn"], table["sample_range_m"], curve, mode)
    count = len(table["name"])
    mean, std = np.empty(count), np.empty(count)
    for index in range(count):
        values = corrected[station == index]
        mean[index], std[index] = values.mean(), values.std()
    return mean, std


def fit_calibration(panels: dict, goniometer: dict, mode: str = "additive",
                    scanner_model: dict | None = None) -> "Calibration":
    """Fit a :class:`Calibration` from a panel table and a goniometer table.

    Parameters
    ----------
    panels : dict of ndarray
        :func:`tlssim.calibration.panel_table` of a ``panel-series`` scan.
    goniometer : dict of ndarray
        :func:`tlssim.calibration.goniometer_table` of a ``goniometer`` scan.
    mode : {"additive", "ratio"}
        Distance-correction form.
    scanner_model : dict, optional
        Parameters of the scanner the tables were measured with (stored).
    """
    curve = reference_curve_from_table(panels)
    corrected, _ = station_intensities(goniometer, curve, mode)
    return Calibration(curve, fit_incidence_relation(goniometer["alpha_rad"], corrected), mode, scanner_model or {})


# --------------------------------------------------------------------------- helpers

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

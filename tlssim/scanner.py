"""Scanner models and the registry of presets.

A :class:`ScannerModel` holds the instrument's fixed properties: beam,
angular sampling limits, range limits, modulation frequencies and the
parameters of the detector chain. Presets are registered by name
(:func:`register_preset`) and fetched with :func:`get_preset`; any field can
be overridden (:meth:`ScannerModel.replace`).

Every value of the ``faro-ls880`` preset is documented in
:data:`FARO_LS880_SOURCES` (source, or "assumption").
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from tlssim.errors import ScanError

SPEED_OF_LIGHT_M_S = 299_792_458.0


@dataclass(frozen=True)
class ScannerModel:
    """Fixed properties of a phase-shift (AM-CW) terrestrial laser scanner.

    Parameters
    ----------
    name : str
        Preset name.
    wavelength_nm : float
        Laser wavelength, nm (informative: materials are given at this wavelength).
    beam_waist_radius_m : float
        1/e² radius of the beam at the exit aperture, m.
    divergence_deg : float
        Half-angle divergence of the 1/e² radius, degrees: the radius grows as
        ``w(z) = beam_waist_radius_m + z·tan(divergence)``. Sub-ray directions
        and power weights both use this definition.
    step_deg : float
        Default angular step on both axes, degrees.
    psi_limits_deg : (float, float)
        Zenith coverage of the instrument, degrees from +z.
    theta_limits_deg : (float, float)
        Azimuth coverage, degrees from +x about +z.
    min_range_m, max_range_m : float
        Range limits: returns outside them are discarded, and sub-ray hits
        beyond ``max_range_m`` contribute no power.
    receiver_fov_mrad : float
        Full field of view of the coaxial receiver, mrad; the beam must fit in it.
    mod_freqs_hz : tuple of float
        AM-CW modulation frequencies, Hz. The lowest sets the unambiguous range
        ``c / (2 f_min)``; finer ones are unwrapped hierarchically against it.
    n_subrays : int
        Number of sub-rays sampling each pulse's Gaussian beam.
    beam_profile : {"gaussian", "tophat"}
        Irradiance profile across the beam.
    intensity_ref_dn : float
        Intensity of the reference target (see the next two fields), DN.
    intensity_ref_range_m : float
        Distance of the reference target, m.
    intensity_ref_reflectance : float
        Lambertian reflectance of the reference target, seen at normal incidence.
    log_gain_dn : float
        Gain of the logarithmic amplifier, DN per e-fold of received power.
    intensity_max_dn : int
        Largest digital number (2**bits - 1).
    """

    name: str = "custom"
    wavelength_nm: float = 785.0
    beam_waist_radius_m: float = 0.0015
    divergence_deg: float = 0.014
    step_deg: float = 0.018
    psi_limits_deg: tuple[float, float] = (0.0, 160.0)
    theta_limits_deg: tuple[float, float] = (0.0, 360.0)
    min_range_m: float = 0.6
    max_range_m: float = 76.0
    receiver_fov_mrad: float = 3.0
    mod_freqs_hz: tuple[float, ...] = (SPEED_OF_LIGHT_M_S / (2 * 76.0),)
    n_subrays: int = 19
    beam_profile: str = "gaussian"
    intensity_ref_dn: float = 1781.45
    intensity_ref_range_m: float = 3.56
    intensity_ref_reflectance: float = 0.99
    log_gain_dn: float = 263.0
    intensity_max_dn: int = 2047

    def __post_init__(self):
        object.__setattr__(self, "psi_limits_deg", tuple(float(x) for x in self.psi_limits_deg))
        object.__setattr__(self, "theta_limits_deg", tuple(float(x) for x in self.theta_limits_deg))
        object.__setattr__(self, "mod_freqs_hz", tuple(sorted(float(f) for f in self.mod_freqs_hz)))
        _check_positive(self, "wavelength_nm", "beam_waist_radius_m", "divergence_deg", "step_deg",
                        "min_range_m", "max_range_m", "receiver_fov_mrad", "intensity_ref_range_m",
                        "intensity_ref_reflectance", "log_gain_dn")
        if self.divergence_deg >= 5.0:
            raise ScanError(f"divergence_deg must be a small half-angle in (0, 5) degrees, got {self.divergence_deg}")
        if math.radians(self.divergence_deg) * 1e3 > self.receiver_fov_mrad / 2:
            raise ScanError(
                f"the beam (half-angle {math.radians(self.divergence_deg) * 1e3:.3g} mrad) does not fit in the "
                f"receiver field of view ({self.receiver_fov_mrad} mrad full angle)"
            )
        if not self.min_range_m < self.max_range_m:
            raise ScanError(f"min_range_m ({self.min_range_m}) must be below max_range_m ({self.max_range_m})")
        lo, hi = self.psi_limits_deg
        if not 0.0 <= lo < hi <= 180.0:
            raise ScanError(f"psi_limits_deg must satisfy 0 <= lo < hi <= 180, got {self.psi_limits_deg}")
        lo, hi = self.theta_limits_deg
        if not (lo < hi and hi - lo <= 360.0):
            raise ScanError(f"theta_limits_deg must satisfy lo < hi and hi - lo <= 360, got {self.theta_limits_deg}")
        if not self.mod_freqs_hz or min(self.mod_freqs_hz) <= 0:
            raise ScanError(f"mod_freqs_hz must list positive frequencies (Hz), got {self.mod_freqs_hz}")
        if self.unambiguous_range_m < self.max_range_m:
            raise ScanError(
                f"the lowest modulation frequency ({self.mod_freqs_hz[0]:.6g} Hz) gives an unambiguous range of "
                f"{self.unambiguous_range_m:.2f} m, shorter than max_range_m = {self.max_range_m} m; "
                f"use a frequency <= {SPEED_OF_LIGHT_M_S / (2 * self.max_range_m):.6g} Hz"
            )
        if not (isinstance(self.n_subrays, int) and self.n_subrays >= 1):
            raise ScanError(f"n_subrays must be a positive integer, got {self.n_subrays!r}")
        if self.beam_profile not in ("gaussian", "tophat"):
            raise ScanError(f"beam_profile must be 'gaussian' or 'tophat', got {self.beam_profile!r}")
        if not (isinstance(self.intensity_max_dn, int) and self.intensity_max_dn > 0):
            raise ScanError(f"intensity_max_dn must be a positive integer, got {self.intensity_max_dn!r}")

    @property
    def unambiguous_range_m(self) -> float:
        """Unambiguous range of the lowest modulation frequency, ``c / (2 f_min)``, m."""
        return SPEED_OF_LIGHT_M_S / (2.0 * self.mod_freqs_hz[0])

    def beam_radius_m(self, distance_m):
        """1/e² beam radius at ``distance_m`` from the exit aperture, m."""
        return self.beam_waist_radius_m + distance_m * math.tan(math.radians(self.divergence_deg))

    def replace(self, **changes) -> "ScannerModel":
        """A copy with some fields changed (validated).

        Raises
        ------
        ScanError
            If a field name is unknown (the message lists the allowed ones) or
            a value is out of range.
        """
        allowed = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - allowed)
        if unknown:
            raise ScanError(f"unknown scanner parameter(s) {unknown}; allowed: {sorted(allowed)}")
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """All fields as JSON-ready data."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}


def _check_positive(model, *fields):
    for name in fields:
        value = getattr(model, name)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ScanError(f"{name} must be a positive finite number, got {value!r}")


#: Where each value of the ``faro-ls880`` preset comes from.
FARO_LS880_SOURCES = {
    "wavelength_nm": "785 nm: Balduzzi et al. 2011 (Sensors 11:1657) Table 1",
    "beam_waist_radius_m": "3 mm exit diameter (Table 1), read as the 1/e² diameter: assumption",
    "divergence_deg": "0.014 deg (Table 1), read as the 1/e² half-angle: this reading reproduces the published "
                      "footprint formula (4.1 mm at 0 deg and 46.5 mm at 85 deg, 2.16 m)",
    "step_deg": "0.018 deg on both axes, the step used in the sources",
    "psi_limits_deg": "320 x 360 deg field of view with a ~20 deg blind cone under the instrument (thesis ch.1)",
    "theta_limits_deg": "360 deg azimuth (Table 1)",
    "min_range_m": "0.6 m (Table 1)",
    "max_range_m": "76 m (Table 1; the thesis' French summary says 78 m)",
    "receiver_fov_mrad": "3 mrad (Table 1)",
    "mod_freqs_hz": "not published: assumption, one frequency c / (2 x 76 m) = 1.972 MHz so that the whole "
                    "range is unambiguous and mixed ranges are intermediate",
    "n_subrays": "simulation choice (19 = 1 + 6 + 12 equal-power sub-rays)",
    "beam_profile": "not published: Gaussian assumed (thesis ch.1 says TLS beams are generally Gaussian)",
    "intensity_ref_dn": "1781.45 DN for the 99 % Spectralon at 3.56 m (Sensors 2011, distance correction)",
    "intensity_ref_range_m": "3.56 m (Sensors 2011)",
    "intensity_ref_reflectance": "0.99 (Spectralon, Sensors 2011)",
    "log_gain_dn": "263 DN per e-fold: least-squares fit through the origin of the Table 2 offsets "
                   "(derived, spec tls-physics A.2)",
    "intensity_max_dn": "11-bit intensity, 0-2047 DN (Table 1; ch.7 says 2044)",
}

_PRESETS: dict[str, ScannerModel] = {}


def register_preset(model: ScannerModel) -> ScannerModel:
    """Register ``model`` under its ``name``."""
    _PRESETS[model.name] = model
    return model


def preset_names() -> list[str]:
    """Names of the registered presets, sorted."""
    return sorted(_PRESETS)


def get_preset(name: str, **overrides) -> ScannerModel:
    """The preset ``name``, with optional field overrides.

    Raises
    ------
    ScanError
        If the preset is unknown (the message lists the known ones) or an
        override is invalid.
    """
    if name not in _PRESETS:
        raise ScanError(f"unknown scanner preset {name!r}; available: {', '.join(preset_names())}")
    return _PRESETS[name].replace(**overrides) if overrides else _PRESETS[name]


register_preset(ScannerModel(name="faro-ls880"))

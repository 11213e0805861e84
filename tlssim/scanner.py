"""Scanner models and the registry of presets.

A :class:`ScannerModel` holds the instrument's fixed properties: beam,
angular sampling limits, range limits, modulation frequencies and the
parameters of the detector chain. Presets are registered by name
(:func:`register_preset`) and fetched with :func:`get_preset`; any field can
be overridden (:meth:`ScannerModel.replace`).

Every value of the ``faro-ls880`` preset is documented in
:data:`FARO_LS880_SOURCES` (source, or "assumption"). The open questions of
the physics digest (``tls-physics.md`` section 7) are decided as follows,
each a field that can be changed per scan unless said otherwise:

- 7.2 modulation: ``mod_freqs_hz``, one coarse 1.972 MHz frequency (76 m unambiguous).
- 7.3 mixed intensity: ``intensity_signal = "phasor"``, the log of the total phasor amplitude.
- 7.4 intensity transfer: ``intensity_ref_*``, ``log_gain_dn``; noise ``intensity_noise_dn``,
  ``intensity_noise_exponent``. No per-material offset table: the log model
  overshoots the 68-83 % offsets of Table 2 by 20-30 DN, and that stays.
- 7.5 near-range attenuator: ``near_filter_range_m``, ``near_filter_exponent``, ``near_filter_table``.
- 7.6 conflicts: ``min_range_m`` 0.6 (the ``panel-series`` scene lowers it to 0.3 m),
  ``max_range_m`` 76, ``intensity_max_dn`` 2047.
- 7.7 beam: ``beam_profile``, ``n_subrays``; scan smear ``smear_fraction`` (one full step).
- 7.9 step: ``step_deg``.
- 7.11 range noise: ``range_noise_m``, ``range_noise_exponent``, ``range_noise_floor_m``
  (from the signal, so partial footprints are noisier); ``range_filter_length``
  for the filtered mode; dropouts ``min_signal_dn``.
- 7.17 timing: no measurement rate; the smear is a fraction of the sampling
  period, which needs none. The in-canopy intensity offset (digest 6.12) is
  not modelled.
- Optional effects: ``leaf_transmission``, ``bsdf`` / ``bsdf_object_types``.

The calibration decisions live with their code: 7.14 (plane-fit angle) in
:mod:`tlssim.calibration`, which measures the tables; 7.1 (sign of the
correction) and 7.13 (inversion) in :mod:`leafsfs.calibration`, which fits
the inverse model.
"""

from __future__ import annotations

import dataclasses
import json
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
    near_filter_range_m, near_filter_exponent : float
        Near-range optical attenuator: the received power is multiplied by
        ``A(d) = 1 / (1 + (d_f / d)**m)`` with ``d_f`` and ``m`` these two
        values, so that the distance factor is ``g(d) = A(d) / d²``
        (``d_f = 0`` turns the attenuator off).
    near_filter_table : tuple of (float, float)
        Optional measured attenuator ``((d_m, A), ...)`` with increasing
        distances; replaces the analytic ``A(d)`` (linear interpolation,
        constant beyond the ends).
    intensity_signal : {"phasor", "power"}
        What the log amplifier sees: the amplitude of the summed phasor at
        the lowest modulation frequency (coherent sum, the default) or the
        summed optical power of the sub-rays (incoherent).
    intensity_noise_dn : float
        Standard deviation of intensity noise for the reference target, DN.
    intensity_noise_exponent : float
        Signal dependence of intensity noise: the noise on the received
        amplitude grows as ``A**(1 - exponent)``, so that after the log
        amplifier ``sigma_I ~ intensity_noise_dn·(A / A_ref)**(-exponent)``
        (0.5: shot-noise limited detection).
    min_signal_dn : float
        Detection threshold on the noisy received signal, expressed as the
        digital number the amplifier would give it: pulses below it have no
        return (dropouts).
    range_noise_m, range_noise_exponent : float
        Range noise ``sigma_d = range_noise_m·(A / A_ref)**(-range_noise_exponent)``
        for a pulse of received amplitude ``A`` (``A_ref``: the reference
        target), m.
    range_noise_floor_m : float
        Signal-independent range noise added in quadrature, m.
    range_filter_length : int
        On-board range averaging: each range is the mean of this many
        consecutive returned samples along the zenith (mirror) axis, centred
        on the sample (1 = raw ranges).
    smear_fraction : float
        Integration time of one measurement as a fraction of the sampling
        period: the beam sweeps ``smear_fraction`` times the zenith step
        while a sample is integrated, which smears the footprint along psi.
    leaf_transmission : bool
        Let the share ``transmittance`` of each sub-ray that hits a
        transmitting material continue undeviated behind it; its return
        crosses the material again (attenuated by ``transmittance²``).
    bsdf : str
        ``"lambertian"``, or a Mitsuba BSDF plugin as JSON (e.g.
        ``{"type": "roughplastic", "alpha": 0.3, "int_ior": 1.47}``)
        evaluated at the backscatter direction for objects whose type is in
        ``bsdf_object_types``; the object's reflectance becomes the plugin's
        diffuse reflectance.
    bsdf_object_types : tuple of str
        Object types (``SceneObject.type``) that use ``bsdf``.
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
    near_filter_range_m: float = 3.0
    near_filter_exponent: float = 3.0
    near_filter_table: tuple[tuple[float, float], ...] = ()
    intensity_signal: str = "phasor"
    intensity_noise_dn: float = 3.0
    intensity_noise_exponent: float = 0.5
    min_signal_dn: float = 0.0
    range_noise_m: float = 1.386e-3
    range_noise_exponent: float = 0.338
    range_noise_floor_m: float = 0.0
    range_filter_length: int = 1
    smear_fraction: float = 1.0
    leaf_transmission: bool = False
    bsdf: str = "lambertian"
    bsdf_object_types: tuple[str, ...] = ("leaf",)

    def __post_init__(self):
        object.__setattr__(self, "psi_limits_deg", tuple(float(x) for x in self.psi_limits_deg))
        object.__setattr__(self, "theta_limits_deg", tuple(float(x) for x in self.theta_limits_deg))
        object.__setattr__(self, "mod_freqs_hz", tuple(sorted(float(f) for f in self.mod_freqs_hz)))
        object.__setattr__(self, "near_filter_table", _filter_table(self.near_filter_table))
        object.__setattr__(self, "bsdf", _bsdf_spec(self.bsdf))
        object.__setattr__(self, "bsdf_object_types", tuple(str(t) for t in self.bsdf_object_types))
        _check_positive(self, "wavelength_nm", "beam_waist_radius_m", "divergence_deg", "step_deg",
                        "min_range_m", "max_range_m", "receiver_fov_mrad", "intensity_ref_range_m",
                        "intensity_ref_reflectance", "log_gain_dn", "near_filter_exponent")
        _check_non_negative(self, "near_filter_range_m", "intensity_noise_dn", "intensity_noise_exponent",
                            "range_noise_m", "range_noise_exponent", "range_noise_floor_m", "smear_fraction")
        if not (isinstance(self.min_signal_dn, (int, float)) and math.isfinite(self.min_signal_dn)):
            raise ScanError(f"min_signal_dn must be a finite number (DN), got {self.min_signal_dn!r}")
        if self.intensity_noise_exponent > 1.0:
            raise ScanError(f"intensity_noise_exponent must lie in [0, 1], got {self.intensity_noise_exponent}")
        if self.smear_fraction > 1.0:
            raise ScanError(f"smear_fraction must lie in [0, 1] (fraction of a step), got {self.smear_fraction}")
        if self.intensity_signal not in ("phasor", "power"):
            raise ScanError(f"intensity_signal must be 'phasor' or 'power', got {self.intensity_signal!r}")
        if not (isinstance(self.range_filter_length, int) and self.range_filter_length >= 1):
            raise ScanError(f"range_filter_length must be a positive integer (samples), got {self.range_filter_length!r}")
        if not isinstance(self.leaf_transmission, bool):
            raise ScanError(f"leaf_transmission must be true or false, got {self.leaf_transmission!r}")
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

    @property
    def bsdf_plugin(self) -> dict | None:
        """The Mitsuba BSDF plugin of ``bsdf`` as a dictionary (``None`` for Lambertian)."""
        return None if self.bsdf == "lambertian" else json.loads(self.bsdf)

    def noise_free(self) -> "ScannerModel":
        """A copy without amplitude and range noise, scan smear or range filter.

        What remains is deterministic: the traced geometry, the radiometry,
        the log amplifier and the detection threshold. Useful to test
        geometry (mixed pixels, footprints) free of noise.
        """
        return self.replace(intensity_noise_dn=0.0, range_noise_m=0.0, range_noise_floor_m=0.0,
                            smear_fraction=0.0, range_filter_length=1)

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
        """All fields as JSON-ready data (:meth:`from_dict` reads it back)."""
        return json.loads(json.dumps(dataclasses.asdict(self)))

    @classmethod
    def from_dict(cls, data: dict) -> "ScannerModel":
        """A model from :meth:`to_dict` output (e.g. the ``scanner_model`` of a saved scan).

        Raises
        ------
        ScanError
            If a field is unknown or invalid.
        """
        if not isinstance(data, dict):
            raise ScanError(f"a scanner model must be a mapping of its fields, got {type(data).__name__}")
        return cls().replace(**data)


def _check_positive(model, *fields):
    for name in fields:
        value = getattr(model, name)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ScanError(f"{name} must be a positive finite number, got {value!r}")


def _check_non_negative(model, *fields):
    for name in fields:
        value = getattr(model, name)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ScanError(f"{name} must be a finite number >= 0, got {value!r}")


def _filter_table(table) -> tuple[tuple[float, float], ...]:
    """Validate a near-range attenuator table ``((d_m, A), ...)``."""
    try:
        rows = tuple((float(d), float(a)) for d, a in table)
    except (TypeError, ValueError):
        raise ScanError(f"near_filter_table must list (distance_m, attenuation) pairs, got {table!r}") from None
    if not rows:
        return rows
    d = [r[0] for r in rows]
    a = [r[1] for r in rows]
    if len(rows) < 2 or not all(math.isfinite(x) and x > 0 for x in d) or any(x1 <= x0 for x0, x1 in zip(d, d[1:])):
        raise ScanError(f"near_filter_table needs >= 2 strictly increasing positive distances (m), got {list(d)}")
    if not all(math.isfinite(x) and 0 < x <= 1 for x in a):
        raise ScanError(f"near_filter_table attenuations must lie in (0, 1], got {list(a)}")
    return rows


def _bsdf_spec(spec) -> str:
    """Canonical text of a BSDF choice: ``"lambertian"`` or a JSON object with a ``type``."""
    if spec == "lambertian":
        return spec
    if isinstance(spec, str):
        try:
            spec = json.loads(spec)
        except json.JSONDecodeError:
            raise ScanError(f"bsdf must be 'lambertian' or a Mitsuba BSDF plugin as JSON, got {spec!r}") from None
    if not isinstance(spec, dict) or not isinstance(spec.get("type"), str):
        raise ScanError(f"bsdf must be 'lambertian' or a Mitsuba BSDF plugin with a 'type', got {spec!r}")
    return json.dumps(spec, sort_keys=True)


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
    "near_filter_range_m": "not published: assumption, d_f = 3 m (digest 7.5). The sources only say the attenuator "
                           "acts below ~3 m and I(d) is 1/d²-like beyond (Kaasalainen et al., cited in both); with "
                           "d_f = 3 m and m = 3 the 99 % target peaks near 2.4 m at ~1827 DN and never saturates",
    "near_filter_exponent": "not published: assumption, m = 3 (digest 7.5)",
    "near_filter_table": "empty: the analytic attenuator is used; a measured table can replace it",
    "intensity_signal": "decision (digest 7.3): the log amplifier sees the total phasor amplitude, so a leaf edge "
                        "over empty space keeps the leaf's distance but loses intensity",
    "intensity_noise_dn": "not published (digest 1.5): assumption, 3 DN at the reference target; with the shot-noise "
                          "exponent this gives ~4 DN for 48 % and ~40 DN for 3 % targets at 10 m (digest 7.4 asks "
                          "for 5-10 DN with extra scatter at low reflectance; Table 2 shift s.d. 30-50 DN at <= 22 %)",
    "intensity_noise_exponent": "assumption: 0.5, shot-noise-limited detection (amplitude noise ~ sqrt(signal))",
    "min_signal_dn": "assumption: 0 DN, the bottom of the log amplifier's range (SNR ~ 3 there with the noise "
                     "model); a 10 % target returns to ~40 m, a 90 % target beyond 76 m, a 3 % target to ~23 m",
    "range_noise_m": "1.386 mm at the reference signal: least-squares fit (log domain) of "
                     "sigma = s0 (A/A_ref)^-gamma to the four raw datasheet points (thesis ch.1; Table 1), A from "
                     "this model's radiometry (attenuator included); see tlssim.noise.fit_range_noise",
    "range_noise_exponent": "0.338: same fit (digest 7.11 gives 0.336 without the attenuator)",
    "range_noise_floor_m": "assumption: 0 (no signal-independent floor is published)",
    "range_filter_length": "1 (raw ranges). The preset 'faro-ls880-filtered' uses 15 consecutive samples: "
                           "averaging 15 gives 2.6/sqrt(15) = 0.67 and 5.2/sqrt(15) = 1.34 mm, close to the "
                           "published filtered 0.7 and 1.3 mm at 10 m (Table 1)",
    "smear_fraction": "assumption: 1.0, a continuously scanning mirror integrates over the whole sampling period "
                      "(digest 7.7 recommends a smear of one step along psi)",
    "leaf_transmission": "off by default (optional effect, digest 6.4); transmittance comes from the materials",
    "bsdf": "Lambertian by default (the sources' model); a Mitsuba BSDF is optional (leaves are not Lambertian, "
            "Sensors 2011 sec. 2.2.2)",
    "bsdf_object_types": "('leaf',): only leaves get the optional BSDF, calibration panels stay Lambertian",
}

#: Raw range precision of the LS880 (reflectance, distance m, RMS m): thesis ch.1 and Table 1.
FARO_LS880_RAW_PRECISION = ((0.90, 10.0, 2.6e-3), (0.10, 10.0, 5.2e-3), (0.90, 25.0, 4.2e-3), (0.10, 25.0, 10.0e-3))
#: Filtered range precision at 10 m (reflectance, distance m, RMS m): Table 1.
FARO_LS880_FILTERED_PRECISION = ((0.90, 10.0, 0.7e-3), (0.10, 10.0, 1.3e-3))

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

    Parameters
    ----------
    name : str
        Preset name (see :func:`preset_names`).
    **overrides
        :class:`ScannerModel` fields to replace, in the fields' units.

    Returns
    -------
    ScannerModel
        The preset, or a copy with the overrides.

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
register_preset(ScannerModel(name="faro-ls880-filtered", range_filter_length=15))


def parameter_table(model: ScannerModel, sources: dict[str, str] = FARO_LS880_SOURCES) -> str:
    """Markdown table of a model's parameters with the source or assumption behind each value.

    Parameters
    ----------
    model : ScannerModel
        The scanner model to tabulate.
    sources : dict of str to str
        Source or assumption behind each field, by field name.

    Returns
    -------
    str
        Markdown table, one row per field (values in the fields' units).
    """
    lines = ["| parameter | value | source / assumption |", "|---|---|---|"]
    for field in dataclasses.fields(model):
        if field.name == "name":
            continue
        value = getattr(model, field.name)
        shown = ", ".join(f"{v:.6g}" if isinstance(v, float) else str(v) for v in value) \
            if isinstance(value, tuple) else (f"{value:.6g}" if isinstance(value, float) else str(value))
        text = sources.get(field.name, "undocumented").replace("|", "/")
        lines.append(f"| `{field.name}` | {shown or '—'} | {text} |")
    return "\n".join(lines)

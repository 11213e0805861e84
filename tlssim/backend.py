"""Ray-tracing backend: Mitsuba 3 / Dr.Jit on the CPU (LLVM) or a GPU (CUDA).

:func:`select_backend` picks the Mitsuba variant (``llvm_ad_rgb`` or
``cuda_ad_rgb``). :class:`TraceScene` uploads a scene once as a single
triangle mesh plus per-face tables, and :meth:`TraceScene.trace` traces all
sub-rays of a chunk of pulses as one Dr.Jit wavefront: the rays are generated
inside the kernel that traces them (``ray_intersect_preliminary``, robust
Embree intersections, with the coherent-ray flag) and computes their
radiometry, and a second kernel, one lane per pulse, sums the phasors and
reduces the sub-rays; only the results are converted to numpy, once per
chunk, without copies on the CPU.

Options of the scanner model that act per sub-ray live here too: the scan
smear (each sub-ray is traced at a point of the integration time, so its
zenith angle is shifted along the fast axis), the optional BSDF (a per-object
table of the effective reflectance against incidence, :mod:`tlssim.bsdf`)
and the optional leaf transmission (a second ``ray_intersect_preliminary``
from the hit points of the sub-rays that met a transmitting material).

The tracing frame is the world frame translated so that the scanner sits at
the origin, which keeps float32 vertex coordinates precise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tlssim.beam import BeamSamples
from tlssim.bsdf import TABLE_ANGLES
from tlssim.errors import ScanError
from tlssim.pattern import ScannerPose
from tlssim.radiometry import subray_power
from tlssim.scanner import SPEED_OF_LIGHT_M_S, ScannerModel

BACKENDS = ("auto", "llvm", "cuda")

#: Fractional part of the golden ratio: spreads the sub-rays of a pulse over its integration time.
_GOLDEN = 0.5 * (math.sqrt(5.0) - 1.0)

#: Largest zenith shift of the scan smear whose sine and cosine are taken from their Taylor series, rad
#: (to the 5th and 6th order: the first term left out, |x|^7/5040 and x^8/40320, stays below 2e-8 at 0.3 rad).
SMALL_ANGLE_RAD = 0.3

#: Distance a transmitted sub-ray is moved past the surface it crossed before it is traced on, m.
TRANSMISSION_OFFSET_M = 1e-4

#: Trace with Embree's coherent-query flag. The sub-rays of a pulse and of its neighbours in a column leave one
#: origin nearly parallel, which is what the flag is for: the same hits (t and triangle compared bit for bit on
#: 2 M sub-rays of wavy-sheet, leafy-tree and orchard-row) about 3.5x faster on the LLVM backend.
COHERENT_RAYS = True


def select_backend(name: str = "auto") -> str:
    """Activate a Mitsuba variant and return the backend used.

    Parameters
    ----------
    name : {"auto", "llvm", "cuda"}
        ``auto`` takes CUDA when a GPU is usable, else LLVM (CPU).

    Returns
    -------
    str
        ``"llvm"`` or ``"cuda"``.

    Raises
    ------
    ScanError
        If the name is unknown or the requested backend cannot run here.
    """
    if name not in BACKENDS:
        raise ScanError(f"unknown backend {name!r}; allowed: {', '.join(BACKENDS)}")
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as exc:  # pragma: no cover - dependency missing
        raise ScanError(f"Mitsuba 3 / Dr.Jit are not installed ({exc}); run `make test` or `pip install -e .`") from exc
    if name == "auto":
        name = "cuda" if dr.has_backend(dr.JitBackend.CUDA) else "llvm"
    if name == "cuda" and not dr.has_backend(dr.JitBackend.CUDA):
        raise ScanError("backend 'cuda' requested but Dr.Jit finds no usable CUDA GPU; use --backend llvm")
    if name == "llvm" and not dr.has_backend(dr.JitBackend.LLVM):
        raise ScanError(
            "backend 'llvm' is unavailable: Dr.Jit could not load libLLVM. Install LLVM (e.g. `apt install "
            "libllvm15`) or point DRJIT_LIBLLVM_PATH at libLLVM.so; on a GPU machine use --backend cuda"
        )
    mi.set_variant(f"{name}_ad_rgb")
    return name


@dataclass
class SubrayHits:
    """Traced sub-rays of ``n`` pulses with ``S`` sub-rays each, with per-pulse reductions.

    Per-pulse arrays have shape ``(n,)``. The per-sub-ray arrays stay on the
    device: the rows of the mixed pulses come with the reductions, and the
    properties ``t``, ``object_id``, ``power`` and ``prim`` read all of them
    (``(n, S)``, read-only views of device memory on the CPU, copies from a
    GPU; sub-ray 0 is the central one).

    Attributes
    ----------
    phasors : list of (ndarray, ndarray)
        Real and imaginary parts of the summed phasor, one pair per
        modulation frequency (float64).
    total_power : ndarray
        Sum of the sub-rays' received power (including power returned
        through transmitting materials).
    axis : ndarray, shape (n, 3)
        Beam direction (world frame).
    central_t : ndarray
        Hit distance of the central sub-ray, m (``inf`` on a miss).
    object_low, object_high : ndarray, int32
        Smallest and largest object id among the sub-rays that returned
        power (``INT32_MAX`` and ``-1`` when none did); equal for pure pulses.
    first : ndarray, int32
        Index of the first sub-ray that returned power (``S`` when none).
    first_prim : ndarray, int64
        Triangle hit by that sub-ray (0 when none).
    mixed : ndarray, int64, shape (m,)
        The pulses whose returning sub-rays met more than one object.
    mixed_object_id, mixed_power, mixed_prim : ndarray, shape (m, S)
        Their sub-rays' object id (-1 on a miss), received power (first
        surface only) and triangle index.
    """

    phasors: list[tuple[np.ndarray, np.ndarray]]
    total_power: np.ndarray
    axis: np.ndarray
    central_t: np.ndarray
    object_low: np.ndarray
    object_high: np.ndarray
    first: np.ndarray
    first_prim: np.ndarray
    mixed: np.ndarray
    mixed_object_id: np.ndarray
    mixed_power: np.ndarray
    mixed_prim: np.ndarray
    _subrays: tuple = ()

    @property
    def t(self) -> np.ndarray:
        """Per-sub-ray hit distance, m (``inf`` on a miss), shape ``(n, S)``."""
        return self._host(0)

    @property
    def object_id(self) -> np.ndarray:
        """Per-sub-ray object id (-1 on a miss), shape ``(n, S)``."""
        return self._host(1)

    @property
    def power(self) -> np.ndarray:
        """Per-sub-ray received power (first surface only), shape ``(n, S)``."""
        return self._host(2)

    @property
    def prim(self) -> np.ndarray:
        """Per-sub-ray triangle index, shape ``(n, S)``."""
        return self._host(3)

    def _host(self, i):
        return np.asarray(self._subrays[i]).reshape(len(self.first), -1)


def _small_angle_sincos(x):
    """Sine and cosine of small angles (``|x| <= SMALL_ANGLE_RAD``) by their Taylor series, in a few multiplies."""
    x2 = x * x
    return (x * (1.0 + x2 * (-1.0 / 6.0 + x2 * (1.0 / 120.0))),
            1.0 + x2 * (-0.5 + x2 * (1.0 / 24.0 + x2 * (-1.0 / 720.0))))


def _pulse_frames(theta, psi, spin, time_shift=None):
    """Per-pulse sines and cosines of the beam angles and the spin, and the smear's time shift (Dr.Jit, evaluated).

    Returns ``([sin theta, cos theta, sin psi, cos psi, cos spin, sin spin], time_shift)``
    (the shift ``None`` without smear), float32 like the tracer: one kernel of
    ``n`` lanes whose results the pulse's sub-rays gather.
    """
    import drjit as dr
    import mitsuba as mi

    th, ps, sp = (mi.Float(np.asarray(a, np.float32)) for a in (theta, psi, spin))
    shift = None if time_shift is None else mi.Float(np.asarray(time_shift, np.float32))
    frame = [dr.sin(th), dr.cos(th), dr.sin(ps), dr.cos(ps), dr.cos(sp), dr.sin(sp)]
    dr.eval(*frame, shift)
    return frame, shift


def _flat_rays(model, beam, pose, frame, smear_rad):
    """The ``n·S`` sub-rays of the pulses of ``frame`` (:func:`_pulse_frames`), pulse-major, and their weights."""
    import drjit as dr
    import mitsuba as mi

    frame, shift = frame
    count = beam.count
    index = dr.arange(mi.UInt32, dr.width(frame[0]) * count)
    pulse = index // count
    k = index - pulse * count
    frame = [dr.gather(mi.Float, value, pulse) for value in frame]
    shift = None if shift is None else dr.gather(mi.Float, shift, pulse)
    u0, v0, weight = (dr.gather(mi.Float, mi.Float(getattr(beam, key).astype(np.float32)), k)
                      for key in ("u", "v", "weight"))
    return _beam_ray(model, pose, frame, shift, smear_rad, k, u0, v0), weight


def _beam_ray(model, pose, frame, time_shift, smear_rad, k, u0, v0):
    """Sub-ray ``k`` at layout offset ``(u0, v0)`` of pulses given per lane by their frame (unevaluated).

    ``k``, ``u0`` and ``v0`` are arrays (:func:`_flat_rays`) or constants
    (one sub-ray of every pulse): the arithmetic is the same, so both give
    the same rays bit for bit. Parameters as in :meth:`TraceScene.subrays`;
    ``frame`` and ``time_shift`` from :func:`_pulse_frames`, one per lane.
    """
    import drjit as dr
    import mitsuba as mi

    st, ct, s_psi, c_psi, cs, sn = frame
    if smear_rad > 0:
        instant = time_shift + mi.Float(k) * _GOLDEN
        shift = dr.select(k == 0, 0.0, (instant - dr.floor(instant) - 0.5) * smear_rad)
        sin_shift, cos_shift = _small_angle_sincos(shift) if smear_rad <= 2 * SMALL_ANGLE_RAD else dr.sincos(shift)
        s_psi, c_psi = s_psi * cos_shift + c_psi * sin_shift, c_psi * cos_shift - s_psi * sin_shift
    u, v = cs * u0 - sn * v0, sn * u0 + cs * v0
    axis = mi.Vector3f(s_psi * ct, s_psi * st, c_psi)
    e_psi = mi.Vector3f(c_psi * ct, c_psi * st, -s_psi)
    e_theta = mi.Vector3f(-st, ct, 0.0)
    offset = u * e_psi + v * e_theta
    origin = model.beam_waist_radius_m * offset
    direction = dr.normalize(axis + math.tan(math.radians(model.divergence_deg)) * offset)
    rotation = mi.Matrix3f(pose.rotation.tolist())
    return mi.Ray3f(rotation @ origin, rotation @ direction)


def _pulse_reductions(model, t, prim, obj, power, transmitted, pulse_start, count):
    """Per-pulse reductions of the sub-ray returns (unevaluated; one kernel of ``n`` lanes).

    Returns the first returning sub-ray, the smallest and largest object id
    among the returning sub-rays, the triangle of the first, the central
    sub-ray's distance, then the sum of the returned power and of its phasor
    at every modulation frequency (float64). The sub-rays of a pulse are
    visited in their order ``k = 0 .. S-1`` by explicit gathers:
    ``dr.block_sum`` (Dr.Jit 1.5) rounds differently depending on where a
    block falls in the array, so a pulse's sums would depend on which other
    pulses share its wavefront, and a tiled scan would not give the bytes of
    the whole one.
    """
    import drjit as dr
    import mitsuba as mi

    wavenumbers = [4.0 * math.pi * freq / SPEED_OF_LIGHT_M_S for freq in model.mod_freqs_hz]
    sums = [mi.Float64(0.0) for _ in range(1 + 2 * len(wavenumbers))]
    # Signed integers throughout: mixing int32 and uint32 reductions in one kernel
    # tripped a Dr.Jit 1.5 code-generation bug (duplicate helper names).
    first = mi.Int32(count)
    low, high = mi.Int32(np.iinfo(np.int32).max), mi.Int32(-1)
    for k in range(count):
        index = pulse_start + k
        t_k = dr.gather(mi.Float, t, index)
        power_k = dr.gather(mi.Float, power, index)
        obj_k = dr.gather(mi.Int32, obj, index)
        hit_k = t_k <= model.max_range_m
        returned = hit_k & (power_k > 0)
        if k == 0:
            central_t = t_k
        first = dr.select(returned & (first == count), k, first)
        low = dr.select(returned & (obj_k < low), obj_k, low)
        high = dr.select(returned & (obj_k > high), obj_k, high)
        returns = [(power_k, dr.select(hit_k, t_k, 1.0))]
        if transmitted is not None:
            returns.append(tuple(dr.gather(mi.Float, value, index) for value in transmitted))
        for p, d in returns:
            p, d = mi.Float64(p), mi.Float64(d)
            sums[0] += p
            for i, wavenumber in enumerate(wavenumbers):
                sin, cos = dr.sincos(d * wavenumber)
                sums[1 + 2 * i] += p * cos
                sums[2 + 2 * i] += p * sin
    has = first < count
    first_prim = dr.gather(mi.UInt32, prim, pulse_start + mi.UInt32(dr.select(has, first, 0)), has)
    return [first, low, high, first_prim, central_t, *sums]


class TraceScene:
    """A scene uploaded to the ray-tracing backend.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        World coordinates, m.
    faces : ndarray, shape (F, 3)
        Triangles.
    face_object : ndarray, shape (F,)
        Object id of every triangle.
    reflectance : ndarray, shape (n_objects,)
        Lambertian reflectance of every object.
    origin : ndarray, shape (3,)
        World position of the scanner; it becomes the tracing origin.
    transmittance : ndarray, shape (n_objects,), optional
        Transmittance of every object (used when the model enables leaf
        transmission).
    reflectance_table : ndarray, shape (n_objects, TABLE_ANGLES), optional
        Effective reflectance against incidence (:func:`tlssim.bsdf.reflectance_table`);
        replaces the Lambertian ``reflectance`` when given.
    """

    def __init__(self, vertices, faces, face_object, reflectance, origin, transmittance=None,
                 reflectance_table=None):
        import drjit as dr
        import mitsuba as mi

        self.origin = np.asarray(origin, dtype=np.float64)
        local = np.asarray(vertices, dtype=np.float64) - self.origin
        faces = np.asarray(faces)
        mesh = mi.Mesh("scene", len(local), len(faces), has_vertex_normals=False)
        params = mi.traverse(mesh)
        params["vertex_positions"] = mi.Float(local.astype(np.float32).ravel())
        params["faces"] = mi.UInt32(faces.astype(np.uint32).ravel())
        params.update()
        self.mi_scene = mi.load_dict({"type": "scene", "mesh": mesh, "embree_use_robust_intersections": True})

        tri = local[faces]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(cross, axis=1, keepdims=True)
        # Column-major, so that each component is contiguous: the truth takes them per pulse, one at a time.
        self.face_normals = np.asfortranarray(np.divide(cross, norm, out=np.zeros_like(cross), where=norm > 0))
        self._face_normal = mi.Float(self.face_normals.astype(np.float32).ravel())
        self._face_object = mi.Int32(np.asarray(face_object, dtype=np.int32))
        self._reflectance = mi.Float(np.asarray(reflectance, dtype=np.float32))
        self._table = None if reflectance_table is None else mi.Float(
            np.asarray(reflectance_table, dtype=np.float32).ravel())
        tau = np.zeros(len(reflectance)) if transmittance is None else np.asarray(transmittance, dtype=np.float32)
        self._transmittance = mi.Float(tau) if np.any(tau > 0) else None
        dr.eval(self._face_normal, self._face_object, self._reflectance, self._table, self._transmittance)

    def subrays(self, model: ScannerModel, beam: BeamSamples, pose: ScannerPose,
                theta: np.ndarray, psi: np.ndarray, spin: np.ndarray, smear_rad: float = 0.0,
                time_shift: np.ndarray | None = None):
        """Build the Dr.Jit sub-rays of a set of pulses (origins in the tracing frame), unevaluated.

        :meth:`trace` leaves them unevaluated too: Dr.Jit emits the Embree /
        OptiX call inside the kernel that generates the rays, so they never
        go through memory.

        Parameters
        ----------
        model : ScannerModel
            Scanner model (beam waist radius and divergence).
        beam : BeamSamples
            Sub-ray layout: offsets in units of the 1/e² radius and power weights (``S`` sub-rays).
        pose : ScannerPose
            Scanner orientation (its rotation turns the rays into the world axes; the position is the
            tracing origin given at construction).
        theta, psi : ndarray, shape (n,)
            Azimuth and zenith angle of each pulse's beam in the scanner frame, rad.
        spin : ndarray, shape (n,)
            Rotation of the sub-ray layout about the beam axis, per pulse, rad.
        smear_rad : float
            Zenith angle swept by the beam during one integration time, rad.
            Sub-ray ``k >= 1`` of a pulse is traced at the instant
            ``tau_k = frac(time_shift + k·0.618...)`` of the integration and
            its zenith is shifted by ``(tau_k - 1/2)·smear_rad``; the central
            sub-ray stays on the nominal beam (it defines the truth range).
        time_shift : ndarray, shape (n,), optional
            Per-pulse random offset in [0, 1) of those instants (required
            when ``smear_rad > 0``).

        Returns
        -------
        ray : mitsuba.Ray3f
            ``n·S`` rays, pulse-major (sub-ray ``k`` of pulse ``p`` at ``p·S + k``); origins in m.
        weight : mitsuba.Float
            Power share of each sub-ray.
        """
        frame = _pulse_frames(theta, psi, spin, time_shift if smear_rad > 0 else None)
        return _flat_rays(model, beam, pose, frame, smear_rad)

    def start_trace(self, model: ScannerModel, beam: BeamSamples, pose: ScannerPose,
                    theta: np.ndarray, psi: np.ndarray, spin: np.ndarray, smear_rad: float = 0.0,
                    time_shift: np.ndarray | None = None):
        """Launch the tracing of the sub-rays of a set of pulses and the sums of their phasors.

        The kernels run in the background (Dr.Jit's queue on the CPU, the
        GPU's stream): the caller can post-process the previous wavefront
        meanwhile, and calls the returned function for the results. Three
        kernels per wavefront: the pulses' sines and cosines; one lane
        per sub-ray for ray generation, first hit and surface radiometry (a
        second one traces behind transmitting surfaces when the model asks
        for it); one lane per pulse for the beam axis, the phasor sums and
        the reductions.

        Parameters
        ----------
        model : ScannerModel
            Scanner model (beam waist radius and divergence; for tracing also ``max_range_m``, the
            radiometry, the modulation frequencies and leaf transmission).
        beam : BeamSamples
            Sub-ray layout: offsets in units of the 1/e² radius and power weights (``S`` sub-rays).
        pose : ScannerPose
            Scanner orientation (its rotation turns the rays into the world axes; the position is the
            tracing origin given at construction).
        theta, psi : ndarray, shape (n,)
            Azimuth and zenith angle of each pulse's beam in the scanner frame, rad.
        spin : ndarray, shape (n,)
            Rotation of the sub-ray layout about the beam axis, per pulse, rad.
        smear_rad : float
            Zenith angle swept by the beam during one integration time, rad.
            Sub-ray ``k >= 1`` of a pulse is traced at the instant
            ``tau_k = frac(time_shift + k·0.618...)`` of the integration and
            its zenith is shifted by ``(tau_k - 1/2)·smear_rad``; the central
            sub-ray stays on the nominal beam (it defines the truth range).
        time_shift : ndarray, shape (n,), optional
            Per-pulse random offset in [0, 1) of those instants (required
            when ``smear_rad > 0``).

        Returns
        -------
        callable
            Without arguments; waits for the kernels and returns the :class:`SubrayHits` of the ``n``
            pulses (per-pulse phasor sums and reductions, and per-sub-ray hits). Call it before the
            next :meth:`start_trace`: reading results waits for every kernel queued before.
        """
        import drjit as dr
        import mitsuba as mi

        frame = _pulse_frames(theta, psi, spin, time_shift if smear_rad > 0 else None)
        ray, weight = _flat_rays(model, beam, pose, frame, smear_rad)
        t, prim = self.first_hits(ray)
        hit = t <= model.max_range_m  # t is +inf on a miss
        obj, power = self._surface_returns(model, ray, weight, prim, hit, dr.select(hit, t, 1.0))
        dr.eval(t, prim, obj, power)
        transmitted = None
        if model.leaf_transmission and self._transmittance is not None:
            transmitted = self._transmitted_returns(model, ray, weight, t, obj, hit)
            dr.eval(*transmitted)

        # The central sub-ray again, one per pulse: the same arithmetic as sub-ray 0 above, bit for bit.
        axis = _beam_ray(model, pose, *frame, smear_rad, 0, float(beam.u[0]), float(beam.v[0])).d
        pulse_start = dr.arange(mi.UInt32, len(theta)) * beam.count
        reduced = _pulse_reductions(model, t, prim, obj, power, transmitted, pulse_start, beam.count)
        dr.eval(axis, *reduced)
        first, low, high, first_prim, central_t, *sums = reduced

        count = beam.count

        def finish() -> SubrayHits:
            low_, high_ = np.asarray(low), np.asarray(high)
            mixed = np.nonzero((high_ >= 0) & (low_ != high_))[0]
            rows = mi.UInt32((mixed[:, None] * count + np.arange(count)).ravel().astype(np.uint32))
            mixed_rows = [np.asarray(dr.gather(type(value), value, rows)).reshape(len(mixed), count)
                          for value in (obj, power, prim)] if len(mixed) else [
                np.empty((0, count), dtype) for dtype in (np.int32, np.float32, np.uint32)]
            return SubrayHits(
                phasors=[(np.asarray(sums[i]), np.asarray(sums[i + 1])) for i in range(1, len(sums), 2)],
                total_power=np.asarray(sums[0]),
                axis=np.stack([np.asarray(axis.x), np.asarray(axis.y), np.asarray(axis.z)]).T,
                central_t=np.asarray(central_t),
                object_low=low_,
                object_high=high_,
                first=np.asarray(first),
                first_prim=np.asarray(first_prim).astype(np.int64),
                mixed=mixed,
                mixed_object_id=mixed_rows[0],
                mixed_power=mixed_rows[1],
                mixed_prim=mixed_rows[2],
                _subrays=(t, obj, power, prim),
            )

        return finish

    def trace(self, model: ScannerModel, beam: BeamSamples, pose: ScannerPose,
              theta: np.ndarray, psi: np.ndarray, spin: np.ndarray, smear_rad: float = 0.0,
              time_shift: np.ndarray | None = None) -> SubrayHits:
        """Trace the sub-rays of a set of pulses and sum their phasors (:meth:`start_trace`, waited for).

        Parameters
        ----------
        model : ScannerModel
            Scanner model (as in :meth:`start_trace`).
        beam : BeamSamples
            Sub-ray layout (``S`` sub-rays).
        pose : ScannerPose
            Scanner orientation.
        theta, psi : ndarray, shape (n,)
            Azimuth and zenith angle of each pulse's beam in the scanner frame, rad.
        spin : ndarray, shape (n,)
            Rotation of the sub-ray layout about the beam axis, per pulse, rad.
        smear_rad : float
            Zenith angle swept by the beam during one integration time, rad.
        time_shift : ndarray, shape (n,), optional
            Per-pulse random offset in [0, 1) of the sub-rays' instants (required when ``smear_rad > 0``).

        Returns
        -------
        SubrayHits
            Per-pulse phasor sums and reductions, and per-sub-ray hits, for the ``n`` pulses.
        """
        return self.start_trace(model, beam, pose, theta, psi, spin, smear_rad, time_shift)()

    def first_hits(self, ray, active=True):
        """Distance and triangle of the first hit of every ray, unevaluated.

        The only fields of the intersection record read: touching any other
        would trace the rays again.

        Parameters
        ----------
        ray : mitsuba.Ray3f
            Rays in the tracing frame (origins in m).
        active : mitsuba.Bool or bool
            Rays to trace.

        Returns
        -------
        t : mitsuba.Float
            Hit distance, m (``inf`` on a miss).
        prim : mitsuba.UInt32
            Triangle hit.
        """
        hit_info = self.mi_scene.ray_intersect_preliminary(ray, COHERENT_RAYS, active)
        return hit_info.t, hit_info.prim_index

    def _surface_returns(self, model, ray, weight, prim, hit, distance):
        """Object id and received power of sub-rays that hit triangles ``prim`` after a path of ``distance``."""
        import drjit as dr
        import mitsuba as mi

        obj = dr.select(hit, dr.gather(mi.Int32, self._face_object, prim, hit), -1)
        normal = dr.gather(mi.Vector3f, self._face_normal, prim, hit)
        cos_incidence = dr.abs(dr.dot(normal, ray.d))
        rho = self._effective_reflectance(obj, cos_incidence, hit)
        return obj, dr.select(hit, subray_power(model, weight, rho, cos_incidence, distance), 0.0)

    def _effective_reflectance(self, obj, cos_incidence, active):
        """Lambertian reflectance of the hit objects, or their BSDF table interpolated at the incidence."""
        import drjit as dr
        import mitsuba as mi

        if self._table is None:
            return dr.gather(mi.Float, self._reflectance, obj, active)
        # Clamps by select: dr.minimum / dr.maximum / dr.clip on floats emit the
        # fminimum / fmaximum intrinsics that LLVM 15 cannot compile on x86.
        cos_incidence = dr.select(cos_incidence < 1.0, cos_incidence, 1.0)
        position = dr.acos(cos_incidence) * ((TABLE_ANGLES - 1) / (0.5 * math.pi))
        node = mi.UInt32(position)
        node = dr.select(node < TABLE_ANGLES - 2, node, TABLE_ANGLES - 2)
        frac = position - mi.Float(node)
        index = mi.UInt32(dr.select(active, obj, 0)) * TABLE_ANGLES + node
        low = dr.gather(mi.Float, self._table, index, active)
        return low + frac * (dr.gather(mi.Float, self._table, index + 1, active) - low)

    def _transmitted_returns(self, model, ray, weight, t, obj, hit):
        """Power and path length of the sub-ray shares that cross a transmitting surface and come back (unevaluated).

        The share ``tau`` of the sub-ray continues undeviated from the hit
        point, is reflected by the next surface, and crosses the first one
        again on its way back (``tau²`` in all). One crossing is modelled.
        """
        import drjit as dr
        import mitsuba as mi

        tau = dr.gather(mi.Float, self._transmittance, obj, hit)
        through = hit & (tau > 0)
        start = dr.select(through, t + TRANSMISSION_OFFSET_M, 0.0)
        behind = mi.Ray3f(ray.o + ray.d * start, ray.d)
        t2, prim2 = self.first_hits(behind, through)
        path = start + t2
        hit2 = through & (path <= model.max_range_m)
        distance = dr.select(hit2, path, 1.0)
        _, power = self._surface_returns(model, behind, weight * tau * tau, prim2, hit2, distance)
        return power, distance

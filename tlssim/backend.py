"""Ray-tracing backend: Mitsuba 3 / Dr.Jit on the CPU (LLVM) or a GPU (CUDA).

:func:`select_backend` picks the Mitsuba variant (``llvm_ad_rgb`` or
``cuda_ad_rgb``). :class:`TraceScene` uploads a scene once as a single
triangle mesh plus per-face tables, and :meth:`TraceScene.trace` traces all
sub-rays of a chunk of pulses as one Dr.Jit wavefront: ray generation,
``ray_intersect_preliminary`` (robust Embree intersections), per-sub-ray
radiometry and the per-pulse phasor sums stay on the device; only the
results are converted to numpy, once per chunk.

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

    Per-pulse arrays have shape ``(n,)``; per-sub-ray arrays ``(n, S)`` are
    read-only views of device memory (sub-ray 0 is the central one).

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
    t, object_id, power, prim : ndarray, shape (n, S)
        Per-sub-ray hit distance (m, ``inf`` on a miss), object id (-1 on a
        miss), received power (first surface only) and triangle index.
    """

    phasors: list[tuple[np.ndarray, np.ndarray]]
    total_power: np.ndarray
    axis: np.ndarray
    central_t: np.ndarray
    object_low: np.ndarray
    object_high: np.ndarray
    first: np.ndarray
    first_prim: np.ndarray
    t: np.ndarray
    object_id: np.ndarray
    power: np.ndarray
    prim: np.ndarray
    _device_arrays: tuple = ()


def _small_angle_sincos(x):
    """Sine and cosine of small angles (``|x| <= SMALL_ANGLE_RAD``) by their Taylor series, in a few multiplies."""
    x2 = x * x
    return (x * (1.0 + x2 * (-1.0 / 6.0 + x2 * (1.0 / 120.0))),
            1.0 + x2 * (-0.5 + x2 * (1.0 / 24.0 + x2 * (-1.0 / 720.0))))


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
        self.face_normals = np.divide(cross, norm, out=np.zeros_like(cross), where=norm > 0)
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
        """Build the Dr.Jit sub-rays of a set of pulses (origins in the tracing frame).

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
        ray : mitsuba.Ray3f
            ``n·S`` rays, pulse-major (sub-ray ``k`` of pulse ``p`` at ``p·S + k``); origins in m.
        weight : mitsuba.Float
            Power share of each sub-ray.
        """
        import drjit as dr
        import mitsuba as mi

        count = beam.count
        # Sines and cosines once per pulse (a kernel of n lanes), gathered by its S sub-rays.
        th, ps, sp = (mi.Float(np.asarray(a, np.float32)) for a in (theta, psi, spin))
        per_pulse = [dr.sin(th), dr.cos(th), dr.sin(ps), dr.cos(ps), dr.cos(sp), dr.sin(sp)]
        dr.eval(*per_pulse)
        index = dr.arange(mi.UInt32, len(theta) * count)
        pulse = index // count
        k = index - pulse * count
        st, ct, s_psi, c_psi, cs, sn = (dr.gather(mi.Float, value, pulse) for value in per_pulse)
        if smear_rad > 0:
            instant = dr.gather(mi.Float, mi.Float(np.asarray(time_shift, np.float32)), pulse) + mi.Float(k) * _GOLDEN
            shift = dr.select(k == 0, 0.0, (instant - dr.floor(instant) - 0.5) * smear_rad)
            sin_shift, cos_shift = _small_angle_sincos(shift) if smear_rad <= 2 * SMALL_ANGLE_RAD else dr.sincos(shift)
            s_psi, c_psi = s_psi * cos_shift + c_psi * sin_shift, c_psi * cos_shift - s_psi * sin_shift
        u0 = dr.gather(mi.Float, mi.Float(beam.u.astype(np.float32)), k)
        v0 = dr.gather(mi.Float, mi.Float(beam.v.astype(np.float32)), k)
        weight = dr.gather(mi.Float, mi.Float(beam.weight.astype(np.float32)), k)
        u, v = cs * u0 - sn * v0, sn * u0 + cs * v0

        axis = mi.Vector3f(s_psi * ct, s_psi * st, c_psi)
        e_psi = mi.Vector3f(c_psi * ct, c_psi * st, -s_psi)
        e_theta = mi.Vector3f(-st, ct, 0.0)
        offset = u * e_psi + v * e_theta
        origin = model.beam_waist_radius_m * offset
        direction = dr.normalize(axis + math.tan(math.radians(model.divergence_deg)) * offset)
        rotation = mi.Matrix3f(pose.rotation.tolist())
        return mi.Ray3f(rotation @ origin, rotation @ direction), weight

    def trace(self, model: ScannerModel, beam: BeamSamples, pose: ScannerPose,
              theta: np.ndarray, psi: np.ndarray, spin: np.ndarray, smear_rad: float = 0.0,
              time_shift: np.ndarray | None = None) -> SubrayHits:
        """Trace the sub-rays of a set of pulses and sum their phasors.

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
        SubrayHits
            Per-pulse phasor sums and reductions, and per-sub-ray hits, for the ``n`` pulses.
        """
        import drjit as dr
        import mitsuba as mi

        ray, weight = self.subrays(model, beam, pose, theta, psi, spin, smear_rad, time_shift)
        dr.eval(ray, weight)
        t, prim = self._first_hits(ray)
        hit = t <= model.max_range_m  # t is +inf on a miss
        distance = dr.select(hit, t, 1.0)
        obj, power = self._surface_returns(model, ray, weight, prim, hit, distance)
        returns = [(power, distance)]
        if model.leaf_transmission and self._transmittance is not None:
            returns.append(self._transmitted_returns(model, ray, weight, t, obj, hit))
        dr.eval(obj, power, *(value for pair in returns[1:] for value in pair))

        count = beam.count
        returned = hit & (power > 0)
        # Signed throughout: mixing int32 and uint32 symbolic reductions in one
        # kernel trips a Dr.Jit 1.5 code-generation bug (duplicate helper names).
        k = dr.arange(mi.Int32, dr.width(t)) % count
        first = dr.block_reduce(dr.ReduceOp.Min, dr.select(returned, k, count), count, mode="symbolic")
        low = dr.block_reduce(dr.ReduceOp.Min, dr.select(returned, obj, np.iinfo(np.int32).max), count, mode="symbolic")
        high = dr.block_reduce(dr.ReduceOp.Max, dr.select(returned, obj, -1), count, mode="symbolic")
        pulse_start = dr.arange(mi.UInt32, len(theta)) * count
        has = first < count
        first_prim = dr.gather(mi.UInt32, prim, pulse_start + mi.UInt32(dr.select(has, first, 0)), has)
        central_t = dr.gather(mi.Float, t, pulse_start)
        axis = dr.gather(mi.Vector3f, ray.d, pulse_start)
        sums = self._phasor_sums(model, returns, pulse_start, count)
        dr.eval(first, low, high, first_prim, central_t, axis, *sums)

        shape = (len(theta), count)
        return SubrayHits(
            phasors=[(np.asarray(sums[i]), np.asarray(sums[i + 1])) for i in range(1, len(sums), 2)],
            total_power=np.asarray(sums[0]),
            axis=np.stack([np.asarray(axis.x), np.asarray(axis.y), np.asarray(axis.z)], axis=1),
            central_t=np.asarray(central_t),
            object_low=np.asarray(low),
            object_high=np.asarray(high),
            first=np.asarray(first).astype(np.int32),
            first_prim=np.asarray(first_prim).astype(np.int64),
            t=np.asarray(t).reshape(shape),
            object_id=np.asarray(obj).reshape(shape),
            power=np.asarray(power).reshape(shape),
            prim=np.asarray(prim).reshape(shape),
            _device_arrays=(t, obj, power, prim),
        )

    @staticmethod
    def _phasor_sums(model, returns, pulse_start, count):
        """Per-pulse sums of the returned power and of its phasor at every modulation frequency (float64).

        The sub-rays of a pulse are added in their order ``k = 0 .. S-1`` by
        explicit gathers: ``dr.block_sum`` (Dr.Jit 1.5) rounds differently
        depending on where a block falls in the array, so a pulse's sums
        would depend on which other pulses share its wavefront, and a tiled
        scan would not give the bytes of the whole one.
        """
        import drjit as dr
        import mitsuba as mi

        dr.eval(*(value for pair in returns for value in pair))
        wavenumbers = [4.0 * math.pi * freq / SPEED_OF_LIGHT_M_S for freq in model.mod_freqs_hz]
        sums = [mi.Float64(0.0) for _ in range(1 + 2 * len(wavenumbers))]
        for k in range(count):
            for power, distance in returns:
                p = mi.Float64(dr.gather(mi.Float, power, pulse_start + k))
                d = mi.Float64(dr.gather(mi.Float, distance, pulse_start + k))
                sums[0] += p
                for i, wavenumber in enumerate(wavenumbers):
                    sin, cos = dr.sincos(d * wavenumber)
                    sums[1 + 2 * i] += p * cos
                    sums[2 + 2 * i] += p * sin
        return sums

    def _first_hits(self, ray, active=True):
        """Distance and triangle of the first hit of every ray, evaluated once.

        Every later kernel reads these two arrays: touching any other field
        of the intersection record would trace the rays again.
        """
        import drjit as dr

        hit_info = self.mi_scene.ray_intersect_preliminary(ray, False, active)
        t, prim = hit_info.t, hit_info.prim_index
        dr.eval(t, prim)
        return t, prim

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
        """Power and path length of the sub-ray shares that cross a transmitting surface and come back.

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
        t2, prim2 = self._first_hits(behind, through)
        path = start + t2
        hit2 = through & (path <= model.max_range_m)
        distance = dr.select(hit2, path, 1.0)
        _, power = self._surface_returns(model, behind, weight * tau * tau, prim2, hit2, distance)
        return power, distance

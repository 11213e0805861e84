"""Ray-tracing backend: Mitsuba 3 / Dr.Jit on the CPU (LLVM) or a GPU (CUDA).

:func:`select_backend` picks the Mitsuba variant (``llvm_ad_rgb`` or
``cuda_ad_rgb``). :class:`TraceScene` uploads a scene once as a single
triangle mesh plus per-face tables, and :meth:`TraceScene.trace` traces all
sub-rays of a chunk of pulses as one Dr.Jit wavefront: ray generation,
``ray_intersect_preliminary`` (robust Embree intersections), per-sub-ray
radiometry and the per-pulse phasor sums stay on the device; only the
results are converted to numpy, once per chunk.

The tracing frame is the world frame translated so that the scanner sits at
the origin, which keeps float32 vertex coordinates precise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tlssim.beam import BeamSamples
from tlssim.errors import ScanError
from tlssim.pattern import ScannerPose
from tlssim.radiometry import subray_power
from tlssim.scanner import SPEED_OF_LIGHT_M_S, ScannerModel

BACKENDS = ("auto", "llvm", "cuda")


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
        Sum of the sub-rays' received power.
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
        miss), received power and triangle index.
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
    """

    def __init__(self, vertices, faces, face_object, reflectance, origin):
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
        dr.eval(self._face_normal, self._face_object, self._reflectance)

    def subrays(self, model: ScannerModel, beam: BeamSamples, pose: ScannerPose,
                theta: np.ndarray, psi: np.ndarray, spin: np.ndarray):
        """Build the Dr.Jit sub-rays of a set of pulses (origins in the tracing frame).

        Parameters
        ----------
        model, beam, pose
            Scanner model, sub-ray layout and pose.
        theta, psi : ndarray, shape (n,)
            Beam angles of the pulses, radians.
        spin : ndarray, shape (n,)
            Rotation of the sub-ray layout about the beam axis, per pulse, radians.

        Returns
        -------
        ray : mitsuba.Ray3f
            ``n·S`` rays, pulse-major (sub-ray ``k`` of pulse ``p`` at ``p·S + k``).
        weight : mitsuba.Float
            Power share of each sub-ray.
        """
        import drjit as dr
        import mitsuba as mi

        count = beam.count
        index = dr.arange(mi.UInt32, len(theta) * count)
        pulse = index // count
        k = index - pulse * count
        th = dr.gather(mi.Float, mi.Float(np.asarray(theta, np.float32)), pulse)
        ps = dr.gather(mi.Float, mi.Float(np.asarray(psi, np.float32)), pulse)
        sp = dr.gather(mi.Float, mi.Float(np.asarray(spin, np.float32)), pulse)
        u0 = dr.gather(mi.Float, mi.Float(beam.u.astype(np.float32)), k)
        v0 = dr.gather(mi.Float, mi.Float(beam.v.astype(np.float32)), k)
        weight = dr.gather(mi.Float, mi.Float(beam.weight.astype(np.float32)), k)
        cs, sn = dr.cos(sp), dr.sin(sp)
        u, v = cs * u0 - sn * v0, sn * u0 + cs * v0

        st, ct, s_psi, c_psi = dr.sin(th), dr.cos(th), dr.sin(ps), dr.cos(ps)
        axis = mi.Vector3f(s_psi * ct, s_psi * st, c_psi)
        e_psi = mi.Vector3f(c_psi * ct, c_psi * st, -s_psi)
        e_theta = mi.Vector3f(-st, ct, 0.0)
        offset = u * e_psi + v * e_theta
        origin = model.beam_waist_radius_m * offset
        direction = dr.normalize(axis + math.tan(math.radians(model.divergence_deg)) * offset)
        rotation = mi.Matrix3f(pose.rotation.tolist())
        return mi.Ray3f(rotation @ origin, rotation @ direction), weight

    def trace(self, model: ScannerModel, beam: BeamSamples, pose: ScannerPose,
              theta: np.ndarray, psi: np.ndarray, spin: np.ndarray) -> SubrayHits:
        """Trace the sub-rays of a set of pulses and sum their phasors.

        Parameters are those of :meth:`subrays`.

        Returns
        -------
        SubrayHits
        """
        import drjit as dr
        import mitsuba as mi

        ray, weight = self.subrays(model, beam, pose, theta, psi, spin)
        dr.eval(ray, weight)
        # Evaluate the intersection once: every later kernel reads these two
        # arrays (touching any other field of `hit_info` would trace again).
        hit_info = self.mi_scene.ray_intersect_preliminary(ray, False)
        t, prim = hit_info.t, hit_info.prim_index
        dr.eval(t, prim)
        hit = t <= model.max_range_m  # t is +inf on a miss
        obj = dr.select(hit, dr.gather(mi.Int32, self._face_object, prim, hit), -1)
        normal = dr.gather(mi.Vector3f, self._face_normal, prim, hit)
        cos_incidence = dr.abs(dr.dot(normal, ray.d))
        rho = dr.gather(mi.Float, self._reflectance, obj, hit)
        distance = dr.select(hit, t, 1.0)
        power = dr.select(hit, subray_power(model, weight, rho, cos_incidence, distance), 0.0)
        dr.eval(obj, power)

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
        sums = [dr.block_sum(mi.Float64(power), count, mode="symbolic")]
        power64, distance64 = mi.Float64(power), mi.Float64(distance)
        for freq in model.mod_freqs_hz:
            phase = distance64 * (4.0 * math.pi * freq / SPEED_OF_LIGHT_M_S)
            sums += [dr.block_sum(power64 * dr.cos(phase), count, mode="symbolic"),
                     dr.block_sum(power64 * dr.sin(phase), count, mode="symbolic")]
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

"""Footprint on inclined planes: traced extent vs eq. 1.4, and the range bias it causes."""

import math

import numpy as np
import pytest

from scenes.primitives import rectangle
from tlssim.backend import TraceScene
from tlssim.beam import footprint_axes_m, sample_beam
from tlssim.pattern import ScannerPose
from tlssim.radiometry import range_gain
from tlssim.ranging import unwrap_distance
from tlssim.scanner import get_preset

DISTANCE = 2.16  # m, the goniometer distance of the sources
SPINS = 8


def _trace_inclined_plane(model, incidence_deg, distance=DISTANCE):
    """Trace SPINS pulses (beam along +x) onto a plane at ``distance`` tilted by the incidence angle.

    Returns the hits, the hit points and sub-ray directions (n, 3), the beam weights and the incidence (rad).
    """
    a = math.radians(incidence_deg)
    vertices, faces = rectangle((distance, 0, 0), (-math.cos(a), math.sin(a), 0), (3.0, 3.0))
    traced = TraceScene(vertices, faces, np.zeros(len(faces), np.int32), np.array([0.5]), np.zeros(3))
    beam = sample_beam(model.n_subrays, model.beam_profile)
    pose, theta, psi = ScannerPose(), np.zeros(SPINS), np.full(SPINS, math.pi / 2)
    spin = np.linspace(0, 2 * math.pi, SPINS, endpoint=False)
    hits = traced.trace(model, beam, pose, theta, psi, spin)
    ray, _ = traced.subrays(model, beam, pose, theta, psi, spin)
    origin = np.stack([np.asarray(c) for c in (ray.o.x, ray.o.y, ray.o.z)], axis=1)
    direction = np.stack([np.asarray(c) for c in (ray.d.x, ray.d.y, ray.d.z)], axis=1)
    points = origin + direction * hits.t.reshape(-1, 1)
    return hits, points, direction, np.tile(beam.weight, SPINS) / SPINS, a


def _extent(points, weight, axis):
    """1/e² extent (4 sigma) of the beam-power distribution of hit points along ``axis``, m."""
    x = points @ axis
    mean = np.sum(weight * x)
    return 4 * math.sqrt(np.sum(weight * (x - mean) ** 2))


@pytest.mark.parametrize("n_subrays", [19, 91])
@pytest.mark.parametrize("incidence_deg", [0, 40, 70, 85])
def test_traced_footprint_follows_eq_1_4(llvm, n_subrays, incidence_deg):
    model = get_preset("faro-ls880", n_subrays=n_subrays)
    hits, points, _, weight, a = _trace_inclined_plane(model, incidence_deg)
    assert np.all(np.isfinite(hits.t))
    major, minor = footprint_axes_m(model, DISTANCE, a)
    # Published: 4.1 mm at 0 deg, 46.5 mm at 85 deg (2.16 m); the issue asks for 10 %.
    assert _extent(points, weight, np.array([math.sin(a), math.cos(a), 0])) == pytest.approx(major, rel=0.02)
    assert _extent(points, weight, np.array([0, 0, 1.0])) == pytest.approx(minor, rel=0.02)


def test_inclined_plane_range_bias(llvm):
    """The phase range is the power-weighted mean distance over the elongated footprint.

    Two geometric effects nearly cancel: the footprint's middle point lies
    beyond the beam axis (the sources' explanation of the over-estimate),
    while the far side is hit at a slightly larger incidence and so returns
    less (cos alpha). What remains is the weighting by the range gain g(d)
    across the spread of distances Delta: bias ~ beta·var(Delta)/d with
    beta = dln g/dln d, i.e. short for a pure 1/d² gain (beta = -2) and long
    where g rises with distance (behind the LS880's near-range filter, beta > 0
    below ~2.6 m).
    """
    model = get_preset("faro-ls880", n_subrays=91)
    beta = (math.log(range_gain(model, DISTANCE * 1.001)) - math.log(range_gain(model, DISTANCE / 1.001))) \
        / (2 * math.log(1.001))
    biases, middles = [], []
    for incidence in (20, 40, 60, 75, 85):
        hits, points, direction, weight, a = _trace_inclined_plane(model, incidence)
        measured = unwrap_distance(hits.phasors, model.mod_freqs_hz) - hits.central_t
        # Independent evaluation of the radiometry on the traced geometry.
        t = hits.t.astype(float)
        cos = np.abs(direction @ np.array([-math.cos(a), math.sin(a), 0])).reshape(t.shape)
        power = weight.reshape(t.shape) * cos * range_gain(model, t)
        weighted = np.sum(power * t, axis=1) / np.sum(power, axis=1) - hits.central_t
        assert np.allclose(measured, weighted, atol=0.5e-6)
        middle = np.mean(t, axis=1) - hits.central_t
        spread = t - t.mean(axis=1, keepdims=True)
        assert np.allclose(measured, beta * np.mean(spread**2, axis=1) / DISTANCE, rtol=0.15, atol=1e-6)
        biases.append(float(np.mean(measured)))
        middles.append(float(np.mean(middle)))
    # middle point beyond the axis (float32 hit distances resolve ~0.3 um at 2 m)
    assert all(m > -0.3e-6 for m in middles) and np.all(np.diff(middles[2:]) > 0)
    # The bias grows with incidence; at 20-40 deg it is below float32 resolution when beta is
    # small (+0.18 at 2.16 m behind the LS880 attenuator, d_f = 3 m, m = 3), so compare from 40 deg.
    assert np.all(np.diff(np.abs(biases[1:])) > 0)
    assert math.copysign(1, biases[-1]) == math.copysign(1, beta)  # long behind a rising gain, short for 1/d²

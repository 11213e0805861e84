"""Scan smear, optional leaf transmission and optional BSDF reflectance."""

import dataclasses
import math

import numpy as np
import pytest

import scenes
from scenes.scene import Material
from tlssim.backend import TraceScene
from tlssim.beam import sample_beam
from tlssim.bsdf import TABLE_ANGLES, backscatter_reflectance, table_angles
from tlssim.detector import log_amplifier_dn
from tlssim.errors import ScanError
from tlssim.pattern import ScannerPose
from tlssim.radiometry import subray_power
from tlssim.ranging import unwrap_distance
from tlssim.scanner import get_preset
from tlssim.simulate import setup_from_section, simulate

from scenes.primitives import rectangle


def _moments(points, weight):
    mean = np.sum(weight[:, None] * points, axis=0) / weight.sum()
    return np.sum(weight[:, None] * (points - mean) ** 2, axis=0) / weight.sum()


def test_smear_stretches_the_footprint_along_psi_only(llvm):
    """Power-weighted variance across the beam grows by (S-1)/S · (smear·d)²/12 along psi, not along theta."""
    distance, pulses = 2.0, 4000
    model = get_preset("faro-ls880")
    vertices, faces = rectangle((distance, 0, 0), (-1, 0, 0), (1.0, 1.0))
    traced = TraceScene(vertices, faces, np.zeros(len(faces), np.int32), np.array([0.5]), np.zeros(3))
    beam = sample_beam(model.n_subrays, model.beam_profile)
    rng = np.random.default_rng(0)
    theta, psi = np.zeros(pulses), np.full(pulses, math.pi / 2)
    spin, shift = rng.uniform(0, 2 * math.pi, pulses), rng.uniform(0, 1, pulses)
    variances = {}
    for smear in (0.0, math.radians(0.3)):
        ray, weight = traced.subrays(model, beam, ScannerPose(), theta, psi, spin, smear, shift)
        hits = traced.trace(model, beam, ScannerPose(), theta, psi, spin, smear, shift)
        direction = np.stack([np.asarray(c) for c in (ray.d.x, ray.d.y, ray.d.z)], axis=1)
        origin = np.stack([np.asarray(c) for c in (ray.o.x, ray.o.y, ray.o.z)], axis=1)
        points = origin + direction * hits.t.reshape(-1, 1)
        variances[smear] = _moments(points[:, 1:], np.asarray(weight, dtype=float))  # (theta: y, psi: z)
    stretch = (beam.count - 1) / beam.count * (math.radians(0.3) * distance) ** 2 / 12
    base = variances[0.0]
    assert base[1] == pytest.approx(base[0], rel=0.03)  # round beam without smear
    smeared = variances[math.radians(0.3)]
    assert smeared[0] == pytest.approx(base[0], rel=0.03)
    assert smeared[1] - base[1] == pytest.approx(stretch, rel=0.05)


def test_smear_follows_the_window_step(llvm):
    """A row 0.15 deg inside a horizontal edge, scanned at a 0.5 deg step: the smear (+-0.25 deg) puts part
    of its footprint over the void, so its intensity drops by k·ln(1/19 + 18/19·0.8)."""
    base = scenes.build("knife-edge")
    scene = dataclasses.replace(base, objects=base.objects[:1])  # plate (z in [-0.1, 0.1] m at 1.5 m), no wall
    psi_row = 90 + math.degrees(math.atan(0.1 / 1.5)) - 0.15
    scene = scene.with_scanner(window={"theta_deg": [-2.0, -1.0], "psi_deg": [psi_row - 1.0, psi_row],
                                       "step_deg": [0.02, 0.5]})
    drop = {}
    for fraction in (0.0, 1.0):
        model = get_preset("faro-ls880").noise_free().replace(smear_fraction=fraction)
        scan = simulate(scene, setup_from_section(scene.scanner, model=model), progress=False, backend="llvm")
        assert np.all(scan.valid)
        drop[fraction] = float(np.mean(scan.intensity[-1] - scan.intensity[0]))
    assert drop[0.0] == pytest.approx(0.0, abs=0.5)
    expected = get_preset("faro-ls880").log_gain_dn * math.log(1 / 19 + 18 / 19 * 0.8)
    assert drop[1.0] == pytest.approx(expected, abs=6)


def _leaf_over_wall(**model_changes):
    scene = scenes.build("knife-edge")
    leaf, wall = scene.objects
    leaf = dataclasses.replace(leaf, type="leaf", material=Material("leaf", 0.5, 0.4))
    scene = dataclasses.replace(scene, objects=[leaf, wall])
    model = get_preset("faro-ls880").noise_free().replace(**model_changes)
    scan = simulate(scene, setup_from_section(scene.scanner, model=model), progress=False, backend="llvm")
    inner = np.degrees(scan.theta) < -0.3  # beams wholly on the leaf
    return scan, model, inner


def test_leaf_transmission_adds_the_attenuated_return_from_behind(llvm):
    scan, model, inner = _leaf_over_wall()
    assert np.allclose(scan.range[inner], 1.5 / np.cos(scan.theta[inner]), atol=1e-4)  # off by default
    scan, model, inner = _leaf_over_wall(leaf_transmission=True)
    r, c = np.nonzero(inner)
    r, c = r[len(r) // 2], c[len(c) // 2]
    cos = math.sin(scan.psi[r, c]) * math.cos(scan.theta[r, c])
    d1, d2 = 1.5 / cos, 2.0 / cos
    powers = np.array([subray_power(model, 1.0, 0.5, cos, d1), subray_power(model, 1.0, 0.4**2 * 0.5, cos, d2)])
    phases = 4 * math.pi * model.mod_freqs_hz[0] / 299_792_458.0 * np.array([d1, d2])
    phasor = (np.sum(powers * np.cos(phases)), np.sum(powers * np.sin(phases)))
    expected_range = unwrap_distance([tuple(np.array([p]) for p in phasor)], model.mod_freqs_hz)[0]
    assert d1 < scan.range[r, c] < d2
    assert scan.range[r, c] == pytest.approx(expected_range, abs=2e-4)
    assert scan.intensity[r, c] == pytest.approx(log_amplifier_dn(model, np.array([math.hypot(*phasor)]))[0], abs=1)


def test_diffuse_bsdf_reproduces_the_lambertian_model(llvm):
    lambertian, _, _ = _leaf_over_wall()
    diffuse, _, _ = _leaf_over_wall(bsdf={"type": "diffuse"})
    assert np.array_equal(lambertian.intensity, diffuse.intensity)
    assert np.allclose(lambertian.range, diffuse.range, atol=1e-6)
    assert np.allclose(backscatter_reflectance({"type": "diffuse"}, 0.3), 0.3)


def test_rough_plastic_leaf_has_a_hot_spot_and_leaves_other_objects_alone(llvm):
    plugin = {"type": "roughplastic", "alpha": 0.3, "int_ior": 1.47}
    table = backscatter_reflectance(plugin, 0.5)
    assert len(table) == TABLE_ANGLES and table_angles()[-1] == pytest.approx(math.pi / 2)
    assert table[0] > 0.5 > table[-1]  # specular hot spot at normal incidence, Fresnel loss towards grazing
    # the diffuse reflectance enters linearly (non-linear internal scattering off in Mitsuba's default)
    halfway = 0.5 * (backscatter_reflectance(plugin, 0.0) + backscatter_reflectance(plugin, 1.0))
    assert np.allclose(table, halfway, atol=1e-5)
    lambertian, _, inner = _leaf_over_wall()
    shiny, _, _ = _leaf_over_wall(bsdf=plugin)
    wall = np.degrees(lambertian.theta) > 0.3
    assert np.all(shiny.intensity[inner] > lambertian.intensity[inner])  # leaf seen near normal incidence
    assert np.array_equal(shiny.intensity[wall], lambertian.intensity[wall])  # the wall is not a leaf


def test_unsupported_bsdf_is_refused(llvm):
    with pytest.raises(ScanError, match="not supported"):
        backscatter_reflectance({"type": "conductor"}, 0.5)
    with pytest.raises(ScanError, match="cannot be loaded"):
        backscatter_reflectance({"type": "roughplastic", "alpha": "rough"}, 0.5)

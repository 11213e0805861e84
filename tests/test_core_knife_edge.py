"""Knife edge: the Gaussian power split and the phase-shift mixed range.

The ``knife-edge`` scene puts a plate (rho 0.5) at 1.5 m in front of a wall
(rho 0.5) at 2 m; its vertical edge lies on the plane y = 0, which the
window's middle column crosses.
"""

import math

import numpy as np
import pytest
from scipy.special import erfc

import scenes
from scenes.scene import Scene
from tlssim.radiometry import range_gain
from tlssim.scanner import get_preset
from tlssim.simulate import setup_from_section, simulate

PLATE, WALL = 1.5, 2.0


def _knife_scan(n_subrays, seed=0, with_wall=True, backend="llvm"):
    scene = scenes.build("knife-edge")
    if not with_wall:
        scene = Scene(objects=scene.objects[:1], scanner=scene.scanner, name="knife-edge-over-sky")
    # Noise-free: these tests pin the geometry of mixing, not the detector noise.
    setup = setup_from_section(scene.scanner, model=get_preset("faro-ls880").noise_free(), n_subrays=n_subrays)
    return simulate(scene, setup, seed=seed, progress=False, backend=backend), setup.model


def _foreground_beam_share(scan, model):
    """Share of the *beam* power on the plate, from the truth's received-power split."""
    on_plate = scan.truth_id == 0
    received = np.where(on_plate, 1 - scan.mixed_fraction, scan.mixed_fraction)
    a, b = range_gain(model, PLATE), range_gain(model, WALL)
    return received * b / (a * (1 - received) + received * b)


def _surface_ranges(scan):
    """Distances along each beam to the plate plane and to the wall plane, m."""
    along_x = np.sin(scan.psi) * np.cos(scan.theta)
    return PLATE / along_x, WALL / along_x


def _edge_offset(scan, model):
    """Signed distance from the beam centre to the edge (positive over the wall) and the 1/e² radius, m."""
    x = PLATE * np.tan(scan.theta)
    return x, model.beam_radius_m(PLATE)


@pytest.fixture(scope="module")
def scans(backend):
    return {n: _knife_scan(n, backend=backend) for n in (19, 91)}


def test_power_split_follows_gaussian_erfc(scans):
    errors = {}
    for n, (scan, model) in scans.items():
        share = _foreground_beam_share(scan, model)
        x, w = _edge_offset(scan, model)
        expected = 0.5 * erfc(math.sqrt(2) * x / w)
        column_mean = share.mean(axis=0)
        # Averaged over the random spin of the sub-ray layout (one per pulse),
        # each column follows the analytic split.
        assert np.max(np.abs(column_mean - expected[0])) < {19: 0.06, 91: 0.03}[n]
        near = np.abs(x) < 1.5 * w
        errors[n] = np.sqrt(np.mean((share - expected)[near] ** 2))
    assert errors[19] < 0.06
    assert errors[91] < 0.7 * errors[19]  # sampling error falls with the number of sub-rays


def test_mixed_range_is_intermediate_and_monotone(scans):
    scan, model = scans[19]
    valid = scan.valid
    assert np.all(valid)
    d = scan.range
    d_fg, d_bg = _surface_ranges(scan)
    assert np.all(d >= d_fg - 1e-6) and np.all(d <= d_bg + 1e-6)
    # received-power share of the plate
    s = np.where(scan.truth_id == 0, 1 - scan.mixed_fraction, scan.mixed_fraction).ravel()
    position = ((d - d_fg) / (d_bg - d_fg)).ravel()  # 0 on the plate, 1 on the wall
    order = np.argsort(s, kind="stable")
    assert np.all(np.diff(position[order]) <= 1e-4)  # falls as the plate's share grows
    # A phase-shift scanner averages: for a small phase difference the range is
    # the received-power-weighted mean, never the first return.
    mixed = (s > 0.05) & (s < 0.95)
    assert mixed.sum() > 50
    mean = s * d_fg.ravel() + (1 - s) * d_bg.ravel()
    assert np.allclose(d.ravel()[mixed], mean[mixed], atol=1e-3)


def test_second_object_and_its_share(scans):
    scan, _ = scans[19]
    second, share = scan.layers["truth_second_id"], scan.layers["second_fraction"]
    mixed = scan.mixed_fraction > 0
    assert mixed.sum() > 50
    # two objects only: the runner-up is the other one and carries all the minority power
    assert np.all(second[mixed] == 1 - scan.truth_id[mixed])
    assert np.allclose(share[mixed], scan.mixed_fraction[mixed], atol=1e-6)
    assert np.all(second[~mixed] == -1) and np.all(share[~mixed] == 0)


def test_mixed_intensity_between_the_pure_surfaces(scans):
    scan, _ = scans[19]
    share = np.where(scan.truth_id == 0, 1 - scan.mixed_fraction, scan.mixed_fraction)
    pure_plate = scan.intensity[share > 0.999]
    pure_wall = scan.intensity[share < 0.001]
    lo, hi = min(pure_plate.min(), pure_wall.min()), max(pure_plate.max(), pure_wall.max())
    mixed = scan.intensity[(share > 0.01) & (share < 0.99)]
    assert len(mixed) > 50
    assert np.all((mixed >= lo) & (mixed <= hi))


def test_edge_over_empty_space_keeps_range_and_loses_intensity(llvm):
    scan, model = _knife_scan(19, with_wall=False)
    x, w = _edge_offset(scan, model)
    valid = scan.valid
    d_fg, _ = _surface_ranges(scan)
    assert np.allclose(scan.range[valid], d_fg[valid], atol=1e-5)  # no background: the plate's distance
    full = np.nanmedian(scan.intensity[x < -2 * w])
    partial = scan.intensity[valid & (x > 0.3 * w)]
    assert len(partial) > 10
    assert np.all(partial < full)  # fewer sub-rays return: lower intensity

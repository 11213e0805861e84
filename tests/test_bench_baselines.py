"""Baseline outlier-removal filters and the baseline leaf traits, on hand-made range images."""

import math

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from benchmarks.metrics import axis_angle_errors
from leafsfs import baselines
from leafsfs.errors import SfsError
from tlssim.pattern import ScannerPose
from tlssim.scan import Scan, grid_to_xyz

STEP_DEG = 0.018
ROWS, COLS = 30, 40
PLATE_COLS = 25          # columns 0..24: a plate facing the scanner at x = 1.5 m
VEIL = (0.1, 0.25, 0.4)  # columns 25..27: mixed points between the plate and the wall
WALL_X = 2.0             # columns 28..: the wall


def make_scan(range_m, intensity=None, step_deg=STEP_DEG) -> Scan:
    theta_axis = np.radians(step_deg * (np.arange(range_m.shape[1]) - range_m.shape[1] / 2))
    psi_axis = np.radians(90.0 + step_deg * (np.arange(range_m.shape[0]) - range_m.shape[0] / 2))
    theta, psi = np.meshgrid(theta_axis, psi_axis)
    if intensity is None:
        intensity = np.where(np.isfinite(range_m), 1600.0, np.nan)
    return Scan(range_m, np.asarray(intensity, np.float32), theta, psi, grid_to_xyz(range_m, theta, psi, ScannerPose()))


def plane_range(x_m, rows=ROWS, cols=COLS):
    """Range to the plane x = x_m on the test grid."""
    scan = make_scan(np.ones((rows, cols)))
    return x_m / (np.sin(scan.psi) * np.cos(scan.theta))


@pytest.fixture(scope="module")
def edge_scan():
    range_m = plane_range(WALL_X)
    range_m[:, :PLATE_COLS] = plane_range(1.5)[:, :PLATE_COLS]
    for i, extra in enumerate(VEIL):
        range_m[:, PLATE_COLS + i] = plane_range(1.5)[:, PLATE_COLS + i] + extra
    intensity = np.full(range_m.shape, 1600.0)
    intensity[:, PLATE_COLS:PLATE_COLS + len(VEIL)] = 1400.0
    scan = make_scan(range_m, intensity)
    plate = np.zeros(scan.shape, bool)
    plate[:, :PLATE_COLS] = True
    veil = np.zeros(scan.shape, bool)
    veil[:, PLATE_COLS:PLATE_COLS + len(VEIL)] = True
    return scan, plate, veil


@pytest.mark.parametrize("name, params", [
    ("shadow_filter", {}),
    ("stray_point_filter", {}),
    ("radius_outlier_removal", {}),
    ("intensity_filter", {}),
    ("intensity_filter", {"below_median_dn": None, "min_dn": 1500.0}),
])
def test_filters_remove_the_veil_and_keep_the_plate(edge_scan, name, params):
    scan, plate, veil = edge_scan
    kept = getattr(baselines, name)(scan, plate | veil, **params)
    assert kept.shape == scan.shape
    assert not (kept & ~(plate | veil)).any(), "a filter never keeps points outside the mask"
    assert not (kept & veil).any()
    assert (kept & plate).sum() == plate.sum()


def test_shadow_filter_also_removes_the_wall_behind_the_veil(edge_scan):
    scan, plate, veil = edge_scan
    kept = baselines.shadow_filter(scan)
    assert not kept[:, PLATE_COLS + len(VEIL)].any()      # first wall column: farther than the veil
    assert kept[:, PLATE_COLS + len(VEIL) + 2:].all()     # the rest of the wall
    assert kept[:, :PLATE_COLS].all()


def test_shadow_filter_costs_points_on_grazing_surfaces():
    # A plane seen at about 85 deg incidence along the rows: neighbour segments run within 10 deg of the beams.
    scan = make_scan(np.ones((ROWS, COLS)))
    normal = np.array([-math.cos(math.radians(85.0)), 0.0, math.sin(math.radians(85.0))])
    beam = scan.xyz / np.linalg.norm(scan.xyz, axis=2, keepdims=True)
    point = np.array([1.5, 0.0, 0.0])
    scan = make_scan(np.dot(point, normal) / np.einsum("ijk,k->ij", beam, normal))
    assert baselines.shadow_filter(scan).mean() < 0.1
    assert baselines.shadow_filter(scan, min_angle_deg=2.0).all()


def test_statistical_outlier_removal_drops_isolated_points():
    range_m = plane_range(1.5)
    rng = np.random.default_rng(3)
    stray = (rng.integers(0, ROWS, 6), rng.integers(0, COLS, 6))
    range_m[stray] += rng.uniform(0.2, 0.5, 6)
    scan = make_scan(range_m)
    kept = baselines.statistical_outlier_removal(scan)
    isolated = np.zeros(scan.shape, bool)
    isolated[stray] = True
    assert not (kept & isolated).any()
    assert kept[~isolated].mean() > 0.98


def test_radius_with_a_fixed_radius_keeps_dense_points_only(edge_scan):
    scan, plate, veil = edge_scan
    kept = baselines.radius_outlier_removal(scan, plate | veil, radius_m=0.002, min_neighbours=8)
    assert kept[plate].all() and not kept[veil].any()
    assert not baselines.radius_outlier_removal(scan, plate, radius_m=1e-5).any()


def test_filters_reject_bad_input(edge_scan):
    scan, plate, _ = edge_scan
    with pytest.raises(SfsError, match="mask has shape"):
        baselines.shadow_filter(scan, plate[:-1])
    with pytest.raises(SfsError, match="min_angle_deg"):
        baselines.shadow_filter(scan, plate, min_angle_deg=95)
    with pytest.raises(SfsError, match="exactly one"):
        baselines.intensity_filter(scan, plate, below_median_dn=None, min_dn=None)
    with pytest.raises(SfsError, match="window_px"):
        baselines.stray_point_filter(scan, plate, window_px=4)
    with pytest.raises(SfsError, match="k must"):
        baselines.statistical_outlier_removal(scan, plate, k=0)
    with pytest.raises(SfsError, match="radius_spacings"):
        baselines.radius_outlier_removal(scan, plate, radius_spacings=-1.0)


def test_leaf_traits_of_a_plate(edge_scan):
    scan, plate, veil = edge_scan
    points = scan.xyz[plate]
    hull_area = ConvexHull(points[:, 1:]).volume  # the plate lies in x = 1.5: its (y, z) outline
    traits = baselines.leaf_traits(scan, plate | veil)
    assert traits["area_m2"] == pytest.approx(hull_area, rel=1e-3)  # the veil is not meshed (edges > 1 cm)
    np.testing.assert_allclose(traits["normal"], [-1.0, 0.0, 0.0], atol=1e-3)
    assert traits["elevation_deg"] > 89.5  # 30 rows by 25 columns: the long axis is vertical
    band = plate.copy()
    band[:10] = band[20:] = False          # 10 rows by 25 columns: the long axis is horizontal, along y
    wide = baselines.leaf_traits(scan, band)
    el, az = axis_angle_errors(wide["elevation_deg"], wide["azimuth_deg"], 0.0, 90.0)
    assert el < 0.5 and az < 0.5
    # Without the edge cap the veil is meshed and inflates the area.
    assert baselines.leaf_traits(scan, plate | veil, max_edge_m=1.0)["area_m2"] > 2 * hull_area
    empty = baselines.leaf_traits(scan, np.zeros(scan.shape, bool))
    assert empty["area_m2"] == 0.0 and math.isnan(empty["elevation_deg"])


def test_leaf_traits_smooth_range_noise():
    rng = np.random.default_rng(5)
    clean = make_scan(plane_range(1.5, 60, 80))
    noisy = make_scan(clean.range + rng.normal(0.0, 0.002, clean.shape))  # 2 mm noise, 0.47 mm spacing
    everything = np.ones(clean.shape, bool)
    area = baselines.leaf_traits(clean, everything)["area_m2"]
    assert baselines.leaf_traits(noisy, everything)["area_m2"] == pytest.approx(area, rel=0.05)
    assert baselines.leaf_traits(noisy, everything, smoothing_m=1e-6)["area_m2"] > 2 * area


def test_leaf_traits_cap_follows_sparse_sampling():
    # A plane 4 m away tilted 60 deg about the vertical, sampled every 0.08 deg (5.6 mm; 11 mm along the tilt).
    step = 0.08
    grid = make_scan(np.ones((20, 20)), step_deg=step)
    normal = np.array([-math.cos(math.radians(60.0)), math.sin(math.radians(60.0)), 0.0])
    beam = grid.xyz / np.linalg.norm(grid.xyz, axis=2, keepdims=True)
    scan = make_scan(np.dot([4.0, 0.0, 0.0], normal) / np.einsum("ijk,k->ij", beam, normal), step_deg=step)
    everything = np.ones(scan.shape, bool)
    wide = baselines.leaf_traits(scan, everything, max_edge_m=1.0)["area_m2"]
    assert baselines.leaf_traits(scan, everything, max_edge_m=0.01)["area_m2"] == 0.0
    assert baselines.leaf_traits(scan, everything)["area_m2"] == pytest.approx(wide, rel=1e-6)


def test_grid_mesh_faces_the_scanner(edge_scan):
    scan, plate, _ = edge_scan
    vertices, faces = baselines.grid_mesh(scan, plate)
    assert len(faces) == 2 * (ROWS - 1) * (PLATE_COLS - 1)
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(normal[:, 0] < 0)

"""Point spacing, voxel subsampling, STEP at a scan density far above its Hough cells, normals without a viewpoint."""

import numpy as np
import pytest

from woody import WoodyError, follow_cylinders, score, step
from woody.density import point_spacing, thin_to_spacing, voxel_subsample
from woody.normals import orient_outward, pca_normals
from woody.synthetic import add_noise, sample_cylinders, straight_cylinder


@pytest.mark.parametrize("per_cm2", [0.75, 3.0, 30.0])
def test_spacing_of_random_and_grid_surfaces_is_one_over_root_density(per_cm2):
    rng = np.random.default_rng(1)
    side = 0.5
    n = int(per_cm2 * 1e4 * side * side)
    random = np.column_stack([rng.uniform(0, side, (n, 2)), np.zeros(n)])
    step_m = 1 / np.sqrt(per_cm2 * 1e4)
    u = np.arange(0, side, step_m)
    grid = np.column_stack([np.repeat(u, len(u)), np.tile(u, len(u)), np.zeros(len(u) ** 2)])
    for points in (random, grid):
        assert point_spacing(points) == pytest.approx(step_m, rel=0.12)


def test_voxel_subsample_keeps_one_surface_point_per_voxel():
    cloud = sample_cylinders(straight_cylinder(0.2, 0.5), 2e5, seed=2)
    kept = voxel_subsample(cloud.points, 0.01)
    cells = {tuple(c) for c in np.floor((cloud.points - cloud.points.min(axis=0)) / 0.01).astype(int)}
    assert len(kept) == len(cells) and len(np.unique(kept)) == len(kept)
    assert np.allclose(np.hypot(*cloud.points[kept, :2].T), 0.2)  # real points, not centroids
    assert point_spacing(cloud.points[kept]) == pytest.approx(0.01, rel=0.25)
    with pytest.raises(WoodyError, match="voxel_m"):
        voxel_subsample(cloud.points, 0.0)
    with pytest.raises(WoodyError, match="too few"):
        point_spacing(cloud.points[:5])


def test_step_subsamples_a_dense_cloud_and_keeps_the_radius():
    cloud = sample_cylinders(straight_cylinder(0.15, 0.5), 3e5, seed=3)  # 30 pts/cm2
    cells = {"cell_m": 0.02, "radius_step_m": 0.01, "r_min_m": 0.08, "r_max_m": 0.25}
    result = step(cloud.points, cloud.normals, **cells)
    assert result.stats["points_used"] < result.stats["points"] / 4
    assert len(result.normals) == result.stats["points_used"]
    assert len(result.tuboids) == 1 and np.abs(result.tuboids[0].radii - 0.15).max() < 0.002
    assert step(cloud.points[:2000], cloud.normals[:2000], subsample_m=0, **cells).stats["points_used"] == 2000


@pytest.mark.parametrize("radius, arc_deg", [(0.02, 360), (0.15, 180), (0.5, 90)])
def test_normals_are_oriented_outwards_without_a_viewpoint(radius, arc_deg):
    cloud = sample_cylinders(straight_cylinder(radius, 1.0), 3e4, seed=1, arc_deg=arc_deg)
    points = add_noise(cloud.points, 0.003, seed=2)
    normals = pca_normals(points, 16) * np.where(np.arange(len(points)) % 2, 1.0, -1.0)[:, None]  # random signs
    outward = np.einsum("ij,ij->i", orient_outward(points, normals), cloud.normals) > 0
    assert outward.mean() > 0.95


def test_step_orients_estimated_normals_outwards_when_asked_without_a_viewpoint():
    cloud = sample_cylinders(straight_cylinder(0.15, 0.6), 2e4, seed=5, arc_deg=180)
    result = step(cloud.points, oriented=True, cell_m=0.02, radius_step_m=0.01, r_min_m=0.08, r_max_m=0.25)
    assert result.stats["oriented"]
    assert (np.einsum("ij,ij->i", result.normals, cloud.normals) > 0).mean() > 0.95
    assert len(result.tuboids) >= 1 and abs(np.median(result.tuboids[0].radii) - 0.15) < 0.01


@pytest.fixture(scope="module")
def y_at_three_densities(y_tree):
    """The Y (a 5 cm stem forking into two 3 cm arms) at 0.75, 3 and 30 pts/cm², followed with a 2 cm thinnest
    branch to resolve (thinned to 10.5 mm: the two dense clouds are, the sparse one is not)."""
    out = {}
    for per_cm2 in (0.75, 3.0, 30.0):
        cloud = sample_cylinders(y_tree, per_cm2 * 1e4, seed=4)
        out[per_cm2] = cloud, follow_cylinders(cloud.points, resolve_radius_m=0.02)
    return out


def test_cylinder_following_thins_dense_clouds_only(y_at_three_densities):
    for per_cm2, (cloud, result) in y_at_three_densities.items():
        fitted = result.stats.get("points_fitted", len(cloud.points))
        assert (fitted < len(cloud.points)) == (per_cm2 > 1)
        assert len(result.labels) == len(cloud.points) and (result.labels >= 0).mean() > 0.99
        assert np.bincount(result.labels[result.labels >= 0]).tolist() == [b["n_points"] for b in result.branches]
    fitted = [y_at_three_densities[d][1].stats["points_fitted"] for d in (3.0, 30.0)]
    assert fitted[1] < len(y_at_three_densities[30.0][0].points) / 10 and fitted[1] == pytest.approx(fitted[0], rel=0.1)


def test_cylinder_following_gives_the_same_tree_at_any_density(y_at_three_densities):
    volumes, radii = [], []
    for cloud, result in y_at_three_densities.values():
        s = score(cloud.truth, result.cylinders())
        assert s["branches_detected"] == 3 and abs(s["volume_error"]) < 0.15  # seeds 1-5: at most 11.7 %
        volumes.append(result.volume)
        radii.append(result.branches[0]["radius_m"])
    assert max(volumes) / min(volumes) < 1.15  # seeds 1-5: 1.02-1.10
    assert np.allclose(radii, 0.05, rtol=0.05)


def test_thinning_keeps_the_share_of_stray_points_and_reaches_the_spacing():
    rng = np.random.default_rng(6)
    surface = sample_cylinders(straight_cylinder(0.15, 0.5), 3e5, seed=6).points  # 30 pts/cm2
    strays = rng.uniform(-0.3, 0.3, (len(surface) // 5, 3)) + [0, 0, 0.25]
    cloud = np.concatenate([surface, strays])
    kept = thin_to_spacing(cloud, 0.01)
    assert (kept >= len(surface)).mean() == pytest.approx(len(strays) / len(cloud), abs=0.02)
    assert point_spacing(surface[kept[kept < len(surface)]]) == pytest.approx(0.01, rel=0.15)
    assert np.array_equal(kept, thin_to_spacing(cloud, 0.01)) and len(thin_to_spacing(cloud, 1e-4)) == len(cloud)
    assert (voxel_subsample(cloud, 0.01) >= len(surface)).mean() > 0.5  # voxels keep every stray, thin the surface

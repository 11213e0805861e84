"""Sparse 4-D point–normal Hough transform: grid rules, voting, neighbourhood statistics, interpolation."""

import numpy as np
import pytest

from woody.errors import WoodyError
from woody.hough import HoughGrid, HoughSpace, hough_transform
from woody.synthetic import sample_cylinders, straight_cylinder


def _cylinder(radius=0.10, length=0.5, density=4e4, seed=0):
    return sample_cylinders(straight_cylinder(radius, length), density, seed=seed)


def test_grid_enforces_the_papers_two_resolution_rules():
    pts = np.zeros((1, 3))
    with pytest.raises(WoodyError, match="at least twice"):
        HoughGrid.around(pts, cell_m=0.015, radius_step_m=0.01, r_min_m=0.05, r_max_m=0.2)
    with pytest.raises(WoodyError, match="smaller than the smallest"):
        HoughGrid.around(pts, cell_m=0.04, radius_step_m=0.02, r_min_m=0.02, r_max_m=0.2)
    with pytest.raises(WoodyError, match="r_max_m"):
        HoughGrid.around(pts, cell_m=0.04, radius_step_m=0.01, r_min_m=0.05, r_max_m=0.05)


def test_grid_index_and_metric_round_trip():
    grid = HoughGrid.around(np.random.default_rng(0).uniform(-1, 1, (50, 3)), 0.02, 0.01, 0.05, 0.3)
    xyzr = np.array([[0.1, -0.2, 0.3, 0.12], [0.0, 0.0, 0.0, 0.05]])
    assert np.allclose(grid.to_metric(grid.to_index(xyzr)), xyzr)
    cells = np.array([[3, 4, 5, 2], [10, 1, 7, 1]])
    assert np.array_equal(grid.unpack(grid.pack(cells)), cells)


@pytest.mark.parametrize("oriented", [True, False])
def test_votes_peak_on_the_axis_at_the_true_radius(oriented):
    cloud = _cylinder()
    normals = cloud.normals if oriented else cloud.normals * np.where(np.arange(len(cloud.normals)) % 2, 1, -1)[:, None]
    grid = HoughGrid.around(cloud.points, 0.02, 0.01, 0.05, 0.2)
    hs = hough_transform(cloud.points, normals, grid, oriented=oriented)
    top = grid.to_metric(grid.unpack(hs.keys[[np.argmax(hs.counts)]])[0].astype(float))
    assert np.hypot(top[0], top[1]) < 0.011  # within half a cell of the axis
    assert abs(top[3] - 0.10) <= 0.0100001  # within one radius bin
    assert 0 <= top[2] <= 0.5


def test_sparse_accumulator_grows_with_occupied_cells_not_with_the_box():
    near = _cylinder(seed=1)
    far = near.points + np.array([12.0, 9.0, 0.0])
    points = np.vstack([near.points, far])
    normals = np.vstack([near.normals, near.normals])
    grid = HoughGrid.around(points, 0.02, 0.01, 0.05, 0.2)
    hs = hough_transform(points, normals, grid)
    dense_bytes = 4 * np.prod(np.array(grid.shape, float))
    assert dense_bytes > 1e9  # a dense int32 grid would need gigabytes ...
    assert hs.nbytes < 2e6  # ... the sparse one a few megabytes


def test_two_samples_per_bin_count_a_point_once_per_cell():
    pts = np.array([[0.0, 0.0, 0.0]])
    normal = np.array([[1.0, 0.0, 0.0]])
    grid = HoughGrid.around(pts, 0.04, 0.01, 0.02, 0.05)
    single = hough_transform(pts, normal, grid, samples_per_bin=1, min_votes=1)
    double = hough_transform(pts, normal, grid, samples_per_bin=2, min_votes=1)
    assert single.counts.max() == 1 and double.counts.max() == 1
    assert len(double.keys) >= len(single.keys) == len(grid.radii)


def _hand_made_space():
    grid = HoughGrid(np.zeros(3), 0.02, 0.01, 0.05, (8, 8, 8, 6))
    cells = np.array([[3, 3, 3, 2], [4, 3, 3, 2], [3, 4, 3, 2], [6, 6, 6, 3]])
    counts = np.array([5, 5, 2, 7], np.int32)
    keys = grid.pack(cells)
    order = np.argsort(keys)
    return grid, HoughSpace(grid, keys[order], counts[order]), cells, counts


def test_neighbourhood_keeps_one_maximum_per_plateau_and_reports_min_max():
    grid, hs, cells, counts = _hand_made_space()
    is_max, h_min, h_max = hs.neighbourhood()
    maxima = {tuple(c) for c in grid.unpack(hs.keys[is_max])}
    # The plateau of two fives keeps its lower key, the isolated seven is a maximum, the two is not.
    assert maxima == {(3, 3, 3, 2), (6, 6, 6, 3)}
    row = {tuple(c): i for i, c in enumerate(grid.unpack(hs.keys))}
    assert h_max[row[(3, 4, 3, 2)]] == 5 and h_min[row[(3, 4, 3, 2)]] == 0


def test_interpolation_is_exact_on_cells_and_linear_between():
    grid, hs, cells, counts = _hand_made_space()
    values = hs.counts.astype(float)
    at = hs.interpolate(values, np.array([[3.0, 3.0, 3.0, 2.0], [3.5, 3.0, 3.0, 2.0], [3.0, 3.0, 3.0, 2.5]]))
    assert np.allclose(at, [5.0, 5.0, 2.5])

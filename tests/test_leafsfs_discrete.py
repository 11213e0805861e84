"""Contours, Freeman codes and the Braquelaire-Vialard Euclidean path (digest §8, test 9)."""

import numpy as np
import pytest
from scipy import ndimage

from leafsfs.contour import FREEMAN4, contour_pixels, open_region, signed_area, trace_contour
from leafsfs.euclid import _recognise, discrete_tangents, marching_squares_path


def _blob(seed, size=40):
    rng = np.random.default_rng(seed)
    field = ndimage.gaussian_filter(rng.normal(size=(size, size)), 4)
    region = open_region(field > np.quantile(field, 0.55))
    labels, count = ndimage.label(region)
    biggest = 1 + np.argmax(ndimage.sum(region, labels, range(1, count + 1)))
    return ndimage.binary_fill_holes(labels == biggest)


def _disc(radius, centre_shift=(0.3, 0.47)):
    n = int(2 * radius + 9)
    rows, cols = np.mgrid[:n, :n]
    centre = np.array([(n - 1) / 2 + centre_shift[0], (n - 1) / 2 + centre_shift[1]])
    return open_region((rows - centre[0]) ** 2 + (cols - centre[1]) ** 2 <= radius**2), centre


def _tangent_errors(radius, estimator):
    region, centre = _disc(radius)
    pixels, codes = trace_contour(region)
    offsets, tangents = discrete_tangents(codes, estimator)
    rel = pixels + offsets - centre
    truth = np.stack([-rel[:, 1], rel[:, 0]], axis=1)
    truth /= np.linalg.norm(truth, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(truth * tangents, axis=1), -1, 1)))


@pytest.mark.parametrize("seed", range(6))
def test_traced_contour_is_the_closed_ccw_4_path_of_the_boundary(seed):
    region = _blob(seed)
    pixels, codes = trace_contour(region)
    assert set(map(tuple, pixels)) == set(map(tuple, np.argwhere(contour_pixels(region))))
    steps = np.roll(pixels, -1, axis=0) - pixels
    assert np.array_equal(steps, FREEMAN4[codes])  # 4-connected and closed, codes match the moves
    assert signed_area(pixels.astype(float)) > 0


@pytest.mark.parametrize("estimator", ["thesis", "lambda"])
@pytest.mark.parametrize("seed", range(6))
def test_euclidean_points_stay_in_their_cells_and_ignore_the_start_point(seed, estimator):
    pixels, codes = trace_contour(_blob(seed))
    offsets, tangents = discrete_tangents(codes, estimator)
    assert np.all(np.abs(offsets) < 0.5)
    assert np.array_equal(np.rint(pixels + offsets).astype(int), pixels)  # reversible
    assert np.allclose(np.linalg.norm(tangents, axis=1), 1.0)
    # tangents follow the path direction
    forward = np.roll(pixels, -1, axis=0) - np.roll(pixels, 1, axis=0)
    assert np.mean(np.sum(forward * tangents, axis=1) > 0) > 0.95
    for shift in (1, 5, len(codes) // 2):
        offsets2, tangents2 = discrete_tangents(np.roll(codes, -shift), estimator)
        assert np.allclose(np.roll(offsets, -shift, axis=0), offsets2)
        assert np.allclose(np.roll(tangents, -shift, axis=0), tangents2)


def test_reversing_the_orientation_changes_the_path_little():
    pixels, codes = trace_contour(_blob(3))
    offsets, tangents = discrete_tangents(codes)
    # The same pixels travelled clockwise: point k of the reversed path is pixels[n-1-k].
    reversed_codes = (np.roll(codes[::-1], -1) + 2) % 4
    offsets_r, tangents_r = discrete_tangents(reversed_codes)
    offsets_r, tangents_r = offsets_r[::-1], -tangents_r[::-1]
    angle = np.degrees(np.arccos(np.clip(np.sum(tangents * tangents_r, axis=1), -1, 1)))
    shift = np.linalg.norm(offsets - offsets_r, axis=1)
    assert np.median(angle) < 1.0 and np.mean(angle) < 5.0
    assert np.median(shift) < 0.05 and np.mean(shift) < 0.2


@pytest.mark.parametrize("a,b", [(0, 1), (1, 1), (3, 7), (2, 5), (5, 8), (1, 9)])
@pytest.mark.parametrize("shift", [0.0, 0.31, 0.77])
def test_digital_straight_segments_are_recognised_whole(a, b, shift):
    xs = np.arange(-12, 13)
    ys = np.floor(a * xs / b + shift).astype(int)
    steps = np.diff(ys)
    origin = 12
    forward, backward = list(steps[origin:]), list(steps[:origin][::-1])
    ys = ys - ys[origin]
    ra, rb, mu, n_f, n_b = _recognise(forward, backward)
    assert (n_f, n_b) == (len(forward), len(backward))
    r = ra * (xs - xs[origin]) - rb * ys
    assert np.all((mu <= r) & (r < mu + rb))  # every point on the naive line
    assert ra * b == rb * a or rb > 4  # exact slope once the segment is long enough to fix it


def test_straight_edge_gives_exact_tangents():
    rows, cols = np.mgrid[:60, :60]
    region = (3 * (rows - 30) - 7 * (cols - 30) < 0.5) & (rows > 3) & (rows < 56) & (cols > 3) & (cols < 56)
    pixels, codes = trace_contour(region)
    offsets, tangents = discrete_tangents(codes, "thesis")
    direction = np.array([7, 3]) / np.hypot(7, 3)
    on_edge = np.abs(tangents @ np.array([-direction[1], direction[0]])) < 1e-9
    assert on_edge.sum() > 25
    points = (pixels + offsets)[on_edge]
    residual = (points - points[0]) @ np.array([-direction[1], direction[0]])
    assert np.abs(residual).max() < 1e-9  # Euclidean points on one straight line


def test_tangent_estimators_on_digitised_circles():
    for radius in (5, 10, 20, 50):
        thesis = _tangent_errors(radius, "thesis").mean()
        improved = _tangent_errors(radius, "lambda").mean()
        assert improved < 0.85 * thesis
        assert improved < 2.5 + 40.0 / radius  # 10.5 deg at r = 5 down to 3.3 deg at r = 50
    points, tangents = marching_squares_path(_disc(20)[0])
    assert signed_area(points) > 0 and np.allclose(np.linalg.norm(tangents, axis=1), 1)

"""The radius of a one-sided stem from its facing arc over a band (woody.facing)."""

import numpy as np
import pytest

from woody.circles import fit_circle
from woody.dbh import measure_dbh
from woody.facing import facing_radius

UP, U, V = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])


def facing_columns(radius, spacing, noise, seed, taper=0.0, lean=0.0, widen=0.0, rows=200, distance=5.0):
    """A stem seen along +x from far away: columns of points every ``spacing`` across it, ``rows`` heights from
    0.8 to 1.8 m, range noise along x; radius ``radius + taper (z - 1.3)``, axis ``x = distance + lean (z - 1.3)``;
    the columns within ``widen`` beyond the silhouette placed at the depth of the surface ``widen`` inside it (the
    part on the stem of a beam partly on it)."""
    rng = np.random.default_rng(seed)
    y = np.arange(-radius - widen, radius + widen + 1e-12, spacing) + rng.uniform(0, spacing)
    y, z = np.repeat(y, rows), np.tile(np.linspace(0.8, 1.8, rows), len(y))
    r = radius + taper * (z - 1.3)
    depth = np.sqrt(np.maximum(r ** 2 - np.minimum(np.abs(y), r) ** 2, 0.0))
    depth = np.where(np.abs(y) > r, np.sqrt(r ** 2 - (r - widen) ** 2), depth) + rng.normal(0.0, noise, len(y))
    keep = np.abs(y) <= r + widen
    return np.column_stack([distance + lean * (z - 1.3) - depth, y, z])[keep]


def test_exact_points_of_a_leaning_tapered_stem_give_its_radius_at_the_measurement_height():
    points = facing_columns(0.1, 0.004, 0.0, seed=1, taper=-0.01, lean=0.02)
    start = fit_circle(points[np.abs(points[:, 2] - 1.3) < 0.05][:, :2])
    radius, centre = facing_radius(points, np.array([5.0, 0.0, 1.3]), UP, U, V, start.centre - [5.0, 0.0],
                                   start.radius_m)
    assert radius == pytest.approx(0.1, abs=1e-6) and np.allclose(centre, [0.0, 0.0], atol=1e-6)


@pytest.mark.parametrize("seed", [2, 3, 4])
def test_range_noise_on_the_facing_arc_leaves_its_radius_unbiased_where_orthogonal_distances_narrow_it(seed):
    # a 5 cm stem, 2 mm columns, 1.8 mm range noise, silhouette columns up to 1.5 mm beyond it
    points = facing_columns(0.025, 0.002, 0.0018, seed, widen=0.0015)
    start = fit_circle(points[np.abs(points[:, 2] - 1.3) < 0.05][:, :2])
    assert start.radius_m > 1.01 * 0.025  # the silhouettes pull the whole arc's circle out
    facing = np.abs(points[:, 1]) <= 0.025 * np.sin(np.radians(60.0))
    assert fit_circle(points[facing][:, :2]).radius_m < 0.985 * 0.025  # orthogonal distances on the kept arc
    radius, _ = facing_radius(points, np.array([5.0, 0.0, 1.3]), UP, U, V, start.centre - [5.0, 0.0],
                              start.radius_m)
    assert radius == pytest.approx(0.025, rel=0.01)


def test_an_arc_sampled_by_too_few_columns_keeps_the_plain_circle():
    points = facing_columns(0.025, 0.0115, 0.002, seed=5, rows=87)  # 5 cm at 10 m, 0.066 deg: 3.8 spacings
    start = fit_circle(points[:, :2])
    assert facing_radius(points, np.array([5.0, 0.0, 1.3]), UP, U, V, start.centre - [5.0, 0.0],
                         start.radius_m) is None


def test_a_stem_seen_from_all_sides_keeps_the_plain_circle(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("the facing arc of a stem seen from all sides")

    monkeypatch.setattr("woody.dbh.facing_radius", refuse)
    rng = np.random.default_rng(6)
    angle, z = rng.uniform(0, 2 * np.pi, 20000), rng.uniform(0.0, 2.5, 20000)
    points = np.column_stack([0.05 * np.cos(angle), 0.05 * np.sin(angle), z])
    points[:, :2] *= (1 + rng.normal(0, 0.01, len(z)))[:, None]
    stem = measure_dbh(points, ground_z=0.0)[0]
    assert stem.arc_deg == 360 and stem.dbh_m == pytest.approx(0.1, rel=0.01)

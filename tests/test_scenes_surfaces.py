"""Analytic test surfaces: exact heights, derivatives, meshes and placement."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scenes import SceneError
from scenes.surfaces import SURFACE_NAMES, get_surface, surface_object


def _interior_points(surface, n=400, seed=0):
    """Random points whose finite-difference stencil stays on a smooth part of the surface."""
    rng = np.random.default_rng(seed)
    (x0, x1), (y0, y1) = surface.domain
    x, y = rng.uniform(x0, x1, 4 * n), rng.uniform(y0, y1, 4 * n)
    h = 1e-6 * max(x1 - x0, y1 - y0)
    ok = np.ones_like(x, dtype=bool)
    for dx, dy in ((h, 0), (-h, 0), (0, h), (0, -h)):
        ok &= surface.support(x + dx, y + dy)
    p, q = surface.gradient(x, y)
    ok &= np.hypot(p, q) < 10  # away from rims where the slope diverges
    if surface.name == "vase":  # the floor meets the body with a kink: stay off the rim
        f = np.poly1d(np.array([-138.24, 92.16, 84.48, -48.64, -17.60, 6.4, 3.2]) / 12.8)(x)
        ok &= np.abs(np.abs(y) - np.abs(f)) > 1e-3
    if surface.name == "cone":
        ok &= np.hypot(x, y) > 1e-3
    return x[ok][:n], y[ok][:n], h


@pytest.mark.parametrize("name", SURFACE_NAMES)
def test_gradient_matches_finite_differences(name):
    surface = get_surface(name)
    x, y, h = _interior_points(surface)
    assert len(x) >= 100
    p, q = surface.gradient(x, y)
    p_fd = (surface.height(x + h, y) - surface.height(x - h, y)) / (2 * h)
    q_fd = (surface.height(x, y + h) - surface.height(x, y - h)) / (2 * h)
    scale = 1 + np.hypot(p, q)
    np.testing.assert_allclose(p / scale, p_fd / scale, atol=2e-5)
    np.testing.assert_allclose(q / scale, q_fd / scale, atol=2e-5)


@pytest.mark.parametrize("name", SURFACE_NAMES)
def test_normal_and_alpha_follow_the_gradient(name):
    surface = get_surface(name)
    x, y, _ = _interior_points(surface, seed=1)
    p, q = surface.gradient(x, y)
    n = surface.normal(x, y)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-12)
    expected = np.stack([-p, -q, np.ones_like(p)], -1) / np.sqrt(1 + p**2 + q**2)[:, None]
    np.testing.assert_allclose(n, expected, atol=1e-9)
    np.testing.assert_allclose(surface.alpha(x, y), np.arctan(np.hypot(p, q)), atol=1e-9)


@pytest.mark.parametrize("name", SURFACE_NAMES)
def test_mesh_lies_on_the_height_field(name):
    surface = get_surface(name)
    vertices, faces = surface.mesh(121)
    np.testing.assert_allclose(vertices[:, 2], surface.height(vertices[:, 0], vertices[:, 1]), atol=1e-9)
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(cross[:, 2] > 0), "faces must be counter-clockwise seen from +z"
    # Linear interpolation error at the centroids is small next to the surface's height range,
    # except in the cells that straddle the vase's rim (a cliff) -- check the median and a high quantile.
    centroid = tri.mean(axis=1)
    gap = np.abs(centroid[:, 2] - surface.height(centroid[:, 0], centroid[:, 1]))
    h_tot = np.ptp(vertices[:, 2])
    assert np.median(gap) < 2e-3 * h_tot
    assert np.quantile(gap, 0.95) < 2e-2 * h_tot


def test_hemisphere_and_cone_mesh_areas_converge_to_the_exact_areas():
    for name, exact in (("hemisphere", 2 * math.pi * 20.0**2),
                        ("cone", math.pi * 20.0 * 20.0 / math.cos(math.pi / 6))):
        vertices, faces = get_surface(name).mesh(201)
        tri = vertices[faces]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
        assert area == pytest.approx(exact, rel=2e-3)


def test_hemisphere_support_domain_and_pixel_grid():
    surface = get_surface("hemisphere", radius=20)
    assert surface.domain == ((-20, 20), (-20, 20))
    x, y, h, mask = surface.sample(40, 30)
    assert x.shape == (30, 40) and x[0, 0] == pytest.approx(-20 + 0.5) and y[0, 0] == pytest.approx(-20 + 40 / 60)
    np.testing.assert_array_equal(mask, x**2 + y**2 <= 400)
    assert np.all(np.isnan(h[~mask])) and np.all(h[mask] >= 0)
    assert surface.height(0, 0) == 20 and np.isnan(surface.height(21, 0))
    np.testing.assert_allclose(surface.normal(20, 0), [1, 0, 0], atol=1e-12)  # rim normal is horizontal
    assert surface.alpha(0, 0) == 0


def test_plane_and_cone_have_constant_alpha():
    x, y, _, mask = get_surface("plane", tilt=0.4).sample(20, 20)
    np.testing.assert_allclose(get_surface("plane", tilt=0.4).alpha(x, y), 0.4)
    cone = get_surface("cone", slope=0.7)
    x, y, _, mask = cone.sample(21, 21)
    alpha = cone.alpha(x, y)[mask & (np.hypot(x, y) > 0)]
    np.testing.assert_allclose(alpha, 0.7)


def test_ellipsoid_matches_the_rotated_quadric():
    surface = get_surface("ellipsoid")
    vertices, _ = surface.mesh(81)
    # Independent construction: roll pi/6 about the long axis, then raise it by pi/8 towards +z.
    rot = Rotation.from_euler("y", -math.pi / 8) * Rotation.from_euler("x", math.pi / 6)
    local = rot.inv().apply(vertices)
    np.testing.assert_allclose(((local / [15.0, 7.5, 5.0]) ** 2).sum(axis=1), 1.0, atol=1e-9)
    long_axis = rot.apply([1.0, 0.0, 0.0])
    assert math.degrees(math.asin(long_axis[2])) == pytest.approx(22.5)
    # Upper envelope: the normal points up, and the mesh reaches the silhouette's bounding box.
    assert np.all(surface.normal(vertices[:, 0], vertices[:, 1])[:, 2] >= -1e-9)
    (x0, x1), (y0, y1) = surface.domain
    assert vertices[:, 0].max() == pytest.approx(x1, rel=1e-3) and vertices[:, 1].min() == pytest.approx(y0, rel=1e-3)


def test_complex_surface_is_eq_3_3():
    x, y = 0.7, -1.2
    expected = 0.1 * (4 * math.sin(x) * math.cos(y) + 3 * math.cos(2 * x + math.pi / 8) * math.sin(y / 2 + math.pi / 5)
                      + 2 * math.cos(x / 3) * math.sin(4 * y) + 4 * math.cos(2 * x) * math.sin(y))
    assert get_surface("complex").height(x, y) == pytest.approx(expected, abs=1e-15)


def test_vase_domain_neck_and_floor():
    surface = get_surface("vase")
    assert surface.domain == ((-0.554, -0.127), (-0.22, 0.22))
    f = lambda x: (-138.24 * x**6 + 92.16 * x**5 + 84.48 * x**4 - 48.64 * x**3 - 17.6 * x**2 + 6.4 * x + 3.2) / 12.8
    assert surface.height(-0.308, 0.0) == pytest.approx(f(-0.308)) == pytest.approx(0.1068, abs=1e-4)
    assert surface.height(-0.3, 0.2) == 0.0  # |y| > f: the floor
    x, y, h, mask = surface.sample(60, 60)
    assert mask.all() and 0.3 < np.mean(h == 0) < 0.6
    # The neck is a saddle: along x the ridge height has a minimum, across y a maximum.
    xs = np.linspace(-0.45, -0.2, 501)
    assert xs[np.argmin(surface.height(xs, 0 * xs))] == pytest.approx(-0.3075, abs=2e-3)


def test_multi_seed_has_bumps_pits_and_seeded_variants():
    surface = get_surface("multi-seed")
    _, _, h, _ = surface.sample(101, 101)
    assert h.max() > 0.3 and h.min() < -0.3
    a, b, c = (get_surface("multi-seed", seed=s).sample(30, 30)[2] for s in (5, 5, 6))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_get_surface_rejects_bad_input():
    with pytest.raises(SceneError, match="unknown surface 'torus'.*hemisphere"):
        get_surface("torus")
    with pytest.raises(SceneError, match="no parameter.*'radius'"):
        get_surface("saddle", radius=3)
    with pytest.raises(SceneError, match="radius must be a positive number"):
        get_surface("hemisphere", radius=-1)
    with pytest.raises(SceneError, match="positive integer"):
        get_surface("plane").sample(0, 10)


def test_surface_object_faces_the_scanner_and_maps_back():
    obj = surface_object("hemisphere", distance_m=2.0, size_m=0.4, direction=(0, 1, 0), resolution=61)
    frame = obj.truth["frame"]
    np.testing.assert_allclose(frame["origin"], [0, 2, 0])
    assert frame["scale"] == pytest.approx(0.4 / 40)
    # Surface +z points back at the scanner: the dome top is the nearest point, 2 m - 0.2 m away.
    assert np.linalg.norm(obj.vertices, axis=1).min() == pytest.approx(1.8, abs=1e-9)
    normals = obj.face_normals()
    assert np.mean(normals @ np.array([0, -1, 0]) > 0) > 0.99
    # Mapping world vertices back gives points on the height field.
    axes = np.array(frame["axes"])
    local = (obj.vertices - frame["origin"]) @ axes.T / frame["scale"] + [*frame["center"], 0]
    surface = get_surface("hemisphere")
    np.testing.assert_allclose(local[:, 2], surface.height(local[:, 0], local[:, 1]), atol=1e-5)  # the rim amplifies rounding
    assert obj.type == "surface" and obj.truth["surface"] == "hemisphere"

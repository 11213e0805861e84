"""Procedural leaves: exact areas, poses, determinism, truth and population statistics."""

import math

import numpy as np
import pytest
from scipy.special import beta

from scenes import SceneError, scene_from_spec
from scenes.leaf import (BLADE, PEAR, PETIOLE, LeafShape, blade_area_m2, leaf_objects, leaf_resolution,
                         leaf_template, leaf_vertices, sample_pear_leaf, sample_pear_leaves)
from scenes.primitives import facet_size_m
from scenes.scene import Material

FLAT = dict(bend=0.0, roll=0.0, twist=0.0, wrinkle_amplitude_m=0.0)
MATERIAL = Material("leaf", 0.48)


def _mesh(shape, facet=None):
    template = leaf_template(*leaf_resolution(shape, facet or facet_size_m(1.5)))
    vertices, petiole_base = leaf_vertices([shape], template)
    return vertices[0], template, petiole_base[0]


def _blade_area(vertices, template):
    tri = vertices[template.faces[template.labels == BLADE]]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()


def test_analytic_area_has_the_beta_closed_form():
    shape = PEAR
    a, b = shape.base_exponent, shape.apex_exponent
    peak = (a / (a + b)) ** a * (b / (a + b)) ** b
    closed = 2 * shape.length_m * shape.half_width_m * beta(a + 1, b + 1) / peak
    assert blade_area_m2(shape) == pytest.approx(closed, rel=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("deformation", ["flat", "bend", "roll", "serrated"])
def test_mesh_area_matches_the_analytic_area(seed, deformation):
    # Bending alone and rolling alone are isometries: the 3-D mesh keeps the flat blade's area.
    shape = sample_pear_leaf(np.random.default_rng(seed)).replace(**FLAT)
    if deformation == "bend":
        shape = shape.replace(bend=0.8)
    elif deformation == "roll":
        shape = shape.replace(roll=0.9)
    elif deformation == "serrated":
        shape = shape.replace(serration_depth=0.08, serration_teeth=12)
    vertices, template, _ = _mesh(shape)
    assert _blade_area(vertices, template) == pytest.approx(blade_area_m2(shape), rel=5e-3)


def test_wrinkles_and_saddle_add_a_little_area():
    flat = sample_pear_leaf(np.random.default_rng(5)).replace(**FLAT)
    curved = flat.replace(bend=0.5, roll=0.4, wrinkle_amplitude_m=0.0004)
    area_flat = _blade_area(*_mesh(flat)[:2])
    area_curved = _blade_area(*_mesh(curved)[:2])
    assert area_flat < area_curved < 1.05 * area_flat


def test_facet_rule_bounds_the_grid_spacing():
    shape = PEAR.replace(**FLAT)
    facet = facet_size_m(3.0)
    assert facet == pytest.approx(0.25 * 2 * (0.0015 + 3.0 * math.tan(math.radians(0.014))))
    vertices, template, _ = _mesh(shape, facet)
    blade = template.faces[template.labels == BLADE]
    a, b = np.concatenate([blade[:, [0, 1]], blade[:, [1, 2]], blade[:, [2, 0]]]).T
    length = np.linalg.norm(vertices[a] - vertices[b], axis=1)
    # Grid sides (same row, or same column including the tip fans) are at most one facet;
    # cell diagonals are longer, up to two facets where the width changes fastest.
    tip = (a == 0) | (b == 0) | (a == template.apex) | (b == template.apex)
    side = (template.row[a] == template.row[b]) | (template.t[a] == template.t[b]) | tip
    assert side.mean() > 0.6
    assert length[side].max() <= facet * (1 + 1e-9)
    assert length.max() <= 2 * facet * (1 + 1e-9)


def test_canonical_frame_and_labels():
    vertices, template, petiole_base = _mesh(PEAR)
    blade_tri = vertices[template.faces[template.labels == BLADE]]
    cross = np.cross(blade_tri[:, 1] - blade_tri[:, 0], blade_tri[:, 2] - blade_tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    centroid = (area[:, None] * blade_tri.mean(axis=1)).sum(axis=0) / area.sum()
    np.testing.assert_allclose(centroid, 0.0, atol=1e-12)
    chord = vertices[template.apex] - vertices[0]
    np.testing.assert_allclose(chord[1:], 0.0, atol=1e-12)  # midrib chord along +x
    assert chord[0] > 0
    normal = cross.sum(axis=0)
    assert abs(normal[1]) < 1e-12 and normal[2] > 0  # mean normal in the x-z plane, adaxial +z
    # The petiole continues the midrib backwards from the blade base.
    assert np.count_nonzero(template.labels == PETIOLE) > 0
    base_to_petiole = petiole_base - vertices[0]
    assert np.linalg.norm(base_to_petiole) == pytest.approx(PEAR.petiole_length_m, rel=1e-9)
    assert base_to_petiole @ chord < 0


def test_roll_curls_the_margin_to_the_adaxial_side():
    shape = PEAR.replace(**{**FLAT, "roll": 0.6})
    vertices, template, _ = _mesh(shape)
    margin = vertices[template.outline]
    midrib = vertices[[0, template.apex]]
    assert margin[:, 2].max() > midrib[:, 2].max() + 1e-3


def test_same_seed_same_bytes_and_other_seeds_differ():
    a = sample_pear_leaves(np.random.default_rng(42), np.ones(5))
    b = sample_pear_leaves(np.random.default_rng(42), np.ones(5))
    c = sample_pear_leaves(np.random.default_rng(43), np.ones(5))
    assert a == b and a != c
    template = leaf_template(*leaf_resolution(a[0], 0.002))
    va, vb, vc = (leaf_vertices(s, template)[0] for s in (a, b, c))
    assert va.tobytes() == vb.tobytes()
    assert not np.allclose(va, vc)


def _leaf_scene(pose: dict, **fields):
    entry = {"name": "leaf", "type": "leaf", "preset": "pear", "length": 0.08, "material": "pear-leaf",
             "pose": pose, **fields}
    return scene_from_spec({"scanner": {"position": [0, 0, 0]}, "objects": [entry]}).objects[0]


@pytest.mark.parametrize("axis", ["vertical", "horizontal"])
@pytest.mark.parametrize("incidence", [0.0, 30.0, 60.0])
def test_flat_leaf_pose_gives_exact_normal_and_midrib(axis, incidence):
    center = np.array([1.5, 0.2, -0.1])
    leaf = _leaf_scene({"center": center.tolist(), "facing": "scanner", "incidence_deg": incidence,
                        "rotation_axis": axis}, bend_deg=0, roll_deg=0, twist_deg=0, wrinkle_amplitude=0)
    truth = leaf.truth
    to_scanner = -center / np.linalg.norm(center)
    normal = np.array(truth["normal"])
    assert math.degrees(math.acos(normal @ to_scanner)) == pytest.approx(incidence, abs=1e-6)
    # A flat blade: every blade face has the truth normal.
    blade = leaf.face_normals()[leaf.face_labels == BLADE]
    np.testing.assert_allclose(blade, np.broadcast_to(normal, blade.shape), atol=1e-9)
    # The midrib starts horizontal (local +x); tilting about the horizontal axis (= the midrib) keeps it there.
    chord = np.array([math.cos(math.radians(truth["azimuth_deg"])), math.sin(math.radians(truth["azimuth_deg"]))])
    if axis == "horizontal":
        assert truth["elevation_deg"] == pytest.approx(0.0, abs=1e-9)
        assert chord @ to_scanner[:2] == pytest.approx(0.0, abs=1e-9)
    assert truth["area_m2"] == pytest.approx(float(leaf.face_areas()[leaf.face_labels == BLADE].sum()), rel=1e-12)


def test_curved_leaf_pose_midrib_angles():
    # Spin turns the midrib within the leaf plane: spin 30 deg raises a facing leaf's midrib by 30 deg.
    leaf = _leaf_scene({"center": [3.0, 0.0, 0.0], "facing": "scanner", "spin_deg": 30.0}, seed=4)
    assert leaf.truth["elevation_deg"] == pytest.approx(30.0, abs=1e-9)
    assert leaf.truth["azimuth_deg"] == pytest.approx(270.0, abs=1e-9)
    # The mean normal of a curved leaf stays close to the facing direction.
    assert leaf.truth["normal"][0] < -math.cos(math.radians(12))
    leaf = _leaf_scene({"center": [3.0, 0.0, 0.0], "facing": "scanner", "incidence_deg": 40.0}, seed=4)
    assert leaf.truth["elevation_deg"] == pytest.approx(0.0, abs=1e-9)
    assert leaf.truth["azimuth_deg"] == pytest.approx(310.0, abs=1e-9)


def test_leaf_objects_truth_and_materials():
    shapes = sample_pear_leaves(np.random.default_rng(0), [1.0, 1.3])
    rotations = np.stack([np.eye(3), np.eye(3)])
    objects = leaf_objects(shapes, rotations, [[0, 0, 0], [1, 0, 0]], ["a", "b"], [MATERIAL] * 2, 0.003,
                           group="g", extra_truth=[{"k": 1}, {"k": 2}])
    assert [o.name for o in objects] == ["a", "b"] and all(o.group == "g" for o in objects)
    for obj, shape in zip(objects, shapes):
        truth = obj.truth
        assert truth["length_m"] == shape.length_m and truth["labels"] == ["blade", "petiole"]
        assert truth["area_m2"] == pytest.approx(blade_area_m2(shape), rel=0.03)
        assert len(obj.face_labels) == len(obj.faces)
        outline = np.array(truth["outline"])
        assert np.min(np.linalg.norm(obj.vertices[None] - outline[:, None], axis=2), axis=1).max() < 1e-6
    assert objects[1].truth["k"] == 2


def test_pear_population_statistics():
    rng = np.random.default_rng(0)
    shapes = sample_pear_leaves(rng, np.ones(3000))
    length = np.array([s.length_m for s in shapes])
    half = np.array([s.half_width_m for s in shapes])
    assert length.mean() == pytest.approx(0.0647, abs=0.0005) and length.std() == pytest.approx(0.005, rel=0.15)
    assert half.mean() == pytest.approx(0.0219, abs=0.0005) and half.std() == pytest.approx(0.0038, rel=0.2)


def test_bad_leaf_parameters():
    with pytest.raises(SceneError, match="half_width_m .* must not exceed length_m"):
        LeafShape(length_m=0.02, half_width_m=0.03)
    with pytest.raises(SceneError, match="length_m must be a positive number"):
        LeafShape(length_m=-1.0)
    with pytest.raises(SceneError, match="unknown leaf parameter"):
        PEAR.replace(colour=1)

"""Procedural trees and orchard rows: cylinder truth, wood meshes, leaves, presets, the Conference row."""

import math

import numpy as np
import pytest

from scenes import SceneError, scene_from_spec
from scenes.pose import Pose
from scenes.shapes import SAGITTA_M, frusta, polygon_sides
from scenes.tree import (LEAF_ANGLE_DISTRIBUTIONS, PRESETS, centreline, grow_tree, sample_leaf_inclination,
                         tree_objects, wood_mesh)

CYLINDER_KEYS = {"id", "parent", "order", "branch", "start", "end", "radius_m", "radius_end_m"}


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_cylinder_truth_is_a_consistent_hierarchy(preset):
    model = grow_tree(preset, seed=3, leaf_count=0)
    cylinders = model.cylinders
    assert all(set(c) == CYLINDER_KEYS for c in cylinders)
    assert [c["id"] for c in cylinders] == list(range(len(cylinders)))
    by_id = {c["id"]: c for c in cylinders}
    assert [c["parent"] for c in cylinders].count(-1) == 1 and cylinders[0]["parent"] == -1
    for c in cylinders[1:]:
        parent = by_id[c["parent"]]
        assert parent["id"] < c["id"] and 0 < c["radius_m"] and 0 <= c["radius_end_m"] <= c["radius_m"] + 1e-12
        start, p0, p1 = np.array(c["start"]), np.array(parent["start"]), np.array(parent["end"])
        if parent["branch"] == c["branch"]:  # next segment of the same branch: starts where the parent ends
            assert c["order"] == parent["order"] and np.allclose(c["start"], parent["end"])
            assert c["radius_m"] == pytest.approx(parent["radius_end_m"])
        else:  # first segment of a child branch: starts on the parent's axis, thinner than the parent there
            assert c["order"] == parent["order"] + 1
            t = np.dot(start - p0, p1 - p0) / np.dot(p1 - p0, p1 - p0)
            assert -1e-9 <= t <= 1 + 1e-9 and np.linalg.norm(p0 + t * (p1 - p0) - start) < 1e-9
            assert c["radius_m"] < max(parent["radius_m"], parent["radius_end_m"])


def test_presets_echo_the_published_set_ups():
    apple = grow_tree("apple", 1, leaf_count=0).arrays()
    assert apple["order"].max() == 4
    volume = sum(math.pi * np.linalg.norm(np.subtract(e, s)) * (r0 * r0 + r0 * r1 + r1 * r1) / 3
                 for s, e, r0, r1 in zip(apple["start"], apple["end"], apple["radius_m"], apple["radius_end_m"]))
    assert 1.5e-3 < volume < 4.5e-3  # Méndez' simulated apple: about 2.8 dm3
    cylinder = grow_tree("cylinder", 0).cylinders
    assert len(cylinder) == 1 and cylinder[0]["radius_m"] == cylinder[0]["radius_end_m"] == 0.5
    assert np.linalg.norm(np.subtract(cylinder[0]["end"], cylinder[0]["start"])) == pytest.approx(2.0)
    conifer = grow_tree("conifer", 0).arrays()
    stubs = conifer["order"] == 1
    assert conifer["radius_m"][0] == 0.15 and np.sum(stubs) == 115
    # Stubs reach 15 cm beyond the stem surface.
    stub_reach = np.linalg.norm(conifer["end"][stubs] - conifer["start"][stubs], axis=1) - conifer["radius_m"][stubs] / 0.12
    assert np.allclose(stub_reach, 0.15, atol=0.02)
    pear = grow_tree("conference-pear", 0, leaf_count=0).arrays()
    leaders = pear["order"] == 1
    tilt = np.degrees(np.arccos((pear["end"] - pear["start"])[leaders][:, 2]
                                / np.linalg.norm((pear["end"] - pear["start"])[leaders], axis=1)))
    assert np.median(tilt) == pytest.approx(20 / math.cos(math.radians(12)) * 1.0, abs=4.0)


def test_same_seed_same_tree_and_leafless_mode():
    a, b, c = grow_tree("apple", 7), grow_tree("apple", 7), grow_tree("apple", 8)
    assert a.cylinders == b.cylinders and a.leaf_shapes == b.leaf_shapes
    assert np.array_equal(a.leaf_rotations, b.leaf_rotations) and a.cylinders != c.cylinders
    leafless = grow_tree("apple", 7, leaf_count=0)
    assert leafless.cylinders == a.cylinders and leafless.leaf_shapes == []


def test_wood_mesh_lies_on_the_frusta():
    model = grow_tree("vine", 2, leaf_count=0)
    arrays = model.arrays()
    vertices, faces = wood_mesh(arrays)
    obj = tree_objects(model, Pose(), "vine")[0]
    assert obj.name == "vine/wood" and obj.type == "wood" and len(obj.faces) == len(faces)
    # Every vertex sits on the surface of some frustum: distance to its axis equals the local radius.
    best = np.full(len(vertices), np.inf)
    for s, e, r0, r1 in zip(arrays["start"], arrays["end"], arrays["radius_m"], arrays["radius_end_m"]):
        d = e - s
        t = np.clip((vertices - s) @ d / (d @ d), 0, 1)
        gap = np.abs(np.linalg.norm(vertices - (s + t[:, None] * d), axis=1) - (r0 + t * (r1 - r0)))
        best = np.minimum(best, gap)
    assert best.max() < 1e-9
    assert obj.truth["volume_m3"] == pytest.approx(sum(
        math.pi * np.linalg.norm(e - s) * (r0 * r0 + r0 * r1 + r1 * r1) / 3
        for s, e, r0, r1 in zip(arrays["start"], arrays["end"], arrays["radius_m"], arrays["radius_end_m"])))


def test_frusta_face_outwards_and_follow_the_sagitta_rule():
    start, end = np.array([[0.0, 0.0, 0.0]]), np.array([[0.3, 0.4, 1.2]])
    sides = polygon_sides(0.05)
    assert 0.05 * (1 - math.cos(math.pi / sides)) <= SAGITTA_M < 0.05 * (1 - math.cos(math.pi / (sides - 1)))
    vertices, faces = frusta(start, end, [0.05], [0.02], sides)
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    axis = (end - start)[0] / np.linalg.norm(end - start)
    centre = tri.mean(axis=1)
    radial = centre - np.outer(centre @ axis, axis)
    assert np.all(np.einsum("ij,ij->i", normal, radial) > 0)


def test_leaves_hang_on_their_branches():
    model = grow_tree("conference-pear", 4, leaf_count=120)
    objects = tree_objects(model, Pose(translation=np.array([2.0, 1.0, 0.0])), "pear", leaf_facet_m=0.004)
    leaves = [o for o in objects if o.type == "leaf"]
    assert len(leaves) == 120 and leaves[0].name == "pear/leaf-0001" and all(o.group == "pear" for o in objects)
    cylinders = {c["id"]: c for c in objects[0].truth["cylinders"]}
    for leaf in leaves[:40]:
        c = cylinders[leaf.truth["cylinder"]]
        assert c["order"] >= 2
        # The petiole's free end (the first of its two rings) lies on the branch surface.
        ring = leaf.vertices[-12:-6].mean(axis=0)
        s, e = np.array(c["start"]), np.array(c["end"])
        t = np.clip((ring - s) @ (e - s) / ((e - s) @ (e - s)), 0, 1)
        distance = np.linalg.norm(ring - (s + t * (e - s)))
        assert distance == pytest.approx(c["radius_m"] + t * (c["radius_end_m"] - c["radius_m"]), abs=2e-4)
    areas = np.array([leaf.truth["area_m2"] for leaf in leaves])
    assert np.all(areas > 5e-4) and np.all(areas < 1.2e-2)


@pytest.mark.parametrize("name, mean_deg", [("spherical", 57.30), ("planophile", 26.76), ("erectophile", 63.24),
                                            ("uniform", 45.0)])
def test_leaf_angle_distributions_have_their_mean_inclination(name, mean_deg):
    sample = sample_leaf_inclination(name, np.random.default_rng(0), 20000)
    assert np.degrees(sample.mean()) == pytest.approx(mean_deg, abs=0.6)
    assert set(LEAF_ANGLE_DISTRIBUTIONS) >= {"spherical", "planophile", "erectophile", "plagiophile", "extremophile"}


def test_tree_errors():
    with pytest.raises(SceneError, match="unknown tree preset 'oak'"):
        grow_tree("oak", 0)
    with pytest.raises(SceneError, match="unknown tree override 'order9_length_m'"):
        grow_tree("apple", 0, order9_length_m=1.0)
    with pytest.raises(SceneError, match="cannot be scaled"):
        tree_objects(grow_tree("cylinder", 0), Pose(scale=2.0), "c")


def test_orchard_row_geometry_counts_and_ranges():
    spec = {"scanner": {"position": [0.0, 0.0, 1.3]},
            "objects": [{"name": "row", "type": "orchard-row", "seed": 5, "pose": {"translate": [0.0, 1.7, 0.0]}}]}
    scene = scene_from_spec(spec)
    wood = [o for o in scene.objects if o.type == "wood"]
    leaves = [o for o in scene.objects if o.type == "leaf"]
    assert len(wood) == 19 and len(leaves) == 19 * 300
    assert wood[0].name == "row/tree-01/wood" and leaves[0].name == "row/tree-01/leaf-0001"
    assert leaves[0].group == "row/tree-01" and scene.objects[-1].name == "row/ground"
    triangles = sum(len(o.faces) for o in scene.objects)
    assert 0.5e6 < triangles < 1.5e6
    heights = np.array([w.truth["height_m"] for w in wood])
    assert np.all((heights >= 2.4) & (heights <= 3.0))
    tops = np.array([w.vertices[:, 2].max() for w in wood])
    assert np.all(np.abs(tops - heights) < 0.3)
    bases = np.array([w.truth["cylinders"][0]["start"] for w in wood])
    np.testing.assert_allclose(np.diff(bases[:, 0]), 1.05)
    np.testing.assert_allclose(bases[:, 1:], [[1.7, 0.0]] * 19)
    # V trellis: leaders lean 20 deg (half the 40 deg aperture) off vertical, towards both inter-rows.
    leaders = [c for c in wood[0].truth["cylinders"] if c["order"] == 1 and c["parent"] == 1]
    lean = [math.degrees(math.atan2(abs(c["end"][1] - c["start"][1]), c["end"][2] - c["start"][2])) for c in leaders]
    assert len(leaders) == 4 and np.allclose(lean, 20.0, atol=3.0)
    assert {np.sign(c["end"][1] - c["start"][1]) for c in leaders} == {-1.0, 1.0}
    # Leaves from about 0.8 m to about 10 m from the scanner.
    centroids = np.array([leaf.vertices.mean(axis=0) for leaf in leaves])
    distance = np.linalg.norm(centroids - [0.0, 0.0, 1.3], axis=1)
    assert 0.6 < distance.min() < 1.2 and 9.0 < distance.max() < 11.0
    areas = np.array([leaf.truth["area_m2"] for leaf in leaves]) * 1e4
    low, high = np.percentile(areas, [2, 98])
    assert 9 < low < 16 and 55 < high < 80 and 28 < areas.mean() < 40  # Ch7 leaves: 12-65 cm2, mean 35
    # Near leaves are meshed finer than far ones (facet follows the footprint).
    near, far = np.argmin(distance), np.argmax(distance)
    assert len(leaves[near].faces) / leaves[near].truth["area_m2"] > len(leaves[far].faces) / leaves[far].truth["area_m2"]


def test_tree_overrides_are_type_checked():
    longer = grow_tree("cylinder", 0, order0_length_m=3)
    assert np.linalg.norm(np.subtract(longer.cylinders[0]["end"], longer.cylinders[0]["start"])) == pytest.approx(3.0)
    with pytest.raises(SceneError, match="'order0_segments' must be an integer, got 2.5"):
        grow_tree("cylinder", 0, order0_segments=2.5)
    with pytest.raises(SceneError, match="'order0_radius' must be a number, got 'thick'"):
        grow_tree("cylinder", 0, order0_radius="thick")


def test_centreline_samples_every_centimetre():
    cylinders = grow_tree("cylinder", 0).cylinders + [
        {"id": 1, "parent": 0, "order": 1, "branch": 1, "start": [0, 0, 1], "end": [0.3, 0, 1], "radius_m": 0.1,
         "radius_end_m": 0.05}]
    points, radius, ids = centreline(cylinders, 0.01)
    assert np.count_nonzero(ids == 0) == 201 and np.count_nonzero(ids == 1) == 31
    assert np.all(np.linalg.norm(np.diff(points[ids == 1], axis=0), axis=1) <= 0.01 + 1e-12)
    np.testing.assert_allclose(radius[ids == 0], 0.5)
    np.testing.assert_allclose(radius[ids == 1][[0, 15, 30]], [0.1, 0.075, 0.05])

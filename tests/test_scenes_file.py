"""Scene files: the issue's vocabulary, object types, poses, round trips and clear errors."""

import json
import math
import textwrap

import numpy as np
import pytest
import trimesh
import yaml

import scenes
from scenes import SceneError, load_scene_file, save_scene, scene_from_spec
from scenes.builtin import window_around
from scenes.materials import MATERIAL_NAMES, get_material, material_from_spec, sample_material

ISSUE_EXAMPLE = """
scanner:
  preset: faro-ls880
  position: [0, 0, 0]
  window: {theta_deg: [-2, 2], psi_deg: [88, 92]}   # azimuth and zenith ranges
  step_deg: 0.018
objects:
  - name: wall
    type: plane
    size: [4, 4]                       # metres
    material: {reflectance: 0.5}       # or a library name, e.g. material: paint-3
    pose: {center: [2.5, 0, 0], facing: scanner}
  - name: leaf1
    type: leaf
    preset: pear
    length: 0.09                       # metres, blade length
    seed: 3
    material: pear-leaf
    pose: {center: [1.5, 0, 0], incidence_deg: 30, rotation_axis: vertical}
  - name: part
    type: mesh
    file: part.ply
    material: {reflectance: 0.3}
    pose: {translate: [3, 0.2, 0], rotate: {axis: [0, 0, 1], angle_deg: 30}, scale: 1.0}
"""


@pytest.fixture
def issue_scene(tmp_path):
    trimesh.creation.box(extents=(0.2, 0.1, 0.3)).export(tmp_path / "part.ply")
    path = tmp_path / "scene.yaml"
    path.write_text(ISSUE_EXAMPLE)
    return path


def test_issue_example_loads(issue_scene):
    scene = scenes.load(str(issue_scene))
    assert scene.name == "scene" and scene.object_names == ["wall", "leaf1", "part"]
    wall, leaf, part = scene.objects
    assert wall.truth["normal"] == pytest.approx([-1, 0, 0]) and wall.truth["area_m2"] == pytest.approx(16.0)
    assert wall.material.reflectance == 0.5 and leaf.material == get_material("pear-leaf")
    assert leaf.truth["length_m"] == pytest.approx(0.09)
    to_scanner = -np.array([1.5, 0, 0]) / 1.5
    assert math.degrees(math.acos(np.dot(leaf.truth["normal"], to_scanner))) < 45  # 30 deg tilt of a curved leaf
    # The box is rotated by 30 deg about z and moved to (3, 0.2, 0).
    np.testing.assert_allclose(part.vertices.mean(axis=0), [3, 0.2, 0], atol=1e-12)
    np.testing.assert_allclose(sorted(part.vertices[:, 2]), sorted([-0.15] * 4 + [0.15] * 4))
    corner = part.vertices[np.argmax(part.vertices[:, 0] + 10 * part.vertices[:, 1])] - [3, 0.2, 0]
    assert math.hypot(*corner[:2]) == pytest.approx(math.hypot(0.1, 0.05))
    assert scene.scanner["window"] == {"theta_deg": [-2, 2], "psi_deg": [88, 92]}
    entries = scene.truth()
    assert [e["id"] for e in entries] == [0, 1, 2] and json.dumps(entries)


def test_round_trip_keeps_meshes_and_truth(issue_scene, tmp_path):
    first = load_scene_file(issue_scene)
    (tmp_path / "elsewhere").mkdir()
    saved = save_scene(first, tmp_path / "elsewhere" / "copy.yaml")
    assert yaml.safe_load(saved.read_text())["objects"][2]["file"] == "../part.ply"
    second = load_scene_file(saved)
    assert second.name == first.name
    for a, b in zip(first.objects, second.objects):
        assert a.name == b.name and a.material == b.material
        assert a.vertices.tobytes() == b.vertices.tobytes() and np.array_equal(a.faces, b.faces)
    assert json.dumps(first.truth()) == json.dumps(second.truth()).replace("copy", "scene")


def test_python_spec_builds_the_same_scene(issue_scene):
    spec = yaml.safe_load(ISSUE_EXAMPLE)
    from_python = scene_from_spec(spec, base_dir=issue_scene.parent)
    from_file = load_scene_file(issue_scene)
    for a, b in zip(from_python.objects, from_file.objects):
        assert a.vertices.tobytes() == b.vertices.tobytes()


ALL_TYPES = [
    {"name": "p", "type": "plane", "size": [1, 2], "pose": {"translate": [3, 0, 0]}},
    {"name": "d", "type": "disk", "radius": 0.2, "material": "canson-48", "pose": {"center": [2, 1, 0]}},
    {"name": "b", "type": "box", "size": [0.1, 0.2, 0.3], "pose": {"translate": [2, -1, 0], "scale": 2}},
    {"name": "s", "type": "sphere", "radius": 0.25, "material": {"library": "spectralon-99"}},
    {"name": "e", "type": "ellipsoid", "radii": [0.3, 0.2, 0.1], "pose": {"translate": [0, 3, 0]}},
    {"name": "c", "type": "cylinder", "radius": 0.5, "length": 2, "pose": {"translate": [5, 0, 0]}},
    {"name": "t", "type": "tube", "radius": 0.1, "radius_end": 0.05, "length": 1, "pose": {"translate": [5, 2, 0]}},
    {"name": "k", "type": "cone", "radius": 0.1, "length": 0.3, "pose": {"translate": [5, -2, 0]}},
    {"name": "h", "type": "surface", "surface": "saddle", "size": 0.2, "params": {"curvature": 0.3},
     "resolution": 41, "pose": {"center": [2, 0, 1]}},
    {"name": "h2", "type": "height-field", "surface": "plane", "size": 0.2, "params": {"tilt_deg": 20},
     "resolution": 11, "pose": {"center": [2, 0, 2]}},
    {"name": "l", "type": "leaf", "seed": 1, "facet": 0.004, "pose": {"center": [1, -1, 0]}},
    {"name": "tree", "type": "tree", "preset": "shoot", "seed": 2, "leaf_count": 3, "pose": {"translate": [4, 4, 0]}},
]


def test_every_type_builds_and_round_trips(tmp_path):
    scene = scene_from_spec({"name": "all", "scanner": {"position": [0, 0, 0]}, "objects": ALL_TYPES})
    kinds = {o.name: o.type for o in scene.objects}
    assert kinds["h2"] == "surface" and kinds["tree/wood"] == "wood" and kinds["tree/leaf-0003"] == "leaf"
    truth = {o.name: o.truth for o in scene.objects}
    assert truth["c"]["volume_m3"] == pytest.approx(math.pi * 0.25 * 2)
    assert truth["k"]["cylinders"][0]["radius_end_m"] == 0
    assert truth["t"]["volume_m3"] == pytest.approx(math.pi * 1 * (0.01 + 0.005 + 0.0025) / 3)
    assert truth["b"]["size_m"] == pytest.approx([0.2, 0.4, 0.6])
    assert truth["h2"]["params"]["tilt"] == pytest.approx(math.radians(20))
    d = scene.objects[scene.object_names.index("d")]
    assert d.truth["normal"] == pytest.approx(-np.array([2, 1, 0]) / math.sqrt(5))
    assert d.face_areas().sum() == pytest.approx(math.pi * 0.04, rel=2e-3)
    sphere = scene.objects[scene.object_names.index("s")]
    assert np.abs(np.linalg.norm(sphere.vertices, axis=1) - 0.25).max() < 1e-12
    again = load_scene_file(save_scene(scene, tmp_path / "all.yaml"))
    assert [o.vertices.tobytes() for o in again.objects] == [o.vertices.tobytes() for o in scene.objects]
    assert json.dumps(again.truth()) == json.dumps(scene.truth())


def test_pose_facing_incidence_and_explicit_forms():
    spec = {"scanner": {"position": [0, 0, 1]}, "objects": [
        {"name": "a", "type": "plane", "size": [1, 1], "pose": {"center": [3, 3, 1], "facing": "scanner",
                                                                 "incidence_deg": 25, "rotation_axis": "vertical"}},
        {"name": "b", "type": "plane", "size": [1, 1], "pose": {"center": [3, 0, 4], "incidence_deg": -40,
                                                                 "rotation_axis": "horizontal"}},
        {"name": "c", "type": "plane", "size": [1, 1], "pose": {"center": [3, 0, 1], "facing": [0, 0, 1],
                                                                 "rotation_axis": [1, 0, 0], "incidence_deg": 10}},
        {"name": "d", "type": "plane", "size": [1, 1],
         "pose": {"translate": [1, 2, 3], "rotate": [{"axis": [0, 0, 1], "angle_deg": 90},
                                                      {"axis": [1, 0, 0], "angle_deg": 90}]}}]}
    a, b, c, d = scene_from_spec(spec).objects
    for obj, center in ((a, [3, 3, 1]), (b, [3, 0, 4])):
        to_scanner = np.array([0, 0, 1]) - center
        to_scanner = to_scanner / np.linalg.norm(to_scanner)
        angle = math.degrees(math.acos(np.dot(obj.truth["normal"], to_scanner)))
        assert angle == pytest.approx(25 if obj is a else 40)
    assert a.truth["normal"][2] == pytest.approx(0.0, abs=1e-12)  # a vertical axis keeps the normal horizontal
    assert c.truth["normal"] == pytest.approx([0, -math.sin(math.radians(10)), math.cos(math.radians(10))])
    # Rotations apply in order: z by 90 (normal +z stays), then x by 90 (+z -> -y).
    assert d.truth["normal"] == pytest.approx([0, -1, 0])
    assert d.truth["center"] == [1, 2, 3]


def _error(tmp_path, text, files=()):
    for name, content in files:
        (tmp_path / name).write_bytes(content)
    path = tmp_path / "bad.yaml"
    path.write_text(textwrap.dedent(text))
    with pytest.raises(SceneError) as info:
        load_scene_file(path)
    message = str(info.value)
    assert message.startswith(str(path)), message
    return message


def test_unknown_type_lists_the_allowed_ones(tmp_path):
    message = _error(tmp_path, """
        objects:
          - {name: thing, type: torus, radius: 1}
        """)
    assert "object #1 'thing' (torus)" in message and "field 'type'" in message
    assert "got 'torus'; allowed: plane, disk, box, sphere" in message and "orchard-row" in message


@pytest.mark.parametrize("entry, expected", [
    ("{name: w, type: plane, size: [4, -1]}", "field 'size': must be 2 positive numbers"),
    ("{name: w, type: plane, size: [4, four]}", "field 'size': must be a list of 2 numbers (m)"),
    ("{name: w, type: sphere, radius: .nan}", "field 'radius': must be a finite number"),
    ("{name: w, type: sphere, radius: 0}", "field 'radius': must be positive"),
    ("{name: w, type: sphere, radius: true}", "field 'radius': must be a number (m)"),
    ("{name: w, type: sphere}", "missing required field 'radius'"),
    ("{name: w, type: sphere, radius: 1, colour: red}", "unknown field(s) ['colour']; allowed:"),
    ("{name: w, type: sphere, radius: 1, material: gold}", "unknown material 'gold'; library: spectralon-99"),
    ("{name: w, type: sphere, radius: 1, material: {reflectance: 1.5}}", "reflectance must be a number in [0, 1]"),
    ("{name: w, type: leaf, length: -0.05}", "leaf length_m must be a positive number"),
    ("{name: w, type: leaf, pose: {center: [1, 0, 0], scale: 2}}", "this type cannot be scaled"),
    ("{name: w, type: tree, preset: oak}", "got 'oak'; allowed: apple, vine, conifer"),
    ("{name: w, type: surface, surface: torus, size: 1}", "got 'torus'; allowed: plane, hemisphere"),
    ("{name: w, type: surface, surface: cone, size: 1, params: {height: 2}}", "unknown parameter(s) ['height']"),
    ("{name: w, type: plane, size: [1, 1], pose: {center: [1, 0, 0], translate: [1, 0, 0]}}", "not both"),
    ("{name: w, type: plane, size: [1, 1], pose: {center: [0, 0, 0]}}", "coincides with the scanner"),
    ("{name: w, type: plane, size: [1, 1], pose: {center: [1, 0, 0], rotation_axis: sideways}}",
     "allowed: vertical, horizontal, or a vector"),
    ("{name: w, type: plane, size: [1, 1], pose: {rotate: {axis: [0, 0, 0], angle_deg: 3}}}",
     "must be a non-zero vector"),
])
def test_bad_values_name_the_object_and_field(tmp_path, entry, expected):
    message = _error(tmp_path, f"objects:\n  - {entry}\n")
    assert "object #1 'w'" in message and expected in message


def test_missing_and_degenerate_mesh_files(tmp_path):
    message = _error(tmp_path, "objects:\n  - {name: m, type: mesh, file: nothere.ply}\n")
    assert "field 'file': 'nothere.ply' not found" in message
    message = _error(tmp_path, "objects:\n  - {name: m, type: mesh, file: x.fbx}\n", [("x.fbx", b"")])
    assert "unsupported extension; allowed: .obj, .ply, .stl" in message
    flat = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], faces=[[0, 1, 2], [1, 2, 3]],
                           process=False)
    message = _error(tmp_path, "objects:\n  - {name: m, type: mesh, file: flat.stl}\n",
                     [("flat.stl", flat.export(file_type="stl"))])
    assert "degenerate: all 2 triangles have zero area" in message
    message = _error(tmp_path, "objects:\n  - {name: m, type: mesh, file: pts.ply}\n",
                     [("pts.ply", trimesh.PointCloud([[0, 0, 0], [1, 1, 1]]).export(file_type="ply"))])
    assert "contains no triangles" in message


def test_file_level_errors(tmp_path):
    assert "not valid YAML" in _error(tmp_path, "objects: [\n")
    assert "must be a mapping with 'objects'" in _error(tmp_path, "- just a list\n")
    assert "field 'objects': must be a non-empty list" in _error(tmp_path, "objects: []\n")
    assert "missing required field 'objects'" in _error(tmp_path, "scanner: {}\n")
    message = _error(tmp_path, "objects:\n  - {name: a, type: sphere, radius: 1}\n  - {name: a, type: disk, radius: 1}\n")
    assert "object #2 'a' (disk): field 'name': 'a' is already used by object #1" in message
    message = _error(tmp_path, "bogus: 1\nobjects:\n  - {name: a, type: sphere, radius: 1}\n")
    assert "unknown field(s) ['bogus']" in message
    with pytest.raises(SceneError, match="unknown built-in scene 'no-such-scene'; available: .*leaf-1.5m"):
        scenes.load("no-such-scene")
    with pytest.raises(SceneError, match="scene file '.*missing.yaml' not found"):
        scenes.load(str(tmp_path / "missing.yaml"))
    with pytest.raises(SceneError, match="built from meshes"):
        save_scene(scenes.build("knife-edge"), tmp_path / "k.yaml")


def test_mitsuba_xml_shapes_become_objects(tmp_path):
    (tmp_path / "scene.xml").write_text("""<scene version="3.0.0">
      <bsdf type="diffuse" id="grey"><rgb name="reflectance" value="0.2, 0.3, 0.4"/></bsdf>
      <shape type="rectangle" id="wall"><transform name="to_world"><scale value="2"/><translate value="3,0,0"/>
        </transform><ref id="grey"/></shape>
      <shape type="sphere" id="ball"><point name="center" value="1,1,1"/><float name="radius" value="0.2"/></shape>
    </scene>""")
    spec = {"objects": [{"name": "xml", "type": "mitsuba", "file": "scene.xml"}]}
    wall, ball = sorted(scene_from_spec(spec, base_dir=tmp_path).objects, key=lambda o: o.name, reverse=True)
    assert wall.name == "xml/wall" and ball.name == "xml/ball" and wall.group == "xml"
    assert wall.material.reflectance == pytest.approx(0.3) and ball.material.reflectance == 0.5
    # Mitsuba's rectangle spans [-1, 1]^2 in the x-y plane; scaled by 2 and moved 3 along x.
    np.testing.assert_allclose(np.sort(wall.vertices[:, 0]), [1, 1, 5, 5], atol=1e-6)
    np.testing.assert_allclose(wall.vertices[:, 2], 0.0, atol=1e-6)
    assert np.abs(np.linalg.norm(ball.vertices - 1.0, axis=1) - 0.2).max() < 1e-6
    (tmp_path / "broken.xml").write_text("<scene version='3.0.0'><shape type='nonsense'/></scene>")
    with pytest.raises(SceneError, match="Mitsuba cannot load broken.xml"):
        scene_from_spec({"objects": [{"name": "x", "type": "mitsuba", "file": "broken.xml"}]}, base_dir=tmp_path)


def test_materials_library():
    assert set(MATERIAL_NAMES) >= {"spectralon-99", "canson-83", "canson-80", "canson-68", "canson-48", "canson-3",
                                   "greycard-22", "paint-3", "pear-leaf", "bark", "soil", "wall"}
    leaf = get_material("pear-leaf")
    assert leaf.reflectance == 0.48 and 0 < leaf.transmittance <= 0.52
    draws = [sample_material("pear-leaf", np.random.default_rng(s)).reflectance for s in range(400)]
    assert np.mean(draws) == pytest.approx(0.48, abs=0.005) and 0.02 < np.std(draws) < 0.04
    assert sample_material("paint-3", np.random.default_rng(0)) == get_material("paint-3")
    assert material_from_spec({"library": "canson-68", "reflectance": 0.6}).reflectance == 0.6


def test_window_around_covers_the_points():
    points = np.array([[2, -0.1, -0.2], [2, 0.1, 0.2]])
    window = window_around(points, [0, 0, 0], margin_deg=0.5)
    half = math.degrees(math.atan(0.05))
    assert window["theta_deg"] == pytest.approx([-half - 0.5, half + 0.5], abs=1e-3)
    assert window["psi_deg"][0] < 90 - math.degrees(math.atan(0.1)) < 90 < window["psi_deg"][1]
    wrapped = window_around(np.array([[-2, 0.1, 0], [-2, -0.1, 0]]), [0, 0, 0], 0.0)
    assert wrapped["theta_deg"][0] > 170 and wrapped["theta_deg"][1] < 190

"""Suites (YAML), cases and the scene generators of the benchmark."""

import math

import numpy as np
import pytest
import yaml

from benchmarks.errors import BenchError
from benchmarks.generators import build_scene, direction_angles_deg
from benchmarks.suite import case_seed, load_suite, parse_suite, suite_names


def write(tmp_path, data, name="suite.yaml"):
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return path


def test_vary_expands_the_product_with_names_and_stable_seeds(tmp_path):
    path = write(tmp_path, {"name": "t", "cases": [
        {"name": "leaf-{distance_m}-{step_deg}", "scene": {"generator": "plate-leaf"},
         "vary": {"distance_m": [1.5, 3.0], "scanner.step_deg": [0.018, 0.036]}},
        {"name": "edge", "scene": {"builtin": "knife-edge"}, "targets": ["plate"], "seed": 7}]})
    suite = load_suite(str(path))
    assert [c.name for c in suite.cases] == ["leaf-1.5-0.018", "leaf-1.5-0.036", "leaf-3.0-0.018",
                                             "leaf-3.0-0.036", "edge"]
    first = suite.cases[1]
    assert first.scene == {"generator": "plate-leaf", "distance_m": 1.5} and first.scanner == {"step_deg": 0.036}
    assert first.seed == case_seed("leaf-1.5-0.036") and suite.cases[-1].seed == 7
    assert suite.cases[-1].targets == ("plate",)
    assert load_suite(str(path)).digest() == suite.digest()
    assert parse_suite({"name": "other", "cases": [c.to_dict() for c in suite.cases]}).digest() != suite.digest()


@pytest.mark.parametrize("data, message", [
    ("name: [unclosed", "not valid YAML"),
    ({"name": "t"}, "non-empty list"),
    ({"name": "t", "cases": [{"name": "a", "scene": {"builtin": "knife-edge"}, "colour": 1}]}, "unknown key"),
    ({"name": "t", "cases": [{"name": "a", "scene": {"builtin": "no-such-scene"}}]}, "unknown built-in scene"),
    ({"name": "t", "cases": [{"name": "a", "scene": {"generator": "plate-leaf", "size": 3}}]}, "no parameter"),
    ({"name": "t", "cases": [{"name": "a", "scene": {"generator": "plate-leaf"}, "scanner": {"zoom": 2}}]},
     "unknown scanner override"),
    ({"name": "t", "cases": [{"name": "a", "scene": {"builtin": "knife-edge"}}] * 2}, "repeated"),
    ({"name": "t", "cases": [{"name": "a", "scene": {"generator": "plate-leaf"},
                              "vary": {"distance_m": [1, 2]}}]}, "every varied key"),
    ({"name": "t", "cases": [{"name": "a-{x}", "scene": {"generator": "plate-leaf"},
                              "vary": {"distance_m": [1, 2]}}]}, "not varied"),
    ({"name": "t", "cases": [{"name": "a", "scene": {"builtin": "knife-edge"}, "seed": "x"}]}, "integer"),
])
def test_malformed_suites_name_the_file_and_the_problem(tmp_path, data, message):
    path = write(tmp_path, data)
    with pytest.raises(BenchError, match=message) as info:
        load_suite(str(path))
    assert str(path) in str(info.value)


def test_vary_reaches_nested_and_method_parameters():
    suite = parse_suite({"name": "t", "cases": [{"name": "h-{n_smooth}-{radius}", "scene": {
        "heightfield": "hemisphere"}, "params": {"prop-sfs": {"eps_alpha": 0.2}},
        "vary": {"params.prop-sfs.n_smooth": [1, 5], "surface_params.radius": [10.0]}}]})
    assert [c.params for c in suite.cases] == [{"prop-sfs": {"eps_alpha": 0.2, "n_smooth": 1}},
                                               {"prop-sfs": {"eps_alpha": 0.2, "n_smooth": 5}}]
    assert suite.cases[0].scene == {"heightfield": "hemisphere", "surface_params": {"radius": 10.0}}
    assert suite.cases[1].name == "h-5-10.0"
    with pytest.raises(BenchError, match="'params' must map"):
        parse_suite({"name": "t", "cases": [{"name": "h", "scene": {"heightfield": "hemisphere"}, "params": [1]}]})
    with pytest.raises(BenchError, match="side"):
        parse_suite({"name": "t", "cases": [{"name": "h", "scene": {"heightfield": "hemisphere", "side": 3}}]})


def test_unknown_suite():
    with pytest.raises(BenchError, match="quick"):
        load_suite("no-such-suite")


def test_builtin_suites_hold_what_they_promise():
    assert {"quick", "standard"} <= set(suite_names())
    quick = load_suite("quick")
    assert len(quick.cases) <= 12
    standard = load_suite("standard")
    single = [c for c in standard.cases if c.scene.get("generator") == "single-leaf"]
    assert len(single) >= 50
    distances = {c.scene["distance_m"] for c in single}
    incidences = {c.scene["incidence_deg"] for c in single}
    assert min(distances) == 0.8 and max(distances) == 5.0
    assert min(incidences) == 0 and max(incidences) == 80
    assert {"leaf-cluster", "leafy-tree", "orchard-row"} <= {c.scene.get("builtin") for c in standard.cases}
    trees = load_suite("trees").cases
    assert {c.scene["preset"] for c in trees} == {"apple", "vine", "conference-pear"}
    assert {c.scene.get("leaf_count") for c in trees if c.scene["preset"] == "apple"} == {0, None}
    synthetic = load_suite("sfs-synthetic").cases
    assert all("heightfield" in c.scene for c in synthetic)
    assert {c.scene.get("alpha_noise_deg") for c in synthetic} >= {1.4, 2.8, 5.7}
    assert {c.scene.get("alpha_bias_deg") for c in synthetic} >= {-7.0, -3.5, 3.5, 7.0}
    assert {c.scene.get("side") for c in synthetic if c.scene["heightfield"] == "hemisphere"} >= {25, 34, 41, 47, 53, 58}
    assert {c.params["prop-sfs"].get("seed_cutoff") for c in synthetic} >= {0.061, 0.029, 0.019}


def test_plate_leaf_truth_matches_its_pose():
    scene = build_scene({"generator": "plate-leaf", "distance_m": 2.0, "incidence_deg": 30.0,
                         "length_m": 0.08, "width_m": 0.05, "roll_deg": 0.0})
    leaf, wall = scene.objects
    assert leaf.type == "leaf" and wall.name == "background"
    truth = leaf.truth
    assert truth["area_m2"] == pytest.approx(math.pi * 0.04 * 0.025, rel=5e-3)
    assert truth["area_m2"] == pytest.approx(leaf.face_areas().sum(), rel=1e-12)
    normal = np.array(truth["normal"])
    to_scanner = -leaf.vertices[0] / np.linalg.norm(leaf.vertices[0])
    assert math.degrees(math.acos(np.dot(normal, to_scanner))) == pytest.approx(30.0)
    np.testing.assert_allclose(leaf.face_normals(), np.tile(normal, (len(leaf.faces), 1)), atol=1e-9)
    # Tilted about the vertical with roll 0: the midrib points straight up.
    assert truth["elevation_deg"] == pytest.approx(90.0)
    assert direction_angles_deg([0.0, -1.0, 1.0]) == pytest.approx((45.0, 270.0))
    # The window covers the blade with margin; the wall lies behind it.
    window = scene.scanner["window"]
    assert window["theta_deg"][0] < -0.9 < 0.9 < window["theta_deg"][1]
    assert wall.vertices[:, 0].min() == pytest.approx(2.5)


def test_single_leaf_is_a_seeded_procedural_leaf():
    a = build_scene({"generator": "single-leaf", "distance_m": 2.0, "incidence_deg": 40.0, "seed": 3})
    b = build_scene({"generator": "single-leaf", "distance_m": 2.0, "incidence_deg": 40.0, "seed": 3})
    c = build_scene({"generator": "single-leaf", "distance_m": 2.0, "incidence_deg": 40.0, "seed": 4})
    leaf = a.objects[0]
    assert leaf.type == "leaf" and {"area_m2", "elevation_deg", "azimuth_deg", "outline"} <= set(leaf.truth)
    assert np.array_equal(leaf.vertices, b.objects[0].vertices)
    assert not np.array_equal(leaf.vertices, c.objects[0].vertices)
    assert a.objects[1].name == "background" and a.objects[1].vertices[:, 0].min() == pytest.approx(2.5)


def test_tree_heading_turns_the_tree_about_its_trunk():
    spec = {"generator": "tree", "preset": "vine", "seed": 1, "leaf_count": 0, "distance_m": 4.0}
    grown = build_scene(spec).objects[0]
    turned = build_scene({**spec, "heading_deg": 90.0}).objects[0]
    # A quarter turn about the vertical through the trunk's base at (4, 0): (x, y) -> (4 - y, x - 4); the woody
    # truth turns exactly (the tube mesh is rebuilt about the turned axes, so its vertices are compared by extent).
    for key in ("start", "end"):
        before, after = (np.array([c[key] for c in tree.truth["cylinders"]]) for tree in (grown, turned))
        np.testing.assert_allclose(after, np.column_stack([4.0 - before[:, 1], before[:, 0] - 4.0, before[:, 2]]),
                                   atol=1e-9)
    # The vine's cordons run along the line of sight as grown and across it once turned.
    extent = np.ptp(grown.vertices, axis=0), np.ptp(turned.vertices, axis=0)
    assert extent[0][0] > 3 * extent[0][1] and extent[1][1] > 3 * extent[1][0]


def test_generator_errors():
    with pytest.raises(BenchError, match="available"):
        build_scene({"generator": "nope"})
    with pytest.raises(BenchError, match="incidence_deg"):
        build_scene({"generator": "plate-leaf", "incidence_deg": 95})
    with pytest.raises(BenchError, match="builtin"):
        build_scene({"distance_m": 3})


def test_analytic_surface_is_a_default_target():
    from benchmarks.scoring import target_ids

    scene = build_scene({"generator": "analytic-surface", "surface": "cone", "distance_m": 2.0, "size_m": 0.06})
    surface, wall = scene.objects
    assert surface.type == "surface" and surface.truth["surface"] == "cone"
    assert target_ids(scene) == [0]
    assert np.linalg.norm(surface.vertices, axis=1).min() == pytest.approx(2.0 - 0.06 / 2 * math.tan(math.pi / 6), rel=1e-3)
    with pytest.raises(BenchError, match="analytic-surface"):
        build_scene({"generator": "analytic-surface", "surface": "teapot"})


@pytest.mark.parametrize("case,message", [
    ({"name": "c", "scene": {"generator": "single-leaf", "distance_m": -1.5}}, "distance_m is a length or distance"),
    ({"name": "c", "scene": {"generator": "single-leaf", "incidence_deg": float("nan")}}, "incidence_deg must be a finite"),
    ({"name": "c", "scene": {"builtin": "knife-edge"}, "scanner": {"step_deg": 0}}, "scanner: .*step_deg"),
    ({"name": "c", "scene": {"builtin": "knife-edge"}, "scanner": {"window": {"theta_deg": [0, 1]}}}, "scanner: window"),
])
def test_invalid_values_are_refused_when_the_suite_is_read(case, message):
    with pytest.raises(BenchError, match=message):
        parse_suite({"name": "s", "cases": [case]})


def test_a_sweep_refuses_invalid_values_before_running():
    from benchmarks.sweeps import sweep_suite

    with pytest.raises(BenchError, match="distance_m is a length"):
        sweep_suite("distance", values=[-1, 0])
    with pytest.raises(BenchError, match="step_deg"):
        sweep_suite("step", values=[0.0])


CANOPY_SCENE = """
name: three-leaves
scanner:
  preset: faro-ls880
  position: [0, 0, 0]
  window: {theta_deg: [-3.5, 3.0], psi_deg: [87.5, 92.5], step_deg: 0.08}
objects:
  - {name: back, type: leaf, preset: pear, seed: 1, length: 0.08, material: pear-leaf,
     pose: {center: [2.0, 0.0, 0.0], facing: scanner}}
  - {name: front, type: leaf, preset: pear, seed: 2, length: 0.08, material: pear-leaf,
     pose: {center: [1.97, 0.035, 0.0], facing: scanner}}
  - {name: apart, type: leaf, preset: pear, seed: 3, length: 0.08, material: pear-leaf,
     pose: {center: [2.0, -0.09, 0.0], facing: scanner}}
  - {name: wall, type: plane, size: [1.0, 1.0], material: wall, pose: {center: [3.0, 0, 0], facing: scanner}}
"""


def test_cases_read_scene_files_relative_to_the_suite(tmp_path):
    (tmp_path / "scenes").mkdir()
    scene_path = tmp_path / "scenes" / "canopy.yaml"
    scene_path.write_text(CANOPY_SCENE)
    path = write(tmp_path, {"name": "mine", "cases": [{"name": "canopy", "scene": {"file": "scenes/canopy.yaml"}}]})
    (case,) = load_suite(str(path)).cases
    assert case.scene["file"] == str(scene_path.resolve()) and len(case.scene["sha256"]) == 64
    assert [o.name for o in build_scene(case.scene).objects] == ["back", "front", "apart", "wall"]
    # The stored case is read back as it is (workers, resumed runs).
    assert parse_suite({"name": "mine", "cases": [case.to_dict()]}).cases[0].scene == case.scene
    scene_path.write_text(CANOPY_SCENE.replace("seed: 3", "seed: 4"))
    with pytest.raises(BenchError, match="changed since its suite was read"):
        build_scene(case.scene)


@pytest.mark.parametrize("scene, text, message", [
    ({"file": "missing.yaml"}, None, "scene file 'missing.yaml' not found"),
    ({"file": "bad.yaml"}, "objects: [{type: no-such-type, name: x}]", "not a valid scene"),
    ({"file": "bad.yaml"}, "name: [unclosed", "not a valid scene"),
    ({"file": "bad.yaml", "scale": 2}, "objects: []", "takes only 'file'"),
    ({"file": 3}, None, "must be a path"),
])
def test_scene_file_entries_are_checked_when_the_suite_is_read(tmp_path, scene, text, message):
    if text is not None:
        (tmp_path / "bad.yaml").write_text(text)
    path = write(tmp_path, {"name": "mine", "cases": [{"name": "c", "scene": scene}]})
    with pytest.raises(BenchError, match=message):
        load_suite(str(path))


def test_a_small_canopy_scored_on_the_whole_scan(tmp_path):
    """Three leaves (two overlapping, 3 cm apart in depth) read from a scene file; PROP-SFS runs once on the whole
    scan: every leaf is found or missed, the isolated one is found, and the case gives its throughput."""
    from benchmarks.registry import get_variant
    from benchmarks.runner import case_rows, variant_specs
    from benchmarks.summary import leaf_printout, validation_table

    (tmp_path / "canopy.yaml").write_text(CANOPY_SCENE)
    path = write(tmp_path, {"name": "mine", "cases": [{"name": "canopy", "scene": {"file": "canopy.yaml"}}]})
    (case,) = load_suite(str(path)).cases
    rows = list(case_rows(case.to_dict(), variant_specs([get_variant("raw"), get_variant("fused")])))
    raw, fused = rows
    assert raw["error"] is None and fused["error"] is None, (raw["error"], fused["error"])
    counts = fused["metrics"]["case"]
    scores = {leaf["target"]: leaf for leaf in fused["metrics"]["targets"]}
    assert set(scores) == {"back", "front", "apart"}
    assert counts["n_leaves"] == 3 and counts["n_found"] + counts["n_missed"] == 3
    assert scores["apart"]["found"] == 1 and scores["apart"]["purity"] > 0.9
    assert abs(scores["apart"]["area_rel_err"]) < 0.2
    assert scores["back"]["visibility"] < 0.8 < scores["front"]["visibility"]
    assert counts["n_pulses"] > 0 and "n_regions" not in raw["metrics"]["case"]
    for row in rows:
        row["case_name"] = "canopy"
    table = {r["variant"]: r for r in validation_table(rows)}
    assert table["fused"]["n_leaves"] == 2 and table["raw"]["n_found"] is None
    assert "fused" in leaf_printout(rows)

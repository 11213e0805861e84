"""Built-in scenes, the truth and preview commands, and an end-to-end scan of a leaf."""

import json
import math

import numpy as np
import pytest
from matplotlib import image

import scenes
from tlssim.cli import main
from tlssim.simulate import setup_from_section, simulate

SCENE = """
scanner:
  position: [0, 0, 0]
  window: {theta_deg: [-3, 3], psi_deg: [87, 93]}
objects:
  - {name: leaf, type: leaf, seed: 2, pose: {center: [2, 0, 0], incidence_deg: 20}}
  - {name: shoot, type: tree, preset: shoot, seed: 1, leaf_count: 2, pose: {translate: [3, 0, -0.1]}}
  - {name: wall, type: plane, size: [2, 2], material: wall, pose: {center: [4, 0, 0]}}
"""

EXPECTED = {"knife-edge", "tilted-plane", "leaf-1.5m", "leaf-3m", "leaf-5m", "leaf-cluster", "leafless-tree",
            "leafy-tree", "orchard-row", "cylinder-50cm"} | {f"surface-{s}" for s in scenes.surfaces.SURFACE_NAMES}


def test_library_lists_the_issue_scenes(capsys):
    assert EXPECTED <= set(scenes.names())
    assert main(["scenes"]) == 0
    listing = capsys.readouterr().out
    assert all(name in listing for name in EXPECTED)


@pytest.mark.parametrize("name", sorted(set(scenes.names()) - {"orchard-row", "wavy-sheet", "knife-edge",
                                                                 "tilted-plane", "panel-series", "goniometer"}))
def test_builtin_scenes_have_scannable_windows(name):
    scene = scenes.build(name)
    setup = setup_from_section(scene.scanner)
    rows, cols = setup.window.shape
    assert rows * cols < 1.5e6, "keep built-in windows scannable in well under a minute on two cores"
    # The objects (their centroid, seen from the scanner) lie inside the window.
    d = np.concatenate([o.vertices for o in scene.objects if o.type != "plane"]).mean(axis=0) - setup.pose.position
    theta, psi = math.degrees(math.atan2(d[1], d[0])), math.degrees(math.acos(d[2] / np.linalg.norm(d)))
    assert setup.window.theta_deg[0] < theta < setup.window.theta_deg[1]
    assert setup.window.psi_deg[0] < psi < setup.window.psi_deg[1]


def test_truth_command_json(tmp_path, capsys):
    path = tmp_path / "scene.yaml"
    path.write_text(SCENE)
    assert main(["truth", str(path), "--json"]) == 0
    entries = json.loads(capsys.readouterr().out)
    by_name = {e["name"]: e for e in entries}
    assert [e["id"] for e in entries] == list(range(len(entries)))
    leaf = by_name["leaf"]
    assert {"id", "name", "type", "area_m2", "normal", "elevation_deg", "azimuth_deg"} <= set(leaf)
    assert "outline" not in leaf and leaf["type"] == "leaf"
    wood = by_name["shoot/wood"]
    assert wood["type"] == "wood" and {"cylinders", "volume_m3"} <= set(wood)
    assert set(wood["cylinders"][0]) == {"id", "parent", "order", "branch", "start", "end", "radius_m", "radius_end_m"}
    assert main(["truth", str(path), "--json", "--full"]) == 0
    assert "outline" in json.loads(capsys.readouterr().out)[0]
    assert main(["truth", str(path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(entries) and "area" in lines[0] and "cylinders" in lines[1]


def test_truth_command_reports_bad_files(tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text("objects:\n  - {name: x, type: sphere, radius: -2}\n")
    assert main(["truth", str(path)]) == 2
    error = capsys.readouterr().err
    assert "bad.yaml: object #1 'x' (sphere): field 'radius': must be positive" in error


def test_preview_renders_the_scene_from_the_scanner(tmp_path, capsys):
    path = tmp_path / "scene.yaml"
    path.write_text(SCENE)
    out = tmp_path / "scene.png"
    assert main(["preview", str(path), "-o", str(out), "--width", "96"]) == 0
    picture = image.imread(out)[..., :3]
    assert picture.shape[1] == 96 and picture.shape[0] == 96  # square window, square picture
    centre = picture[picture.shape[0] // 2, picture.shape[1] // 2]
    assert centre[1] > centre[0] and centre[1] > centre[2]  # the leaf in the middle is green
    assert json.loads(capsys.readouterr().out)["objects"] == len(scenes.load(str(path)).objects)


def test_scan_of_a_leaf_covers_it_in_truth_id():
    scene = scenes.build("leaf-5m")
    setup = setup_from_section(scene.scanner)
    scan = simulate(scene, setup, seed=0, progress=False)
    leaf_id = scene.object_names.index("leaf")
    leaf = scene.objects[leaf_id]
    hits = scan.truth_id == leaf_id
    assert hits.sum() > 500
    # Pulses credited to the leaf ≈ the leaf's projected area over the area of one grid cell at its distance.
    centroid = leaf.vertices.mean(axis=0)
    view = centroid / np.linalg.norm(centroid)
    projected = np.sum(leaf.face_areas() * np.abs(leaf.face_normals() @ view))
    step = math.radians(setup.window.step_deg[0])
    cell = (np.linalg.norm(centroid) * step) ** 2
    assert hits.sum() == pytest.approx(projected / cell, rel=0.1)
    # Every pulse that hits the leaf lies within the leaf's angular extent, and the wall fills the rest.
    assert set(np.unique(scan.truth_id)) <= {leaf_id, scene.object_names.index("wall")}
    assert np.nanmedian(scan.range[hits]) == pytest.approx(np.linalg.norm(centroid), abs=0.02)

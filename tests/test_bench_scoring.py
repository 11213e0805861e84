"""Scoring against the scene truth on small simulated scans."""

import numpy as np
import pytest
from scipy.spatial import cKDTree
from trimesh.triangles import closest_point

from benchmarks import scoring
from benchmarks.generators import background_wall, elliptic_leaf, scanner_window
from benchmarks.registry import VariantOutput
from scenes.scene import Scene
from tlssim.simulate import setup_from_section, simulate


@pytest.fixture(scope="module")
def two_leaves():
    """A leaf at 3 m half hidden by another leaf 10 cm in front of it, a wall behind both."""
    back = elliptic_leaf("back", (3.0, 0.0, 0.0), (-1, 0, 0), (0, 1, 0), 0.08, 0.05)
    front = elliptic_leaf("front", (2.9, 0.04 * 2.9 / 3.0, 0.0), (-1, 0, 0), (0, 1, 0), 0.08, 0.05)
    objects = [back, front]
    scene = Scene(objects + [background_wall(objects, 3.5, 0.3)], scanner_window(objects), "two-leaves")
    scan = simulate(scene, setup_from_section(scene.scanner), seed=1, progress=False)
    return scene, scan, scoring.prepare_leaves(scene, scan)


def test_visible_areas_count_edge_on_parts_and_leave_out_hidden_and_out_of_window_ones():
    """Analytic visible areas: a leaf facing the scanner, one at 89.5 deg (a footprint sum diverges or misses it),
    one whose middle another leaf hides exactly, one half outside the window."""
    tilt = np.radians(89.5)
    facing = elliptic_leaf("facing", (2.0, 0.0, 0.0), (-1, 0, 0), (0, 1, 0), 0.08, 0.05)
    grazing = elliptic_leaf("grazing", (2.0, 0.2, 0.0), (-np.cos(tilt), 0, np.sin(tilt)), (0, 1, 0), 0.08, 0.05)
    hidden = elliptic_leaf("hidden", (3.0, -0.2, 0.0), (-1, 0, 0), (0, 1, 0), 0.08, 0.05)
    cover = elliptic_leaf("cover", (2.0, -0.2 * 2.0 / 3.0, 0.0), (-1, 0, 0), (0, 1, 0), 0.04, 0.025)
    cut = elliptic_leaf("cut", (2.0, 0.0, 0.3), (-1, 0, 0), (0, 0, 1), 0.08, 0.05)
    objects = [facing, grazing, hidden, cover, cut]
    section = scanner_window(objects[:4], margin_deg=0.2)
    section["window"]["psi_deg"][0] = 90.0 - np.degrees(np.arctan2(0.3, 2.0))  # through the cut leaf's centre
    section["window"]["step_deg"] = 0.2
    scene = Scene(objects, section, "visible-areas")
    scan = simulate(scene, setup_from_section(scene.scanner), seed=1, progress=False)
    seen = scoring.visible_areas(scene, scan, range(5))
    area = {i: o.truth["area_m2"] for i, o in enumerate(objects)}
    assert seen[0] == pytest.approx(area[0], rel=1e-9)
    assert seen[1] == pytest.approx(area[1], rel=1e-9)
    # The cover, at 2/3 of the distance and 1/2 the size, spans 3/4 of its angles: it hides 9/16 of its area.
    assert seen[2] == pytest.approx(7 / 16 * area[2], rel=0.02)
    assert seen[3] == pytest.approx(area[3], rel=1e-9)
    # The window's first row (half a step beyond the first beam) cuts the 8 x 5 cm ellipse at height z_b.
    t = (2.0 / np.tan(scan.psi[0, 0] - np.radians(0.1)) - 0.3) / 0.04
    assert seen[4] / area[4] == pytest.approx((t * np.sqrt(1 - t * t) + np.arcsin(t) + np.pi / 2) / np.pi, rel=0.01)


def test_leaf_points_include_mixed_pulses_and_visibility_sees_occlusion(two_leaves):
    scene, scan, leaves = two_leaves
    back, front = leaves
    assert (back.name, front.name) == ("back", "front")
    assert front.scan_stats["visibility"] == pytest.approx(1.0)
    # The front leaf is seen whole; it hides half the back leaf (visible areas traced on the mesh).
    assert front.scan_stats["visible_area_ratio"] == pytest.approx(1.0, rel=1e-9)
    assert back.scan_stats["visible_area_ratio"] == pytest.approx(0.5, abs=0.1)
    assert back.scan_stats["visibility"] == pytest.approx(0.5, abs=0.1)
    # The leaf's points: its own pulses plus wall- or leaf-dominated pulses with >= 10 % of their power from it.
    assert front.own.sum() < front.mask.sum()
    others = set(np.unique(front.attributed[~front.own]))
    assert others and others <= {0, 2}
    assert front.scan_stats["range_m"] == pytest.approx(2.9, abs=0.01)
    sigma = front.scan_stats["sigma_range_m"]
    assert 0.0003 < sigma < 0.003, "range noise of the simulator (mm level at 3 m)"
    assert front.taus["auto"] == pytest.approx(max(3 * sigma, 0.002)) and front.taus["1cm"] == 0.01


def test_raw_and_an_oracle_correction(two_leaves):
    scene, scan, leaves = two_leaves
    front = leaves[1]
    raw = scoring.score_leaf(front, VariantOutput(front.scan.xyz.copy()))
    assert raw["rop_before"] == raw["rop_after"] > 0.1
    assert raw["good_points_lost"] == 0.0 and raw["outliers_restored"] == 0.0
    assert raw["object_type"] == "leaf" and "area_rel_err" not in raw
    # The oracle moves every point onto the true surface of its object (onto a triangle: any point of a
    # triangle lies on the mesh).
    xyz = front.scan.xyz.copy()
    rows, cols = np.nonzero(front.mask)
    for oid in np.unique(front.attributed):
        triangles = scene.objects[oid].vertices[scene.objects[oid].faces]
        sel = front.attributed == oid
        points = xyz[rows[sel], cols[sel]]
        _, face = cKDTree(triangles.mean(axis=1)).query(points)
        xyz[rows[sel], cols[sel]] = closest_point(triangles[face], points)
    oracle = scoring.score_leaf(front, VariantOutput(xyz, traits={"area_m2": front.truth["area_m2"],
                                                                   "elevation_deg": front.truth["elevation_deg"],
                                                                   "azimuth_deg": front.truth["azimuth_deg"]}))
    assert oracle["rop_after"] < 0.01 and oracle["outliers_restored"] > 0.99
    assert oracle["completeness"] > 0.99 and oracle["surface_rmse_m"] < 1e-6 and oracle["inlier_p90_m"] < 1e-6
    assert oracle["area_rel_err"] == 0.0 and oracle["elevation_err_deg"] == pytest.approx(0.0, abs=1e-6)
    # Dropping every point leaves no outlier and loses every good point.
    dropped = scoring.score_leaf(front, VariantOutput(np.full_like(xyz, np.nan)))
    assert dropped["rop_after"] == 0.0 and dropped["good_points_lost"] == 1.0 and dropped["completeness"] == 0.0


def test_crop_margin_covers_the_mixed_band_near_the_scanner():
    """At 0.8 m and 0.018 deg the 1/e² beam radius (1.70 mm) spans 6.75 pixels of 0.251 mm: the crop keeps two
    radii beyond the fixed margin; on a coarse far scan (4 m, 0.08 deg: radius 0.44 px) the margin barely grows."""
    from types import SimpleNamespace

    from tlssim.pattern import ScanWindow
    from tlssim.scan import ScannerDescription
    from tlssim.scanner import ScannerModel

    def scan(step_deg):
        window = ScanWindow((0.0, 1.0), (89.0, 91.0), step_deg)
        return SimpleNamespace(scanner=ScannerDescription(ScannerModel(beam_waist_radius_m=0.0015, divergence_deg=0.014),
                                                          window))

    assert scoring.crop_margin_px(scan(0.018), 0.8) == scoring.CROP_MARGIN_PX + 14
    assert scoring.crop_margin_px(scan(0.08), 4.0) == scoring.CROP_MARGIN_PX + 1


def test_visibility_counts_close_occluders_and_the_window_border():
    """A leaf 3 cm behind another that covers its left half (the old rule needed a whole leaf length in front), and
    a leaf whose right half lies beyond the window's border."""
    back = elliptic_leaf("back", (3.0, 0.0, 0.0), (-1, 0, 0), (0, 1, 0), 0.08, 0.05)
    front = elliptic_leaf("front", (2.97, 0.04 * 2.97 / 3.0, 0.0), (-1, 0, 0), (0, 1, 0), 0.08, 0.05)
    objects = [back, front]
    section = scanner_window(objects)
    scene = Scene(objects + [background_wall(objects, 3.5, 0.3)], section, "close-leaves")
    scan = simulate(scene, setup_from_section({**section, "step_deg": 0.08}), seed=1, progress=False)
    by_name = {leaf.name: leaf for leaf in scoring.prepare_leaves(scene, scan)}
    assert by_name["front"].scan_stats["visibility"] == pytest.approx(1.0)
    assert by_name["back"].scan_stats["visibility"] == pytest.approx(0.5, abs=0.12)
    # The same scan cut at the front leaf's centre column: half its silhouette lies outside the window.
    centre = int(np.argmin(np.abs(scan.theta[0] - np.arctan2(0.04, 3.0))))
    half = scoring.crop_scan(scan, slice(None), slice(0, centre))
    cut = scoring.visibility(half, 1, front.truth["outline"], 2.97)
    assert cut == pytest.approx(0.5, abs=0.12)


def test_whole_scan_regions_are_matched_to_true_leaves(two_leaves):
    """Hand-made output regions on the two-leaf scan: the front leaf whole (region 1, with a stray wall pixel), the
    back leaf split in a visible third (region 2) and the rest (region 3), a wall patch (region 4)."""
    scene, scan, leaves = two_leaves
    back, front = leaves
    labels = np.zeros(scan.shape, int)
    labels[front.own_pixels()] = 1
    rows, cols = back.own_pixels()
    third = cols < np.quantile(cols, 1 / 3)
    labels[rows[third], cols[third]] = 2
    labels[rows[~third], cols[~third]] = 3
    wall = np.argwhere((scan.truth_id == 2) & (labels == 0))
    labels[tuple(wall[:5].T)] = 4
    labels[tuple(wall[5])] = 1
    regions = {k: {"area_m2": 0.001 * k, "elevation_deg": 0.0, "azimuth_deg": 0.0} for k in (1, 2, 3, 4)}
    output = VariantOutput(scan.xyz.copy(), stats={"skipped": 0}, flags=np.zeros(scan.shape, bool), labels=labels,
                           regions=regions, candidates=np.where(labels > 0, 1, 0))
    (back_out, front_out), counts = scoring.leaf_outputs(leaves, output, scene, scan)
    assert front_out.traits["area_m2"] == 0.001 and front_out.stats["found"] == 1
    assert front_out.stats["coverage"] == 1.0
    assert front_out.stats["purity"] == pytest.approx(1 - 1 / front_out.stats["region_pixels"])
    assert front_out.stats["rppp_1"] == 1.0 and front_out.xyz.shape == front.scan.xyz.shape
    assert front_out.stats["merged"] == 0 and "label" not in front_out.stats
    # The back leaf's larger part (two thirds of its visible pulses) is its match: found.
    assert back_out.traits["area_m2"] == 0.003 and back_out.stats["found"] == 1
    assert back_out.stats["coverage"] == pytest.approx(2 / 3, abs=0.05)
    # Region 2 (a split-off part of the back leaf) and region 4 (on the wall) match no leaf: false leaves.
    assert counts == {"n_regions": 4, "n_false": 2, "n_false_on_leaves": 1, "n_false_off_leaves": 1, "n_merged": 0}
    scores, counts = scoring.score_scan(leaves, output, scene, scan)
    assert counts["n_leaves"] == 2 and counts["n_found"] == 2 and counts["n_visible"] == 1
    assert counts["n_found_visible"] == 1 and scores[1]["area_m2"] == 0.001
    # A leaf no region touches is missed and gets no area; the other leaf's regions are then all false.
    labels[front.own_pixels()] = 0
    (_, front_out), counts = scoring.leaf_outputs(leaves, output, scene, scan)
    assert front_out.stats == {"skipped": 0, "found": 0, "coverage": 0.0} and front_out.traits == {"area_m2": 0.0}
    assert counts["n_false"] == 3
    # One region over both leaves: both found, in a shared (merged) region.
    labels[front.own_pixels()] = 3
    labels[back.own_pixels()] = 3
    (back_out, front_out), counts = scoring.leaf_outputs(leaves, output, scene, scan)
    assert back_out.stats["found"] == front_out.stats["found"] == 1 and counts["n_merged"] == 2
    assert back_out.stats["merged"] == front_out.stats["merged"] == 1
    assert front_out.stats["purity"] < 0.75
    # A third of the back leaf inside the front leaf's region, the rest in none: the back leaf is missed, its few
    # pulses there make no merge.
    labels[back.own_pixels()] = 0
    labels[rows[third], cols[third]] = 3
    (back_out, front_out), counts = scoring.leaf_outputs(leaves, output, scene, scan)
    assert back_out.stats["found"] == 0 and front_out.stats["found"] == 1
    assert back_out.stats["merged"] == front_out.stats["merged"] == 0 and counts["n_merged"] == 0
    # Given the targets: each leaf's own pulses carry its label.
    given = scoring.target_labels(scan.shape, leaves)
    assert set(np.unique(given)) == {0, 1, 2}
    assert (given[front.own_pixels()] == 2).all() and (given[back.own_pixels()] == 1).all()


@pytest.mark.parametrize("min_share, margin", [(0.1, None), (0.6, 0)])
def test_leaf_points_and_windows_match_their_whole_scan_definition(two_leaves, monkeypatch, min_share, margin):
    """Each leaf's points, found inside its object's bounding box, are the pulses of the whole scan with at least
    ``min_share`` of their power from it (without a margin, the window is smaller than the box of all its pulses)."""
    scene, scan, _ = two_leaves
    if margin is not None:
        monkeypatch.setattr(scoring, "crop_margin_px", lambda scan, distance_m: margin)
    for leaf in scoring.prepare_leaves(scene, scan, min_share=min_share):
        whole = scan.valid & (scoring.power_share(scan, leaf.object_id) >= min_share)
        inside = np.zeros(scan.shape, bool)
        inside[leaf.window] = leaf.mask
        assert (inside == whole).all() and whole.sum() > 0
        assert leaf.scan.shape == scan.range[leaf.window].shape

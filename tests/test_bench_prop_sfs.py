"""The PROP-SFS variants scored by the benchmark on simulated leaves: the corrections they make, pinned."""

import numpy as np
import pytest

from benchmarks import scoring
from benchmarks.errors import BenchError
from benchmarks.generators import build_scene
from benchmarks.registry import get_variant
from tlssim.simulate import setup_from_section, simulate


def leaf_case(distance_m: float, incidence_deg: float, seed: int):
    """A 9 cm pear leaf (the thesis' ROP set-up) tilted about the horizontal, a wall 1 m behind: scene, scan, truth."""
    scene = build_scene({"generator": "single-leaf", "distance_m": distance_m, "incidence_deg": incidence_deg,
                         "length_m": 0.09, "axis": "horizontal", "spin_deg": 0.0, "seed": seed,
                         "background_gap_m": 1.0})
    scan = simulate(scene, setup_from_section(scene.scanner), seed=seed, progress=False)
    return scene, scan, scoring.prepare_leaves(scene, scan)


def whole_scan_scores(variant, scene, scan, leaves):
    """The variant run once on the whole scan, scored on its leaves; the case's counts."""
    return scoring.score_scan(leaves, variant(scan, scoring.target_labels(scan.shape, leaves)), scene, scan)


@pytest.fixture(scope="module")
def scores():
    """Scores of buffer and fused on three simulated leaves (distance m, incidence deg, seed)."""
    rows = []
    for case in ((1.5, 40.0, 1), (3.0, 20.0, 2), (5.0, 40.0, 1)):
        scene, scan, leaves = leaf_case(*case)
        for name in ("buffer", "fused"):
            (scores,), counts = whole_scan_scores(get_variant(name), scene, scan, leaves)
            rows.append({"case": case, "variant": name, **scores, **counts})
    return rows


def test_phase_shift_outliers_are_corrected_and_leaf_areas_kept(scores):
    # Measured: ROP 23-33 % before; reductions 0.85-0.99 (buffer), 0.97-0.99 (fused); 1 cm outliers after
    # 0.1-2.2 % (buffer), 0.1-0.3 % (fused); area errors -1.2..+1.4 % (fused), -0.8..+12.9 % (buffer), medians
    # 0.8 % (buffer) and 0.9 % (fused); angle errors <= 1.5 deg (fused). Buffer's propagation goes astray on the
    # 1.5 m / 40 deg leaf (area +12.9 %, azimuth 13.8 deg, the same on the whole scan: a tighter crop hid it). The
    # petiole's mixed pulses, which no leaf region holds, go to the wall or take the distance where the petiole
    # leaves the blade (they were most of what remained, reductions 0.70-0.87).
    # With the simulator's per-column noise streams (tiled scans, issue 14) the same cases give fused reductions
    # 0.94 / 0.96 / 0.99 and fresh seeds of the 1.5 m / 40 deg leaf 0.97 (seed 5) and 0.90 (seed 6): the bound
    # that held one noise realisation at 0.95 is 0.9 across realisations.
    for row in scores:
        fused = row["variant"] == "fused"
        assert row["rop_before"] > 0.2
        assert row["rop_reduction"] > (0.9 if fused else 0.8), row
        assert row["rop_after_1cm"] < (0.01 if fused else 0.03) and row["good_points_damaged"] < 0.005, row
        assert abs(row["area_rel_err"]) < (0.03 if fused else 0.15), row
        assert row["purity"] > 0.99 and row["coverage"] > 0.98 and row["found"] == 1, row
        # The whole scan (leaf, wall, the window's margin) holds one leaf region: no false leaf.
        assert row["n_regions"] == 1 and row["n_false"] == 0 and row["n_found_visible"] == 1, row
        assert max(row["elevation_err_deg"], row["azimuth_err_deg"]) < (3 if fused else 15), row
    for variant in ("buffer", "fused"):
        errors = [abs(r["area_rel_err"]) for r in scores if r["variant"] == variant]
        assert np.median(errors) < 0.02


def test_buffer_keeps_the_measured_inliers_and_fused_improves_them(scores):
    # Inlier error p90 against the raw pulses' (range noise): the buffer variant keeps them, the fused one
    # averages the noise down (measured: 2.4-2.7 mm buffer, 1.9-2.7 mm fused).
    for buffer, fused in zip(scores[::2], scores[1::2]):
        assert fused["inlier_p90_m"] <= buffer["inlier_p90_m"] * 1.02
        assert buffer["inlier_p90_m"] < 3.5 * buffer["sigma_range_m"]


def test_given_the_leafs_points_as_mask_the_correction_holds():
    scene, scan, leaves = leaf_case(3.0, 20.0, 2)
    (scores,), counts = whole_scan_scores(get_variant("buffer").with_params(segmentation="mask"), scene, scan, leaves)
    assert scores["found"] == 1 and scores["purity"] > 0.95 and counts["n_false"] == 0
    assert scores["rop_reduction"] > 0.8 and abs(scores["area_rel_err"]) < 0.06
    with pytest.raises(BenchError, match="segmentation"):
        get_variant("buffer").with_params(segmentation="truth")(scan, scoring.target_labels(scan.shape, leaves))

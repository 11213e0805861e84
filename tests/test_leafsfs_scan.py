"""PROP-SFS on scans: local frame, simulated single and clustered leaves, outputs, CLI and errors."""

import copy
import functools
import json
import sys

import numpy as np
import pytest
from scipy import ndimage

import scenes
import tlssim
from benchmarks.experiments.calibration import simulated_calibration
from leafsfs import SfsError, SfsParams, reconstruct
from leafsfs.cli import main
from leafsfs.frame import local_frame
from leafsfs.grid import PixelGrid, local_planes, local_planes_of
from leafsfs.leaves import segment_leaves
from leafsfs.preprocess import scan_alpha
from leafsfs.edges import MixedPulses
from leafsfs.reconstruct import (ENGINE_OWNER_EQUAL_DEG, OWNER_BAND_SIGMA, PIECE_LINK_SIGMA, PIECE_MIN_LINKED,
                                  engine_owner_weight, linked_neighbours, nearest_incidence, no_owner, plausible)
from leafsfs.synthetic import LambertCalibration
from tlssim.pattern import beam_frame


def _simulate(name):
    scene = scenes.build(name)
    return scene, tlssim.simulate(scene, tlssim.setup_from_section(scene.scanner), seed=0, progress=False)


@pytest.fixture(scope="module")
def leaf_scan():
    scene, scan = _simulate("leaf-1.5m")
    # the benchmarks' simulated panel + goniometer calibration of the scan's scanner model
    return scene, scan, simulated_calibration(scan.scanner.model)


@pytest.fixture(scope="module")
def leaf_result(leaf_scan):
    _, scan, calibration = leaf_scan
    return reconstruct(scan, variant="buffer", calibration=calibration)


def test_local_frame_makes_the_eikonal_relation_exact():
    # A plane seen off-axis: in the frame, |grad h| = tan(local incidence) to within the chart's distortion.
    step = np.radians(0.018)
    theta, psi = np.meshgrid(np.radians(30) + step * np.arange(-60, 60), np.radians(80) + step * np.arange(-50, 50))
    axis = beam_frame(theta, psi)[0]
    normal = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    range_m = (normal @ (1.2 * axis[50, 60])) / (axis @ normal)
    incidence = np.arccos(np.abs(axis @ normal))
    frame = local_frame(theta, psi, range_m, np.ones(theta.shape, bool))
    heights = frame.height(range_m[frame.box])
    centres = np.argwhere(np.ones(heights.shape, bool))[::53]
    slope = np.linalg.norm(local_planes(heights, np.isfinite(heights), frame.grid, centres, 2).gradient, axis=1)
    assert np.allclose(slope, np.tan(incidence[frame.box][centres[:, 0], centres[:, 1]]), rtol=0.004)
    assert np.allclose(frame.range(heights), range_m[frame.box])


def test_planes_of_several_images_are_those_of_each():
    # A tilted plane plus noise (NaN where invalid) and a second image on the same pixels: one call for both gives
    # each image's own planes, exactly; the gradient of the noiseless plane is exact.
    rng = np.random.default_rng(3)
    rows, cols = np.mgrid[0:30, 0:40].astype(float)
    grid = PixelGrid(np.array([[5e-4, 1e-4], [0.0, 4e-4]]), np.array([0.2, -0.1]))
    plane = 1.5 + 0.3 * (rows * 5e-4 + cols * 1e-4) - 0.7 * (cols * 4e-4)  # in the continuous coordinates
    valid = rng.random(plane.shape) > 0.3
    noisy = np.where(valid, plane + rng.normal(0, 1e-3, plane.shape), np.nan)
    centres = np.argwhere(np.ones(plane.shape, bool))[::7]
    both = local_planes_of([plane, noisy], valid, grid, centres, 3.5, order=2)
    for image, planes in zip((plane, noisy), both):
        alone = local_planes(image, valid, grid, centres, 3.5, order=2)
        for name in ("height", "gradient", "covariance", "rms", "count"):
            assert np.array_equal(getattr(planes, name), getattr(alone, name), equal_nan=True)
    fitted = np.isfinite(both[0].height)
    assert fitted.mean() > 0.9
    assert np.allclose(both[0].gradient[fitted], [0.3, -0.7], atol=1e-9)
    # Without the spread: the same planes, no RMS nor covariance; on a grid of pixel steps too (integer sums).
    for g in (grid, PixelGrid()):
        full = local_planes_of([plane, noisy], valid, g, centres, 3.5)
        for planes, bare in zip(full, local_planes_of([plane, noisy], valid, g, centres, 3.5, spread=False)):
            for name in ("height", "gradient", "count"):
                assert np.array_equal(getattr(planes, name), getattr(bare, name), equal_nan=True)
            assert np.isnan(bare.rms).all() and np.isnan(bare.covariance).all()


def test_runaway_heights_are_not_plausible():
    # A flat 40 x 40 px leaf 1.5 m away (pixels of 0.47 mm: a 2.7 cm bounding-box diagonal): heights up to a
    # diagonal beyond its pure pulses' heights are plausible, a runaway propagation's are not (no overflow).
    step = np.radians(0.018)
    theta, psi = np.meshgrid(step * np.arange(-30, 30), np.pi / 2 + step * np.arange(-30, 30))
    leaf = np.zeros(theta.shape, bool)
    leaf[10:50, 10:50] = True
    frame = local_frame(theta, psi, np.full(theta.shape, 1.5), leaf)
    measured = frame.height(np.full(theta.shape, 1.5))[frame.box]
    diagonal = 39 * np.sqrt(2) * 1.5 * step
    height = np.array([0.0, 0.9 * diagonal, -0.9 * diagonal, 1.1 * diagonal, 1e6, -np.inf, np.nan])
    pure = leaf[frame.box]
    assert plausible(height, measured, pure, frame).tolist() == [True, True, True, False, False, False, False]
    with np.errstate(over="raise"):
        frame.range(np.where(plausible(height, measured, pure, frame), height, np.nan))


def test_measured_outliers_move_to_the_true_surface(leaf_scan, leaf_result):
    scene, scan, _ = leaf_scan
    leaf = scan.object_names.index("leaf")
    # (the few leaf-edge pulses that no surface owns are removed: see the skipped-region test)
    on_leaf = (scan.truth_id == leaf) & (np.abs(scan.truth_range - 1.5) < 0.1) & leaf_result.corrected \
        & ~leaf_result.removed
    measured = np.abs(scan.range - scan.truth_range)
    corrected = np.abs(leaf_result.range - scan.truth_range)
    # The phase-shift outliers: mixed pulses (the buffer variant keeps the measured distance of pure pulses,
    # whose range-noise tails are left alone; see tests/test_bench_prop_sfs.py for the numbers behind that choice).
    outliers = on_leaf & (measured > 0.005) & (scan.mixed_fraction > 0.01)
    assert outliers.sum() > 300
    assert np.mean(corrected[outliers] < measured[outliers]) > 0.95
    assert np.median(corrected[outliers]) < 0.05 * np.median(measured[outliers])
    assert np.quantile(corrected[on_leaf], 0.9) < 0.005  # m (the inliers keep their measured distance)
    points = leaf_result.points()  # the corrected point cloud, world frame
    kept_points = leaf_result.corrected & ~leaf_result.removed
    assert len(points) == kept_points.sum()
    assert np.allclose(np.linalg.norm(points - scan.pose.position, axis=1), leaf_result.range[kept_points])
    # flags: exactly the corrected pixels whose distance was replaced; inliers keep their measured distance
    assert np.array_equal(leaf_result.outlier, leaf_result.corrected & (leaf_result.range != scan.range))
    threshold = leaf_result.leaves[0].traits["outlier_threshold_m"]
    kept = leaf_result.corrected & ~leaf_result.outlier
    assert kept.sum() > 0.5 * on_leaf.sum() and 0.002 <= threshold < 0.01


def test_leaf_traits_and_redundancy(leaf_scan, leaf_result):
    scene, _, _ = leaf_scan
    truth = scene.objects[0].truth
    (traits,) = leaf_result.traits()
    # Measured: -1 % area, 0.3 deg elevation and azimuth, 1.4 deg normal (before the mixed-pulse attribution
    # and the share-weighted, local-plane traits: +28 %, 5.6, 7.6 and 11 deg).
    assert traits["area_m2"] == pytest.approx(truth["area_m2"], rel=0.05)
    # the scan cannot tell the tip from the petiole: compare the midrib azimuth modulo 180 deg
    assert abs((traits["azimuth_deg"] - truth["azimuth_deg"] + 90) % 180 - 90) < 3
    assert abs(traits["elevation_deg"] - truth["elevation_deg"]) < 3
    normal = np.array(truth["normal"]) * np.sign(truth["normal"][2] or 1)
    assert np.degrees(np.arccos(np.clip(np.dot(normal, traits["normal"]), -1, 1))) < 5
    rppp = leaf_result.rppp()
    assert rppp["rppp_0"] < 0.05 and rppp["rppp_1"] > 0.6
    assert traits["n_outliers"] == int((leaf_result.outlier & (leaf_result.labels == traits["leaf"])).sum())


def test_a_given_mask_counts_the_mixed_pulses_of_its_leaf(leaf_scan, leaf_result):
    # The automatic region given back as a mask: the same leaf, the same area (its mixed pulses outside the mask,
    # which the wall dominates, still count for the leaf's share of their footprints; its outline pulses count for
    # their share from the intensity, the reference taken at the nearest interior pulse: ties broken on another
    # window, 1e-4 apart).
    _, scan, calibration = leaf_scan
    given = reconstruct(scan, mask=leaf_result.labels > 0, calibration=calibration)
    assert given.traits()[0]["area_m2"] == pytest.approx(leaf_result.traits()[0]["area_m2"], rel=1e-3)
    assert not given.background.any() and leaf_result.background.sum() > 1000


def test_a_wide_mask_gives_its_background_pulses_the_backgrounds_distance(leaf_scan, leaf_result):
    # A mask 4 pixels wider than the leaf holds mixed pulses that the wall dominates: they take the wall's
    # distance (as in the automatic segmentation) instead of the leaf's, and the area stays.
    scene, scan, calibration = leaf_scan
    wide = ndimage.binary_dilation(leaf_result.labels > 0, iterations=4)
    given = reconstruct(scan, mask=wide, calibration=calibration)
    walled = wide & leaf_result.background
    assert walled.sum() > 1000 and np.array_equal(given.background, walled)
    assert np.array_equal(given.range[walled], leaf_result.range[walled], equal_nan=True)  # NaN: no owner
    assert np.nanmedian(np.abs(given.range - scan.truth_range)[walled]) < 0.002
    assert np.median(np.abs(scan.range - scan.truth_range)[walled]) > 0.1
    assert given.traits()[0]["area_m2"] == pytest.approx(leaf_result.traits()[0]["area_m2"], rel=0.01)


def test_leaf_cluster_segmentation_separates_the_leaves():
    _, scan = _simulate("leaf-cluster")
    alpha, _ = scan_alpha(scan.intensity, scan.range, LambertCalibration(scan.scanner.model, 0.48))
    labels = segment_leaves(scan.range, scan.theta, scan.psi, alpha)
    purity, regions, cover = [], set(), []
    for index, name in enumerate(scan.object_names):
        pixels = scan.truth_id == index
        if "leaf" not in name or pixels.sum() < 1000:
            continue
        values, counts = np.unique(labels[pixels], return_counts=True)
        best = values[np.argmax(counts)]
        assert best > 0  # one region holds the leaf: all of it, but for the smallest leaf's mixed pulses with the
        cover.append(counts.max() / pixels.sum())  # twig it touches (a thin part, given to no leaf)
        purity.append(np.mean(scan.truth_id[labels == best] == index))
        regions.add(best)
    assert min(cover) > 0.85 and np.median(cover) > 0.99
    assert len(regions) == len(purity) == 8  # a region per leaf
    # Little else in them: the mixed pulses go to the surface that returned most of their power; only the twig
    # where it touches the smallest leaf (same distance, linked) stays in that leaf's region.
    assert min(purity) > 0.75 and np.median(purity) > 0.99
    # The twig is not a leaf: no region is mostly wood.
    wood = scan.object_names.index("shoot/wood")
    for label in np.unique(labels[labels > 0]):
        assert np.mean(scan.truth_id[labels == label] == wood) < 0.25


def test_corrected_scan_round_trip_and_cli(leaf_scan, tmp_path):
    _, scan, calibration = leaf_scan
    path = scan.save(tmp_path / "leaf.npz")
    outdir = tmp_path / "out"
    calibration_path = str(calibration.save(tmp_path / "calibration.json"))
    assert main(["reconstruct", str(path), "--variant", "buffer", "--calibration", calibration_path, "-o",
                 str(outdir)]) == 0
    corrected = tlssim.Scan.load(outdir / "corrected.npz")
    with np.load(path) as before, np.load(outdir / "corrected.npz") as after:
        assert set(before.files) | {"outlier", "candidates", "leaf", "background", "removed", "range_spread"} == \
            set(after.files)
    assert corrected.layers["outlier"].dtype == bool and corrected.layers["candidates"].max() >= 1
    changed = corrected.range != scan.range
    leaf, background = corrected.layers["leaf"] > 0, corrected.layers["background"]
    assert changed.any() and np.all((leaf | background)[changed]) and not (leaf & background).any()
    # mixed pulses the wall dominates take the wall's distance (1 m behind the leaf)
    # (NaN: the few that no surface owns, removed)
    assert np.nanmax(np.abs(corrected.range[background] - 2.5)) < 0.05
    assert np.mean(np.isnan(corrected.range[background])) < 0.02
    report = json.loads((outdir / "traits.json").read_text())
    assert {"area_m2", "elevation_deg", "azimuth_deg", "n_points", "n_outliers"} <= set(report["leaves"][0])
    assert (outdir / "mesh.ply").stat().st_size > 1000 and (outdir / "preview.png").stat().st_size > 1000


def test_cli_fused_stray_is_fused_without_the_moved_strays(leaf_scan, tmp_path):
    _, scan, calibration = leaf_scan
    path = scan.save(tmp_path / "leaf.npz")
    calibration_path = str(calibration.save(tmp_path / "calibration.json"))
    for variant in ("fused", "fused-stray"):
        assert main(["reconstruct", str(path), "--variant", variant, "--calibration", calibration_path, "-o",
                     str(tmp_path / variant)]) == 0
    fused, stray = (tlssim.Scan.load(tmp_path / variant / "corrected.npz") for variant in ("fused", "fused-stray"))
    # the same reconstruction, less the pulses the rule removed: each of them one fused moved, now NaN and flagged
    gone = stray.layers["removed"] & ~fused.layers["removed"]
    same = ~gone
    assert np.array_equal(stray.range[same], fused.range[same], equal_nan=True)
    assert np.isnan(stray.range[gone]).all() and stray.layers["outlier"][gone].all()
    assert (fused.range[gone] != scan.range[gone]).all()


def test_reconstruct_errors(leaf_scan, tmp_path, capsys):
    _, scan, calibration = leaf_scan
    with pytest.raises(SfsError, match="must match the scan grid"):
        reconstruct(scan, mask=np.ones((3, 3), bool), calibration=calibration)
    with pytest.raises(SfsError, match="needs an intensity calibration"):
        reconstruct(scan)
    empty = tlssim.Scan(np.full((4, 4), np.nan), np.full((4, 4), np.nan, np.float32), np.zeros((4, 4)),
                        np.zeros((4, 4)), np.full((4, 4, 3), np.nan))
    with pytest.raises(SfsError, match="no valid pixels"):
        reconstruct(empty, calibration=calibration)
    with pytest.raises(SfsError, match="alpha_max_deg must be a number"):
        SfsParams(alpha_max_deg=95)
    with pytest.raises(SfsError, match="unknown PROP-SFS variant"):
        reconstruct(scan, variant="best", calibration=calibration)
    assert main(["reconstruct", str(tmp_path / "missing.npz"), "--calibration", "c.json", "-o", str(tmp_path)]) == 2
    assert "no such scan file" in capsys.readouterr().err
    (tmp_path / "scan.xyz").write_text("1 2 3")
    assert main(["reconstruct", str(tmp_path / "scan.xyz"), "--calibration", "c.json", "-o", str(tmp_path)]) == 2
    assert "unknown scan format" in capsys.readouterr().err


def test_fused_variant_beats_the_measurement_and_survives_a_wrong_reflectance(leaf_scan):
    _, scan, calibration = leaf_scan
    on_leaf = (scan.truth_id == 0) & (np.abs(scan.truth_range - 1.5) < 0.1)
    fused = reconstruct(scan, variant="fused", calibration=calibration)
    error = np.abs(fused.range - scan.truth_range)[on_leaf & fused.corrected]
    noise = np.abs(scan.range - scan.truth_range)[on_leaf & fused.corrected & (scan.mixed_fraction < 0.01)]
    assert np.nanmedian(error) < np.median(noise)  # the fusion also averages the range noise down
    # The calibration assumes reflectance 0.58 instead of 0.48: alpha is overestimated by ~20 deg. The
    # reconstructed surfaces are compared (every leaf point takes them).
    p90 = {}
    for variant in ("buffer", "fused"):
        result = reconstruct(scan, variant=variant, params=SfsParams(inliers="replace"),
                             calibration=LambertCalibration(scan.scanner.model, 0.58))
        p90[variant] = np.nanquantile(np.abs(result.range - scan.truth_range)[on_leaf & result.corrected], 0.9)
    assert p90["fused"] < 0.6 * p90["buffer"] and p90["fused"] < 0.01


def test_refine_pulls_the_noise_tails_onto_their_neighbours_plane_whatever_the_surface(leaf_scan):
    # Under a wrong reflectance (alpha ~20 deg too high) the buffer surface is centimetres off: "replace" drags
    # the pure pulses onto it; "refine" leaves them at their measurement except the noise's tails, which take the
    # plane of their neighbours' measurements (not the surface).
    _, scan, calibration = leaf_scan
    wrong = LambertCalibration(scan.scanner.model, 0.58)
    refine, replace = (reconstruct(scan, variant="buffer", params=SfsParams(inliers=mode), calibration=wrong)
                       for mode in ("refine", "replace"))
    (leaf,) = refine.leaves
    threshold = leaf.traits["outlier_threshold_m"]
    pure = (refine.labels == leaf.label) & (scan.mixed_fraction < 1e-3)
    moved = pure & (refine.range != scan.range)
    before, after = (np.abs(r - scan.truth_range) for r in (scan.range, refine.range))
    # 693 of 14,551 pure pulses moved, median error 4.0 -> 0.14 mm; beyond the threshold 49 -> 0-1 (a noisy pure
    # pulse the straddle detector flags, which takes the wrong surface: 16.9 mm at row 41, col 81). Since round 18
    # the region also holds its unpaired outline pulses on its plane (leafsfs.canopy.grow_outline: 6 here), flagged
    # straddling: the engine corrects them, and under this wrong calibration 4 of them take its surface 8-12 mm off.
    assert 0.01 * pure.sum() < moved.sum() < 0.1 * pure.sum()
    assert np.median(after[moved]) < 0.2 * np.median(before[moved])
    assert np.sum(after[pure] > threshold) <= 5 and np.sum(before[pure] > threshold) > 20
    truth = {name: np.quantile(np.abs(r.range - scan.truth_range)[pure], 0.9)
             for name, r in (("refine", refine), ("replace", replace), ("measured", refine.scan))}
    # measured p90 errors: 3.0 mm measured, 2.6 mm refine, 10.0 mm replace
    assert truth["refine"] < truth["measured"] and truth["refine"] < 0.5 * truth["replace"], truth


@pytest.mark.parametrize("suffix", [".e57", ".ptx"])
def test_reconstruct_an_e57_or_ptx_scan_without_truth(leaf_scan, leaf_result, tmp_path, suffix):
    # A simulated scan exported as a real scanner's file (no truth, no scanner model) and a calibration file.
    from tlssim import formats

    _, scan, calibration = leaf_scan
    path = formats.export_scan(scan, tmp_path / f"leaf{suffix}")
    calibration.save(tmp_path / "calibration.json")
    outdir = tmp_path / "out"
    assert main(["reconstruct", str(path), "--calibration", str(tmp_path / "calibration.json"), "-o", str(outdir)]) == 0
    corrected = tlssim.Scan.load(outdir / "corrected.npz")
    assert not corrected.has_truth and corrected.shape == scan.shape
    (leaf,) = json.loads((outdir / "traits.json").read_text())["leaves"]
    (reference,) = leaf_result.traits()
    assert leaf["area_m2"] == pytest.approx(reference["area_m2"], rel=0.01)
    assert leaf["n_points"] == pytest.approx(reference["n_points"], rel=0.01)
    # the same distances as from the NPZ file, to the files' coordinate precision
    both = (corrected.layers["leaf"] > 0) & (leaf_result.labels > 0)
    assert np.nanmedian(np.abs(corrected.range - leaf_result.range)[both]) < 1e-4


def test_mixed_pulses_of_a_leaf_without_heights_take_the_leaf_planes_distance(leaf_scan, monkeypatch):
    # A region the engine cannot reconstruct (here: it rejects every region) is skipped, but its mixed pulses are
    # still paired with the leaf and the wall: those the leaf dominates take the leaf's distance extrapolated from
    # its own pure pulses; nothing is deleted but the few whose range lies within OWNER_TOLERANCE_M of the midpoint
    # between leaf and wall (no owner: the leaf's and the wall's power shares are then equal within 0.6 %).
    module = sys.modules["leafsfs.reconstruct"]  # the package exports the function under the module's name

    def reject(*args, **kwargs):
        raise SfsError("rejected")

    monkeypatch.setattr(module, "reconstruct_heights", reject)
    _, scan, calibration = leaf_scan
    result = reconstruct(scan, variant="buffer", calibration=calibration)
    assert not result.leaves and result.skipped
    leaf = scan.object_names.index("leaf")
    measured = np.abs(scan.range - scan.truth_range)
    mixed = (scan.truth_id == leaf) & (scan.mixed_fraction > 0.05) & (measured > 0.01) & (result.labels > 0)
    assert mixed.sum() > 100
    corrected = np.abs(result.range - scan.truth_range)
    assert np.all(result.outlier[mixed]) and np.all(np.isfinite(result.range[mixed]) == ~result.removed[mixed])
    assert 0 < result.removed[mixed].sum() < 0.02 * mixed.sum()
    assert np.all(np.abs(scan.mixed_fraction[result.removed] - 0.5) < 0.1)
    assert np.nanmedian(corrected[mixed]) < 0.05 * np.median(measured[mixed])
    # pure pulses keep their measured distance (all but the rare pure pulse the straddle test takes for a mixed
    # one: a noise tail, about 1 in 10^4)
    pure = (result.labels > 0) & (scan.mixed_fraction < 1e-3)
    assert np.mean(result.range[pure] != scan.range[pure]) < 1e-3 and pure.sum() > 1000


def test_mixed_pulses_of_a_leaf_weigh_the_engine_and_the_leaf_planes_distance_by_incidence(leaf_scan, monkeypatch):
    # The engine's surface and the plane of the leaf's own pure pulses both estimate the distance of a mixed pulse
    # the leaf dominates; the pulse takes the engine's height with engine_owner_weight of the leaf's incidence beside
    # it, the plane's distance with the rest. An engine made 1 cm too far leaves the flat leaf's mixed pulses off by
    # that weight of the bias (the plane is right), its pure pulses as measured.
    module = sys.modules["leafsfs.reconstruct"]
    engine = module.reconstruct_heights
    bias = 0.01  # m (the frame's heights are distances near the leaf)

    def biased(*args, **kwargs):
        result = engine(*args, **kwargs)
        result.height = result.height + bias
        return result

    monkeypatch.setattr(module, "reconstruct_heights", biased)
    _, scan, calibration = leaf_scan
    result = reconstruct(scan, variant="buffer", calibration=calibration)
    leaf = scan.object_names.index("leaf")
    measured = scan.range - scan.truth_range
    mixed = (scan.truth_id == leaf) & (scan.mixed_fraction > 0.05) & (np.abs(measured) > 0.01) \
        & (result.labels > 0) & result.outlier & ~result.removed
    assert mixed.sum() > 100
    error = (result.range - scan.truth_range)[mixed]
    weight = np.median(engine_owner_weight(scan.incidence[mixed]))  # the leaf is flat: its true incidence
    assert 0.05 < weight < 0.95 and abs(np.median(error) - weight * bias) < 0.15 * bias
    pure = (result.labels > 0) & (scan.mixed_fraction < 1e-3)
    assert np.mean(result.range[pure] != scan.range[pure]) < 1e-3 and pure.sum() > 1000


def test_fused_gives_the_pulses_nothing_moved_their_single_surfaces_distance_and_keeps_the_traits(leaf_scan,
                                                                                                     monkeypatch):
    # A pulse within the range noise of one surface (here: every pulse, given a distance 1 mm beyond its measured
    # range) takes that distance in the corrected scan unless another rule moved it; the leaf's traits are those of
    # its measured range, and no other pulse changes.
    _, scan, calibration = leaf_scan
    monkeypatch.setattr(MixedPulses, "single_range", lambda self: np.full(self.surfaces.shape, np.nan))
    without = reconstruct(scan, variant="fused", calibration=calibration)
    monkeypatch.setattr(MixedPulses, "single_range",
                        lambda self: scan.range + 0.001)
    result = reconstruct(scan, variant="fused", calibration=calibration)
    changed = ~((result.range == without.range) | (np.isnan(result.range) & np.isnan(without.range)))
    assert np.array_equal(changed, without.range == scan.range) and changed.sum() > 1000
    assert np.allclose(result.range[changed], scan.range[changed] + 0.001)
    assert np.all(result.outlier[changed]) and not result.removed[changed].any()
    assert [leaf.traits for leaf in result.leaves] == [leaf.traits for leaf in without.leaves]
    kept = reconstruct(scan, variant="fused", params=SfsParams(single_surface="keep"), calibration=calibration)
    assert np.array_equal(kept.range, without.range, equal_nan=True)


def _scan_to_edit_far_on_the_wall(leaf_scan):
    """A copy of the leaf scan whose ranges may be edited, its calibration, and a wall pulse more than 12 pulses
    from anything but the wall (2.5 m)."""
    _, scan, calibration = leaf_scan
    scan = copy.copy(scan)
    scan.range = scan.range.copy()
    wall = np.isfinite(scan.range) & (np.abs(scan.range - 2.5) < 0.01)
    far = ndimage.distance_transform_edt(wall) > 12
    return scan, calibration, tuple(np.argwhere(far)[len(np.argwhere(far)) // 2])


def test_a_mixed_pulse_that_no_surface_explains_is_removed(leaf_scan, leaf_result):
    # A one-pulse fragment 30 cm before the wall (a twig end: no surface, fewer pulses than a piece) ringed by
    # pulses half way between it and the wall: no pair of surfaces brackets them, their range proves them mixed
    # (the fragment nearer, the wall farther): they are removed. The fragment's own pulse is kept, as is the leaf.
    scan, calibration, (i, j) = _scan_to_edit_far_on_the_wall(leaf_scan)
    ring = np.zeros(scan.shape, bool)
    ring[i - 1:i + 2, j - 1:j + 2] = True
    ring[i, j] = False
    scan.range[ring] = scan.range[i, j] - 0.15
    scan.range[i, j] -= 0.3
    result = reconstruct(scan, variant="buffer", calibration=calibration)
    # (besides the few leaf-edge pulses that no surface owns, removed without the fragment too)
    assert result.removed[ring].all() and not result.removed[i, j]
    assert np.array_equal(result.removed & ~ring, leaf_result.removed)
    assert result.outlier[ring].all() and np.isnan(result.corrected_scan().xyz[ring]).all()
    assert len(result.points()) == int((result.corrected & ~result.removed).sum())
    # the leaf is untouched (its area moves by the range noise's estimate only); with unexplained="keep" nothing goes
    areas = [leaf.traits["area_m2"] for leaf in result.leaves]
    assert areas == pytest.approx([leaf.traits["area_m2"] for leaf in leaf_result.leaves], rel=1e-4)
    kept = reconstruct(scan, variant="buffer", params=SfsParams(unexplained="keep"), calibration=calibration)
    assert not kept.removed.any() and np.array_equal(kept.range[ring], scan.range[ring])


def test_a_piece_of_pulses_that_share_their_range_is_not_removed(leaf_scan, leaf_result):
    # A 3 x 3 piece 15 cm before the wall (a hidden leaf's visible piece, too small to be a surface) beside a
    # one-pulse fragment 30 cm before it: the bracket test takes the piece for mixed pulses (a nearer and a farther
    # pulse within its window) and no surface explains it, but the piece's pulses share their range with their
    # neighbours within the noise: those with at least PIECE_MIN_LINKED such neighbours (its centre and the middles
    # of its sides) are kept, its corners (3 neighbours) go; with the ring of the test above, every pulse went.
    scan, calibration, (i, j) = _scan_to_edit_far_on_the_wall(leaf_scan)
    piece = np.zeros(scan.shape, bool)
    piece[i - 1:i + 2, j - 1:j + 2] = True
    scan.range[piece] = scan.range[i, j] - 0.15
    scan.range[i - 1, j + 3] -= 0.3
    result = reconstruct(scan, variant="buffer", calibration=calibration)
    corners = np.zeros(scan.shape, bool)
    corners[i - 1:i + 2:2, j - 1:j + 2:2] = True
    assert not result.removed[piece & ~corners].any() and result.removed[corners].all()
    assert np.array_equal(result.range[piece & ~corners], scan.range[piece & ~corners])
    assert np.array_equal(result.removed & ~piece & ~(np.arange(scan.shape[1]) == j + 3)[None, :],
                          leaf_result.removed & ~piece & ~(np.arange(scan.shape[1]) == j + 3)[None, :])


def test_linked_neighbours_holds_a_noisy_plane_together_and_not_a_ramp_across_an_edge():
    # Pulses of one plane with Gaussian noise sigma: each neighbour lies within 2 sqrt(2) sigma of the pulse with
    # probability 0.954, but the differences share the pulse's own noise, so a pulse in the tail of its own noise
    # (beyond about 2 sigma: 5 % of them) loses most of its links at once; nearly all the others keep at least
    # PIECE_MIN_LINKED (here 98.6 % of the pulses in all). Across an edge the footprint's share, hence the range,
    # changes by more than the noise from pulse to pulse (here 2 cm per pixel across, constant along): only the 2
    # neighbours along the edge are linked.
    rng = np.random.default_rng(0)
    sigma = 0.002
    plane = 2.0 + 0.0004 * np.arange(60)[:, None] + 0.0002 * np.arange(60)[None, :] \
        + rng.normal(0, sigma, (60, 60))
    count = linked_neighbours(plane, sigma, PIECE_LINK_SIGMA)[1:-1, 1:-1]
    assert np.mean(count >= PIECE_MIN_LINKED) > 0.97
    ramp = 2.0 + 0.02 * np.arange(60)[None, :] + np.zeros((60, 1)) + rng.normal(0, sigma, (60, 60))
    count = linked_neighbours(ramp, sigma, PIECE_LINK_SIGMA)[1:-1, 1:-1]
    assert count.max() <= 2 and np.mean(count >= PIECE_MIN_LINKED) == 0
    # no return: no link
    plane[5, 5] = np.nan
    full = linked_neighbours(plane, sigma, PIECE_LINK_SIGMA)
    assert full[5, 5] == 0
    # counted at some pulses only (the scan's corners and borders among them): the same counts there, 0 elsewhere
    at = rng.random(plane.shape) < 0.2
    at[[0, 0, -1, -1], [0, -1, 0, -1]] = True
    assert np.array_equal(linked_neighbours(plane, sigma, PIECE_LINK_SIGMA, at=at), np.where(at, full, 0))


def test_no_owner_spares_an_even_split_within_the_noise_of_a_surface():
    # Two surfaces 12 mm apart and pulses at power shares 0.5, 0.45 and 0.7 of the first: the midpoint lies 6 mm
    # from each surface, an ownerless pulse when the noise is 1 mm, a good point of either surface within
    # OWNER_BAND_SIGMA deviations when it is 4 mm; a share of 0.7 has an owner whatever the noise.
    shares = np.array([[0.5, 0.45, 0.7]])
    near, far = 2.0, 2.012
    measured = far + shares * (near - far)
    pair = np.broadcast_to(np.array([1, 2]), (1, 3, 2))
    pair_range = np.broadcast_to(np.array([near, far]), (1, 3, 2))
    mixed = MixedPulses(np.zeros((1, 3), int), pair.copy(), shares, pair_range.copy(), np.full((1, 3, 2), np.nan),
                        np.where(shares >= 0.5, 1, 2), np.zeros((1, 3), bool))
    assert no_owner(mixed, measured, 0.001).tolist() == [[True, True, False]]
    assert 0.006 <= OWNER_BAND_SIGMA * 0.004
    assert not no_owner(mixed, measured, 0.004).any()
    # per-pulse noise: only the first pulse is noisy
    assert no_owner(mixed, measured, np.array([[0.004, 0.001, 0.001]])).tolist() == [[False, True, False]]


@functools.lru_cache(maxsize=None)
def _outline_leaf():
    """A 6 cm pear leaf 3 m away at 35 deg incidence with nothing behind it, scanned at 0.018 deg: the scene, its
    scan and the simulated scanner's calibration (shared by the outline tests, which do not modify them)."""
    scene = scenes.scene_from_spec({"objects": [
        {"name": "leaf", "type": "leaf", "preset": "pear", "seed": 3, "length": 0.06, "material": "pear-leaf",
         "pose": {"center": [3.0, 0, 0], "facing": "scanner", "incidence_deg": 35}}]})
    setup = tlssim.setup_from_section({"window": {"theta_deg": [-0.8, 0.8], "psi_deg": [89.2, 90.8],
                                                  "step_deg": 0.018}})
    scan = tlssim.simulate(scene, setup, seed=0, progress=False)
    return scene, scan, simulated_calibration(scan.scanner.model)


def test_outline_pulses_mostly_off_their_leaf_take_part_of_the_engines_height(monkeypatch):
    # The same kind of leaf (6 cm, 3 m, 35 deg, nothing behind) at 0.018 deg. Its outline pulses whose beam axis misses
    # it are unreliable (rim shares) and take RIM_ENGINE_WEIGHT of the engine's height and the rest of their measured
    # range: an engine biased 1 cm farther moves them by that weight of the bias, the leaf's pure pulses not at all.
    _, scan, calibration = _outline_leaf()
    module = sys.modules["leafsfs.reconstruct"]
    engine, bias = module.reconstruct_heights, 0.01  # m

    def biased(*args, **kwargs):
        result = engine(*args, **kwargs)
        result.height = result.height + bias
        return result

    plain = reconstruct(scan, variant="fused", calibration=calibration)
    monkeypatch.setattr(module, "reconstruct_heights", biased)
    shifted = reconstruct(scan, variant="fused", calibration=calibration)
    off_axis = scan.valid & ~np.isfinite(scan.truth_range) & (plain.labels > 0) & plain.outlier & shifted.outlier
    assert off_axis.sum() > 100
    moved = np.median((shifted.range - plain.range)[off_axis])
    assert moved == pytest.approx(module.RIM_ENGINE_WEIGHT * bias, rel=0.1)
    pure = (plain.labels > 0) & (scan.mixed_fraction < 1e-3) & ~plain.outlier
    assert np.array_equal(shifted.range[pure], plain.range[pure]) and pure.sum() > 500


def test_outline_pulses_mostly_off_their_leaf_take_its_corrected_distance(monkeypatch):
    # A 6 cm pear leaf 3 m away at 35 deg incidence with nothing behind it, at the FARO protocol's 0.018 deg. The
    # pulses whose beam axis misses the leaf (truth range NaN) return the range of the lit part of their footprint,
    # off the axis. In a canopy the edge test does not flag all of them; here they are made to look pure (part of
    # the leaf's surface): their intensity deficit alone (leafsfs.canopy.rim_shares) must mark them unreliable.
    scene, scan, calibration = _outline_leaf()
    module = sys.modules["leafsfs.reconstruct"]
    segment = module.segment_scan
    off_axis = scan.valid & ~np.isfinite(scan.truth_range)

    def pure_outline(*args, **kwargs):
        out = segment(*args, **kwargs)
        mixed, leaf = out.mixed, out.leaf_surfaces[0]
        hide = off_axis & (out.leaves == 1)
        mixed.surfaces[hide], mixed.owner[hide], mixed.pair[hide], mixed.share[hide] = leaf, leaf, 0, np.nan
        return out

    monkeypatch.setattr(module, "segment_scan", pure_outline)
    from benchmarks.metrics import SurfaceDistance

    truth = SurfaceDistance(scene.objects[0].vertices, scene.objects[0].faces)
    results = {}
    for share in (0.0, module.RIM_PARTIAL_SHARE):
        monkeypatch.setattr(module, "RIM_PARTIAL_SHARE", share)
        results[share] = reconstruct(scan, variant="fused", calibration=calibration)
    outline = off_axis & (results[0.0].labels > 0)
    assert outline.sum() > 150
    off = {share: np.abs(truth(result.corrected_scan().xyz[outline], signed=True)) > 0.003
           for share, result in results.items()}
    moved = {share: result.outlier[outline].mean() for share, result in results.items()}
    assert moved[module.RIM_PARTIAL_SHARE] > 0.5 and moved[module.RIM_PARTIAL_SHARE] > moved[0.0] + 0.2
    assert off[module.RIM_PARTIAL_SHARE].sum() < 0.5 * off[0.0].sum()


def test_engine_owner_weight_is_the_inverse_variance_weight_of_a_secant_growing_plane_error():
    # Engine error constant, plane error proportional to the secant, equal at ENGINE_OWNER_EQUAL_DEG: the engine's
    # inverse-variance weight is 1 / (1 + (cos i / cos i0)^2): one half at i0, rising monotonically towards grazing.
    angles = np.radians(np.arange(0.0, 90.0, 5.0))
    weight = engine_owner_weight(angles)
    assert np.all(np.diff(weight) > 0) and np.all((weight > 0) & (weight < 1))
    assert engine_owner_weight(np.radians([ENGINE_OWNER_EQUAL_DEG]))[0] == pytest.approx(0.5)
    sigma_engine, sigma_plane = 1.0, np.cos(np.radians(ENGINE_OWNER_EQUAL_DEG)) / np.cos(angles)
    assert weight == pytest.approx(sigma_plane ** 2 / (sigma_plane ** 2 + sigma_engine ** 2))
    assert engine_owner_weight(np.array([np.nan]))[0] == pytest.approx(0.5)  # unknown incidence: equal weights


def test_nearest_incidence_takes_the_mean_of_the_reliable_pulses_next_to_each_pulse():
    # Two reliable blocks at 20 and 70 deg with a gap between them: every pulse of the gap takes the mean incidence
    # of the block it is nearest to (a pure pulse's window mean; the gap's own alpha is ignored).
    alpha = np.full((12, 30), np.radians(85.0))
    alpha[:, :10], alpha[:, 20:] = np.radians(20.0), np.radians(70.0)
    reliable = np.zeros(alpha.shape, dtype=bool)
    reliable[:, :10] = reliable[:, 20:] = True
    gap = ~reliable
    got = np.degrees(nearest_incidence(alpha, reliable, gap))
    cols = np.nonzero(gap)[1]
    assert got[cols < 15] == pytest.approx(20.0) and got[cols >= 15] == pytest.approx(70.0)
    assert np.isnan(nearest_incidence(alpha, np.zeros_like(reliable), gap)).all() and len(got) == gap.sum()

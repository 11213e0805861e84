"""Tests of leafsfs.splits: a surface that is two surfaces is split, a curved leaf is not."""
import math

import numpy as np
from scipy.spatial import ConvexHull

from leafsfs.leaves import segment_scan
from leafsfs.splits import MIN_ANGLE_DEG, MIN_EVIDENCE, part_scores, split_merged, surface_areas, two_parts
from tlssim.pattern import beam_frame

STEP = math.radians(0.036)
NOISE_M = 0.0015  # range noise of a FARO-class scanner on a leaf at a few metres, m (assumption)
ROWS, COLS = 90, 150


def _grid(cols=COLS):
    theta, psi = np.meshgrid(STEP * (np.arange(cols) - COLS / 2), np.pi / 2 + STEP * (np.arange(ROWS) - ROWS / 2))
    return theta, psi


def _with_typical_leaves(range_m, count=3, seed=2):
    """The ranges ``range_m`` (one surface, label 1) with ``count`` single planar leaves of a typical size (an
    ellipse of 24 x 32 pixels half-axes, a little smaller than each of :func:`_two_leaves`' two: the overlapping
    pair measures 2.5 typical leaves) to their right, labels 2, 3, ...: the scan's median surface is a typical
    leaf. Returns the ranges, the labels and the grids."""
    width = 90
    cols = COLS + count * width
    i, j = np.mgrid[:ROWS, :cols]
    out = np.full((ROWS, cols), np.nan)
    labels = np.zeros((ROWS, cols), dtype=int)
    out[:, :COLS] = range_m
    labels[:, :COLS] = np.isfinite(range_m)
    rng = np.random.default_rng(seed)
    for n in range(count):
        leaf = np.hypot((i - 45) / 24, (j - COLS - width * n - 45) / 32) <= 1
        out[leaf] = 2.0 + 0.2 * (j[leaf] - COLS) * 2.0 * STEP + NOISE_M * rng.standard_normal(leaf.sum())
        labels[leaf] = 2 + n
    return out, labels, _grid(cols)


def _leaf(centre, half_axes):
    """An elliptic outline on the grid (rows, cols), pixels."""
    i, j = np.mgrid[:ROWS, :COLS]
    return np.hypot((i - centre[0]) / half_axes[0], (j - centre[1]) / half_axes[1]) <= 1


def _two_leaves(behind_m, slope_front, slope_back, seed=0):
    """Ranges of two elliptic leaves 2 m away overlapping in the image, the second ``behind_m`` farther at the
    overlap, each a plane whose range grows by ``slope`` times the across-beam distance along the columns; the
    nearer one is seen where they overlap. Returns the ranges (NaN: no return) and each leaf's visible pulses."""
    i, j = np.mgrid[:ROWS, :COLS]
    x = j * 2.0 * STEP  # across-beam distance at 2 m, m
    front, back = _leaf((45, 55), (30, 40)), _leaf((45, 100), (30, 40))
    x_meet = 95 * 2.0 * STEP  # the front leaf's right end, where they overlap
    r_front = 2.0 + slope_front * (x - x_meet)
    r_back = 2.0 + behind_m + slope_back * (x - x_meet)
    range_m = np.where(front, r_front, np.where(back, r_back, np.nan))
    range_m = range_m + NOISE_M * np.random.default_rng(seed).standard_normal(range_m.shape)
    return range_m, front, back & ~front


def _split(range_m):
    """split_merged on the surface ``range_m`` among typical leaves; the labels on its grid and the parents."""
    wide, labels, (theta, psi) = _with_typical_leaves(range_m)
    out, parents = split_merged(labels, np.ones(labels.max() + 1, dtype=bool), wide, theta, psi, NOISE_M, 30)
    out = out[:, :COLS]
    return np.where(out > 4, out - 3, out), parents


def _apart(labels, front, back):
    """Whether each leaf lies (95 % of its pulses) in one label and the two labels differ."""
    shares = []
    for leaf in (front, back):
        values, counts = np.unique(labels[leaf], return_counts=True)
        shares.append((values[np.argmax(counts)], counts.max() / leaf.sum()))
    return shares[0][0] != shares[1][0] and min(s for _, s in shares) >= 0.95


def test_two_overlapping_leaves_at_different_tilts_are_split_into_the_two_leaves():
    # 40 deg apart (tan 20 deg and tan -20 deg), the back leaf 4 mm behind where they meet: no crease without a step
    range_m, front, back = _two_leaves(0.004, math.tan(math.radians(20)), -math.tan(math.radians(20)))
    labels, parents = _split(range_m)
    assert parents.tolist() == [1] and labels.max() == 2
    assert _apart(labels, front, back)
    assert np.array_equal(labels > 0, np.isfinite(range_m))  # every pulse keeps a surface


def test_two_parallel_leaves_at_different_distances_are_parted_but_not_split():
    # the same tilt, 1 cm apart (7 noise deviations): the partition finds them, but their cubics meet at 0 deg
    # (MIN_ANGLE_DEG: told apart by their tilts only)
    range_m, front, back = _two_leaves(0.01, 0.3, 0.3)
    theta, psi = _grid()
    inside = np.isfinite(range_m)
    part = two_parts(inside, range_m, theta, psi, np.full(inside.shape, NOISE_M))
    assert _apart(part, front, back)
    assert part_scores(part, range_m, theta, psi, np.full(inside.shape, NOISE_M))[3] < MIN_ANGLE_DEG
    labels, parents = _split(range_m)
    assert len(parents) == 0 and labels.max() == 1


def test_a_curved_leaf_and_a_plane_stay_whole_and_only_candidates_are_split():
    theta, psi = _grid()
    i, j = np.mgrid[:ROWS, :COLS]
    x, y = (j - 75) * 2.0 * STEP, (i - 45) * 2.0 * STEP
    blade = _leaf((45, 75), (40, 70))
    rng = np.random.default_rng(1)
    # rolled across (5 cm radius: normals turn 30 deg over the blade), bent along (the tip droops by the cube of
    # the distance), tilted 45 deg, twisted
    curved = 2.0 + x + y ** 2 / (2 * 0.05) + 40.0 * x ** 3 + 2.0 * x * y
    for surface in (curved, 2.0 + 0.5 * x - 0.2 * y):
        range_m = np.where(blade, surface + NOISE_M * rng.standard_normal(blade.shape), np.nan)
        labels, parents = _split(range_m)
        assert len(parents) == 0 and np.array_equal(labels, blade.astype(int))
    range_m, _, _ = _two_leaves(0.004, 0.36, -0.36)
    wide, labels, (theta, psi) = _with_typical_leaves(range_m)
    candidates = np.ones(labels.max() + 1, dtype=bool)
    candidates[1] = False
    out, parents = split_merged(labels, candidates, wide, theta, psi, NOISE_M, 30)
    assert len(parents) == 0 and np.array_equal(out, labels)


def test_the_partition_and_scores_are_the_same_at_any_distance():
    # the same two leaves three times as far (every length and the noise times 3): the same partition and scores
    range_m, front, back = _two_leaves(0.004, 0.36, -0.36)
    theta, psi = _grid()
    inside = np.isfinite(range_m)
    noise = np.full(inside.shape, NOISE_M)
    part = two_parts(inside, range_m, theta, psi, noise)
    one, apart, step, angle = part_scores(part, range_m, theta, psi, noise)
    assert 0.8 < apart < 1.2 < one  # each part on its cubic within the noise, not both on one
    assert abs(angle - 2 * math.degrees(math.atan(0.36))) < 5  # the two planes' tilts
    assert np.array_equal(two_parts(inside, 3 * range_m, theta, psi, 3 * noise), part)
    assert np.allclose(part_scores(part, 3 * range_m, theta, psi, 3 * noise), (one, apart, step, angle), rtol=1e-6)
    # too few pulses for two cubics: no score apart
    small = np.zeros(inside.shape, dtype=int)
    small[40:45, 50:56] = 1
    small[45:47, 50:56] = 2
    assert np.isnan(part_scores(small, range_m, theta, psi, noise)[1])


def test_segment_scan_gives_two_overlapping_leaves_two_regions():
    range_m, front, back = _two_leaves(0.004, 0.36, -0.36)
    wide, _, (theta, psi) = _with_typical_leaves(range_m)
    for split, regions in ((True, 2), (False, 1)):
        labels = segment_scan(wide, theta, psi, noise_m=NOISE_M, drop_border=False,
                              split_merged_surfaces=split).leaves[:, :COLS]
        assert len(np.unique(labels[labels > 0])) == regions


def test_a_folded_leaf_of_typical_size_stays_whole_though_its_halves_are_two_planes():
    # a leaf folded along its midrib (each half 20 deg off the blade: 40 deg between the halves, a crease 6 mm
    # deep), the size of the scan's other leaves: the two-surface test alone would part it along the fold, but
    # only surfaces of about two leaves' area are tested
    theta, psi = _grid()
    i, j = np.mgrid[:ROWS, :COLS]
    blade = _leaf((45, 75), (22, 34))
    y = np.abs(i - 45) * 2.0 * STEP  # distance from the midrib, m
    range_m = np.where(blade, 2.0 - math.tan(math.radians(20)) * y, np.nan)
    range_m = range_m + NOISE_M * np.random.default_rng(3).standard_normal(range_m.shape)
    inside = np.isfinite(range_m)
    noise = np.full(inside.shape, NOISE_M)
    part = two_parts(inside, range_m, theta, psi, noise)
    one, apart, _, angle = part_scores(part, range_m, theta, psi, noise)
    n = inside.sum()
    assert n * (one - apart) > MIN_EVIDENCE * 10 * np.log(n) and angle >= MIN_ANGLE_DEG  # two planes by the test
    labels, parents = _split(range_m)
    assert len(parents) == 0 and np.array_equal(labels, blade.astype(int))


def test_surface_areas_are_the_areas_of_planar_leaves():
    # a planar disc facing the scanner and one tilted 60 deg (its range grows by tan 60 deg per metre across the
    # beam): the area on their planes; a surface with fewer pulses than asked is not measured
    theta, psi = _grid()
    i, j = np.mgrid[:ROWS, :COLS]
    x = (j - COLS / 2) * 2.0 * STEP
    labels = np.zeros((ROWS, COLS), dtype=int)
    labels[_leaf((45, 37), (30, 30))] = 1
    labels[_leaf((45, 112), (30, 30))] = 2
    labels[_leaf((10, 75), (3, 3))] = 3
    range_m = np.where(labels == 2, 2.0 + math.tan(math.radians(60)) * x, 2.0)
    range_m = np.where(labels > 0, range_m, np.nan)
    area = surface_areas(labels, np.ones(4, dtype=bool), range_m, theta, psi, 100)
    assert np.isnan(area[0]) and np.isnan(area[3])
    points = beam_frame(theta, psi)[0] * range_m[..., None]
    for k in (1, 2):
        pts = points[labels == k]
        plane = np.linalg.svd(pts - pts.mean(axis=0), full_matrices=False)[2][:2]  # the plane's two axes
        hull = ConvexHull((pts - pts.mean(axis=0)) @ plane.T).volume  # area through the rim pulses' centres, m^2
        # the pulses cover half a pulse beyond the rim: 3 % more than the hull for a 30-pulse radius
        assert 1.0 < area[k] / hull < 1.06
    assert 1.9 < area[2] / area[1] < 2.3  # about 1 / cos 60 deg as much


def test_a_curled_leaf_beside_a_plane_keeps_its_far_end():
    # a leaf curled along the columns (5 cm radius; its tangent 20 deg off the beam's normal where it meets the
    # other) beside a plane 40 deg from that tangent, 4 mm behind: its curled far end lies nearer the plane's fit
    # than its own, so planes alone give 11 % of it to the plane; the last round with cubics gives it back
    theta, psi = _grid()
    i, j = np.mgrid[:ROWS, :COLS]
    x = (j - 95) * 2.0 * STEP
    front, back = _leaf((45, 55), (30, 40)), _leaf((45, 100), (30, 40))
    range_m = np.where(front, 2.0 + 0.36 * x + x ** 2 / (2 * 0.05), np.where(back, 2.004 - 0.36 * x, np.nan))
    range_m = range_m + NOISE_M * np.random.default_rng(0).standard_normal(range_m.shape)
    inside = np.isfinite(range_m)
    part = two_parts(inside, range_m, theta, psi, np.full(inside.shape, NOISE_M))
    assert _apart(part, front, back & ~front)

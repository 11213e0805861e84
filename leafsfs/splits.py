"""Leaf surfaces that hold two surfaces (two leaves, or a leaf and the branch it lies on) split apart.

The linking of :func:`leafsfs.leaves.segment_scan` joins neighbouring pulses
whose range step a steep slope could explain, so two leaves that meet in the
image a few millimetres apart in range, or a leaf lying on a branch, can
become one surface; the neck cut (:func:`leafsfs.canopy.split_necks`) misses
them where the two outlines join along a wide front, and the crease cut
(:func:`leafsfs.canopy.split_creases`) where a range step lies between them.
Such a region is compared with one of its leaves, and its area is the sum of
both.

The test uses the range and the scan grid only, in units of each pulse's
range noise (the same at any step and distance): a surface is two when one
smooth surface per part of a partition into two connected parts
(:func:`two_parts`) explains its pulses much better than one smooth surface
for all, and the two meet at an angle (:func:`part_scores`,
:data:`MIN_EVIDENCE`, :data:`MIN_ANGLE_DEG`). Only a surface at least
:data:`MIN_AREA_RATIO` times the median area of the scan's candidate
surfaces is tested (:func:`surface_areas`): the area of two leaves, where a
merge's area error is large; a single leaf of typical size that folds,
curls or carries its stalk can pass the two-surface test, and cutting it
loses a part of its area. Smooth surface: a cubic height field
over the principal plane of the pulses (assumption: a leaf blade, with its
bend, roll and twist, departs from a cubic by much less than the range noise
over its extent, as the leaf model of :mod:`scenes.leaf` does, whose
wrinkles are 0.1-0.4 mm against 1-2 mm of noise; a branch across a leaf's
width is close to one too).
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from tlssim.pattern import beam_frame

#: Squared residuals are clipped at this many range-noise standard deviations (squared), so that the few edge
#: pulses the edge test kept weigh as a pulse off by this much.
CLIP_SIGMA = 4.0
#: The drop of the sum of squared residuals (noise variances) from one cubic to one per part must exceed this many
#: times the Bayesian information criterion's price of the second cubic (its 10 coefficients times the log of the
#: number of pulses). Assumption: 5, a margin for what the BIC does not see, a real leaf's small departures from a
#: cubic and from the noise model, and a partition chosen to fit best.
MIN_EVIDENCE = 5.0
#: Where the parts touch, the two cubics' normals must lie at least this far apart, deg (assumption: the parts of one
#: smooth leaf share their tangent plane where they meet; two leaves meeting at less than 20 deg are not told apart).
MIN_ANGLE_DEG = 20.0
#: Only a surface whose area is at least this many times the median area of the candidate surfaces of at least
#: ``2 min_pixels`` pulses is tested. Assumption: 2, the area of two typical leaves (the median surface is a typical
#: leaf when the scan holds many; the simulated pears' leaf areas span 0.3-3.3 times their median, 90 % under 1.75).
#: On the development canopies' truth (leafy tree, pears s7, s23, s31, s41), the merges of two objects the partition
#: parted measured 0.4-4.8 times the median, those whose split moved a leaf's area most 2.1-4.8; the single leaves
#: cut in two 0.25-1.75, once 2.2.
MIN_AREA_RATIO = 2.0
#: Smallest share of the surface's pulses in a part.
MIN_PART_SHARE = 0.1
#: Half-size of the window over which the local normals of the first partition are taken, pixels.
NORMAL_HALF_PX = 3
#: Rounds of fitting a plane to each part and giving each pulse to the nearer one.
ROUNDS = 6
#: Smallest cosine between the beam and a surface's normal used to turn a range noise into a height noise
#: (85 deg: beyond it the height field is ill-defined).
MIN_COS = np.cos(np.radians(85.0))


def split_merged(surfaces: np.ndarray, candidates: np.ndarray, range_m: np.ndarray, theta: np.ndarray,
                 psi: np.ndarray, noise_m: np.ndarray | float, min_pixels: int) -> tuple[np.ndarray, np.ndarray]:
    """Candidate surfaces that are two smooth surfaces split into their two parts.

    A surface of at least :data:`MIN_AREA_RATIO` times the median area of
    the candidate surfaces of at least ``2 min_pixels`` pulses
    (:func:`surface_areas`) is partitioned into two connected parts
    (:func:`two_parts`) and split when the parts are two surfaces (:func:`part_scores`): one
    cubic per part lowers the sum of the squared residuals (in noise
    variances, clipped at :data:`CLIP_SIGMA` squared) of one cubic for all
    by more than :data:`MIN_EVIDENCE` times the information criterion's price
    of the second cubic, the two cubics' normals lie at least
    :data:`MIN_ANGLE_DEG` apart where the parts touch, and each part holds
    at least ``min_pixels`` pulses and :data:`MIN_PART_SHARE` of the
    surface.

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    candidates : ndarray of bool
        Surfaces that may be split (index = label), e.g. the leaves.
    range_m, theta, psi : ndarray, 2-D
        Scan grids (m, rad).
    noise_m : ndarray or float
        Range noise per pulse (or one for all), m.
    min_pixels : int
        Smallest part, pixels.

    Returns
    -------
    surfaces : ndarray of int, 2-D
        Surface labels: the larger part keeps its label, the smaller is
        numbered after the largest existing label.
    parents : ndarray of int
        For each new label (after the largest existing one, in order), the
        label it was split from.
    """
    out = surfaces.copy()
    count = int(surfaces.max(initial=0))
    noise = np.broadcast_to(noise_m, range_m.shape)
    parents = []
    area = surface_areas(surfaces, candidates, range_m, theta, psi, 2 * min_pixels)
    measured = np.isfinite(area)
    tested = np.zeros(len(area), dtype=bool)
    if measured.any():
        tested[measured] = area[measured] >= MIN_AREA_RATIO * np.median(area[measured])
    for k, box in enumerate(ndimage.find_objects(surfaces), start=1):
        if box is None or k >= len(tested) or not tested[k]:
            continue
        inside = (surfaces[box] == k) & np.isfinite(range_m[box])
        n = int(inside.sum())
        price = MIN_EVIDENCE * 10 * np.log(n)
        if n * part_scores(inside.astype(int), range_m[box], theta[box], psi[box], noise[box])[0] <= price:
            continue  # no partition can gain that much
        part = two_parts(inside, range_m[box], theta[box], psi[box], noise[box])
        if part is None:
            continue
        sizes = np.array([(part == 1).sum(), (part == 2).sum()])
        if sizes.min() < max(min_pixels, MIN_PART_SHARE * n):
            continue
        one, apart, _, angle = part_scores(part, range_m[box], theta[box], psi[box], noise[box])
        if not (n * (one - apart) > price and angle >= MIN_ANGLE_DEG):
            continue
        count += 1
        out[box][part == 1 + int(np.argmin(sizes))] = count
        parents.append(k)
    return out, np.array(parents, dtype=int)


def surface_areas(surfaces: np.ndarray, candidates: np.ndarray, range_m: np.ndarray, theta: np.ndarray,
                  psi: np.ndarray, min_pulses: int) -> np.ndarray:
    """Area of each candidate surface of at least ``min_pulses`` pulses, from its pulses' footprints on its
    principal plane.

    A pulse covers ``(range x step)^2 / cos`` of the plane, ``step`` the
    median angular step between columns and ``cos`` the cosine between its
    beam and the plane's normal (at least :data:`MIN_COS`).

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    candidates : ndarray of bool
        Surfaces to measure (index = label).
    range_m, theta, psi : ndarray, 2-D
        Scan grids (m, rad).
    min_pulses : int
        Fewest pulses (with a range) of a measured surface.

    Returns
    -------
    ndarray of float
        Area per label, m^2 (index = label; NaN where not measured).
    """
    area = np.full(int(surfaces.max(initial=0)) + 1, np.nan)
    step = float(np.nanmedian(np.abs(np.diff(theta, axis=1)))) if theta.shape[1] > 1 else np.nan
    for k, box in enumerate(ndimage.find_objects(surfaces), start=1):
        if box is None or k >= len(candidates) or not candidates[k]:
            continue
        rows, cols = np.nonzero((surfaces[box] == k) & np.isfinite(range_m[box]))
        if len(rows) < max(min_pulses, 3):
            continue
        _, cos, _ = _heights(rows, cols, range_m[box], theta[box], psi[box], np.ones(surfaces[box].shape))
        area[k] = float(np.sum((range_m[box][rows, cols] * step) ** 2 / cos))
    return area


def two_parts(inside: np.ndarray, range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray,
              noise_m: np.ndarray) -> np.ndarray | None:
    """A partition of one surface into two connected parts, each near its own plane.

    The first partition is the two clusters of the pulses' local normals
    (two leaves at different tilts), or the two signs of the residuals from
    one plane (two leaves at different distances); then, for :data:`ROUNDS`
    rounds, each part takes a plane and each pulse goes to the plane it lies
    nearer to (in noise deviations), smoothed by its 3 x 3 neighbours'
    majority, and each part keeps its largest connected piece (the rest goes
    to the other part). Planes, not cubics: they do not bend to follow the
    other part. Of the two results, the one whose cubic per part leaves the
    smaller residual (:func:`part_scores`); then one more round with a cubic
    per part, kept when it leaves a smaller residual still (a curved leaf's
    far end that lies nearer the other part's plane than its own goes back
    to its leaf).

    Parameters
    ----------
    inside : ndarray of bool, 2-D
        The surface's pulses.
    range_m, theta, psi : ndarray, 2-D
        Scan grids on the same window (m, rad).
    noise_m : ndarray, 2-D
        Range noise per pulse, m.

    Returns
    -------
    ndarray of int, 2-D, or None
        1 or 2 on the surface's pulses, 0 elsewhere; None when no partition
        keeps two parts.
    """
    rows, cols = np.nonzero(inside)
    local, noise, axis = _heights(rows, cols, range_m, theta, psi, noise_m)
    cubic = _design(local[:, 1:])
    design = cubic[:, :3]
    z_one = _fit_residuals(design, local[:, 0], noise, np.ones(len(rows), dtype=bool))[0]
    xyz = beam_frame(theta, psi)[0] * range_m[..., None]
    best, score = None, np.inf
    for start in (_normal_clusters(xyz, inside, rows, cols), 1 + (z_one > 0).astype(int)):
        if start is None:
            continue
        labels = _refine(start, design, local[:, 0], noise, inside, rows, cols)
        if labels is None:
            continue
        part = np.zeros(inside.shape, dtype=int)
        part[rows, cols] = labels
        apart = part_scores(part, range_m, theta, psi, noise_m)[1]
        if apart < score:
            best, score = part, apart
    if best is not None:
        labels = _refine(best[rows, cols], cubic, local[:, 0], noise, inside, rows, cols, rounds=1)
        if labels is not None:
            part = np.zeros(inside.shape, dtype=int)
            part[rows, cols] = labels
            if part_scores(part, range_m, theta, psi, noise_m)[1] < score:
                best = part
    return best


def part_scores(parts: np.ndarray, range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray,
                noise_m: np.ndarray) -> tuple[float, float, float, float]:
    """How much better one cubic per part explains the pulses than one for all, and how the parts' cubics meet.

    Heights are taken along the normal of the principal plane of all the
    parts' points; a pulse's height noise is its range noise times the
    cosine of its beam to that normal (at least :data:`MIN_COS`); squared
    residuals are in noise variances, clipped at :data:`CLIP_SIGMA` squared.

    Parameters
    ----------
    parts : ndarray of int, 2-D
        Part of each pulse (1 or 2; 0: none).
    range_m, theta, psi : ndarray, 2-D
        Scan grids on the same window (m, rad).
    noise_m : ndarray, 2-D
        Range noise per pulse, m.

    Returns
    -------
    one, apart : float
        Mean squared residual per pulse from one cubic and from one per
        part, noise variances (``apart`` NaN when a part has fewer pulses
        than twice a cubic's coefficients).
    step : float
        Median over the pulses where the parts touch (4-neighbours) of the
        two cubics' height difference, in height-noise deviations (NaN
        without two parts).
    angle : float
        Median angle between the two cubics' normals there, deg.
    """
    rows, cols = np.nonzero(parts)
    label = parts[rows, cols]
    local, noise, _ = _heights(rows, cols, range_m, theta, psi, noise_m)
    design, scale = _design(local[:, 1:], scale=True)
    z_one = _fit_residuals(design, local[:, 0], noise, np.ones(len(rows), dtype=bool))[0]
    counts = np.bincount(label, minlength=3)[1:3]
    if len(counts) < 2 or counts.min() < 2 * design.shape[1]:
        return _score(z_one), np.nan, np.nan, np.nan
    z_apart = np.zeros(len(rows))
    coefs = []
    for p in (1, 2):
        sel = label == p
        z, coef = _fit_residuals(design, local[:, 0], noise, sel)
        z_apart[sel] = z[sel]
        coefs.append(coef)
    index = np.full(parts.shape, -1)
    index[rows, cols] = np.arange(len(rows))
    touch = np.zeros(len(rows), dtype=bool)
    for di, dj in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        other = np.roll(np.pad(parts, 1), (-di, -dj), axis=(0, 1))[1:-1, 1:-1][rows, cols]
        touch |= (other > 0) & (other != label)
    if not touch.any():
        return _score(z_one), _score(z_apart), np.nan, np.nan
    uv = local[touch, 1:]
    heights = [_design(uv, scale=scale)[0] @ c for c in coefs]
    step = float(np.median(np.abs(heights[0] - heights[1]) / noise[touch]))
    normals = [_normal(c, uv, scale) for c in coefs]
    angle = float(np.median(np.degrees(np.arccos(np.clip(np.sum(normals[0] * normals[1], axis=1), -1, 1)))))
    return _score(z_one), _score(z_apart), step, angle


def _heights(rows: np.ndarray, cols: np.ndarray, range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray,
             noise_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pulses' points in the frame of their principal plane (normal first, m), their height noise (m) and
    their beam directions."""
    axis = beam_frame(theta[rows, cols], psi[rows, cols])[0]
    pts = axis * range_m[rows, cols][:, None]
    centre = pts.mean(axis=0)
    frame = np.linalg.eigh(np.cov((pts - centre).T))[1]  # columns: smallest spread first (the normal)
    local = (pts - centre) @ frame
    return local, noise_m[rows, cols] * np.maximum(np.abs(axis @ frame[:, 0]), MIN_COS), axis


def _score(z: np.ndarray) -> float:
    """Mean squared residual, in noise variances clipped at :data:`CLIP_SIGMA` squared."""
    return float(np.mean(np.minimum(z * z, CLIP_SIGMA ** 2)))


def _design(uv: np.ndarray, scale=None):
    """Columns of a cubic height field in the plane coordinates ``uv`` (m), centred and scaled to unit spread;
    with ``scale=True`` also that centring and scale (mean, spread), and with a given (mean, spread) those."""
    mean, spread = (uv.mean(axis=0), np.maximum(uv.std(axis=0), 1e-12)) if scale is None or scale is True else scale
    u, v = ((uv - mean) / spread).T
    columns = np.stack([u ** (d - e) * v ** e for d in range(4) for e in range(d + 1)], axis=1)
    return (columns, (mean, spread)) if scale is not None else columns


def _normal(coef: np.ndarray, uv: np.ndarray, scale) -> np.ndarray:
    """Unit normals (height axis first) of the cubic ``coef`` at the plane coordinates ``uv`` (m)."""
    mean, spread = scale
    u, v = ((uv - mean) / spread).T
    powers = [(d - e, e) for d in range(4) for e in range(d + 1)]
    du = sum(c * a * u ** max(a - 1, 0) * v ** b for c, (a, b) in zip(coef, powers) if a > 0) / spread[0]
    dv = sum(c * b * u ** a * v ** max(b - 1, 0) for c, (a, b) in zip(coef, powers) if b > 0) / spread[1]
    n = np.stack([np.ones_like(u), -du, -dv], axis=1)
    return n / np.linalg.norm(n, axis=1)[:, None]


def _fit_residuals(design: np.ndarray, height: np.ndarray, noise: np.ndarray,
                   sel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residuals of every pulse, in noise deviations, from the surface fitted (weighted by ``1 / noise``) to the
    pulses ``sel``, and its coefficients."""
    w = 1.0 / noise
    coef = np.linalg.lstsq(design[sel] * w[sel, None], height[sel] * w[sel], rcond=None)[0]
    return (height - design @ coef) * w, coef


def _normal_clusters(xyz: np.ndarray, inside: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray | None:
    """Two clusters (1, 2) of the pulses' local normals (from the surface's points averaged over a
    ``2 NORMAL_HALF_PX + 1`` window; 0 where a pulse has none), or None when too few pulses have one."""
    h = NORMAL_HALF_PX
    weight = ndimage.uniform_filter(inside.astype(float), 2 * h + 1, mode="constant")
    mean = np.stack([ndimage.uniform_filter(np.where(inside, xyz[..., a], 0.0), 2 * h + 1, mode="constant")
                     for a in range(3)], axis=-1) / np.maximum(weight, 1e-12)[..., None]
    shape = inside.shape
    r0, r1 = np.clip(rows - h, 0, shape[0] - 1), np.clip(rows + h, 0, shape[0] - 1)
    c0, c1 = np.clip(cols - h, 0, shape[1] - 1), np.clip(cols + h, 0, shape[1] - 1)
    ok = inside[r0, cols] & inside[r1, cols] & inside[rows, c0] & inside[rows, c1]
    if ok.sum() < 12:
        return None
    normal = np.cross(mean[r1, cols] - mean[r0, cols], mean[rows, c1] - mean[rows, c0])[ok]
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    centre = normal.mean(axis=0)
    centres = np.stack([centre / max(np.linalg.norm(centre), 1e-300), normal[np.argmin(normal @ centre)]])
    for _ in range(10):
        label = np.argmax(normal @ centres.T, axis=1)
        if label.min() == label.max():
            return None
        centres = np.stack([normal[label == c].mean(axis=0) for c in (0, 1)])
        centres /= np.linalg.norm(centres, axis=1)[:, None]
    out = np.zeros(len(rows), dtype=int)
    out[ok] = 1 + label
    return out


def _refine(start: np.ndarray, design: np.ndarray, height: np.ndarray, noise: np.ndarray, inside: np.ndarray,
            rows: np.ndarray, cols: np.ndarray, rounds: int = ROUNDS) -> np.ndarray | None:
    """Alternate fits (of the columns ``design``) and assignments from the partition ``start`` (1, 2; 0
    unassigned) for ``rounds`` rounds; None when a part vanishes."""
    labels = start.copy()
    image = np.zeros(inside.shape, dtype=int)
    for _ in range(rounds):
        if min((labels == 1).sum(), (labels == 2).sum()) < 2 * design.shape[1]:
            return None
        z = np.stack([np.abs(_fit_residuals(design, height, noise, labels == p)[0]) for p in (1, 2)])
        image[rows, cols] = 1 + np.argmin(z, axis=0)
        votes = [ndimage.uniform_filter((image == p).astype(float), 3, mode="constant") for p in (1, 2)]
        image[rows, cols] = np.where(votes[0][rows, cols] >= votes[1][rows, cols], 1, 2)
        for p in (1, 2):
            pieces, n = ndimage.label(image == p, structure=np.ones((3, 3), bool))
            if n > 1:
                keep = 1 + int(np.argmax(np.bincount(pieces.ravel())[1:]))
                image[(pieces > 0) & (pieces != keep)] = 3 - p
        labels = image[rows, cols]
    return labels if min((labels == 1).sum(), (labels == 2).sum()) > 0 else None

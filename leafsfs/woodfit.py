"""The distance of a wood surface at its mixed pulses, from a circle across the branch.

:func:`leafsfs.edges.attribute_mixed` extrapolates each surface to its
mixed pulses with a local plane of its own pulses. A branch is a cylinder:
towards its silhouette its surface turns away from the beam, and the plane,
fitted a few pulses inside, stops short of it (millimetres to a centimetre
where the footprint lies on the last millimetres of the branch).

Here the pulse's owner surface (its pure pulses and the mixed pulses it
dominates, whose footprints are centred on it) is followed across the
branch through the pulse, along the direction from the pulse to the
centroid of the surface's pure pulses around it, silhouette to silhouette:
half that extent is the branch's apparent radius ``R`` (pixels times ``r *
step``, m) and its middle the axis' offset ``x0``. The surface's pure
pulses around the pulse, at lateral offset ``x`` and offset ``y`` along the
branch, then fit ``z = D - s sqrt(R^2 - (x - x0)^2) + g y`` (least squares
in ``D`` and ``g``; ``s = sqrt(1 + g^2)``: an axis inclined to the beam by
``atan g`` cuts the plane of ``x`` and the beam in an ellipse of depth axis
``s R``). The pulse's range is that profile at ``x = 0``. No circle fits,
and the plane's distance stays, where the extent does not end in a
silhouette on both sides (a nearer surface cuts it), the branch is wider
than :data:`MAX_RADIUS_M`, too few pulses fit, the residuals exceed the
noise, or a plane fits the same pulses at least as well (a flat surface:
a leaf, or leaves joined into one surface); nor where the circle's
distance no longer brackets the pulse's range with the pair's other
surface.

Where no circle fits (a nearer surface ends the extent on one side, a
silhouette is missing, ...: the circle was kept for 15 % of the scored
wood-dominated mixed pulses that wood owns on the leafy tree at 0.018
deg), a quadric
``z = a + b x + c y + d x^2 + e x y + f y^2`` over the owner's pure pulses
within :data:`QUADRIC_RADIUS_FACTOR` times the neighbourhood's radius
around the pulse gives its distance (:func:`quadric_ranges`): the plane of
:func:`leafsfs.edges.attribute_mixed` ignores the curvature of a branch
turning away from the beam (or a leaf surface taken for wood curling away),
and stops short by a few millimetres. It is kept where it fits the pulses
within the noise and passes the same bracket test as the circle. The
quadrics and the twig's median are tried on every owner that is no leaf
surface, the circle only on the wood-shaped ones (:func:`wood_fitted_range`). For a
pulse paired with another surface (which takes its owner's plane distance
where nothing fits) a quadric over :data:`WIDE_QUADRIC_FACTOR` times the
neighbourhood's radius is tried next the same way (a branch piece cut
short on one side by a nearer leaf has few pulses near the pulse), then,
for an owner with fewer than :data:`MIN_PULSES` pure pulses within
:data:`TWIG_RADIUS_FACTOR` times that radius (a twig a few footprints
wide), their median (:func:`twig_ranges`), with the same bracket test.

Assumption: the pixel spacing is ``r * step`` along both grid axes (a
panoramic grid's horizontal spacing shrinks by ``sin(zenith)``, under 2 %
within 11 deg of the horizon).
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from leafsfs.canopy import MIN_LEAF_WIDTH_M, narrow_surfaces, wood_surfaces
from leafsfs.edges import MixedPulses
from leafsfs.leaves import angular_step

#: Largest branch radius fitted, m (assumption: orchard and tree branches near leaves are under 5 cm thick; larger
#: fits are flat or wide surfaces, whose plane is kept).
MAX_RADIUS_M = 0.05
#: Fewest pulses of a circle fit (two unknowns, the axis' depth and the slope along the branch, and residuals left to
#: judge it): a twig a few footprints wide has few pure pulses. Measured on a 800 x 800 crop of the leafy tree at 0.018
#: deg (wood-dominated mixed pulses given a circle, error beyond 6 mm from the truth): 12: 327 pulses, 33 -> 14 %; 5:
#: 476 pulses, 35 -> 22 %; 4 with no flatness test: 1342 pulses, 36 -> 35 %.
MIN_PULSES = 5
#: Fewest pulses on which a plane is compared with the circle (:func:`cylinder_ranges`; fewer: the circle is kept).
MIN_FLAT_TEST = 12
#: Largest RMS residual of a circle fit, in range-noise sigmas.
MAX_RESIDUAL_SIGMA = 2.0
#: Radius of a quadric fit's neighbourhood, in units of the circle's (:func:`wood_fitted_range`). Measured with the
#: truth on the mixed pulses that a surface not taken for a leaf owns (scored leaf pulses, outliers at each leaf's
#: 3-sigma threshold against the dominant object's true surface; plane -> circle -> circle or quadric; a scratch
#: truth-budget script, not kept): leafy tree at 0.018 deg, 14,749 pulses, 3,819 -> 3,808 ->
#: 3,650 (factor 1: 3,633; 2: 3,609); pear seed 7 at 3 m, 26,657 pulses, 6,810 -> 6,685 -> 6,030 (1: 6,195; 2:
#: 5,997).
QUADRIC_RADIUS_FACTOR = 1.5
#: Fewest pulses of a quadric fit (six unknowns, twice as many pulses).
MIN_QUADRIC_PULSES = 12
#: Largest standard deviation of a quadric's range at the pulse, in range-noise sigmas (a quadric extrapolated far
#: beyond its pulses amplifies their noise; here it stays within one pulse's noise). Same measure as above: 0.5:
#: 3,727 / 6,239; 1: 3,650 / 6,030; 2: 3,771 / 6,164; no limit: 4,243 / 6,835.
MAX_QUADRIC_SPREAD = 1.0
#: Radius of the second, wider quadric fit, in units of the circle's neighbourhood (tried where neither the circle nor
#: the first quadric fits). Measured as above, with the truth: outliers among all scored pulses of the leafy tree at
#: 0.018 deg (main 3322899, pooled, 11,866 left; a scratch what-if, not kept), on every target: factor 2: 11,862;
#: 3: 11,825. Pear seed 7 at 3 m (19,225): 3: 19,143.
WIDE_QUADRIC_FACTOR = 3.0
#: Radius of a twig's neighbourhood (:func:`twig_ranges`), in units of the circle's. Same measure, with the wider
#: quadric: factor 1: 11,783; 2: 11,768 (pear seed 7: 19,126; 19,105). Both on the paired pulses only (the module
#: docstring): tree 11,781, pear 19,114.
TWIG_RADIUS_FACTOR = 2.0
#: Targets fitted per batch (bounds the memory of the neighbourhood tables).
CHUNK = 4096
#: Most cells of a batch's neighbourhood tables (targets x the widest target's pulses): the quadric's design
#: matrices hold six times that. Without it the orchard window at 0.018 deg peaked at 6.4 GB (3.2 GB before the
#: quadric): near the scanner a disc holds thousands of pulses.
TABLE_CELLS = 2 ** 20


def wood_fitted_range(mixed: MixedPulses, range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray,
                      alpha: np.ndarray | None, leaf_surfaces: np.ndarray, band_px: int, noise_m: float) -> np.ndarray:
    """Distance of the owner of each mixed pulse that is no leaf from its circle (wood-shaped owners only), else its
    quadric, else a wider quadric, else its twig's median (NaN where none fits).

    The pulses are those with a pair (or within the range tolerance of one
    surface) that are not ``thin`` and whose owner is no leaf surface; a fit
    is kept where it still explains the pulse's range (module docstring).
    The circle is tried only where the owner is wood-shaped
    (:func:`wood_labels`); the quadrics and the twig's median on every such
    owner: a surface the segmentation did not take for a leaf nor for wood
    (a leaf piece too small or too hidden to be a leaf, a curled lobe) curves
    as well, and its plane, fitted a third of the band inside its border,
    stops short where it turns away. Measured with the truth on the dumps
    of main's fused run (the pulses whose output changes, judged against the
    true surface of their dominant object; a scratch measurement, round
    21): leafy tree at 0.018 deg 1,866
    scored pulses, outliers 702 -> 290, mean per-leaf ROP reduction 0.688 ->
    0.695; pear seed 7 at 3 m 2,441 pulses, 339 -> 296, 0.725 -> 0.726.

    Parameters
    ----------
    mixed : MixedPulses
        The scan's mixed-pulse attribution.
    range_m, theta, psi : ndarray, 2-D
        Scan grids (m, rad).
    alpha : ndarray, 2-D, optional
        Intensity-derived incidence, rad.
    leaf_surfaces : ndarray of int
        Labels of the surfaces taken for leaves (never wood).
    band_px : int
        The mixed band's width, pixels: the radius of the neighbourhood fitted is at least that (and 8).
    noise_m : float
        Range noise, m (sigma).

    Returns
    -------
    ndarray, 2-D
        Fitted owner distance per pulse, m (NaN where nothing fits).
    """
    planar = mixed.owner_range()
    step = angular_step(theta, psi)
    wood = wood_labels(mixed.surfaces, range_m, theta, psi, step, alpha)
    # Every owner that is no leaf surface is fitted (docstring); the circle, a branch's profile, only where it is
    # wood-shaped.
    curved = np.ones(wood.shape, dtype=bool)
    curved[np.asarray(leaf_surfaces, dtype=int)] = False
    curved[0] = False
    wood &= curved
    targets = (mixed.surfaces == 0) & ~mixed.thin & curved[mixed.owner] & np.isfinite(planar)
    if not targets.any():
        return np.full(range_m.shape, np.nan)
    radius = max(8.0, float(band_px))
    circle = cylinder_ranges(range_m, mixed.surfaces, mixed.owner, targets & wood[mixed.owner], step, radius, noise_m)
    # The circle must still explain the pulse: its range between the circle's and the pair's other surface's (within
    # the noise), and nearer the circle (the owner keeps most of the power). A pulse of one surface has no other.
    first = np.nan_to_num(mixed.share, nan=1.0) >= 0.5
    other = np.where(mixed.pair[..., 1] > 0, np.where(first, mixed.pair_range[..., 1], mixed.pair_range[..., 0]),
                     range_m)
    tolerance = 3 * noise_m

    def explains(fitted):
        with np.errstate(invalid="ignore"):
            return np.isfinite(fitted) & (range_m >= np.fmin(fitted, other) - tolerance) \
                & (range_m <= np.fmax(fitted, other) + tolerance) \
                & (np.abs(range_m - fitted) <= np.abs(range_m - other) + tolerance * (mixed.pair[..., 1] == 0))

    fitted = np.where(explains(circle), circle, np.nan)
    quadric = quadric_ranges(range_m, mixed.surfaces, mixed.owner, targets & np.isnan(fitted),
                             QUADRIC_RADIUS_FACTOR * radius, noise_m)
    fitted = np.where(np.isnan(fitted) & explains(quadric), quadric, fitted)
    # A pulse paired with another surface is moved to its owner's distance even where nothing fits (the plane): there
    # a quadric of a wider neighbourhood (a branch piece cut short on one side by a nearer leaf has few pulses near
    # the pulse), else the median of a twig's few pulses, is tried. A pulse of one surface keeps its measured range
    # where nothing fits, as before: moving it would expose a good point to the stray-point rule of ``fused-stray``.
    paired = targets & (mixed.pair[..., 1] > 0)
    quadric = quadric_ranges(range_m, mixed.surfaces, mixed.owner, paired & np.isnan(fitted),
                             WIDE_QUADRIC_FACTOR * radius, noise_m)
    fitted = np.where(np.isnan(fitted) & explains(quadric), quadric, fitted)
    twig = twig_ranges(range_m, mixed.surfaces, mixed.owner, paired & np.isnan(fitted), TWIG_RADIUS_FACTOR * radius)
    return np.where(np.isnan(fitted) & explains(twig), twig, fitted)


def wood_labels(surfaces: np.ndarray, range_m: np.ndarray, theta: np.ndarray, psi: np.ndarray, step_rad: float,
                alpha: np.ndarray | None, min_leaf_width_m: float = MIN_LEAF_WIDTH_M) -> np.ndarray:
    """Which surfaces are wood-shaped: elongated, sparse or narrower than a leaf (index = label; False for 0).

    :func:`leafsfs.canopy.wood_surfaces` and
    :func:`leafsfs.canopy.narrow_surfaces` with the segmentation's default
    thresholds.

    Parameters
    ----------
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    range_m, theta, psi : ndarray, 2-D
        Scan grids (m, rad).
    step_rad : float
        Angle between neighbouring beams, rad.
    alpha : ndarray, 2-D, optional
        Intensity-derived incidence, rad.
    min_leaf_width_m : float
        Narrowest leaf, m.

    Returns
    -------
    ndarray of bool
        Per label.
    """
    return wood_surfaces(surfaces, range_m, theta, psi, step_rad, alpha) | \
        narrow_surfaces(surfaces, range_m, theta, psi, min_leaf_width_m)


def cylinder_ranges(range_m: np.ndarray, cores: np.ndarray, owner: np.ndarray, targets: np.ndarray, step_rad: float,
                    radius_px: float, noise_m: float) -> np.ndarray:
    """Distance of each target pulse's owner surface from the circle across it (NaN where none fits).

    Parameters
    ----------
    range_m : ndarray, 2-D
        Measured ranges, m (NaN = no return).
    cores : ndarray of int, 2-D
        Surface labels of the pulses trusted as pure (0: none), e.g. those
        a little inside their surface.
    owner : ndarray of int, 2-D
        Surface that returned most of each pulse's power (0: unknown): its
        pure pulses and the mixed pulses it dominates, which span the
        branch's silhouette to silhouette.
    targets : ndarray of bool, 2-D
        The pulses to give their owner's circle distance.
    step_rad : float
        Angle between neighbouring beams, rad.
    radius_px : float
        Radius of the neighbourhood whose core pulses fit the depth, pixels.
    noise_m : float
        Range noise, m (sigma).

    Returns
    -------
    ndarray, 2-D
        Range of the owner's circle at each target, m (NaN elsewhere).
    """
    out = np.full(range_m.shape, np.nan)
    for r, c, w, z, dr, dc in _neighbourhoods(range_m, cores, owner, targets, radius_px):
        out[r, c] = _fit(range_m, owner, r, c, w, z, dr, dc, step_rad, noise_m)
    return out


def quadric_ranges(range_m: np.ndarray, cores: np.ndarray, owner: np.ndarray, targets: np.ndarray, radius_px: float,
                   noise_m: float) -> np.ndarray:
    """Distance of each target pulse's owner surface from a quadric of its pure pulses around it (NaN where none fits).

    ``z = a + b x + c y + d x^2 + e x y + f y^2`` (``x``, ``y``: offsets along
    the grid's rows and columns, pixels: the range at the pulse, ``a``, does
    not depend on their unit, and pixels keep the normal equations well
    conditioned) by least squares over the owner's core pulses within
    ``radius_px``; the range at the pulse is ``a``. None where fewer than
    :data:`MIN_QUADRIC_PULSES` pulses enter the fit, its RMS residual (six degrees of freedom spent)
    exceeds :data:`MAX_RESIDUAL_SIGMA` times the noise, or the noise of its
    range at the pulse exceeds :data:`MAX_QUADRIC_SPREAD` times the noise
    (the extrapolation's variance, from the normal equations).

    Parameters
    ----------
    range_m : ndarray, 2-D
        Measured ranges, m (NaN = no return).
    cores : ndarray of int, 2-D
        Surface labels of the pulses trusted as pure (0: none).
    owner : ndarray of int, 2-D
        Surface that returned most of each pulse's power (0: unknown).
    targets : ndarray of bool, 2-D
        The pulses to give their owner's quadric distance.
    radius_px : float
        Radius of the neighbourhood whose core pulses are fitted, pixels.
    noise_m : float
        Range noise, m (sigma).

    Returns
    -------
    ndarray, 2-D
        Range of the owner's quadric at each target, m (NaN elsewhere).
    """
    out = np.full(range_m.shape, np.nan)
    for r, c, w, z, x, y in _neighbourhoods(range_m, cores, owner, targets, radius_px):
        n = w.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            zbar = (w * np.nan_to_num(z)).sum(axis=1) / n
        x, y = x.astype(float), y.astype(float)
        zl = np.where(w > 0, np.nan_to_num(z) - np.nan_to_num(zbar)[:, None], 0.0)
        columns = [np.ones_like(x), x, y, x * x, x * y, y * y]
        coef = _solve(w, columns, zl)
        # The fitted range's standard deviation at the pulse, in noise deviations: sqrt of the first diagonal element
        # of the inverse normal matrix (the solution of the normal equations for the unit vector).
        spread = np.sqrt(np.abs(_solve(w, columns, np.zeros_like(zl), np.eye(len(columns))[0])[:, 0]))
        with np.errstate(invalid="ignore", divide="ignore"):
            residual = zl - sum(coef[:, k, None] * column for k, column in enumerate(columns))
            rms = np.sqrt((w * residual ** 2).sum(axis=1) / (n - len(columns)))
            ok = (n >= MIN_QUADRIC_PULSES) & (rms <= MAX_RESIDUAL_SIGMA * noise_m) & (spread <= MAX_QUADRIC_SPREAD)
        out[r, c] = np.where(ok, zbar + coef[:, 0], np.nan)
    return out


def twig_ranges(range_m: np.ndarray, cores: np.ndarray, owner: np.ndarray, targets: np.ndarray,
                radius_px: float) -> np.ndarray:
    """Median range of the owner's core pulses around each target whose owner has too few of them for a circle.

    A twig a few footprints wide has fewer than :data:`MIN_PULSES` pure
    pulses near its mixed pulses: a plane through them extrapolates their
    noise (and the twig's curvature) over the lever to the pulse, while
    the twig's depth across it varies by no more than its radius (under
    about 5 mm for a twig of 1 cm). Their median is the distance
    (assumption: the twig's axis runs nearly across the beam within the
    neighbourhood, so its range along it varies by less than the noise).

    Parameters
    ----------
    range_m : ndarray, 2-D
        Measured ranges, m (NaN = no return).
    cores : ndarray of int, 2-D
        Surface labels of the pulses trusted as pure (0: none).
    owner : ndarray of int, 2-D
        Surface that returned most of each pulse's power (0: unknown).
    targets : ndarray of bool, 2-D
        The pulses to give their owner's distance.
    radius_px : float
        Radius of the neighbourhood, pixels.

    Returns
    -------
    ndarray, 2-D
        Median range (m) where 1 to ``MIN_PULSES - 1`` core pulses of the owner lie within ``radius_px`` (NaN
        elsewhere: a circle or quadric is fitted there, or none can be).
    """
    out = np.full(range_m.shape, np.nan)
    for r, c, w, z, _, _ in _neighbourhoods(range_m, cores, owner, targets, radius_px):
        n = w.sum(axis=1)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # rows without a pulse: NaN
            median = np.nanmedian(np.where(w > 0, z, np.nan), axis=1)
        out[r, c] = np.where((n >= 1) & (n < MIN_PULSES), median, np.nan)
    return out


def _neighbourhoods(range_m: np.ndarray, cores: np.ndarray, owner: np.ndarray, targets: np.ndarray,
                    radius_px: float):
    """Batches of target pulses with the owner's core pulses within ``radius_px`` of each.

    Yields ``(rows, cols, w, z, dr, dc)``: the targets' pixels, and tables with
    a row per target of weights (1 for a pulse, 0 for padding), ranges (m)
    and pixel offsets from the target, each row's pulses packed to the left
    of tables as wide as the most of them in the batch.
    """
    rows, cols = np.nonzero(targets & (owner > 0))
    h = int(math.ceil(radius_px))
    # Padded images (a core label where a return is, 0 elsewhere, flat; the range) read the discs without bounds
    # checks.
    fitted = np.pad(np.where(np.isfinite(range_m), cores, 0), h)
    fitted = fitted.astype(np.int32).ravel() if fitted.max(initial=0) < 2**31 else fitted.ravel()
    padded = np.pad(range_m, h, constant_values=np.nan)
    dr, dc = np.mgrid[-h:h + 1, -h:h + 1]
    disc = dr ** 2 + dc ** 2 <= radius_px ** 2
    dr, dc = dr[disc], dc[disc]
    width = range_m.shape[1] + 2 * h
    delta = dr * width + dc  # the disc's offsets in the padded images' flat index
    # Targets fitted in order of their count of core pulses, so a batch's neighbourhood tables, holding only those
    # pulses, are about as wide as each row needs (a target's fit does not depend on its batch). The discs are read
    # again per batch: keeping every target's pulses would hold ~70 bytes per pulse of the orchard window.
    def members(r, c):  # each row's owner core pulses in the disc (row, index into the offsets)
        return np.nonzero(fitted[((r + h) * width + c + h)[:, None] + delta] == owner[r, c, None])

    count = np.concatenate([np.bincount(members(rows[i:i + CHUNK], cols[i:i + CHUNK])[0],
                                        minlength=len(rows[i:i + CHUNK])) for i in range(0, len(rows), CHUNK)]
                           or [np.zeros(0, int)])
    order = np.argsort(count, kind="stable")
    widest = count[order]  # ascending: a batch's tables are as wide as its last target's pulses
    start = 0
    while start < len(rows):
        end = min(start + CHUNK, len(rows))
        while end - start > 1 and (end - start) * widest[end - 1] > TABLE_CELLS:
            end = start + (end - start) // 2
        batch, start = order[start:end], end
        r, c = rows[batch], cols[batch]
        ti, tj = members(r, c)
        per_row = np.bincount(ti, minlength=len(r))
        slot = np.arange(len(ti)) - (np.cumsum(per_row) - per_row)[ti]
        shape = (len(r), int(per_row.max(initial=0)))
        w, z = np.zeros(shape), np.full(shape, np.nan)
        w[ti, slot] = 1.0
        z[ti, slot] = padded[r[ti] + dr[tj] + h, c[ti] + dc[tj] + h]
        tdr, tdc = np.zeros(shape, dtype=int), np.zeros(shape, dtype=int)
        tdr[ti, slot], tdc[ti, slot] = dr[tj], dc[tj]
        yield r, c, w, z, tdr, tdc


def _take(image: np.ndarray, rows: np.ndarray, cols: np.ndarray, fill):
    """``image[rows, cols]`` with ``fill`` outside the image (integer indices of any shape)."""
    inside = (rows >= 0) & (rows < image.shape[0]) & (cols >= 0) & (cols < image.shape[1])
    value = image[np.clip(rows, 0, image.shape[0] - 1), np.clip(cols, 0, image.shape[1] - 1)]
    return np.where(inside, value, fill)


def _fit(range_m, owner, rows, cols, w, z, dr, dc, step_rad, noise_m):
    """Circle-profile ranges at the pulses ``(rows, cols)`` from the tables of their owner's core pulses
    (:func:`_neighbourhoods`: weights, ranges, pixel offsets)."""
    label = owner[rows, cols]
    n = w.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mr, mc = (w * dr).sum(axis=1) / n, (w * dc).sum(axis=1) / n
        norm = np.hypot(mr, mc)
        nr, nc = np.nan_to_num(mr / norm), np.nan_to_num(mc / norm)
        zbar = (w * np.nan_to_num(z)).sum(axis=1) / n
    spacing = zbar * step_rad
    # The owner's extent across the branch through the pulse, pixels: silhouette to silhouette.
    reach = int(math.ceil(2 * MAX_RADIUS_M / max(float(np.nanmin(spacing, initial=np.inf)), 1e-6))) + 1
    reach = min(reach, 4 * max(range_m.shape))
    steps = np.arange(1, reach + 1)
    ends = []
    for sign in (1, -1):
        sr = np.rint(rows[:, None] + sign * steps * nr[:, None]).astype(int)
        sc = np.rint(cols[:, None] + sign * steps * nc[:, None]).astype(int)
        owned = _take(owner, sr, sc, 0) == label[:, None]
        first = np.where(owned.all(axis=1), reach, np.argmin(owned, axis=1))  # owned steps before leaving
        beyond = _take(range_m, sr[np.arange(len(rows)), np.minimum(first, reach - 1)],
                       sc[np.arange(len(rows)), np.minimum(first, reach - 1)], np.nan)
        # The branch ends at a silhouette: beyond it no return or something farther (not a nearer occluder).
        silhouette = (first < reach) & ~(beyond < zbar - 3 * noise_m)
        ends.append((first + 0.5, silhouette))
    (far, far_ok), (near, near_ok) = ends
    radius = 0.5 * (far + near) * spacing
    x0 = 0.5 * (far - near) * spacing  # the branch's axis, m from the pulse towards the surface
    out = np.full(len(rows), np.nan)
    # Only pulses that can pass the tests below are fitted (the fits are per row: the same values for them).
    fit = (n >= MIN_PULSES) & (norm > 0) & far_ok & near_ok & (radius <= MAX_RADIUS_M)
    if not fit.any():
        return out
    nr, nc, spacing, radius, x0, zbar, n, w, z, dr, dc = (a[fit] for a in (nr, nc, spacing, radius, x0, zbar, n, w, z,
                                                                           dr, dc))
    x = (dr * nr[:, None] + dc * nc[:, None]) * spacing[:, None]
    y = (-dr * nc[:, None] + dc * nr[:, None]) * spacing[:, None]
    zl = np.where(w > 0, np.nan_to_num(z) - zbar[:, None], 0.0)
    with np.errstate(invalid="ignore"):
        depth = np.sqrt(np.clip(radius[:, None] ** 2 - (x - x0[:, None]) ** 2, 0, None))
    # z = D - s depth + g y: the axis' depth D and the slope g along the branch; the ellipse's stretch
    # s = sqrt(1 + g^2).
    g = _solve(w, [np.ones_like(x), -depth, y], zl)[:, 2]
    s = np.sqrt(1 + np.nan_to_num(g) ** 2)
    d, g = _solve(w, [np.ones_like(x), y], zl + s[:, None] * depth).T
    with np.errstate(invalid="ignore"):
        residual = zl - (d[:, None] - s[:, None] * depth + g[:, None] * y)
        rms = np.sqrt((w * residual ** 2).sum(axis=1) / n)
        ok = rms <= MAX_RESIDUAL_SIGMA * noise_m
    # A flat surface (a leaf, several leaves joined) fits a plane better than the circle of its width: plane kept
    # (judged on at least MIN_FLAT_TEST pulses).
    plane = _solve(w, [np.ones_like(x), x, y], zl)
    with np.errstate(invalid="ignore"):
        flat = plane[:, 0, None] + plane[:, 1, None] * x + plane[:, 2, None] * y
        ok &= (rms < np.sqrt((w * (zl - flat) ** 2).sum(axis=1) / n)) | (n < MIN_FLAT_TEST)
        at = d - s * np.sqrt(np.clip(radius ** 2 - x0 ** 2, 0, None))
    out[fit] = np.where(ok, zbar + at, np.nan)
    return out


def _solve(w: np.ndarray, columns: list, rhs: np.ndarray, moment: np.ndarray | None = None) -> np.ndarray:
    """Weighted least squares per row: the coefficients (rows, k) of ``columns`` fitting ``rhs`` (NaN if singular);
    with ``moment`` (k,), the solution of the normal equations for that right-hand side instead."""
    design = np.stack(columns, axis=-1)  # (n, m, k)
    normal = np.einsum("nm,nmi,nmj->nij", w, design, design)
    moment = np.einsum("nm,nmi,nm->ni", w, design, rhs) if moment is None else np.broadcast_to(moment, normal.shape[:2])
    out = np.full(moment.shape, np.nan)
    with np.errstate(invalid="ignore"):
        good = np.abs(np.linalg.det(normal)) > 1e-30
    if good.any():
        out[good] = np.linalg.solve(normal[good], moment[good][..., None])[..., 0]
    return out

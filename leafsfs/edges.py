"""Mixed pulses at object edges: which surfaces share a footprint, in what proportion, and who owns the pulse.

A phase-shift scanner returns, for a footprint split between two surfaces,
the power-weighted mean of their distances (the phasor sum of thesis ch.1
§2.3, nearly linear for separations far below the ambiguity interval:
1 m bends it by 0.1 % at the LS880-class 2 MHz). Given the distances
``r_a`` and ``r_b`` that the two surfaces would have at that pulse, the
measured range ``r`` gives the power share of surface ``a``:
``w = (r - r_b) / (r_a - r_b)``, with a precision of ``sigma_r / |r_a -
r_b|`` (0.2 % for a leaf 1 m in front of a wall, 10 % for two leaves 2 cm
apart).

The surfaces are the large linked components of the range image (the
pulses that :func:`leafsfs.leaves.link_components` joins by plausible
steps). Their distances at a mixed pulse are extrapolated from a local
least-squares plane of their own pulses nearest to it, a third of the band
inside their border (the outermost pulses of a surface may still hold a
little of the other one). A pulse's pair of surfaces is the nearest pair (in
pixels) whose extrapolated distances bracket the measured one; a pulse
within the range noise of a surface is that surface's own instead, unless
that pair gives most of its power to another surface. The pulse
belongs to the surface that returned most of its power (``w >= 0.5``):
that is the surface the issue's outlier definition judges it against, and
the one whose distance it should be given.

The *geometric* share of the footprint (what a leaf area needs) differs
from the power share when the two surfaces return different powers per
unit of beam: ``f = w a_b / (w a_b + (1 - w) a_a)`` with ``a`` the pure
returns' amplitudes, ``a_a / a_b = exp((I_a - I_b) / k)`` from the pure
intensities of a log-amplified scanner of gain ``k`` DN per e-fold
(tls-physics §2.3, §7.3). :func:`geometric_share` does that conversion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from leafsfs.grid import PixelGrid, local_planes_of

#: Candidate surfaces kept per mixed pulse (the nearest ones). In a canopy the nearest few are often pieces of
#: twigs and hidden leaves all in front of (or all behind) the pulse, none of whose pairs brackets its range, while
#: the surface behind the edge comes next: 8 candidates pair more mixed pulses than 4 (800 x 800 crops of the leafy
#: tree and of pear seed 7 at 0.018 deg: ROP reduction 3 sigma +0.013 / +0.004, 1 cm +0.018 / +0.010).
MAX_CANDIDATES = 8


@dataclass
class MixedPulses:
    """Attribution of the mixed pulses of a scan to the pairs of surfaces they straddle.

    Attributes
    ----------
    surfaces : ndarray of int, 2-D
        Surface label of every pure pulse (0: none, i.e. mixed or no return).
    pair : ndarray of int, (rows, cols, 2)
        The two surfaces a mixed pulse straddles; ``(label, 0)`` for a pulse
        within the range noise of one surface, ``(0, 0)`` where none was found.
    share : ndarray, 2-D
        Power share of ``pair[..., 0]`` (1 for a pulse of one surface, NaN
        where none was found).
    pair_range : ndarray, (rows, cols, 2)
        Distances of the two surfaces extrapolated to the pulse, m.
    pair_intensity : ndarray, (rows, cols, 2)
        Intensities of the two surfaces' pure pulses extrapolated to the
        pulse, DN (NaN without an intensity image).
    owner : ndarray of int, 2-D
        Surface that returned most of the pulse's power: ``surfaces`` on pure
        pulses, the dominant member of the pair on mixed ones, 0 where unknown.
    thin : ndarray of bool, 2-D
        Mixed pulses of a thin part attached to a surface (a petiole): paired
        with that surface beyond the band, at the distance where the part is
        attached (``reach_px`` of :func:`attribute_mixed`). They are no part
        of that surface (:meth:`share_of` gives them 0).
    """

    surfaces: np.ndarray
    pair: np.ndarray
    share: np.ndarray
    pair_range: np.ndarray
    pair_intensity: np.ndarray
    owner: np.ndarray
    thin: np.ndarray

    @property
    def straddling(self) -> np.ndarray:
        """Pulses whose range is not that of one surface: between two of them, or near none (and no-return pixels)."""
        return (self.surfaces == 0) & ((self.pair[..., 1] > 0) | (self.pair[..., 0] == 0))

    def share_of(self, label: int, gain_dn: float | None = None, box: tuple | None = None) -> np.ndarray:
        """Share of surface ``label`` of every pulse (1 on its pure pulses, 0 where it is absent).

        The power share; with the log amplifier's ``gain_dn`` the geometric
        share of the footprint (:func:`geometric_share`). With ``box`` (a
        pair of slices) only the pulses of that window, in its shape.

        Parameters
        ----------
        label : int
            Surface label.
        gain_dn : float, optional
            Log-amplifier gain, DN per e-fold (None: the power share).
        box : tuple of slice, optional
            Window of the scan grid (None: the whole grid).

        Returns
        -------
        ndarray of float, 2-D
            Share in [0, 1] per pulse.
        """
        box = box or (slice(None), slice(None))
        share = (self.surfaces[box] == label).astype(float)
        pair, thin = self.pair[box], self.thin[box]
        for member, other, fraction in ((0, 1, self.share[box]), (1, 0, 1.0 - self.share[box])):
            sel = (pair[..., member] == label) & ~thin
            value = fraction[sel]
            if gain_dn is not None:
                value = geometric_share(value, self.pair_intensity[box][..., member][sel],
                                        self.pair_intensity[box][..., other][sel], gain_dn)
            share[sel] = value
        return share

    def extents(self) -> dict[int, tuple]:
        """Per surface label, the window (pair of slices) holding its pulses and the mixed pulses paired with it."""
        out = {}
        for image in (self.surfaces, self.pair[..., 0], self.pair[..., 1]):
            for k, box in enumerate(ndimage.find_objects(image), start=1):
                if box is not None:
                    old = out.get(k, box)
                    out[k] = tuple(slice(min(a.start, b.start), max(a.stop, b.stop)) for a, b in zip(old, box))
        return out

    def owner_range(self) -> np.ndarray:
        """Distance of each mixed pulse's owner surface extrapolated to it, m (NaN where no pair was found)."""
        first = np.nan_to_num(self.share, nan=1.0) >= 0.5
        return np.where(first, self.pair_range[..., 0], self.pair_range[..., 1])

    def single_range(self) -> np.ndarray:
        """Distance of the one surface within whose range noise a pulse of no surface lies, extrapolated to it, m.

        NaN on the pure pulses of a surface, on the pulses paired with two
        surfaces or with none, and on a thin part's pulses.
        """
        single = (self.surfaces == 0) & (self.pair[..., 0] > 0) & (self.pair[..., 1] == 0) & ~self.thin
        return np.where(single, self.pair_range[..., 0], np.nan)


def attribute_mixed(range_m: np.ndarray, surfaces: np.ndarray, band_px: int, intensity: np.ndarray | None = None,
                    *, radius_px: float = 8.0, tolerance_m: float = 0.006, reach_px: int = 0) -> MixedPulses:
    """Find the two surfaces each mixed pulse straddles and the power share of each.

    Parameters
    ----------
    range_m : ndarray, 2-D
        Measured ranges, m (NaN = no return).
    surfaces : ndarray of int, 2-D
        Pure pulses labelled by surface (1..K; 0 = mixed or none).
    band_px : int
        How far from a surface (pixels) its mixed pulses may lie.
    intensity : ndarray, 2-D, optional
        Intensities, DN: the pure intensities of the two surfaces are
        extrapolated to each mixed pulse as well (for :func:`geometric_share`).
    radius_px : float
        Radius of the local planes extrapolating a surface's distances, pixels (at least ``band_px``).
    tolerance_m : float
        How far outside the two surfaces' distances a measured range may lie
        (range noise), m.
    reach_px : int
        How far along a thin part attached to a surface (pixels) its mixed
        pulses may lie (0: not looked for). A part narrower than the
        footprint, such as a petiole, has no pure pulse: every pulse mixes
        it with what lies behind, and no pair of surfaces within the band
        brackets them. Such a pulse is paired, where a pair brackets it,
        with the surfaces its 8-connected run of mixed pulses touches up to
        ``reach_px`` away, the far one at the distance of its nearest core
        pulse (where the part is attached: the thin part's own distance is
        unknown); these pulses are flagged ``thin``. Such a pulse keeps no
        pair unless a chain of pulses its owner shares joins it to that
        owner's pure pulses (:func:`attached`).

    Returns
    -------
    MixedPulses
    """
    valid = np.isfinite(range_m)
    mixed = valid & (surfaces == 0)
    band = int(band_px)
    out = _empty(surfaces)
    if not surfaces.any():
        return out
    # Surfaces are extrapolated from their pulses at least `margin` pixels inside: their outermost pulses can
    # still hold a little of the other surface's power (steps within the noise link them).
    images = _Images(range_m, intensity, surfaces, _cores(surfaces, band, max(1, band // 3)))
    # A surface is extrapolated up to the band's width from its cores: planes fitted over less than that width
    # multiply their slope error by the lever (near leaves have bands of tens of pixels).
    radius_px = max(float(radius_px), float(band))
    # A footprint's share of a surface falls from all to nothing within about two 1/e^2 radii of its edge (the band
    # is three radii, see band_pixels): a mixed pulse lies no farther than two radii from a pulse that is not mixed
    # (a surface's, or a no-return). Unlinked pulses deeper inside a run of them are the pure pulses of a piece too
    # small to be a surface (a leaf mostly hidden): no pair explains them, they keep their measured distance.
    mixed &= ndimage.distance_transform_edt(mixed) <= max(1.0, 2 * band / 3)
    _store(out, _attribute(images, mixed, reach_px=band, band_px=band, radius_px=radius_px, tolerance_m=tolerance_m))
    if reach_px > band:
        unresolved = mixed & (out.pair[..., 0] == 0)
        runs, _ = ndimage.label(mixed, structure=np.ones((3, 3), bool))
        # (run, surface) pairs that touch: a run's pulses next to a surface's pulses.
        grown = ndimage.grey_dilation(runs, size=(3, 3))
        touching = np.unique(grown[surfaces > 0].astype(np.int64) * (surfaces.max() + 1) + surfaces[surfaces > 0])
        keys = runs.astype(np.int64) * (surfaces.max() + 1)
        _store(out, _attribute(images, unresolved, reach_px=int(reach_px), band_px=band, radius_px=radius_px,
                               tolerance_m=tolerance_m,
                               allowed=lambda pixel, k: _member(keys.ravel()[pixel] + k, touching)))
        out.thin = unresolved & (out.pair[..., 0] > 0)  # the pulses that only the second pass paired
        _unpair(out, out.thin & ~attached(out))
    return out


def _member(values: np.ndarray, sorted_set: np.ndarray) -> np.ndarray:
    """``np.isin(values, sorted_set)`` for a sorted array without duplicates (a binary search, no sort per call)."""
    at = np.minimum(np.searchsorted(sorted_set, values), max(len(sorted_set) - 1, 0))
    return sorted_set[at] == values if len(sorted_set) else np.zeros(len(values), bool)


def attached(mixed: MixedPulses) -> np.ndarray:
    """Thin-part pulses joined to a pure pulse of their owner surface by a chain of pulses that surface shares.

    A thin part (a petiole) leaves its surface: the pulses along it, from
    the surface's pure pulses on, are all paired with that surface (8-connected).
    A pulse paired beyond the band whose owner it is not joined to that way
    is not a part attached there; its pair is a guess (on a canopy it is
    mostly a piece of a leaf that has no surface of its own, given to a
    surface several footprints away).

    Parameters
    ----------
    mixed : MixedPulses
        Mixed pulses with their pairs, owners and ``thin`` flags.

    Returns
    -------
    ndarray of bool, 2-D
        The ``thin`` pulses so joined to their owner.
    """
    out = np.zeros(mixed.owner.shape, dtype=bool)
    boxes = mixed.extents()
    for k in np.unique(mixed.owner[mixed.thin]):
        box = boxes[int(k)]
        own = mixed.surfaces[box] == k
        chain, _ = ndimage.label(own | (mixed.pair[box] == k).any(axis=-1), structure=np.ones((3, 3), bool))
        rooted = np.unique(chain[own])
        out[box] |= mixed.thin[box] & (mixed.owner[box] == k) & np.isin(chain, rooted[rooted > 0])
    return out


def _unpair(out: MixedPulses, pulses: np.ndarray) -> None:
    """Leave ``pulses`` without a pair (they keep their measured distance)."""
    out.pair[pulses] = 0
    out.pair_range[pulses] = np.nan
    out.pair_intensity[pulses] = np.nan
    out.share[pulses] = np.nan
    out.owner[pulses] = 0
    out.thin &= ~pulses


def _cores(surfaces: np.ndarray, band: int, margin: int) -> np.ndarray:
    """Surface labels of the pulses more than ``margin`` pixels inside their surface (all of a sliver's)."""
    shape = surfaces.shape
    cores = np.zeros(shape, dtype=int)
    for k, box in enumerate(ndimage.find_objects(surfaces), start=1):
        if box is None:
            continue
        box = tuple(slice(max(s.start - band, 0), min(s.stop + band, n)) for s, n in zip(box, shape))
        inside = surfaces[box] == k
        core = ndimage.distance_transform_edt(inside) > margin
        cores[box][core if core.sum() >= 3 else inside] = k
    return cores


@dataclass
class _Images:
    """The images :func:`_attribute` reads.

    Attributes
    ----------
    range_m : ndarray, 2-D
        Measured ranges, m (NaN = no return).
    intensity : ndarray, 2-D, or None
        Intensities, DN.
    surfaces : ndarray of int, 2-D
        Pure pulses labelled by surface (0 = mixed or none).
    cores : ndarray of int, 2-D
        Surface labels of the pulses well inside their surface (:func:`_cores`).
    """

    range_m: np.ndarray
    intensity: np.ndarray | None
    surfaces: np.ndarray
    cores: np.ndarray


@dataclass
class _Pairs:
    """The pairs of surfaces found for some pulses (one row per pulse).

    Attributes
    ----------
    pixel : ndarray of int, (n,)
        Flat pixel indices of the pulses.
    pair : ndarray of int, (n, 2)
        The two surfaces (``(label, 0)`` for a pulse of one surface).
    pair_range : ndarray, (n, 2)
        The surfaces' distances extrapolated to the pulse, m.
    pair_intensity : ndarray, (n, 2)
        The surfaces' intensities extrapolated to the pulse, DN.
    share : ndarray, (n,)
        Power share of ``pair[:, 0]``.
    owner : ndarray of int, (n,)
        The member that returned most of the power.
    """

    pixel: np.ndarray
    pair: np.ndarray
    pair_range: np.ndarray
    pair_intensity: np.ndarray
    share: np.ndarray
    owner: np.ndarray


def _store(out: MixedPulses, pairs: _Pairs) -> None:
    """Enter ``pairs`` into the per-pulse images of ``out`` (at their pixels; the rest is left as it is)."""
    rows, cols = np.divmod(pairs.pixel, out.share.shape[1])
    out.pair[rows, cols] = pairs.pair
    out.pair_range[rows, cols] = pairs.pair_range
    out.pair_intensity[rows, cols] = pairs.pair_intensity
    out.share[rows, cols] = pairs.share
    out.owner[rows, cols] = pairs.owner


def _attribute(images: _Images, targets: np.ndarray, *, reach_px: int, band_px: int, radius_px: float,
               tolerance_m: float, allowed=None) -> _Pairs:
    """Pair the ``targets`` pulses with surfaces up to ``reach_px`` pixels away.

    A surface's distance (and intensity) at a pulse is the local plane around
    its nearest core pulse up to ``band_px`` pixels away, that pulse's own value
    beyond.

    Parameters
    ----------
    images : _Images
        Ranges (m), intensities (DN), surfaces and their cores.
    targets : ndarray of bool, 2-D
        The pulses to pair.
    reach_px : int
        How far from a surface its candidate pulses may lie, pixels.
    band_px : int
        Up to how far (pixels) a surface's distance is extrapolated by its local plane.
    radius_px : float
        Radius of the local planes, pixels.
    tolerance_m : float
        How far outside the two surfaces' distances a measured range may lie, m.
    allowed : callable, optional
        ``allowed(pixels, k)`` (flat pixel indices, surface label) vetoes candidates.

    Returns
    -------
    _Pairs
        The pulses for which a pair was found.
    """
    range_m, surfaces, cores = images.range_m, images.surfaces, images.cores
    shape = range_m.shape
    pixel, label, gap, source = [], [], [], []
    for k, box in enumerate(ndimage.find_objects(surfaces), start=1):
        if box is None:
            continue
        box = tuple(slice(max(s.start - reach_px, 0), min(s.stop + reach_px, n)) for s, n in zip(box, shape))
        distance = ndimage.distance_transform_edt(surfaces[box] != k)
        near = targets[box] & (distance <= reach_px)
        if not near.any():
            continue
        ii, jj = ndimage.distance_transform_edt(cores[box] != k, return_distances=False, return_indices=True)
        rows, cols = np.nonzero(near)
        flat = (rows + box[0].start) * shape[1] + cols + box[1].start
        keep = allowed(flat, k) if allowed is not None else np.ones(len(flat), bool)
        pixel.append(flat[keep])
        source.append(((ii[near] + box[0].start) * shape[1] + jj[near] + box[1].start)[keep])
        label.append(np.full(keep.sum(), k))
        gap.append(distance[near][keep])
    if not sum(len(p) for p in pixel):
        return _Pairs(np.zeros(0, int), np.zeros((0, 2), int), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0),
                      np.zeros(0, int))
    pixel, label, gap, source = map(np.concatenate, (pixel, label, gap, source))
    extrapolated = np.full((len(pixel), 2), np.nan)  # range, intensity
    by_label = np.argsort(label, kind="stable")
    bounds = np.flatnonzero(np.r_[True, np.diff(label[by_label]) != 0, True])
    present = [(column, image) for column, image in enumerate((range_m, images.intensity)) if image is not None]
    for start, stop in zip(bounds[:-1], bounds[1:]):
        sel = by_label[start:stop]
        values = _extrapolate([image for _, image in present], cores, int(label[sel[0]]), source[sel], pixel[sel],
                              radius_px)
        for (column, image), value in zip(present, values):
            extrapolated[sel, column] = np.where(gap[sel] <= band_px, value, image.flat[source[sel]])
    keep = np.isfinite(extrapolated[:, 0])
    order = np.lexsort((gap[keep], pixel[keep]))
    pixel, label, gap, extrapolated = (a[keep][order] for a in (pixel, label, gap, extrapolated))
    starts = np.flatnonzero(np.r_[True, pixel[1:] != pixel[:-1]])
    rank = np.arange(len(pixel)) - np.repeat(starts, np.diff(np.r_[starts, len(pixel)]))
    keep = rank < MAX_CANDIDATES
    pixel, label, gap, extrapolated, rank = (a[keep] for a in (pixel, label, gap, extrapolated, rank))
    # Candidates per pixel as (n, MAX_CANDIDATES) tables.
    unique, slot = np.unique(pixel, return_inverse=True)
    n = len(unique)
    lab = np.zeros((n, MAX_CANDIDATES), int)
    dist = np.full((n, MAX_CANDIDATES), np.inf)
    values = np.full((n, MAX_CANDIDATES, 2), np.nan)
    lab[slot, rank], dist[slot, rank], values[slot, rank] = label, gap, extrapolated
    rng = values[..., 0]
    measured = range_m.ravel()[unique]
    # The two candidates of each pulse (-1: none), first the nearest bracketing pair.
    choice = np.full((n, 2), -1)
    best = np.full(n, np.inf)
    for a in range(MAX_CANDIDATES):
        for b in range(a + 1, MAX_CANDIDATES):
            lo, hi = np.fmin(rng[:, a], rng[:, b]), np.fmax(rng[:, a], rng[:, b])
            with np.errstate(invalid="ignore"):
                brackets = (measured >= lo - tolerance_m) & (measured <= hi + tolerance_m) \
                    & (hi - lo > tolerance_m)
            cost = dist[:, a] + dist[:, b]
            better = brackets & (cost < best)
            best[better] = cost[better]
            choice[better] = (a, b)
    # A pulse within the noise of a surface is that surface's own (the nearest such one), unless the nearest pair
    # bracketing it gives most of its power to another surface: a pulse on the far side of a leaf's edge mixed with a
    # branch behind can fall within the noise of a third surface's (another leaf's, another branch piece's) plane
    # extrapolated across the gap, while the pair beside it explains its range.
    with np.errstate(invalid="ignore"):
        close = np.abs(measured[:, None] - rng) <= tolerance_m
    nearest = np.argmax(close, axis=1)
    alone = close.any(axis=1) & ~_dominated_elsewhere(lab, rng, measured, choice, nearest)
    choice[alone] = np.stack([nearest[alone], np.full(alone.sum(), -1)], axis=1)
    rows = np.arange(n)[:, None]
    pair = np.where(choice >= 0, lab[rows, choice], 0)
    picked = np.where((choice >= 0)[..., None], values[rows, choice], np.nan)
    found = pair[:, 0] > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.where(pair[:, 1] > 0, (measured - picked[:, 1, 0]) / (picked[:, 0, 0] - picked[:, 1, 0]), 1.0)
    share = np.clip(share, 0.0, 1.0)
    unique, pair, picked, share = unique[found], pair[found], picked[found], share[found]
    return _Pairs(unique, pair, picked[..., 0], picked[..., 1], share, np.where(share >= 0.5, pair[:, 0], pair[:, 1]))


def _dominated_elsewhere(label: np.ndarray, range_m: np.ndarray, measured: np.ndarray, choice: np.ndarray,
                         candidate: np.ndarray) -> np.ndarray:
    """Pulses whose chosen bracketing pair gives most of their power to a surface other than ``candidate``'s.

    Parameters
    ----------
    label : ndarray of int, (n, k)
        Candidate surfaces of each pulse.
    range_m : ndarray, (n, k)
        Their distances extrapolated to the pulse, m.
    measured : ndarray, (n,)
        The pulses' ranges, m.
    choice : ndarray of int, (n, 2)
        Columns of the bracketing pair (-1: none).
    candidate : ndarray of int, (n,)
        Column of the surface tested.

    Returns
    -------
    ndarray of bool, (n,)
        True where a pair brackets the pulse and its dominant member (power share at least one half) is not
        ``label[candidate]``.
    """
    rows = np.arange(len(measured))
    a, b = np.maximum(choice[:, 0], 0), np.maximum(choice[:, 1], 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        share = (measured - range_m[rows, b]) / (range_m[rows, a] - range_m[rows, b])
    dominant = np.where(share >= 0.5, label[rows, a], label[rows, b])
    return (choice[:, 1] >= 0) & (dominant != label[rows, candidate])


def _empty(surfaces: np.ndarray) -> MixedPulses:
    shape = surfaces.shape
    return MixedPulses(surfaces.copy(), np.zeros((*shape, 2), int), np.full(shape, np.nan),
                       np.full((*shape, 2), np.nan), np.full((*shape, 2), np.nan), surfaces.copy(),
                       np.zeros(shape, bool))


def _extrapolate(images: list, cores: np.ndarray, label: int, source: np.ndarray, target: np.ndarray,
                 radius_px: float) -> list:
    """Values of each image at ``target`` pixels from the local planes of the core pulses of surface ``label``
    around their ``source`` pixels (flat indices); only the window around the sources is read."""
    cols = cores.shape[1]
    unique, inverse = np.unique(source, return_inverse=True)
    centres = np.stack(np.divmod(unique, cols), axis=1)
    r = int(np.ceil(radius_px))
    low = np.maximum(centres.min(axis=0) - r, 0)
    high = np.minimum(centres.max(axis=0) + r + 1, cores.shape)
    window = (slice(low[0], high[0]), slice(low[1], high[1]))
    offset = np.stack(np.divmod(target, cols), axis=1) - centres[inverse]
    values = []
    for image, planes in zip(images, local_planes_of([image[window] for image in images], cores[window] == label,
                                                     PixelGrid(), centres - low, radius_px, spread=False)):
        value = planes.height[inverse] + np.sum(planes.gradient[inverse] * offset, axis=1)
        # Too few pixels for a plane (a sliver): the nearest pixel's value.
        values.append(np.where(np.isfinite(value), value, image.flat[source]))
    return values


def bracketed(range_m: np.ndarray, band_px: int, tolerance_m: float) -> np.ndarray:
    """Pulses whose range lies between those of two other pulses within the band, by more than the noise on each side.

    A pulse that mixes two surfaces returns a distance between theirs, and
    both surfaces have pulses within a footprint or two of it: within
    ``band_px`` (a square of side ``2 band_px + 1``) there is a pulse nearer
    and one farther by more than ``tolerance_m``. That is the range's proof
    that a pulse is mixed; a pure pulse on the far side of an edge has no
    farther pulse beside it, one on the near side no nearer one. A pure
    pulse of a piece lying between a nearer and a farther surface passes the
    test as well (the test cannot tell it from a mixed one).

    Parameters
    ----------
    range_m : ndarray, 2-D
        Measured ranges, m (NaN = no return).
    band_px : int
        Half the side of the square searched, pixels.
    tolerance_m : float
        Range difference that counts, m (the range noise's bound).

    Returns
    -------
    ndarray of bool, 2-D
        The bracketed pulses (False where there is no return).
    """
    size = 2 * int(band_px) + 1
    valid = np.isfinite(range_m)
    nearest = ndimage.minimum_filter(np.where(valid, range_m, np.inf), size=size, mode="nearest")
    farthest = ndimage.maximum_filter(np.where(valid, range_m, -np.inf), size=size, mode="nearest")
    with np.errstate(invalid="ignore"):
        return valid & (range_m - nearest > tolerance_m) & (farthest - range_m > tolerance_m)


def band_pixels(band_m: float, range_m: np.ndarray, surfaces: np.ndarray, step_rad: float) -> int:
    """``band_m`` in pixels at the nearest surface's median range (at least 2).

    A mixed pulse lies within about a footprint of the edge of the surface
    in front, whose distance sets the footprint's size in pixels; the
    nearest surface gives the widest band (the bracketing test of
    :func:`attribute_mixed` keeps far surfaces from claiming unrelated pulses).

    Parameters
    ----------
    band_m : float
        Band width, m.
    range_m : ndarray, 2-D
        Ranges, m.
    surfaces : ndarray of int, 2-D
        Surface labels (0: none).
    step_rad : float
        Angular step of the scan grid, rad.

    Returns
    -------
    int
        Band width, pixels (at least 2).
    """
    if not surfaces.any():
        return 2
    # Per-surface medians from one sort by (surface, range) (the lower middle value for an even count).
    inside = surfaces > 0
    label, value = surfaces[inside], range_m[inside]
    order = np.lexsort((value, label))
    label, value = label[order], value[order]
    starts = np.flatnonzero(np.r_[True, label[1:] != label[:-1]])
    counts = np.diff(np.r_[starts, len(label)])
    upper, lower = value[starts + counts // 2], value[starts + (counts - 1) // 2]
    nearest = float(np.min(0.5 * (upper + lower)))
    return max(2, int(math.ceil(band_m / (nearest * step_rad))))


def geometric_share(power_share: np.ndarray, intensity_a: np.ndarray, intensity_b: np.ndarray,
                    gain_dn: float) -> np.ndarray:
    """Geometric footprint share of surface ``a`` from its power share and the pure intensities of ``a`` and ``b``.

    ``f = w / (w + (1 - w) q)`` with ``q = exp((I_a - I_b) / gain_dn)`` the
    amplitude ratio of the pure returns (module docstring). Where an
    intensity is unknown (NaN) the power share is returned.

    Parameters
    ----------
    power_share : ndarray
        Share of the returned power from surface ``a``, in [0, 1].
    intensity_a, intensity_b : ndarray
        Intensities of pure returns of surfaces ``a`` and ``b``, DN.
    gain_dn : float
        Log-amplifier gain, DN per e-fold.

    Returns
    -------
    ndarray
        Geometric share of ``a``'s footprint, in [0, 1].
    """
    q = np.exp((np.asarray(intensity_a, float) - np.asarray(intensity_b, float)) / gain_dn)
    w = np.asarray(power_share, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        f = w / (w + (1.0 - w) * q)
    return np.where(np.isfinite(f), f, w)

"""Recursive watershed of the quantised alpha image into parts with one seed each (thesis ch.5 §2, Fig. 2).

Starting from the whole object at the outermost level ``n``, every part ``r``
is split by a watershed of the smoothed alpha image whose markers are the
connected components of ``r`` within the max-alpha domain ``s_0 ∪ ... ∪
s_(i-1)``; the children are split again one level down, until the markers are
the seeds (level 0). Each final part holds one seed, and its chain is the
sequence of its iso-alpha domains from the seed outward.

Parts without a seed ("orphans": a local alpha minimum above ``alpha_0``,
digest A22) are merged into the neighbouring part with which they share the
longest border (default), or keep their own lowest domain as an extra seed
(``orphans="seed"``). Isolated orphans (a separate piece of the object) always
keep their own seed.

A seed component that the 3 x 3 opening of the curve extraction
(:func:`leafsfs.contour.open_region`, thesis App. III §2.1) cuts into several
pieces (blocks joined only by 1-2 px strips) gives one marker per piece, so
that every piece seeds a part of its own; otherwise only one piece would be a
seed and the others would be reached through the walls around them. The strip
pixels go to the pieces' parts through the watershed.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from skimage.segmentation import watershed

from leafsfs.contour import open_region

_EIGHT = np.ones((3, 3), dtype=bool)


def split_parts(alpha: np.ndarray, levels: np.ndarray, min_seed_px: int = 4, orphans: str = "merge") -> np.ndarray:
    """Partition the object into parts with one seed each.

    Parameters
    ----------
    alpha : ndarray, 2-D
        Smoothed alpha image (rad), the watershed relief.
    levels : ndarray of int, 2-D
        Domain index per pixel (:func:`leafsfs.quantize.assign_levels`), -1 off the object.
    min_seed_px : int
        Seed components smaller than this are not used as markers.
    orphans : {"merge", "seed"}
        What to do with parts that received no seed (see the module docstring).

    Returns
    -------
    ndarray of int, 2-D
        Part label per pixel, 1..K, 0 off the object.
    """
    mask = levels >= 0
    top = int(levels.max()) if mask.any() else 0
    parts = [mask]
    for level in range(top, 0, -1):
        children = []
        for region in parts:
            markers, count = ndimage.label(region & (levels < level), structure=_EIGHT)
            if level == 1 and count:
                sizes = ndimage.sum(region, markers, np.arange(1, count + 1))
                small = np.isin(markers, 1 + np.nonzero(sizes < min_seed_px)[0])
                markers, count = _opened_pieces(np.where(small, 0, markers))
            if count <= 1:
                children.append(region)
                continue
            split = watershed(alpha, markers, mask=region, connectivity=2)
            children.extend(split == k for k in range(1, count + 1))
        parts = children
    labels = np.zeros(levels.shape, dtype=int)
    for k, region in enumerate(parts, start=1):
        labels[region] = k
    return _resolve_orphans(labels, levels, min_seed_px, orphans)


def _opened_pieces(markers: np.ndarray) -> tuple[np.ndarray, int]:
    """Relabel seed markers so that a component cut into several pieces by the 3 x 3 opening gives one per piece
    (the strips between them unlabelled); a component that the opening keeps whole or removes stays as it is."""
    out = np.zeros_like(markers)
    count = 0
    for k, box in enumerate(ndimage.find_objects(markers), start=1):
        if box is None:
            continue
        component = markers[box] == k
        pieces, n = ndimage.label(open_region(component), structure=_EIGHT)
        if n < 2:
            pieces, n = component.astype(int), 1
        out[box][pieces > 0] = pieces[pieces > 0] + count
        count += n
    return out, count


def _resolve_orphans(labels: np.ndarray, levels: np.ndarray, min_seed_px: int, orphans: str) -> np.ndarray:
    count = labels.max()
    seeded = ndimage.sum((levels == 0), labels, np.arange(1, count + 1)) >= min_seed_px
    if orphans == "merge":
        # Merge the smallest orphan first, into the neighbour with the longest shared border.
        while not seeded.all():
            sizes = np.bincount(labels.ravel(), minlength=count + 1)[1:]
            candidates = np.nonzero(~seeded & (sizes > 0))[0]
            if not len(candidates):
                break
            progressed = False
            for k in candidates[np.argsort(sizes[candidates])]:
                target = _longest_border_neighbour(labels, k + 1)
                if target:
                    labels[labels == k + 1] = target
                    seeded[k] = True
                    progressed = True
                    break
            if not progressed:
                break  # the rest are isolated pieces: they keep their own seed
    return _relabel(labels)


def _longest_border_neighbour(labels: np.ndarray, k: int) -> int:
    """Label of the part sharing the most 4-adjacent pixel pairs with part ``k`` (0 if none)."""
    region = labels == k
    counts = np.zeros(labels.max() + 1, dtype=int)
    for axis in (0, 1):
        for shift in (1, -1):
            neighbour = np.roll(labels, shift, axis=axis)
            edge = np.roll(region, shift, axis=axis)
            # np.roll wraps: drop the wrapped row/column.
            valid = np.ones_like(region)
            index = [slice(None)] * 2
            index[axis] = 0 if shift == 1 else -1
            valid[tuple(index)] = False
            touching = region & valid & ~edge  # pixel of k whose shifted neighbour is another part
            np.add.at(counts, neighbour[touching], 1)
    counts[[0, k]] = 0
    return int(np.argmax(counts)) if counts.any() else 0


def _relabel(labels: np.ndarray) -> np.ndarray:
    values = np.unique(labels[labels > 0])
    lookup = np.zeros(labels.max() + 1, dtype=int)
    lookup[values] = np.arange(1, len(values) + 1)
    return lookup[labels]

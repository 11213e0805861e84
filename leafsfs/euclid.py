"""Discrete tangents and the Euclidean path of a 4-connected contour (Braquelaire & Vialard).

For every point ``P`` of a closed Freeman 4-chain, the discrete tangent is
the longest digital straight segment around ``P`` within one quadrant
(pair of consecutive codes). The segment is recognised with the arithmetic
(Debled) algorithm after reflecting the quadrant onto the first one and
reading the 4-path as an 8-path (``X = x + y, Y = y``: code 0 -> (1, 0),
code 1 -> (1, 1)); it grows alternately forward and backward and continues
on one side when the other cannot grow (the thesis' rule, appendix III).
With the segment ``mu <= a X - b Y < mu + b``, the Euclidean point of ``P``
is ``P + (e, -e)`` in the first-quadrant 4-frame, ``e = (b - 1 + 2 mu) /
(2 b)``, which lies strictly inside the pixel cell (``|e| < 1/2``); the
tangent is ``(b - a, a)``. Both are mapped back by the quadrant's
reflection. The result depends only on the cyclic chain, not on its start.
:func:`discrete_tangents` offers the thesis' tangent and an improved one.

:func:`marching_squares_path` is the comparison method of the digest (§8.5):
the marching-squares iso-line of the binary region with Gaussian-smoothed
finite-difference tangents.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from skimage import measure

from leafsfs.contour import FREEMAN4


def _recognise(forward: list[int], backward: list[int]) -> tuple[int, int, int, int]:
    """Grow a digital straight segment from the origin of a first-octant 8-path.

    Parameters
    ----------
    forward : list of int
        Steps (0 = (1, 0), 1 = (1, 1)) after the origin, the first one
        included; their number bounds the forward growth.
    backward : list of int
        Steps before the origin, nearest first.

    Returns
    -------
    a, b, mu : int
        The naive line ``mu <= a X - b Y < mu + b`` through all recognised points.
    n_forward, n_backward : int
        Number of steps it covers after and before the origin.
    """
    # Initialisation from the first forward step (appendix III, Table 1 header).
    a, b, mu = (1, 1, 0) if forward[0] else (0, 1, 0)
    um = lm = (0, 0)
    uM = lM = (1, forward[0])
    end, head = (1, forward[0]), (0, 0)
    i_f, i_b = 1, 0
    grow_f, grow_b = i_f < len(forward), i_b < len(backward)
    while grow_f or grow_b:
        if grow_f:
            x, y = end[0] + 1, end[1] + forward[i_f]
            r = a * x - b * y
            if mu <= r <= mu + b - 1:
                if r == mu:
                    uM = (x, y)
                if r == mu + b - 1:
                    lM = (x, y)
            elif r == mu - 1:  # steeper
                a, b = y - um[1], x - um[0]
                mu = a * x - b * y
                lm, uM = lM, (x, y)
            elif r == mu + b:  # flatter
                a, b = y - lm[1], x - lm[0]
                mu = a * x - b * y - b + 1
                um, lM = uM, (x, y)
            else:
                grow_f = False
            if grow_f:
                end = (x, y)
                i_f += 1
                grow_f = i_f < len(forward)
        if grow_b:
            x, y = head[0] - 1, head[1] - backward[i_b]
            r = a * x - b * y
            if mu <= r <= mu + b - 1:
                if r == mu:
                    um = (x, y)
                if r == mu + b - 1:
                    lm = (x, y)
            elif r == mu - 1:  # flatter (Table 2)
                a, b = uM[1] - y, uM[0] - x
                mu = a * x - b * y
                um, lM = (x, y), lm
            elif r == mu + b:  # steeper (Table 2)
                a, b = lM[1] - y, lM[0] - x
                mu = a * x - b * y - b + 1
                uM, lm = um, (x, y)
            else:
                grow_b = False
            if grow_b:
                head = (x, y)
                i_b += 1
                grow_b = i_b < len(backward)
    return a, b, mu, i_f, i_b


_PAIR_QUADRANT = {frozenset((0, 1)): 0, frozenset((1, 2)): 1, frozenset((2, 3)): 2, frozenset((3, 0)): 3}

#: Longest growth of a segment on each side of its point, steps: bounds the cost on long straight
#: runs (the tangent of a longer run is already exact to 1/64 in slope).
MAX_GROWTH = 64


def _run_lengths(inside: np.ndarray) -> np.ndarray:
    """For a cyclic boolean array: number of consecutive True entries starting at each index (at most n)."""
    n = len(inside)
    stops = np.flatnonzero(~inside)
    if not len(stops):
        return np.full(n, n)
    nxt = np.searchsorted(stops, np.arange(n))
    after = np.where(nxt < len(stops), stops[np.minimum(nxt, len(stops) - 1)], stops[0] + n)
    return after - np.arange(n)


def _neighbour_codes(codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First different code after and before each index of a cyclic chain (-1 if the chain has one code)."""
    n = len(codes)
    starts = np.flatnonzero(codes != np.roll(codes, 1))  # indices that begin a run
    if not len(starts):
        return np.full(n, -1), np.full(n, -1)
    i = np.arange(n)
    k = np.searchsorted(starts, i, side="right")  # first run start after i
    after = codes[starts[k % len(starts)]]
    own = starts[(k - 1) % len(starts)]  # start of the run holding i
    before = codes[(own - 1) % n]
    return after, before


TANGENT_ESTIMATORS = ("lambda", "thesis")


def discrete_tangents(codes: np.ndarray, estimator: str = "lambda") -> tuple[np.ndarray, np.ndarray]:
    """Euclidean-point offsets and unit discrete tangents along a closed Freeman 4-chain.

    Parameters
    ----------
    codes : ndarray of int, (n,)
        Freeman 4-codes of a closed path (``codes[k]`` leads from point ``k``
        to point ``k + 1``), as returned by :func:`leafsfs.contour.trace_contour`.
    estimator : {"lambda", "thesis"}
        ``"thesis"``: where the forward and backward code changes give two
        quadrants (a corner), keep the longer segment (digest §8.3), and use
        each point's own segment as its tangent. ``"lambda"`` (default): keep
        the segment in which the point is most central (largest
        ``min(forward, backward)`` growth, then the longer), and average the
        tangents of all the points' segments that cover a point, weighted by
        a triangle of its position in each segment (the idea of the lambda-MST
        estimator of Lachaud et al.). On digitised circles of radius 5-50 px
        this lowers the mean tangent error by 25-45 % (``leafsfs perf
        --tangents``). The Euclidean points are the same in both.

    Returns
    -------
    offsets : ndarray, (n, 2)
        Euclidean point of each path point minus the point itself, pixels;
        every component lies in ]-1/2, 1/2[.
    tangents : ndarray, (n, 2)
        Unit discrete tangent at each point, oriented along the path.

    Notes
    -----
    A point whose quadrant is undefined (a U-turn such as codes 0 then 2,
    which the opening normally removes) falls back to the central difference
    tangent and the pixel centre.
    """
    if estimator not in TANGENT_ESTIMATORS:
        raise ValueError(f"unknown tangent estimator {estimator!r}; allowed: {TANGENT_ESTIMATORS}")
    codes = np.asarray(codes, dtype=int)
    n = len(codes)
    doubled = np.concatenate([codes, codes]).tolist()
    after, before = _neighbour_codes(codes)
    forward_run, backward_run = {}, {}
    for q in range(4):
        inside = (codes == q) | (codes == (q + 1) % 4)
        forward_run[q] = np.minimum(_run_lengths(inside), MAX_GROWTH).tolist()
        backward_run[q] = np.minimum(np.roll(_run_lengths(inside[::-1])[::-1], 1), MAX_GROWTH).tolist()
    lines = np.zeros((n, 5))  # a, b, mu, sx, sy of each point's segment (b = 0: no segment)
    spans = []
    for i in range(n):
        m0 = doubled[i]
        best = None
        quadrants = {_PAIR_QUADRANT[pair] for pair in (frozenset((m0, int(after[i]))), frozenset((m0, int(before[i]))))
                     if pair in _PAIR_QUADRANT}
        for q in sorted(quadrants):
            n_forward = forward_run[q][i]
            n_backward = min(backward_run[q][i], n - n_forward)
            forward = [c % 2 for c in doubled[i:i + n_forward]]
            backward = [c % 2 for c in doubled[i - 1 + n:i - 1 + n - n_backward:-1]]
            a, b, mu, n_f, n_b = _recognise(forward, backward)
            score = (n_f + n_b,) if estimator == "thesis" else (min(n_f, n_b), n_f + n_b)
            if best is None or score > best[0]:
                # Reflection that maps the quadrant onto the first one (and back).
                best = (score, a, b, mu, 1.0 if q in (0, 3) else -1.0, 1.0 if q in (0, 1) else -1.0, n_f, n_b)
        if best is not None:
            lines[i] = best[1:6]
            spans.append((i, best[6], best[7]))
    a, b, mu, sx, sy = lines.T
    found = b > 0
    e = np.where(found, (b - 1 + 2 * mu) / np.where(found, 2 * b, 1.0), 0.0)
    offsets = np.stack([sx * e, -sy * e], axis=1)
    # Without a quadrant (a U-turn): the central difference of the moves and the pixel centre.
    steps = FREEMAN4[codes]
    central = (np.roll(steps, 1, axis=0) + steps).astype(float)
    central = np.where(np.any(central != 0, axis=1)[:, None], central, steps)
    tangents = np.where(found[:, None], np.stack([sx * (b - a), sy * a], axis=1), central)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    if estimator == "lambda" and spans:
        tangents = _lambda_average(tangents, spans)
    return offsets, tangents


def _lambda_average(tangents: np.ndarray, spans: list[tuple[int, int, int]]) -> np.ndarray:
    """Average the segment tangents covering each point, weighted by its position in the segment."""
    n = len(tangents)
    owner, n_f, n_b = (np.array(v) for v in zip(*spans))
    length = n_f + n_b
    size = length + 1
    which = np.repeat(np.arange(len(owner)), size)
    step = np.arange(size.sum()) - np.repeat(np.cumsum(size) - size, size)
    position = step / length[which]
    weight = np.minimum(position, 1.0 - position) + 1e-3
    target = (owner[which] - n_b[which] + step) % n
    total = np.stack([np.bincount(target, weight * tangents[owner[which], c], n) for c in (0, 1)], axis=1)
    norm = np.linalg.norm(total, axis=1, keepdims=True)
    return np.where(norm > 0, total / np.where(norm > 0, norm, 1.0), tangents)


def marching_squares_path(region: np.ndarray, sigma: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Comparison method: marching-squares boundary of a region with smoothed finite-difference tangents.

    Parameters
    ----------
    region : ndarray of bool
        One 4-connected region without holes.
    sigma : float
        Gaussian smoothing of the vertex sequence before differencing, in vertices.

    Returns
    -------
    points, tangents : ndarray, (n, 2)
        Counter-clockwise boundary vertices (row, col; the closing duplicate
        removed) and unit tangents.
    """
    contours = measure.find_contours(np.pad(region.astype(float), 1), 0.5)
    points = max(contours, key=len)[:-1] - 1.0
    x, y = points[:, 0], points[:, 1]
    if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0:
        points = points[::-1]
    smooth = ndimage.gaussian_filter1d(points, sigma, axis=0, mode="wrap") if sigma > 0 else points
    diff = np.roll(smooth, -1, axis=0) - np.roll(smooth, 1, axis=0)
    return points, diff / np.linalg.norm(diff, axis=1, keepdims=True)

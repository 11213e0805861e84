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


def _run(codes: list[int], start: int, step: int, allowed: tuple[int, int], limit: int) -> list[int]:
    """Codes met from ``start`` in direction ``step`` (+1/-1) while they stay in ``allowed`` (at most ``limit``)."""
    n = len(codes)
    out = []
    k = start
    while len(out) < limit and codes[k % n] in allowed:
        out.append(codes[k % n])
        k += step
    return out


def _first_change(codes: list[int], i: int, step: int) -> int | None:
    n = len(codes)
    for k in range(1, n):
        code = codes[(i + step * k) % n]
        if code != codes[i]:
            return code
    return None


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
    codes_list = [int(c) for c in codes]
    n = len(codes_list)
    offsets = np.zeros((n, 2))
    tangents = np.zeros((n, 2))
    spans = []
    for i in range(n):
        m0 = codes_list[i]
        best = None
        quadrants = set()
        for step in (1, -1):
            other = _first_change(codes_list, i, step)
            if other is not None and frozenset((m0, other)) in _PAIR_QUADRANT:
                quadrants.add(_PAIR_QUADRANT[frozenset((m0, other))])
        for q in sorted(quadrants):
            allowed = (q, (q + 1) % 4)
            forward = _run(codes_list, i, 1, allowed, n)
            backward = _run(codes_list, i - 1, -1, allowed, n - len(forward))
            a, b, mu, n_f, n_b = _recognise([c % 2 for c in forward], [c % 2 for c in backward])
            score = (n_f + n_b,) if estimator == "thesis" else (min(n_f, n_b), n_f + n_b)
            if best is None or score > best[0]:
                # Reflection that maps the quadrant onto the first one (and back).
                sx = 1.0 if 0 in allowed else -1.0
                sy = 1.0 if 1 in allowed else -1.0
                best = (score, a, b, mu, sx, sy, n_f, n_b)
        if best is None:
            back, ahead = FREEMAN4[codes_list[i - 1]], FREEMAN4[m0]
            direction = (back + ahead).astype(float)
            if not direction.any():
                direction = ahead.astype(float)
            tangents[i] = direction / np.linalg.norm(direction)
            continue
        _, a, b, mu, sx, sy, n_f, n_b = best
        e = (b - 1 + 2 * mu) / (2 * b)
        offsets[i] = (sx * e, -sy * e)
        t = np.array([sx * (b - a), sy * a], dtype=float)
        tangents[i] = t / np.linalg.norm(t)
        spans.append((i, n_f, n_b))
    if estimator == "lambda" and spans:
        tangents = _lambda_average(tangents, spans)
    return offsets, tangents


def _lambda_average(tangents: np.ndarray, spans: list[tuple[int, int, int]]) -> np.ndarray:
    """Average the segment tangents covering each point, weighted by its position in the segment."""
    n = len(tangents)
    total = np.zeros((n, 2))
    for i, n_f, n_b in spans:
        length = n_f + n_b
        position = np.arange(length + 1) / length
        weight = np.minimum(position, 1.0 - position) + 1e-3
        np.add.at(total, np.arange(i - n_b, i + n_f + 1) % n, weight[:, None] * tangents[i])
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

"""Radii the points cannot resolve, from the pipe model: a cylinder's cross-section in proportion to what it carries.

A branch thinner than the point spacing, or a cluster of twigs fitted as
one cylinder, gives a circle whose radius is the noise or the cluster's
width, not the wood's: on a simulated leafless apple-like tree at 4 m
(0.05 deg) 0.1-2 mm twigs came out 5-10 mm wide, and 1.5-4.5 dm3 of excess
volume against 2.7 dm3 of wood. The pipe model (Shinozaki et al. 1964, "A
quantitative analysis of plant form - the pipe model theory", Jpn. J. Ecol.
14: 97-105) makes a stem's cross-sectional area proportional to the amount
of shoots above it; with the *growth length* (the length of a cylinder and
of everything it carries) as that amount, as QSM tools do for their
unreliable cylinders (Hackenberg et al. 2015, SimpleTree, Forests 6:
4245-4294, fit ``r = a GL^b`` to the reliable ones), an unresolved
cylinder's radius is its nearest resolved ancestor's radius times
``sqrt(GL / GL_ancestor)``. The fitted radius stays an upper bound: the
correction only shrinks.
"""

from __future__ import annotations

import numpy as np


def growth_length(lengths: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """Length of each cylinder plus that of every cylinder it carries, m.

    Parameters
    ----------
    lengths : ndarray, (n,)
        Cylinder lengths, m.
    parents : ndarray of int, (n,)
        Index of each cylinder's parent (-1: a root); every parent must come
        before its children.

    Returns
    -------
    ndarray, (n,)
        Growth length, m.
    """
    total = np.asarray(lengths, float).copy()
    for i in range(len(total) - 1, -1, -1):
        if parents[i] >= 0:
            total[parents[i]] += total[i]
    return total


def pipe_radii(radii, lengths, parents, reliable, exponent: float = 0.5) -> np.ndarray:
    """Radii with each unreliable cylinder's at most its nearest reliable ancestor's times ``sqrt(GL / GL_a)``.

    Parameters
    ----------
    radii : array_like, (n,)
        Fitted radii, m.
    lengths : array_like, (n,)
        Cylinder lengths, m.
    parents : array_like of int, (n,)
        Parent index (-1: a root); parents come before their children.
    reliable : array_like of bool, (n,)
        Whether the points resolve each radius. A cylinder with no reliable
        ancestor keeps its radius.
    exponent : float
        ``b`` of ``r ~ GL^b`` (0.5: the pipe model).

    Returns
    -------
    ndarray, (n,)
        Radii, m (never larger than ``radii``).

    Examples
    --------
    A 2 cm stem (1 m) carrying two twigs of 0.5 m whose fitted radii (1 cm) are noise:

    >>> pipe_radii([0.02, 0.01, 0.01], [1.0, 0.5, 0.5], [-1, 0, 0], [True, False, False]).round(4).tolist()
    [0.02, 0.01, 0.01]
    >>> pipe_radii([0.02, 0.01, 0.01], [1.0, 0.1, 0.1], [-1, 0, 0], [True, False, False]).round(4).tolist()
    [0.02, 0.0058, 0.0058]
    """
    radii = np.asarray(radii, float)
    parents = np.asarray(parents, np.int64)
    reliable = np.asarray(reliable, bool)
    carried = growth_length(lengths, parents)
    out = radii.copy()
    anchor = np.full(len(radii), -1, np.int64)
    for i in range(len(radii)):
        p = parents[i]
        anchor[i] = i if reliable[i] else (anchor[p] if p >= 0 else -1)
        a = anchor[i]
        if not reliable[i] and a >= 0 and carried[a] > 0:
            out[i] = min(radii[i], out[a] * (carried[i] / carried[a]) ** exponent)
    return out

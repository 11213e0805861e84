"""Quantisation of the alpha image into nested iso-alpha domains (thesis ch.5 eqs 2.2-2.4, ch.7 eqs 1.1-1.3).

Thresholds ``alpha_0 < ... < alpha_n = pi/2`` split the object's pixels into
domains ``s_0 = {alpha <= alpha_0}`` (the seeds, digest A17) and
``s_i = {alpha_(i-1) < alpha <= alpha_i}``. The thresholds are empirical
quantiles of the (smoothed, masked) alpha values so that the seed domain
covers the fraction ``eps_seed`` of the pixels and every further domain
``eps_alpha``; the last (shell) domain takes the remainder (digest §3.2).

Seeds are the regions of locally minimal alpha. A flat plateau, pixels
sharing exactly the lowest alpha (a flat floor at alpha = 0, or an alpha
clipped at 0), is one value, not a spread of them: it belongs to the seed
domain but does not count in the fractions, which are measured on the pixels
above it. Counted, a plateau near or above ``eps_seed`` would make
``alpha_0`` its own value: the seed domain would be the plateau alone, no
other alpha minimum (a crest beside the floor) could be a seed, and the next
domains would collapse into it (ours, not in the thesis: its quantile rule
assumes a continuous alpha distribution). Fewer than :data:`PLATEAU_PX` tied
pixels are no plateau and leave the rule as it is.

The *shell rule* of chapter 7 ties ``eps_alpha`` to the size of the object:
``eps_alpha = mu * a_shell / a_tot``, with ``a_shell`` the number of pixels of
a one-pixel-wide shell of the object (its contour; ``4 (Theta - 1)`` for a
``Theta x Theta`` square) and ``a_tot`` its pixel count, so that every domain
is about ``mu`` pixels wide; ``eps_seed = nu * eps_alpha``.
"""

from __future__ import annotations

import numpy as np

from leafsfs.contour import contour_pixels

#: Pixels tied at the lowest alpha that make a flat plateau: more than the 8 that the symmetries of the square
#: pixel grid can make equal around an isolated minimum (the 4 centre pixels of an even-sided dome, say).
PLATEAU_PX = 9
#: Chapter-7 parameter sets: shell number mu and seed factor nu.
SHELL_SETS = {"T1": (2, 2), "T2": (3, 2), "T3": (4, 2), "T3*": (4, 1)}


def shell_fractions(mask: np.ndarray, shell_set: str) -> tuple[float, float]:
    """``(eps_alpha, eps_seed)`` of the shell rule for an object mask and a parameter set.

    Parameters
    ----------
    mask : ndarray of bool, 2-D
        The object's pixels.
    shell_set : {"T1", "T2", "T3", "T3*"}
        Chapter-7 parameter set: shell number ``mu`` and seed factor ``nu`` (:data:`SHELL_SETS`).

    Returns
    -------
    eps_alpha, eps_seed : float
        Area fractions (of the object's pixels) of every domain and of the seed domain, in (0, 1].
    """
    mu, nu = SHELL_SETS[shell_set]
    a_tot = int(mask.sum())
    a_shell = int(contour_pixels(mask).sum())
    eps_alpha = min(1.0, mu * a_shell / max(a_tot, 1))
    return eps_alpha, min(1.0, nu * eps_alpha)


def quantile_thresholds(values: np.ndarray, eps_alpha: float, eps_seed: float) -> np.ndarray:
    """Thresholds ``alpha_0 .. alpha_n`` (rad, strictly increasing, last = pi/2) from area fractions.

    ``alpha_0 = Q(eps_seed)``, ``alpha_i = Q(eps_seed + i eps_alpha)`` while the
    fraction is below 1 (digest §3.2). ``Q`` is the quantile of all values,
    or of those above the lowest one when :data:`PLATEAU_PX` or more values
    tie at it (a flat plateau; see the module docstring). Equal quantiles (flat
    alpha) collapse.

    Parameters
    ----------
    values : ndarray
        Alpha values of the object's pixels, rad.
    eps_alpha : float
        Area fraction of every domain after the seed, in (0, 1].
    eps_seed : float
        Area fraction of the seed domain, in (0, 1].

    Returns
    -------
    ndarray
        The thresholds, rad.
    """
    values = np.asarray(values, dtype=float).ravel()
    above = values[values > values.min()]
    if len(above) and len(values) - len(above) >= PLATEAU_PX:
        values = above  # a plateau tied at the lowest alpha: the fractions are those of the pixels above it
    fractions = np.arange(eps_seed, 1.0 - 1e-9, eps_alpha)
    inner = np.quantile(values, fractions) if len(fractions) else np.zeros(0)
    return np.unique(np.append(np.minimum(inner, np.pi / 2), np.pi / 2))


def assign_levels(alpha: np.ndarray, mask: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Domain index of every pixel: 0 for ``alpha <= alpha_0``, ``i`` for ``alpha_(i-1) < alpha <= alpha_i``; -1 off the mask.

    Parameters
    ----------
    alpha : ndarray, 2-D
        Alpha image, rad.
    mask : ndarray of bool, 2-D
        The object's pixels.
    thresholds : ndarray
        Increasing thresholds ``alpha_0 .. alpha_n``, rad (:func:`quantile_thresholds`).

    Returns
    -------
    ndarray of int, 2-D
        Domain index of every pixel.
    """
    levels = np.searchsorted(thresholds, np.where(mask, alpha, 0.0), side="left")
    return np.where(mask, np.minimum(levels, len(thresholds) - 1), -1)

"""The stray-point rule after PROP-SFS: remove the pulses the rule flags where PROP-SFS cannot vouch for them.

At a coarse step (0.08 deg, a footprint of several pulses) PROP-SFS's
corrections of mixed pulses are often wrong, and many pulses lie where it
reconstructs nothing (small leaves it did not find, wood). Measured with the
truth on the leafy tree and pear seed 41 at 5 m at 0.08 deg (`fused`, target
leaves' pulses): of the outliers left, 36 / 30 % are pulses PROP-SFS moved
onto a surface other than a reconstructed leaf and 32 / 22 % pulses it moved
within a leaf region; FARO SCENE's stray-point rule
(:func:`leafsfs.baselines.stray_point_filter`) on the measured ranges flags
82 / 84 % and 43 / 36 % of them, at 119 / 147 and 94 / 50 good pulses.
:func:`remove_strays` removes the flagged pulses among those PROP-SFS moved
(scope ``moved``: both its reconstruction and the rule find the measured
range off its neighbours, and its correction is the less reliable of the two
at a coarse step), or also among those no leaf region holds (``unclaimed``:
what it left as measured outside its leaves). The pulses of reconstructed
leaves that it kept as measured are never removed.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from leafsfs.baselines import stray_point_filter
from leafsfs.errors import SfsError
from leafsfs.reconstruct import SfsResult

#: Where :func:`remove_strays` applies the stray-point rule.
SCOPES = ("moved", "unclaimed")


def stray_scope(result: SfsResult, scope: str = "moved") -> np.ndarray:
    """Pulses whose measured range :func:`remove_strays` may judge.

    Parameters
    ----------
    result : SfsResult
        A reconstruction.
    scope : {"moved", "unclaimed"}
        ``moved``: pulses PROP-SFS gave a new range; ``unclaimed``: those and
        the pulses in no reconstructed leaf region.

    Returns
    -------
    ndarray of bool
        Grid-shaped mask.

    Raises
    ------
    SfsError
        For an unknown scope.
    """
    if scope not in SCOPES:
        raise SfsError(f"stray scope must be one of {SCOPES}, got {scope!r}")
    valid = result.scan.valid & np.isfinite(result.range)
    moved = valid & result.corrected & (result.range != result.scan.range)
    if scope == "moved":
        return moved
    return moved | (valid & ~np.isin(result.labels, [leaf.label for leaf in result.leaves]))


def remove_strays(result: SfsResult, scope: str = "moved", window_px: int = 3, max_range_diff_m: float = 0.02,
                  min_share: float = 0.5) -> SfsResult:
    """A copy of ``result`` without the pulses of :func:`stray_scope` that the stray-point rule flags.

    The rule (FARO SCENE's, settings of the heritage-science study quoted in
    the prior-art digest §2.3; :func:`leafsfs.baselines.stray_point_filter`)
    judges the measured ranges of the whole scan. Removed pulses get a NaN
    range and are marked ``removed``, ``outlier`` and ``corrected``.

    Parameters
    ----------
    result : SfsResult
        A reconstruction (:func:`leafsfs.reconstruct`).
    scope : {"moved", "unclaimed"}
        Pulses the rule may remove (:func:`stray_scope`).
    window_px : int
        Odd window size of the rule, pixels.
    max_range_diff_m : float
        Range tolerance of the rule, m.
    min_share : float
        Share of agreeing neighbours a pulse needs to be kept, in (0, 1].

    Returns
    -------
    SfsResult
        The same reconstruction with the removals (the input is not changed).
    """
    candidates = stray_scope(result, scope)
    strays = candidates & ~stray_point_filter(result.scan, None, window_px, max_range_diff_m, min_share)
    return dataclasses.replace(result, range=np.where(strays, np.nan, result.range),
                               corrected=result.corrected | strays, outlier=result.outlier | strays,
                               removed=result.removed | strays)

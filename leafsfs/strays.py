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
what it left as measured outside its leaves), or, for those, only the pulses
with no neighbour at their range (``isolated``: a range step to each of the
eight neighbours, which no surface explains). The pulses of reconstructed
leaves that it kept as measured are never removed.

At 0.08 deg (truth, per-leaf means), ``isolated`` with a 5 px window for the
moved pulses (tlsbench ``fused-stray5``) reduces the ROP by 0.630 / 0.708 /
0.596 losing 9.1 / 7.7 / 9.1 % of the good points on the leafy tree and pears
seed 31 at 2.5 m and seed 41 at 5 m, against the stray-point rule alone
0.632 / 0.633 / 0.710 losing 15.3 / 8.2 / 22.0 % (``moved`` with 3 px: 0.560 /
0.571 / 0.523 losing 6.0 / 4.6 / 4.8 %): ahead on the nearer pears, short at
5 m, where the outliers left lie mostly outside the leaves it finds. The 5 px
window was chosen on the tree and seed 31.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from leafsfs.baselines import STRAY_POINT_RULE, stray_point_filter
from leafsfs.errors import SfsError
from leafsfs.reconstruct import SfsResult

#: Where :func:`remove_strays` applies the stray-point rule.
SCOPES = ("moved", "unclaimed", "isolated")

#: Window of the ``isolated`` scope's test of unclaimed pulses, pixels: the eight nearest neighbours.
ISOLATED_WINDOW_PX = 3


def stray_scope(result: SfsResult, scope: str = "moved") -> np.ndarray:
    """Pulses whose measured range :func:`remove_strays` may judge.

    Parameters
    ----------
    result : SfsResult
        A reconstruction.
    scope : {"moved", "unclaimed", "isolated"}
        ``moved``: pulses PROP-SFS gave a new range; ``unclaimed`` and
        ``isolated``: those and the pulses in no reconstructed leaf region.

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


def remove_strays(result: SfsResult, scope: str = "moved", window_px: int = STRAY_POINT_RULE["window_px"],
                  max_range_diff_m: float = STRAY_POINT_RULE["max_range_diff_m"],
                  min_share: float = STRAY_POINT_RULE["min_share"]) -> SfsResult:
    """A copy of ``result`` without the pulses of :func:`stray_scope` that the stray-point rule flags.

    The rule (FARO SCENE's, :func:`leafsfs.baselines.stray_point_filter`;
    default settings :data:`leafsfs.baselines.STRAY_POINT_RULE`)
    judges the measured ranges of the whole scan. Removed pulses get a NaN
    range and are marked ``removed``, ``outlier`` and ``corrected``.

    Parameters
    ----------
    result : SfsResult
        A reconstruction (:func:`leafsfs.reconstruct`).
    scope : {"moved", "unclaimed", "isolated"}
        Pulses the rule may remove (:func:`stray_scope`); with ``isolated``
        the moved pulses are judged by the rule and the pulses in no leaf
        region (moved or not) are removed also when none
        of their :data:`ISOLATED_WINDOW_PX` neighbours lies within
        ``max_range_diff_m`` (or none returned).
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
    if scope == "isolated":
        moved = stray_scope(result, "moved")
        # a share of at least one neighbour in eight: one neighbour at the pulse's range keeps it
        lone = ~stray_point_filter(result.scan, None, ISOLATED_WINDOW_PX, max_range_diff_m,
                                   1.0 / (ISOLATED_WINDOW_PX ** 2 - 1))
        strays = (strays & moved) | (candidates & ~np.isin(result.labels, [leaf.label for leaf in result.leaves])
                                     & lone)
    return dataclasses.replace(result, range=np.where(strays, np.nan, result.range),
                               corrected=result.corrected | strays, outlier=result.outlier | strays,
                               removed=result.removed | strays)

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

Why 5 m fails (truth, pulses of the target leaves, seed 41 at 5 m): of the
608 outliers ``isolated`` leaves, 446 are pulses PROP-SFS kept as measured
outside its leaves (304 of them on leaves it did not find), 100 pulses it
moved within its leaves, 47 kept within them, 15 moved outside them; the
stray-point rule flags 240 of the 446. And PROP-SFS's changes outside its
leaves cost more than they give at a coarse step: with the rule's flags
everywhere, its corrections of the pulses the rule keeps lower the ROP
reduction from 0.727 to 0.689 (per-leaf means: they help the large leaves
it reconstructs and harm the small leaves it does not). Scope ``outside``
therefore keeps PROP-SFS's changes only within its leaves: every return
outside them gets back its measured range and is judged by the rule, as in
the ``stray-point`` variant, and within them the rule judges the pulses it
moved (tlsbench ``fused-stray-out``, the rule's default settings: no step
or distance enters). A range tolerance that follows the point spacing
(``spacing * tan(60-80 deg)`` per neighbour) or a test of the range's
second difference along the four grid lines did no better at the same
good points lost on the tree, seed 31 and seed 41.

``fused-stray-out`` against the stray-point rule at 0.08 deg (ROP reduction
3 sigma / 1 cm, good points lost): leafy tree 0.651 / 0.845, 14.5 % against
0.632 / 0.868, 15.3 %; pear seed 31 at 2.5 m 0.689 / 0.881, 7.7 % against
0.633 / 0.876, 8.2 %; seed 41 at 5 m 0.721 / 0.882, 21.1 % against 0.710 /
0.893, 22.0 % (chosen on these three); not tuned on: seed 53 at 2 m 0.730 /
0.897, 5.7 % against 0.630 / 0.874, 6.0 %; seed 67 at 3.5 m 0.653 / 0.828,
12.9 % against 0.627 / 0.833, 13.5 %; seed 41 at 4 m 0.728 / 0.912, 13.1 %
against 0.717 / 0.908, 14.0 %; seed 79 at 3 m 0.738 / 0.898, 8.7 % against
0.670 / 0.893, 9.3 %; but seed 23 at 6 m 0.656 / 0.813, 23.4 % against
0.688 / 0.817, 24.4 %: there PROP-SFS's corrections within its leaves
already cost ROP reduction (0.675 with them undone); keeping them only in
regions of many pulses did not mend it.

Where that scope fell short (truth, per-leaf means, pulses of the target
leaves): the gap at 6 m (3 sigma) and on the tree (1 cm) lies in small
leaves that a larger region holds, where PROP-SFS moves pulses onto a
surface that is not theirs (seed 23 at 6 m: of its moved pulses the rule
keeps, 129 good ones made outliers and 128 outliers made good) and keeps
pulses the rule removes (23 outliers). The rule therefore also reads the
ranges PROP-SFS left within its leaves (those outside them measured): a
pulse it moved goes when it is off its neighbours on either range, a pulse
it kept when on both (a kept pulse whose neighbours PROP-SFS brought to its
range is on its leaf). And a pulse the rule keeps on its measured range
that PROP-SFS moved by more than the rule's tolerance gets its measured
range back: the move takes it off its measured neighbours, and at 0.08 deg
those large moves are wrong about as often as right (seed 23 at 6 m: of the
moved pulses kept, 95 good ones moved over 1 cm became outliers, 77
outliers became good), while the per-leaf means weigh the small leaves
where they are wrong. Giving the measured range back to a one-pulse rim of
each region, tolerances that follow the point spacing (``k * spacing *
offset``, k 1.5-3, on the ranges it left), or undoing moves beyond 3
spacings instead of the tolerance did worse: at 2.5 m the spacing (3.5 mm)
is below the range noise and the losses rise (undoing beyond 3 spacings:
seed 31 at 2.5 m 0.694 / 0.886 against 0.719 / 0.909). At 0.08 deg (ROP
reduction 3 sigma / 1 cm, good points lost; against the stray-point rule
above): leafy tree 0.695 / 0.899, 14.9 %; seed 31 at 2.5 m 0.719 / 0.909,
8.0 %; seed 41 at 5 m 0.738 / 0.902, 21.6 %; seed 23 at 6 m 0.694 / 0.847,
24.2 % (chosen on these four, the tolerance for undoing among 1, 2 and 3
cm; seed 67 seen when choosing the kept pulses' test): seed 67 at 3.5 m
0.670 / 0.843, 13.3 %; checked only: seed 53 at 2 m 0.741 / 0.912, 5.9 %;
seed 41 at 4 m 0.747 / 0.924, 13.6 %; seed 79 at
3 m 0.751 / 0.914, 9.0 %. More ROP reduction than the rule at both
definitions and fewer good points lost on all eight. On four pears looked
at only after the choice: seed 97 at 4.5 m 0.710 / 0.880, 16.3 % against
0.671 / 0.874, 16.6 %; seed 5 at 3 m with a wall 1 m behind 0.898 / 0.957,
20.6 % against 0.875 / 0.951, 22.8 %; but seed 11 at 6 m 0.659 / 0.848,
26.5 % against 0.656 / 0.851, 26.8 % (1 cm short) and seed 88 at 1.5 m
0.752 / 0.882, 4.96 % against 0.641 / 0.846, 4.93 % (0.03 points more
lost).

At 0.018 deg (``fused-stray``, scope ``moved``) the rule lost 1.0-1.6 % of
the good points on the leafy tree and the pears (4.5 % on a pear 1 m before
a wall; ``fused`` itself removes 0.3-0.5 %). Of the good points the rule
removes (truth, per-leaf means), 20-28 % on the tree and seeds 7, 23 and 41
had been moved onto the range most of their neighbours measure, and a
further 9-21 % (14 % before the wall) by at most two deviations of the
range noise. Scope ``moved`` therefore judges neither
(:data:`MOVE_NOISE_SIGMA`, :func:`_placed_on_measured`, with the rule's own
window, tolerance and share): a pulse moved onto the range its neighbours
measure is placed on a surface the scan shows there (removing such pulses
cost ROP reduction: on the tree and seeds 7 and 41, 94 % of the scored
pulses the two tests keep lie within 3 sigma of their surface after the
move, 8 % as measured), and one moved within the noise is in effect kept
as measured, which the rule never judges. ROP reduction 3 sigma / 1 cm and
good points lost, before -> after (truth, per-leaf means; chosen on the
tree and seeds 7 and 41, seed 173 looked at while choosing): leafy tree
0.752 / 0.877 / 0.97 % -> 0.751 / 0.874 / 0.65 %; seed 7 at 3 m 0.764 /
0.851 / 1.54 % -> 0.768 / 0.856 / 1.20 %; seed 41 at 5 m 0.778 / 0.885 /
1.60 % -> 0.778 / 0.885 / 1.21 %; seed 23 at 4 m 0.794 / 0.895 / 1.16 % ->
0.794 / 0.894 / 0.80 %; seed 173 at 4 m, a wall 1 m behind, 0.817 / 0.872 /
4.53 % -> 0.842 / 0.897 / 3.81 %. What it still loses are mostly pure leaf
pulses PROP-SFS took for mixed pulses of another surface and moved onto it
(then outliers in ``fused``), on small leaves with few good points.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from leafsfs.baselines import STRAY_POINT_RULE, agreeing_share, stray_point_filter
from leafsfs.errors import SfsError
from leafsfs.leaves import range_noise
from leafsfs.reconstruct import SfsResult

#: Where :func:`remove_strays` applies the stray-point rule.
SCOPES = ("moved", "unclaimed", "isolated", "outside")

#: Window of the ``isolated`` scope's test of unclaimed pulses, pixels: the eight nearest neighbours.
ISOLATED_WINDOW_PX = 3

#: Largest move, in deviations of the scan's range noise (:func:`leafsfs.leaves.range_noise`), that the ``moved``
#: scope counts as no move (assumption: the bound of :data:`leafsfs.surfacetails.SURFACE_TAIL_SIGMA`, beyond which
#: ``fused`` itself takes a pure pulse for a noise tail; 1, 2, 3 and 5 compared in round 22).
MOVE_NOISE_SIGMA = 2.0


def stray_scope(result: SfsResult, scope: str = "moved") -> np.ndarray:
    """Pulses whose measured range :func:`remove_strays` may judge.

    Parameters
    ----------
    result : SfsResult
        A reconstruction.
    scope : {"moved", "unclaimed", "isolated", "outside"}
        ``moved``: pulses PROP-SFS gave a new range; ``unclaimed`` and
        ``isolated``: those and the pulses in no reconstructed leaf region;
        ``outside``: every return (in no leaf region judged on its measured
        range, which :func:`remove_strays` gives back; within the leaf regions
        also on the ranges PROP-SFS left).

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
    outside = _in_no_leaf(result)
    if scope == "outside":
        return valid | (result.scan.valid & outside)
    return moved | (valid & outside)


def _placed_on_measured(result: SfsResult, window_px: int, max_range_diff_m: float, min_share: float) -> np.ndarray:
    """Pulses whose range in ``result`` agrees with the measured ranges of their neighbours, as the stray-point rule
    judges agreement (:func:`leafsfs.baselines.agreeing_share`; the rule's parameters as in :func:`remove_strays`);
    False where ``result`` has no range."""
    measured = np.where(result.scan.valid, result.scan.range, np.nan)
    share = agreeing_share(measured, result.range, window_px, max_range_diff_m)
    with np.errstate(invalid="ignore"):
        return np.isfinite(result.range) & (share >= min_share)


def _in_no_leaf(result: SfsResult) -> np.ndarray:
    """Pixels in no reconstructed leaf region of ``result``."""
    return ~np.isin(result.labels, [leaf.label for leaf in result.leaves])


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
    scope : {"moved", "unclaimed", "isolated", "outside"}
        Pulses the rule may remove (:func:`stray_scope`); with ``moved`` not
        those moved by at most :data:`MOVE_NOISE_SIGMA` deviations of the
        scan's range noise (every move where it cannot be estimated) nor
        those moved onto the range of at least
        ``min_share`` of their measured neighbours (:func:`_placed_on_measured`);
        with ``outside``
        every return in no leaf region first gets back its measured range
        (PROP-SFS's changes are kept only within its leaves) and within them the
        rule also reads the ranges PROP-SFS left: a moved pulse goes when it
        is off its neighbours on either range, a kept one when on both, and a
        pulse moved by more than ``max_range_diff_m`` that the rule keeps on its
        measured range gets that range back; with
        ``isolated``
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
    off_measured = ~stray_point_filter(result.scan, None, window_px, max_range_diff_m, min_share)
    strays = candidates & off_measured
    if scope == "moved":
        # a pulse moved onto the range its neighbours measure is placed on a surface the scan shows there, and one
        # moved within the range noise is in effect kept as measured (the rule does not judge those)
        with np.errstate(invalid="ignore"):
            # without three consecutive returns the noise is unknown: every move counts
            noise = np.nan_to_num(range_noise(result.scan.range))
            beyond_noise = np.abs(result.range - result.scan.range) > MOVE_NOISE_SIGMA * noise
        strays &= beyond_noise & ~_placed_on_measured(result, window_px, max_range_diff_m, min_share)
    if scope == "outside":
        moved = stray_scope(result, "moved")
        back = result.scan.valid & _in_no_leaf(result)
        # within the leaves, a move beyond the rule's tolerance takes a pulse the rule keeps off its neighbours
        with np.errstate(invalid="ignore"):
            undone = moved & ~back & ~off_measured & (np.abs(result.range - result.scan.range) > max_range_diff_m)
        moved &= ~undone
        result = dataclasses.replace(result, range=np.where(back | undone, result.scan.range, result.range),
                                     corrected=result.corrected & ~back, outlier=result.outlier & ~(back | undone),
                                     removed=result.removed & ~back)
        left = dataclasses.replace(result.scan, range=result.range)
        off_left = left.valid & ~stray_point_filter(left, None, window_px, max_range_diff_m, min_share)
        # within the leaves: a moved pulse goes when either range is off its neighbours', a kept one when both are
        strays = (strays & (back | moved)) | (off_left & ~back & (moved | off_measured))
    if scope == "isolated":
        moved = stray_scope(result, "moved")
        # a share of at least one neighbour in eight: one neighbour at the pulse's range keeps it
        lone = ~stray_point_filter(result.scan, None, ISOLATED_WINDOW_PX, max_range_diff_m,
                                   1.0 / (ISOLATED_WINDOW_PX ** 2 - 1))
        strays = (strays & moved) | (candidates & _in_no_leaf(result) & lone)
    return dataclasses.replace(result, range=np.where(strays, np.nan, result.range),
                               corrected=result.corrected | strays, outlier=result.outlier | strays,
                               removed=result.removed | strays)

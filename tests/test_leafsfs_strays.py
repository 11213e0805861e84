"""The stray-point rule after PROP-SFS (leafsfs.strays): only pulses PROP-SFS moved, or left outside its leaves."""

import dataclasses
import types

import numpy as np
import pytest

from leafsfs.baselines import stray_point_filter
from leafsfs.errors import SfsError
from leafsfs.params import SfsParams
from leafsfs.reconstruct import SfsResult
from leafsfs.strays import remove_strays, stray_scope
from tlssim.pattern import ScannerPose
from tlssim.scan import Scan, grid_to_xyz

ROWS, COLS, STEP_DEG = 20, 30, 0.08


def _result(measured, corrected_range, labels, leaves=(1,)):
    theta, psi = np.meshgrid(np.radians(STEP_DEG * (np.arange(COLS) - COLS / 2)),
                             np.radians(90.0 + STEP_DEG * (np.arange(ROWS) - ROWS / 2)))
    scan = Scan(measured, np.where(np.isfinite(measured), 1600.0, np.nan).astype(np.float32), theta, psi,
                grid_to_xyz(measured, theta, psi, ScannerPose()))
    zeros = np.zeros(measured.shape, bool)
    corrected = (labels > 0) | ~(corrected_range == measured)
    return SfsResult(scan, "fused", SfsParams(), labels, corrected_range, corrected, np.zeros(measured.shape, int),
                     np.full(measured.shape, np.nan), zeros.copy(), np.zeros(measured.shape), zeros.copy(),
                     zeros.copy(), [types.SimpleNamespace(label=label) for label in leaves])


@pytest.fixture
def plate():
    """A plate at 2 m with four stray pulses 30 cm behind it: one moved by PROP-SFS inside a leaf region, one
    moved outside every region, one kept inside a region, one kept outside (in a skipped region, label 2)."""
    measured = np.full((ROWS, COLS), 2.0)
    measured[:, 25:] = np.nan                    # no return beyond column 25
    for r, c in ((12, 8), (5, 20), (10, 6), (3, 17)):
        measured[r, c] = 2.3
    corrected = measured.copy()
    corrected[12, 8] = 2.1                       # moved within the leaf
    corrected[5, 20] = 2.25                      # moved onto some other surface
    labels = np.zeros((ROWS, COLS), int)
    labels[8:16, 4:12] = 1
    labels[0:8, 13:19] = 2
    return _result(measured, corrected, labels)


def test_moved_scope_removes_only_moved_strays(plate):
    scope = stray_scope(plate, "moved")
    assert scope[12, 8] and scope[5, 20] and scope.sum() == 2
    out = remove_strays(plate)
    gone = out.removed & ~np.isfinite(out.range)
    assert set(zip(*np.nonzero(gone))) == {(12, 8), (5, 20)}
    assert (out.outlier == gone).all() and (out.corrected == (plate.corrected | gone)).all()
    assert np.isfinite(plate.range[12, 8]) and not plate.removed.any()   # the input is unchanged


def test_unclaimed_scope_adds_pulses_outside_the_leaves(plate):
    out = remove_strays(plate, scope="unclaimed")
    gone = set(zip(*np.nonzero(out.removed)))
    # the kept stray inside the reconstructed leaf stays; the one in the skipped region goes
    assert gone == {(12, 8), (5, 20), (3, 17)}
    # plate pulses beside the edge of the returns keep most neighbours at their range: none removed
    assert not out.removed[:, 24].any()


def test_unknown_scope_is_refused(plate):
    with pytest.raises(SfsError, match="stray scope"):
        remove_strays(plate, scope="all")


def test_isolated_scope_keeps_unclaimed_pulses_with_a_neighbour_at_their_range(plate):
    # a pair of strays side by side in the skipped region: each has one neighbour of eight at its range
    measured = plate.scan.range.copy()
    measured[1, 14] = measured[1, 15] = 2.3
    corrected = plate.range.copy()
    corrected[1, 14] = corrected[1, 15] = 2.3
    pair = _result(measured, corrected, plate.labels)
    assert {(1, 14), (1, 15)} <= set(zip(*np.nonzero(remove_strays(pair, scope="unclaimed").removed)))
    gone = set(zip(*np.nonzero(remove_strays(pair, scope="isolated").removed)))
    # the moved strays go as with "moved", the lone kept stray outside the leaves too; the pair stays
    assert gone == {(12, 8), (5, 20), (3, 17)}
    assert stray_scope(pair, "isolated").sum() == stray_scope(pair, "unclaimed").sum()


def test_outside_scope_gives_back_the_measured_pulses_outside_the_leaves(plate):
    corrected = plate.range.copy()
    corrected[9, 5] = 2.01                       # a plate pulse moved within the leaf: its correction stays
    corrected[2, 2] = 2.05                       # a plate pulse moved outside the leaves: measured range back
    corrected[18, 20] = np.nan                   # a plate pulse removed outside the leaves: given back
    moved = _result(plate.scan.range, corrected, plate.labels)
    moved = dataclasses.replace(moved, removed=~np.isfinite(corrected) & plate.scan.valid)
    out = remove_strays(moved, scope="outside")
    gone = set(zip(*np.nonzero(out.removed)))
    # the rule's strays: moved within the leaf, moved outside it (judged on the measured range), kept outside, and
    # the stray PROP-SFS kept as measured within its leaf (off its neighbours as measured and as PROP-SFS left them)
    assert gone == {(12, 8), (5, 20), (3, 17), (10, 6)}
    assert out.range[9, 5] == 2.01 and out.corrected[9, 5]
    assert out.range[2, 2] == out.range[18, 20] == 2.0
    assert not (out.corrected | out.outlier)[2, 2] and not (out.corrected | out.outlier)[18, 20]
    scope = stray_scope(moved, "outside")
    assert scope[18, 20] and scope[3, 17] and scope[9, 5] and scope[10, 6]


def test_outside_scope_judges_the_leaves_on_the_ranges_prop_sfs_left(plate):
    """Within a leaf region a moved pulse goes when its new range is off its neighbours' new ranges (its measured
    range agreeing), a kept pulse off its measured neighbours stays when PROP-SFS moved them to its range, and a
    pulse the rule keeps as measured gets its measured range back when PROP-SFS moved it beyond the tolerance."""
    measured = plate.scan.range.copy()
    measured[10, 10] = 2.03                      # a leaf pulse 3 cm behind its measured neighbours ...
    corrected = plate.range.copy()
    corrected[9:12, 10:12] = 2.015               # ... five of which PROP-SFS moves 1.5 cm towards it
    corrected[10, 10] = 2.03
    corrected[13:16, 5:8] = 1.99                 # a patch moved 1 cm ...
    corrected[14, 6] = 2.015                     # ... its centre 1.5 cm the other way: 2.5 cm off the patch
    corrected[15, 10] = 2.2                      # a plate pulse moved 20 cm
    result = _result(measured, corrected, plate.labels)
    assert not stray_scope(result, "moved")[10, 10]
    out = remove_strays(result, scope="outside")
    gone = set(zip(*np.nonzero(out.removed)))
    assert (14, 6) in gone and (10, 10) not in gone and (15, 10) not in gone
    assert out.range[15, 10] == 2.0 and not out.outlier[15, 10] and out.range[13, 5] == 1.99
    # the rule on the measured ranges alone keeps the centre of the patch
    assert (14, 6) not in set(zip(*np.nonzero(remove_strays(result, scope="unclaimed").removed)))


def _leaf_strip_before_wall(seed=0):
    """A wall at 3 m (2 mm range noise) with a leaf seen edge-on before it: a strip one pulse high at 2 m (row 10,
    columns 5-19) ending in a pulse mixing leaf and wall at 2.5 m (column 20)."""
    rng = np.random.default_rng(seed)
    measured = 3.0 + rng.normal(0.0, 0.002, (ROWS, COLS))
    measured[10, 5:20] = 2.0 + rng.normal(0.0, 0.002, 15)
    measured[10, 20] = 2.5
    return measured


def test_moved_scope_keeps_a_leaf_before_a_wall_and_removes_the_mixed_pulse_between():
    """Good leaf and wall pulses that PROP-SFS moved within the range noise stay although the rule finds the leaf's
    off their neighbours; the mixed pulse PROP-SFS moved onto the leaf still goes."""
    measured = _leaf_strip_before_wall()
    corrected = measured.copy()
    corrected[10, 5:20] += 0.001                 # the strip refitted within the noise
    corrected[9, 5:21] -= 0.001                  # so are the wall pulses above it ...
    corrected[11, 5:21] += 0.001                 # ... and below it
    corrected[10, 20] = 2.0                      # the mixed pulse placed on the leaf
    result = _result(measured, corrected, np.zeros((ROWS, COLS), int), leaves=())
    off = ~stray_point_filter(result.scan)
    assert off[10, 5:20].all() and off[10, 20]   # the rule on the measured ranges flags the strip and the mix
    gone = set(zip(*np.nonzero(remove_strays(result).removed)))
    assert gone == {(10, 20)}


def test_moved_scope_keeps_a_pulse_moved_onto_the_range_its_neighbours_measure():
    """A mixed pulse moved onto the wall that most of its neighbours measure stays; moved onto the leaf strip, which
    two of its eight neighbours measure, it goes; moved by less than the tolerance but beyond the noise it goes."""
    measured = _leaf_strip_before_wall()
    for new, removed in ((3.0, False), (2.0, True), (2.49, True)):
        corrected = measured.copy()
        corrected[10, 20] = new
        result = _result(measured, corrected, np.zeros((ROWS, COLS), int), leaves=())
        assert remove_strays(result).removed[10, 20] == removed


def test_moved_scope_counts_every_move_where_the_noise_cannot_be_estimated(plate):
    """Without three consecutive returns along a row or column the range noise is unknown: a moved stray still goes."""
    measured = np.full((ROWS, COLS), np.nan)
    measured[::2, ::2] = 2.0                      # isolated returns: no second difference anywhere
    measured[10, 10] = 2.3
    corrected = measured.copy()
    corrected[10, 10] = 2.3001                    # moved by 0.1 mm
    result = _result(measured, corrected, np.zeros((ROWS, COLS), int), leaves=())
    assert remove_strays(result).removed[10, 10]

"""Footprint shares of leaf regions at their outline (``leafsfs.reconstruct``)."""

import numpy as np

from leafsfs.reconstruct import _mixes_in_range


def test_outline_on_paired_pulses_mixes_in_range_and_on_no_return_does_not():
    region = np.zeros((20, 20), bool)
    region[5:15, 5:15] = True
    paired = np.zeros((20, 20, 2), bool)
    ring = np.zeros((20, 20), bool)
    ring[3:17, 3:17] = True
    ring[:, 10:] = False  # the right half of the outline borders no return
    paired[..., 1] = ring & ~region
    seen = _mixes_in_range(region, paired, 1.5)
    assert seen[5:15, 5:8].all()  # the left outline: every neighbour within 1.5 px is the leaf's or paired with it
    assert not seen[5:15, 14].any()  # the right outline: a footprint may reach past it unseen in range
    assert not seen[~region].any()
    assert _mixes_in_range(region, np.zeros_like(paired), 1.5)[7:13, 7:13].all()  # deeper than a footprint

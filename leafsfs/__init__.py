"""leafsfs: PROP-SFS leaf reconstruction from phase-shift TLS intensity and range.

Main entry points: :func:`reconstruct` (scans), :func:`reconstruct_heights`
(alpha and height images), :class:`SfsParams`, :func:`segment_leaves`.
"""

from leafsfs.engine import HeightResult, reconstruct_heights
from leafsfs.errors import SfsError
from leafsfs.leaves import segment_leaves
from leafsfs.params import VARIANTS, SfsParams
from leafsfs.reconstruct import LeafResult, SfsResult, reconstruct

__all__ = ["HeightResult", "LeafResult", "SfsError", "SfsParams", "SfsResult", "VARIANTS", "reconstruct",
           "reconstruct_heights", "segment_leaves"]

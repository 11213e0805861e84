"""Binary regions to closed 4-connected contours with their Freeman code.

Boundary extraction of the thesis' appendix III §2.1: the region is opened by
the 3 x 3 square (``D' = (D ⊖ E) ⊕ E``, which removes features one or two
pixels thick), and its contour is ``D' minus (D' ⊖ E)``, the pixels with at
least one 8-neighbour outside. Those pixels form a 4-connected closed path,
traced here counter-clockwise.

Coordinates are pixel indices ``(x, y) = (row, col)``. "Counter-clockwise"
means positive signed (shoelace) area in that ``(x, y)`` plane, so the
interior lies on the left of the path. Freeman 4-codes are numbered
counter-clockwise from +x: 0 = +x, 1 = +y, 2 = -x, 3 = -y.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

#: Unit steps of the Freeman 4-codes 0..3, in (row, col).
FREEMAN4 = np.array([(1, 0), (0, 1), (-1, 0), (0, -1)])

_SQUARE = np.ones((3, 3), dtype=bool)


def open_region(region: np.ndarray) -> np.ndarray:
    """Morphological opening of a boolean image by the 3 x 3 square (border treated as outside)."""
    padded = np.pad(region, 2)
    return ndimage.binary_opening(padded, structure=_SQUARE)[2:-2, 2:-2]


def contour_pixels(region: np.ndarray) -> np.ndarray:
    """The contour set ``D minus (D ⊖ E)`` of a boolean image (pixels with an 8-neighbour outside)."""
    padded = np.pad(region, 1)
    inner = ndimage.binary_erosion(padded, structure=_SQUARE)[1:-1, 1:-1]
    return region & ~inner


def trace_contour(region: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Trace the outer contour of a 4-connected region counter-clockwise.

    The path keeps the outside on its right: at every pixel it tries to turn
    right, then to go straight, left, and finally back. It starts at the
    region's first pixel in (row, col) order and stops when the first move
    repeats, so pixels where the region is one pixel wide are visited twice.

    Parameters
    ----------
    region : ndarray of bool, 2-D
        A 4-connected region (other components are ignored only if they do
        not touch the traced one).

    Returns
    -------
    pixels : ndarray of int, (n, 2)
        Contour pixels ``(row, col)`` in counter-clockwise order (the path is
        closed: the last pixel is 4-adjacent to the first).
    codes : ndarray of int, (n,)
        Freeman code of the move from ``pixels[k]`` to ``pixels[k + 1]``
        (cyclically). Empty for a single-pixel region.
    """
    rows, cols = np.nonzero(region)
    if len(rows) == 0:
        return np.zeros((0, 2), dtype=int), np.zeros(0, dtype=int)
    padded = np.pad(region, 1)
    start = (int(rows[0]) + 1, int(cols[0]) + 1)
    steps = [tuple(s) for s in FREEMAN4]

    def next_move(pixel, heading):
        for turn in (-1, 0, 1, 2):
            code = (heading + turn) % 4
            dx, dy = steps[code]
            if padded[pixel[0] + dx, pixel[1] + dy]:
                return code
        return None

    # The first pixel has no region pixel at -x or at -y: arriving "from +y"
    # (heading -y, code 3) keeps the outside on the right.
    first = next_move(start, 3)
    if first is None:
        return np.array([[rows[0], cols[0]]]), np.zeros(0, dtype=int)
    pixels, codes = [start], [first]
    pixel, code = start, first
    limit = 4 * region.size + 4
    while True:
        pixel = (pixel[0] + steps[code][0], pixel[1] + steps[code][1])
        code = next_move(pixel, code)
        if pixel == start and code == first:
            break
        pixels.append(pixel)
        codes.append(code)
        if len(pixels) > limit:  # cannot happen for a finite region; guards the loop
            raise RuntimeError("contour tracing did not close")
    return np.array(pixels, dtype=int) - 1, np.array(codes, dtype=int)


def signed_area(points: np.ndarray) -> float:
    """Shoelace signed area of a closed polygon given by its vertices ``(n, 2)`` (positive = CCW)."""
    x, y = points[:, 0], points[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))

"""The PROP-SFS mesh under construction and the rasterisation of its triangles onto the pixel grid.

Each triangle built by the propagation covers some pixel centres; every
covered pixel receives one candidate height (this is what produces the
redundancy counts rppp_n). Triangle edges can be *exclusive*: a pixel centre
lying exactly on such an edge is left to the neighbouring triangle, so that
pixels on an inner curve or on a line shared by two wedges are not counted
twice.
"""

from __future__ import annotations

import numpy as np


class MeshBuilder:
    """Growing mesh: vertices (continuous ``x1, x2, h`` and pixel position) and triangles."""

    def __init__(self, capacity: int = 1024):
        self._vertices = np.zeros((capacity, 3))
        self._pixels = np.zeros((capacity, 2))
        self._faces: list[np.ndarray] = []
        self.count = 0

    def add(self, points: np.ndarray, points_px: np.ndarray, heights: np.ndarray) -> np.ndarray:
        """Append vertices; returns their indices.

        Parameters
        ----------
        points : ndarray, (n, 2)
            Lateral positions ``x1, x2``, continuous units (m in a scan's local frame).
        points_px : ndarray, (n, 2)
            The same positions in pixels (row, col).
        heights : ndarray, (n,)
            Heights ``h``, same units as ``points``.

        Returns
        -------
        ndarray of int, (n,)
            Indices of the new vertices.
        """
        n = len(points)
        while self.count + n > len(self._vertices):
            self._vertices = np.concatenate([self._vertices, np.zeros_like(self._vertices)])
            self._pixels = np.concatenate([self._pixels, np.zeros_like(self._pixels)])
        ids = np.arange(self.count, self.count + n)
        self._vertices[ids, :2] = points
        self._vertices[ids, 2] = heights
        self._pixels[ids] = points_px
        self.count += n
        return ids

    def add_faces(self, faces: np.ndarray) -> None:
        """Append triangles (vertex index triples)."""
        if len(faces):
            self._faces.append(np.asarray(faces, int).reshape(-1, 3))

    def pixels_of(self, faces: np.ndarray) -> np.ndarray:
        """Pixel positions of the corners of triangles, ``(F, 3, 2)``."""
        return self._pixels[faces]

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(vertices (V, 3) = x1, x2, h; vertex pixel positions (V, 2); faces (F, 3))``."""
        faces = np.concatenate(self._faces) if self._faces else np.zeros((0, 3), int)
        return self._vertices[:self.count].copy(), self._pixels[:self.count].copy(), faces


#: Most (triangle, candidate pixel) pairs tested at once: bounds the memory to some hundred MB.
_CHUNK_PAIRS = 1 << 20
_EPS = 1e-9


def rasterize_triangles(corners_px: np.ndarray, exclusive: np.ndarray, shape: tuple[int, int]
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Pixel centres covered by triangles.

    Candidates are the pixel centres of each row a triangle spans between
    the row's crossings with the triangle's edges (a scanline fill, so long
    thin triangles cost their area, not their bounding box); each candidate
    is then tested exactly with barycentric coordinates. Triangles are
    processed in chunks of at most ``_CHUNK_PAIRS`` candidates.

    Parameters
    ----------
    corners_px : ndarray, (T, 3, 2)
        Triangle corners in pixel coordinates (row, col).
    exclusive : ndarray of bool, (T, 3)
        ``exclusive[t, k]``: the edge opposite corner ``k`` excludes the
        centres lying exactly on it.
    shape : (rows, cols)
        Grid shape; centres outside it are dropped.

    Returns
    -------
    triangle, pixel : ndarray of int
        For every (triangle, covered pixel) pair: the triangle index and the
        flat pixel index, ordered by triangle.
    """
    corners_px = np.asarray(corners_px, dtype=float)
    exclusive = np.asarray(exclusive, dtype=bool)
    lo = np.maximum(np.ceil(corners_px[:, :, 0].min(axis=1) - _EPS).astype(int), 0)
    hi = np.minimum(np.floor(corners_px[:, :, 0].max(axis=1) + _EPS).astype(int), shape[0] - 1)
    n_rows = np.maximum(hi - lo + 1, 0)
    # (triangle, row) pairs and each row's span of columns
    tri = np.repeat(np.arange(len(corners_px)), n_rows)
    rows = lo[tri] + np.arange(n_rows.sum()) - np.repeat(np.cumsum(n_rows) - n_rows, n_rows)
    first, last = _row_span(corners_px[tri], rows.astype(float), shape[1])
    counts = np.maximum(last - first + 1, 0)
    out_tri, out_pix = [], []
    bounds = np.cumsum(counts)
    start = 0
    while start < len(counts):
        stop = max(int(np.searchsorted(bounds, bounds[start] - counts[start] + _CHUNK_PAIRS, side="right")),
                   start + 1)
        part = slice(start, stop)
        t, p = _covered(corners_px, exclusive, tri[part], rows[part], first[part], counts[part], shape)
        out_tri.append(t)
        out_pix.append(p)
        start = stop
    if not out_tri:
        return np.zeros(0, int), np.zeros(0, int)
    return np.concatenate(out_tri), np.concatenate(out_pix)


def _row_span(corners: np.ndarray, rows: np.ndarray, n_cols: int) -> tuple[np.ndarray, np.ndarray]:
    """First and last candidate column of each (triangle, row) pair: the row's crossings with the edges."""
    low = np.full(len(rows), np.inf)
    high = np.full(len(rows), -np.inf)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        u, v = corners[:, i], corners[:, j]
        d_row = v[:, 0] - u[:, 0]
        crosses = (np.minimum(u[:, 0], v[:, 0]) - _EPS <= rows) & (rows <= np.maximum(u[:, 0], v[:, 0]) + _EPS)
        flat = np.abs(d_row) < _EPS
        t = np.clip((rows - u[:, 0]) / np.where(flat, 1.0, d_row), 0.0, 1.0)
        at = u[:, 1] + t * (v[:, 1] - u[:, 1])
        for col in (at, np.where(flat, v[:, 1], at)):  # a flat edge on the row spans both its ends
            low = np.where(crosses, np.minimum(low, col), low)
            high = np.where(crosses, np.maximum(high, col), high)
    first = np.maximum(np.ceil(low - 1e-6), 0)
    last = np.minimum(np.floor(high + 1e-6), n_cols - 1)
    ok = np.isfinite(first) & np.isfinite(last)
    return np.where(ok, first, 0).astype(int), np.where(ok, last, -1).astype(int)


def _covered(corners_px, exclusive, tri, rows, first, counts, shape) -> tuple[np.ndarray, np.ndarray]:
    """The candidates of some (triangle, row) spans that lie in their triangle (barycentric test)."""
    pair = np.repeat(np.arange(len(tri)), counts)
    cols = first[pair] + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    tri, rows = tri[pair], rows[pair]
    a, b, c = corners_px[tri, 0], corners_px[tri, 1], corners_px[tri, 2]
    p = np.stack([rows, cols], axis=1).astype(float)

    def edge(u, v, w):  # twice the signed area of (u, v, w)
        return (v[:, 0] - u[:, 0]) * (w[:, 1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (w[:, 0] - u[:, 0])

    area = edge(a, b, c)
    ok = np.abs(area) > 1e-12
    safe = np.where(ok, area, 1.0)
    lam = np.stack([edge(b, c, p), edge(c, a, p), edge(a, b, p)], axis=1) / safe[:, None]
    inside = np.all(np.where(exclusive[tri], lam > _EPS, lam >= -_EPS), axis=1) & ok
    return tri[inside], rows[inside] * shape[1] + cols[inside]

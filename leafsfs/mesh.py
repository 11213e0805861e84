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
        """Append vertices; returns their indices."""
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


def rasterize_triangles(corners_px: np.ndarray, exclusive: np.ndarray, shape: tuple[int, int]
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Pixel centres covered by triangles.

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
        flat pixel index.
    """
    if not len(corners_px):
        return np.zeros(0, int), np.zeros(0, int)
    lo = np.maximum(np.ceil(corners_px.min(axis=1) - 1e-9).astype(int), 0)
    hi = np.minimum(np.floor(corners_px.max(axis=1) + 1e-9).astype(int), np.array(shape) - 1)
    extent = np.maximum(hi - lo + 1, 0)
    counts = extent[:, 0] * extent[:, 1]
    tri = np.repeat(np.arange(len(corners_px)), counts)
    local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    width = np.maximum(extent[tri, 1], 1)
    rows = lo[tri, 0] + local // width
    cols = lo[tri, 1] + local % width
    a, b, c = corners_px[tri, 0], corners_px[tri, 1], corners_px[tri, 2]
    p = np.stack([rows, cols], axis=1).astype(float)

    def edge(u, v, w):  # twice the signed area of (u, v, w)
        return (v[:, 0] - u[:, 0]) * (w[:, 1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (w[:, 0] - u[:, 0])

    area = edge(a, b, c)
    ok = np.abs(area) > 1e-12
    safe = np.where(ok, area, 1.0)
    lam = np.stack([edge(b, c, p), edge(c, a, p), edge(a, b, p)], axis=1) / safe[:, None]
    eps = 1e-9
    inside = np.all(np.where(exclusive[tri], lam > eps, lam >= -eps), axis=1) & ok
    return tri[inside], rows[inside] * shape[1] + cols[inside]

"""Closed iso-alpha boundary curves in continuous coordinates and the polyline geometry on them.

A :class:`Curve` is the Euclidean path of a region's 4-connected contour
(:mod:`leafsfs.contour`, :mod:`leafsfs.euclid`) mapped through the pixel
grid: counter-clockwise vertices with unit tangents and arc lengths, plus the
contour pixel of every vertex (used by the curve-crossing inspection).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leafsfs.contour import signed_area, trace_contour
from leafsfs.euclid import discrete_tangents
from leafsfs.grid import PixelGrid
from leafsfs.slope import cross2


@dataclass
class Curve:
    """A closed counter-clockwise polyline.

    Attributes
    ----------
    pixels : ndarray of int, (n, 2)
        Contour pixel (row, col) of each vertex.
    points_px : ndarray, (n, 2)
        Euclidean points in pixel coordinates.
    points : ndarray, (n, 2)
        Euclidean points in continuous coordinates.
    tangents : ndarray, (n, 2)
        Unit tangents in continuous coordinates, along the path.
    arc : ndarray, (n,)
        Arc length from vertex 0 to each vertex (continuous units).
    length : float
        Total length of the closed polyline.
    """

    pixels: np.ndarray
    points_px: np.ndarray
    points: np.ndarray
    tangents: np.ndarray
    arc: np.ndarray
    length: float

    def __len__(self) -> int:
        return len(self.points)

    @property
    def segment_lengths(self) -> np.ndarray:
        """Length of the segment from each vertex to the next."""
        return np.linalg.norm(np.roll(self.points, -1, axis=0) - self.points, axis=1)

    def tangents_at(self, arc: np.ndarray) -> np.ndarray:
        """Unit tangents at arc parameters (wrapped to ``[0, length)``), interpolated between vertices."""
        arc = np.mod(arc, self.length)
        index = np.clip(np.searchsorted(self.arc, arc, side="right") - 1, 0, len(self) - 1)
        frac = ((arc - self.arc[index]) / np.maximum(self.segment_lengths[index], 1e-300))[:, None]
        tangents = (1 - frac) * self.tangents[index] + frac * self.tangents[(index + 1) % len(self)]
        norm = np.linalg.norm(tangents, axis=1, keepdims=True)
        return np.where(norm > 1e-9, tangents / np.maximum(norm, 1e-300), self.tangents[index])


def extract_curve(region: np.ndarray, grid: PixelGrid, estimator: str = "lambda") -> Curve | None:
    """Boundary curve of a 4-connected region in continuous coordinates (None if it has < 4 points).

    The Euclidean path of the region's contour pixels runs through those
    pixels, i.e. about half a pixel inside the region's real boundary (the
    pixel edges between the region and the outside, which is where the
    iso-alpha threshold lies). The path is therefore moved outward along its
    normals by ``(region area - path area) / path length`` (about 0.5 px on
    straight edges, 0.7 px on digitised discs), so that it encloses the
    region's area. Without this, every annulus is propagated with the alpha
    of a band lying farther out than its rays, a bias that accumulates from
    the seed to the shell.

    Parameters
    ----------
    region : ndarray of bool, 2-D
        A 4-connected region of pixels.
    grid : PixelGrid
        Map from pixel indices to continuous coordinates (m in a scan's local frame).
    estimator : {"lambda", "thesis"}
        Discrete tangent estimator (:func:`leafsfs.euclid.discrete_tangents`).

    Returns
    -------
    Curve or None
        The counter-clockwise boundary curve, in continuous units.
    """
    pixels, codes = trace_contour(region)
    if len(codes) < 4:
        return None
    offsets, tangents_px = discrete_tangents(codes, estimator)
    points_px = pixels + offsets
    normal_px = np.stack([tangents_px[:, 1], -tangents_px[:, 0]], axis=1)  # outward for a CCW (row, col) path
    perimeter = np.sum(np.linalg.norm(np.roll(points_px, -1, axis=0) - points_px, axis=1))
    points_px = points_px + (float(region.sum()) - signed_area(points_px)) / perimeter * normal_px
    if grid.flips:  # keep counter-clockwise in the continuous plane
        pixels, points_px, tangents_px = pixels[::-1], points_px[::-1], -tangents_px[::-1]
    points = grid.to_continuous(points_px)
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    closing = np.linalg.norm(points[0] - points[-1])
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    return Curve(pixels, points_px, points, grid.directions(tangents_px), arc, float(arc[-1] + closing))


def cast_rays(origins: np.ndarray, directions: np.ndarray, curve: Curve, min_distance: float = 1e-9,
              chunk: int = 2_000_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First crossing of rays ``o + u d`` (``u > min_distance``) with a closed polyline.

    Parameters
    ----------
    origins : ndarray, (n, 2)
        Ray origins, continuous units (m in a scan's local frame).
    directions : ndarray, (n, 2)
        Unit ray directions.
    curve : Curve
        The closed polyline.
    min_distance : float
        Crossings at ``u <= min_distance`` (continuous units) are ignored, so a
        ray starting on the polyline does not hit it at its origin.
    chunk : int
        Number of ray-edge pairs tested at once (bounds the memory of the
        temporaries, a few tens of bytes per pair).

    Returns
    -------
    hit : ndarray of bool, (n,)
    distance : ndarray, (n,)
        ``u`` of the first crossing (``d`` unit: the horizontal distance Δd); inf if none.
    arc : ndarray, (n,)
        Arc parameter of the crossing on ``curve``.
    """
    start = curve.points
    edge = np.roll(start, -1, axis=0) - start
    n = len(origins)
    best_u = np.full(n, np.inf)
    best_arc = np.zeros(n)
    rows = max(1, chunk // max(len(start), 1))
    for lo in range(0, n, rows):
        o, d = origins[lo:lo + rows, None, :], directions[lo:lo + rows, None, :]
        rel = start[None] - o
        denom = cross2(d, edge[None])
        with np.errstate(divide="ignore", invalid="ignore"):
            u = cross2(rel, edge[None]) / denom
            v = cross2(rel, d) / denom
        ok = (np.abs(denom) > 1e-12) & (u > min_distance) & (v >= 0) & (v < 1)
        u = np.where(ok, u, np.inf)
        k = np.argmin(u, axis=1)
        rows_idx = np.arange(len(k))
        best_u[lo:lo + rows] = u[rows_idx, k]
        best_arc[lo:lo + rows] = curve.arc[k] + np.where(np.isfinite(u[rows_idx, k]), v[rows_idx, k], 0) \
            * np.linalg.norm(edge[k], axis=1)
    return np.isfinite(best_u), best_u, best_arc


def segments_cross(p1, p2, q1, q2, eps: float = 1e-9) -> np.ndarray:
    """Whether segments ``[p1, p2]`` and ``[q1, q2]`` cross at interior points (broadcasting over leading axes).

    Parameters
    ----------
    p1, p2 : ndarray, (..., 2)
        End points of the first segments, continuous units.
    q1, q2 : ndarray, (..., 2)
        End points of the second segments, same units.
    eps : float
        Margin in segment parameter (dimensionless, fraction of each segment)
        within which a touch at an end point does not count as a crossing.

    Returns
    -------
    ndarray of bool, (...)
        Whether each pair crosses (parallel segments never do).
    """
    r, s = p2 - p1, q2 - q1
    denom = cross2(r, s)
    rel = q1 - p1
    with np.errstate(divide="ignore", invalid="ignore"):
        t = cross2(rel, s) / denom
        u = cross2(rel, r) / denom
    return (np.abs(denom) > 1e-12) & (t > eps) & (t < 1 - eps) & (u > eps) & (u < 1 - eps)


def crosses_polyline(starts: np.ndarray, ends: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Whether each segment ``[starts[j], ends[j]]`` crosses the closed polyline ``vertices``.

    Segment ``j`` starts at vertex ``j`` of the polyline, so the two polyline
    edges that touch vertex ``j`` are not tested.

    Parameters
    ----------
    starts : ndarray, (n, 2)
        Segment starts: the polyline's vertices, continuous units.
    ends : ndarray, (n, 2)
        Segment ends, same units.
    vertices : ndarray, (n, 2)
        Vertices of the closed polyline, same units.

    Returns
    -------
    ndarray of bool, (n,)
        Whether each segment crosses the polyline.
    """
    n = len(vertices)
    nxt = np.roll(vertices, -1, axis=0)
    crossing = segments_cross(starts[:, None], ends[:, None], vertices[None], nxt[None])
    own = np.arange(n)
    crossing[own, own] = False
    crossing[own, (own - 1) % n] = False
    return crossing.any(axis=1)


def project_on_curve(points: np.ndarray, curve: Curve) -> tuple[np.ndarray, np.ndarray]:
    """Arc parameter of the nearest point of ``curve`` and the distance to it.

    Parameters
    ----------
    points : ndarray, (n, 2)
        Points, continuous units (m in a scan's local frame).
    curve : Curve
        The closed polyline.

    Returns
    -------
    arc : ndarray, (n,)
        Arc parameter of the nearest point of the curve, continuous units from its vertex 0.
    distance : ndarray, (n,)
        Distance to that point, continuous units.
    """
    start = curve.points
    edge = np.roll(start, -1, axis=0) - start
    length2 = np.maximum(np.sum(edge**2, axis=1), 1e-300)
    rel = points[:, None, :] - start[None]
    t = np.clip(np.sum(rel * edge[None], axis=2) / length2[None], 0, 1)
    dist = np.linalg.norm(rel - t[..., None] * edge[None], axis=2)
    k = np.argmin(dist, axis=1)
    rows = np.arange(len(points))
    return curve.arc[k] + t[rows, k] * np.sqrt(length2[k]), dist[rows, k]

"""One annulus of the SPS propagation (thesis Algorithm 5.1, digest §3.6.3).

From every point of the inner 3-D curve a greatest-slope (GS) line, or a
level-curve line at toggle points, is shot outward until it meets the outer
curve's projection (eqs 2.7-2.11). Depending on the variant:

- ``simple``: the hit points alone form the outer curve (no fill);
- ``sps``: consecutive lines bound wedges filled with planar sand-pile
  surfaces; the fill completes the outer curve and gives every pixel centre
  inside a wedge one candidate height;
- ``buffer`` (and ``fused``): in addition, inner points lying on the outer
  curve are copied (curve-crossing inspection) and lines that miss the outer
  curve, cross the inner curve or cross the previous accepted line(s) end at
  the last valid outer point (the buffer, digest A5 prose rule) or, with
  ``buffer_rule="literal"``, follow Algorithm 5.1 as printed.

The planar fill (digest A7) keeps the slope exact along both bounding lines:
``h(p) = (1 - w) P_a(p) + w P_b(p)``, ``P`` the tangent plane of the surface
along a line (inclination alpha along a GS line; the toggle plane at a toggle
point) and ``w`` the relative distance of ``p`` to the two lines (for outer
curve vertices, their arc position between the two hits). Ruled and cone
fills are options (:func:`fill_heights`). The outer curve's
3-D tangents then follow from eq 2.12 with the blended normal, and its signs
are recomputed from the blended descending direction, with toggles where
they change (step 7).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from leafsfs.curves import Curve, cast_rays, crosses_polyline, project_on_curve
from leafsfs.grid import PixelGrid
from leafsfs.mesh import MeshBuilder, rasterize_triangles
from leafsfs.seed import CurveState, mark_toggles
from leafsfs.slope import (
    cross2, curve_tangent_3d, descending_direction, outward_normal, propagation_direction, sps_normal,
    toggle_gradient,
)

#: Below this domain alpha the annulus is treated as flat (digest A30): level-curve propagation.
FLAT_ALPHA = math.radians(1.0)


@dataclass
class Workspace:
    """What the annuli of one part share: grid, allowed pixels, mesh, counters and the measured heights."""

    grid: PixelGrid
    shape: tuple[int, int]
    allowed: np.ndarray  # flat bool: pixels that may receive wedge candidates (the part minus its seed)
    mesh: MeshBuilder
    variant: str
    fill: str = "planar"
    buffer_rule: str = "prose"
    crossing_window: int = 1
    toggle_window: int = 3
    fusion: object = None  # leafsfs.fusion.Fusion for the fused variant
    stats: dict = field(default_factory=dict)

    def count(self, key: str, value: int) -> None:
        """Add to a counter of :attr:`stats`.

        Parameters
        ----------
        key : str
            Counter name.
        value : int
            Amount added (the counter starts at 0).
        """
        self.stats[key] = self.stats.get(key, 0) + int(value)


@dataclass
class Lines:
    """The propagation lines of one annulus (one per inner point)."""

    start: np.ndarray
    end: np.ndarray
    start_h: np.ndarray
    end_h: np.ndarray
    arc: np.ndarray  # arc parameter of the end on the outer curve
    gradient: np.ndarray  # height gradient of the line's tangent plane
    direction: np.ndarray  # unit horizontal direction of the line
    valid: np.ndarray
    end_variance: np.ndarray

    def plane(self, k: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Height of the tangent planes of lines ``k`` at ``points``.

        Parameters
        ----------
        k : ndarray of int, (n,)
            Line indices.
        points : ndarray, (n, 2)
            Points, continuous units (m in a scan's local frame).

        Returns
        -------
        ndarray, (n,)
            Heights, height units (m in a scan's local frame).
        """
        return self.start_h[k] + np.sum(self.gradient[k] * (points - self.start[k]), axis=1)

    def slope(self, k: np.ndarray) -> np.ndarray:
        """Height change per unit length along lines ``k``."""
        return np.sum(self.gradient[k] * self.direction[k], axis=1)


def propagate_annulus(inner: CurveState, outer: Curve, alpha: float, ws: Workspace, alpha_spread: float = 0.0
                      ) -> tuple[CurveState | None, np.ndarray, np.ndarray]:
    """Propagate the inner curve across one annulus.

    Parameters
    ----------
    inner : CurveState
        The inner 3-D curve (counter-clockwise).
    outer : Curve
        The outer curve's projection.
    alpha : float
        Alpha of the annulus' domain, rad.
    ws : Workspace
        Shared state (variant, mesh, counters...).
    alpha_spread : float
        Standard deviation of ``tan(alpha)`` over the annulus (fused variant).

    Returns
    -------
    outer_state : CurveState or None
        The outer 3-D curve (None if nothing reached it).
    pixel, value : ndarray
        Candidate heights for flat pixel indices.
    """
    lines = _shoot(inner, outer, alpha, alpha_spread, ws)
    if ws.variant == "simple":
        return _simple(inner, outer, lines, ws)
    return _fill(inner, outer, lines, ws)


def _shoot(inner: CurveState, outer: Curve, alpha: float, alpha_spread: float, ws: Workspace) -> Lines:
    n = len(inner)
    t, sign = inner.tangents, inner.sign
    toggle = sign == 0
    alphas = np.full(n, alpha)
    if alpha < FLAT_ALPHA:
        direction, gradient = outward_normal(t), np.zeros((n, 2))
    else:
        g = descending_direction(t, inner.gamma, alphas, sign)
        direction = propagation_direction(t, g, sign)
        gradient = np.where(toggle[:, None], toggle_gradient(t, inner.gamma),
                            sign[:, None] * math.tan(alpha) * direction)
    gradient_variance = None
    if ws.fusion is not None:
        direction, gradient, gradient_variance = ws.fusion.fuse_gradients(inner, alpha, alpha_spread, direction,
                                                                          gradient)
    hit, distance, arc = cast_rays(inner.points, direction, outer)
    end = inner.points + np.where(hit, distance, 0.0)[:, None] * direction
    end_h = inner.height + np.sum(gradient * (end - inner.points), axis=1)
    lines = Lines(inner.points, end, inner.height, end_h, arc, gradient, direction, hit.copy(), inner.variance.copy())
    ws.count("lines", n)
    ws.count("toggle_lines", toggle.sum())
    ws.count("missed", (~hit).sum())
    if ws.variant in ("buffer", "fused"):
        _buffer(inner, outer, lines, hit, ws)
    if ws.fusion is not None:
        ws.fusion.fuse_heights(lines, gradient_variance)
    return lines


def _buffer(inner: CurveState, outer: Curve, lines: Lines, hit: np.ndarray, ws: Workspace) -> None:
    """Curve-crossing inspection (step 1) and line-crossing tests with the buffer (step 4)."""
    n = len(inner)
    flat_outer = outer.pixels[:, 0] * ws.shape[1] + outer.pixels[:, 1]
    order = np.argsort(flat_outer)
    flat_inner = inner.pixels[:, 0] * ws.shape[1] + inner.pixels[:, 1]
    pos = np.clip(np.searchsorted(flat_outer[order], flat_inner), 0, len(order) - 1)
    same_pixel = flat_outer[order][pos] == flat_inner
    distance, nearest = cKDTree(outer.points_px).query(inner.points_px)
    crossing = same_pixel | (distance < 0.5)
    vertex = np.where(same_pixel, order[pos], nearest)
    lines.end[crossing] = lines.start[crossing]
    lines.end_h[crossing] = lines.start_h[crossing]
    lines.arc[crossing] = outer.arc[vertex[crossing]]
    icp = np.zeros(n, dtype=bool)
    test = hit & ~crossing
    if test.any() and n >= 3:
        icp[test] = crosses_polyline(lines.start, lines.end, inner.points)[test]
    ws.count("curve_crossings", crossing.sum())
    ws.count("inner_crossings", icp.sum())
    good = crossing | (hit & ~icp)
    if not good.any():
        lines.valid[:] = False
        return
    first = int(np.argmax(good))
    buffer = -1
    previous: list[int] = []
    valid = np.zeros(n, dtype=bool)
    replaced = np.zeros(n, dtype=bool)
    for j in np.roll(np.arange(n), -first):
        if crossing[j]:
            valid[j] = True
            buffer = j
            continue
        ok = hit[j] and not icp[j]
        crossed = ok and any(_cross(lines.start[j], lines.end[j], lines.start[k], lines.end[k])
                             for k in previous[-ws.crossing_window:])
        if ok and not crossed:
            valid[j] = True
            buffer = j
            previous.append(j)
            continue
        ws.count("line_crossings", crossed)
        if ws.buffer_rule == "literal":
            if crossed:  # Alg. 5.1 step 4b flips the outer tangent, which the re-orientation along t' undoes
                valid[j] = True
                continue
            # step 4a (and a missed outer curve): X' := X
            lines.end[j], lines.end_h[j] = lines.start[j], lines.start_h[j]
            lines.arc[j] = project_on_curve(lines.start[j][None], outer)[0][0]
        else:
            lines.end[j], lines.end_h[j], lines.arc[j] = lines.end[buffer], lines.end_h[buffer], lines.arc[buffer]
            lines.end_variance[j] = lines.end_variance[buffer]
            replaced[j] = True
        valid[j] = True
    ws.count("buffered", replaced.sum())
    # A replaced line runs from its start to the buffer point: its plane keeps that slope.
    vector = lines.end[replaced] - lines.start[replaced]
    length = np.linalg.norm(vector, axis=1)
    long_enough = length > 1e-12
    slope = (lines.end_h[replaced] - lines.start_h[replaced]) / np.where(long_enough, length, 1.0)
    unit = vector / np.where(long_enough, length, 1.0)[:, None]
    lines.gradient[replaced] = np.where(long_enough[:, None], slope[:, None] * unit, lines.gradient[replaced])
    lines.direction[replaced] = np.where(long_enough[:, None], unit, lines.direction[replaced])
    lines.valid = valid


def _cross(p1, p2, q1, q2, eps=1e-9) -> bool:
    """Scalar test: do segments [p1, p2] and [q1, q2] cross at interior points?"""
    rx, ry = p2[0] - p1[0], p2[1] - p1[1]
    sx, sy = q2[0] - q1[0], q2[1] - q1[1]
    denom = rx * sy - ry * sx
    if abs(denom) < 1e-12:
        return False
    qx, qy = q1[0] - p1[0], q1[1] - p1[1]
    t = (qx * sy - qy * sx) / denom
    u = (qx * ry - qy * rx) / denom
    return eps < t < 1 - eps and eps < u < 1 - eps


def _outer_state(points, points_px, pixels, tangents, height, gradient, variance, vertex, window) -> CurveState:
    """3-D state of the outer curve from its heights and surface gradients (eq 2.12 and step 7)."""
    tangent3 = curve_tangent_3d(tangents, sps_normal(gradient))
    norm = np.linalg.norm(gradient, axis=1)
    descending = -gradient / np.maximum(norm, 1e-300)[:, None]
    sines = np.where(norm > 1e-12, cross2(tangents, descending), 0.0)
    sign = mark_toggles(sines, window)
    return CurveState(points, points_px, pixels, tangents, height, np.arcsin(np.clip(tangent3[:, 2], -1, 1)),
                      sign, gradient, variance, vertex)


def _simple(inner: CurveState, outer: Curve, lines: Lines, ws: Workspace):
    """SFS-Simple: the hit points are the outer curve; each line gives candidates to the pixels it crosses."""
    k = np.nonzero(lines.valid)[0]
    if not len(k):
        return None, np.zeros(0, int), np.zeros(0)
    k = k[np.argsort(lines.arc[k], kind="stable")]
    tangents = outer.tangents_at(lines.arc[k])
    points = lines.end[k]
    points_px = ws.grid.to_pixels(points)
    vertex = ws.mesh.add(points, points_px, lines.end_h[k])
    pixels = np.rint(points_px).astype(int)
    state = _outer_state(points, points_px, pixels, tangents, lines.end_h[k], lines.gradient[k],
                         lines.end_variance[k], vertex, ws.toggle_window)
    # Rasterise the segments: samples every quarter pixel, one candidate per (line, pixel).
    start_px, end_px = ws.grid.to_pixels(lines.start[k]), points_px
    steps = np.maximum(np.ceil(4 * np.linalg.norm(end_px - start_px, axis=1)).astype(int), 1) + 1
    which = np.repeat(np.arange(len(k)), steps)
    frac = (np.arange(steps.sum()) - np.repeat(np.cumsum(steps) - steps, steps)) / np.repeat(steps - 1, steps)
    samples = start_px[which] + frac[:, None] * (end_px - start_px)[which]
    cells = np.rint(samples).astype(int)
    inside = (cells[:, 0] >= 0) & (cells[:, 0] < ws.shape[0]) & (cells[:, 1] >= 0) & (cells[:, 1] < ws.shape[1])
    flat = np.where(inside, cells[:, 0] * ws.shape[1] + cells[:, 1], 0)
    keep = inside & ws.allowed[flat]
    pairs = np.unique(np.stack([which[keep], flat[keep]], axis=1), axis=0)
    if not len(pairs):
        return state, np.zeros(0, int), np.zeros(0)
    centres = ws.grid.to_continuous(np.stack(np.divmod(pairs[:, 1], ws.shape[1]), axis=1).astype(float))
    return state, pairs[:, 1], lines.plane(k[pairs[:, 0]], centres)


def _fill(inner: CurveState, outer: Curve, lines: Lines, ws: Workspace):
    """SFS-SPS / SFS-Buffer: planar SPS wedges between consecutive lines, outer-curve completion, rasterisation."""
    k = np.nonzero(lines.valid)[0]
    if len(k) < 2:
        return None, np.zeros(0, int), np.zeros(0)
    m = len(outer)
    length = outer.length
    # Wedges between consecutive valid lines (closed curve: the last pairs with the first).
    a, b = k, np.roll(k, -1)
    forward = np.mod(lines.arc[b] - lines.arc[a], length)
    # Each wedge takes the outer arc between its two hits that makes the smaller polygon: normally the
    # forward (counter-clockwise) one; backward when the lines reach the outer curve in reverse order
    # (crossed lines, a bow tie; or a hit in a concavity behind the previous one).
    i_a = np.searchsorted(outer.arc, lines.arc[a], side="left") % m
    i_b = np.searchsorted(outer.arc, lines.arc[b], side="left") % m
    count_fwd = np.where(forward > 0, np.mod(i_b - i_a, m), 0)
    count_bwd = np.where(forward > 0, np.mod(i_a - i_b, m), 0)
    area_fwd = _wedge_area(lines, a, b, outer, i_a, count_fwd, 1)
    area_bwd = _wedge_area(lines, a, b, outer, np.mod(i_a - 1, m), count_bwd, -1)
    reverse = np.abs(area_bwd) < np.abs(area_fwd)
    ws.count("reversed_wedges", reverse.sum())
    span = np.where(reverse, length - forward, forward)
    i0 = np.where(reverse, i_b, i_a)
    i1 = np.where(reverse, i_a, i_b)
    count = np.where(reverse, count_bwd, count_fwd)
    # Outer vertices of every wedge, ordered from line a towards line b.
    wedge = np.repeat(np.arange(len(a)), count)
    step = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    vertex = np.where(reverse[wedge], i1[wedge] - 1 - step, i0[wedge] + step) % m
    w = np.mod(np.where(reverse[wedge], lines.arc[a][wedge] - outer.arc[vertex],
                        outer.arc[vertex] - lines.arc[a][wedge]), length) / np.maximum(span[wedge], 1e-300)
    p = outer.points[vertex]
    ka, kb = a[wedge], b[wedge]
    h, w = fill_heights(p, ka, kb, lines, ws.fill, np.clip(w, 0.0, 1.0))
    grad = (1 - w)[:, None] * lines.gradient[ka] + w[:, None] * lines.gradient[kb]
    var = (1 - w) * lines.end_variance[ka] + w * lines.end_variance[kb]
    # Vertices reached by several (reversed) wedges take the mean.
    hits = np.bincount(vertex, minlength=m)
    covered = hits > 0
    if not covered.any():
        return None, np.zeros(0, int), np.zeros(0)
    mean_h = np.bincount(vertex, h, m)[covered] / hits[covered]
    mean_g = np.stack([np.bincount(vertex, grad[:, c], m)[covered] for c in (0, 1)], axis=1) / hits[covered, None]
    mean_v = np.bincount(vertex, var, m)[covered] / hits[covered]
    outer_ids = np.full(m, -1)
    outer_ids[covered] = ws.mesh.add(outer.points[covered], outer.points_px[covered], mean_h)
    state = _outer_state(outer.points[covered], outer.points_px[covered], outer.pixels[covered],
                         outer.tangents[covered], mean_h, mean_g, mean_v, outer_ids[covered], ws.toggle_window)
    # End vertices of the lines: new vertices, except lines ending on their start (crossings) or on the buffer.
    end_ids = np.full(len(inner), -1)
    moved = lines.valid & (np.linalg.norm(lines.end - lines.start, axis=1) > 1e-12)
    end_ids[~moved] = inner.vertex[~moved]
    moved_idx = np.nonzero(moved)[0]
    unique_end, first, inverse = np.unique(lines.end[moved], axis=0, return_index=True, return_inverse=True)
    new_ids = ws.mesh.add(unique_end, ws.grid.to_pixels(unique_end), lines.end_h[moved_idx[first]])
    end_ids[moved_idx] = new_ids[inverse.ravel()]
    faces, exclusive, face_wedge = _wedge_triangles(a, b, count, vertex, inner.vertex, end_ids, outer_ids)
    ws.mesh.add_faces(faces)
    pixel, value = _rasterise(faces, exclusive, face_wedge, a, b, lines, ws)
    return state, pixel, value


def _wedge_area(lines: Lines, a, b, outer: Curve, first, count, step) -> np.ndarray:
    """Signed areas of the wedge polygons (start a, end a, ``count`` outer vertices from ``first`` by
    ``step``, end b, start b), from prefix sums of the outer curve's shoelace terms."""
    m = len(outer)
    p = outer.points
    terms = cross2(p, np.roll(p, -1, axis=0))  # term k joins vertex k to k + 1
    prefix = np.concatenate([[0.0], np.cumsum(np.tile(terms, 2))])
    last = np.mod(first + step * (count - 1), m)
    # Sum of the terms between consecutive chain vertices (count - 1 of them).
    lo = np.where(step > 0, first, last)
    chain = prefix[lo + np.maximum(count - 1, 0)] - prefix[lo]
    chain = chain * step
    vf, vl = p[first], p[last]
    sa, ea, sb, eb = lines.start[a], lines.end[a], lines.start[b], lines.end[b]
    joins = np.where(count > 0, cross2(ea, vf) + chain + cross2(vl, eb), cross2(ea, eb))
    return 0.5 * (cross2(sa, ea) + joins + cross2(eb, sb) + cross2(sb, sa))


def _wedge_triangles(a, b, count, vertex, inner_ids, end_ids, outer_ids):
    """Triangles of every wedge: polygon (inner a, end a, outer vertices..., end b, inner b) as two fans.

    Edges on the inner curve and on line b are exclusive for the rasterisation.
    """
    faces, exclusive, owner = [], [], []
    starts = np.cumsum(count) - count
    for w in range(len(a)):
        chain = [end_ids[a[w]], *outer_ids[vertex[starts[w]:starts[w] + count[w]]], end_ids[b[w]]]
        ia, ib = inner_ids[a[w]], inner_ids[b[w]]
        last = len(chain) - 1
        mid = last // 2
        for c in range(mid):
            faces.append((ia, chain[c], chain[c + 1]))
            exclusive.append((False, False, False))
        faces.append((ia, chain[mid], ib))
        exclusive.append((mid == last, True, False))
        for c in range(mid, last):
            faces.append((ib, chain[c], chain[c + 1]))
            exclusive.append((False, c + 1 == last, False))
        owner.extend([w] * (last + 1))
    faces = np.array(faces, dtype=int).reshape(-1, 3)
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    return faces[keep], np.array(exclusive, dtype=bool).reshape(-1, 3)[keep], np.array(owner, dtype=int)[keep]


def _rasterise(faces, exclusive, face_wedge, a, b, lines: Lines, ws: Workspace):
    """Candidate heights of the pixel centres inside the wedges (one per wedge and pixel)."""
    corners = ws.mesh.pixels_of(faces)
    tri, pixel = rasterize_triangles(corners, exclusive, ws.shape)
    keep = ws.allowed[pixel]
    pairs = np.unique(np.stack([face_wedge[tri[keep]], pixel[keep]], axis=1), axis=0)
    if not len(pairs):
        return np.zeros(0, int), np.zeros(0)
    wedge, pixel = pairs[:, 0], pairs[:, 1]
    centres = ws.grid.to_continuous(np.stack(np.divmod(pixel, ws.shape[1]), axis=1).astype(float))
    return pixel, fill_heights(centres, a[wedge], b[wedge], lines, ws.fill)[0]


def fill_heights(points: np.ndarray, ka: np.ndarray, kb: np.ndarray, lines: Lines, fill: str,
                 weight: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Heights of the sand-pile fill between lines ``ka`` and ``kb`` at ``points``.

    Parameters
    ----------
    points : ndarray, (n, 2)
        Points to fill, continuous units (m in a scan's local frame).
    ka, kb : ndarray of int, (n,)
        The two bounding lines of each point's wedge.
    lines : Lines
        The annulus' propagation lines.
    fill : {"planar", "ruled", "cone"}
        ``planar``: blend of the two lines' tangent planes with weight
        ``weight`` (default: relative distance to the two lines).
        ``ruled``: the ruled surface ``x(v) + u g(v)`` whose rulings turn
        linearly from one line to the other (``x(v)`` on the chord between
        the line starts, ``g(v)`` the normalised blend of their directions)
        and whose slope along each ruling is the blend of the lines' slopes;
        ``v`` solves a quadratic. ``cone``: where the two lines meet behind
        their starts at heights that agree within 5 %, the circular cone of
        that apex; elsewhere ``ruled``.
    weight : ndarray, (n,), optional
        Blend weight toward line ``kb``, in [0, 1] (``planar`` only).

    Returns
    -------
    height, weight : ndarray
        Heights and the blend weight toward line ``kb`` (for the gradients).
    """
    if fill == "planar":
        if weight is None:
            da = _segment_distance(points, lines.start[ka], lines.end[ka])
            db = _segment_distance(points, lines.start[kb], lines.end[kb])
            weight = np.where(da + db > 1e-12, da / np.maximum(da + db, 1e-300), 0.5)
        return (1 - weight) * lines.plane(ka, points) + weight * lines.plane(kb, points), weight
    xa, xb, da, db = lines.start[ka], lines.start[kb], lines.direction[ka], lines.direction[kb]
    e, q, dd = xb - xa, points - xa, db - da
    qa, qb = cross2(e, dd), cross2(q, dd) - cross2(e, da)
    qc = cross2(q, da)
    disc = np.maximum(qb * qb + 4 * qa * qc, 0.0)  # roots of -qa v^2 + qb v + qc = 0
    root = np.sqrt(disc)
    with np.errstate(divide="ignore", invalid="ignore"):
        linear = -qc / qb
        v1 = (qb - root) / (2 * qa)
        v2 = (qb + root) / (2 * qa)
    v1 = np.where(np.abs(qa) < 1e-12, linear, v1)
    v2 = np.where(np.abs(qa) < 1e-12, linear, v2)
    off1 = np.abs(np.clip(v1, 0, 1) - v1)
    off2 = np.abs(np.clip(v2, 0, 1) - v2)
    v = np.where(np.nan_to_num(off1, nan=np.inf) <= np.nan_to_num(off2, nan=np.inf), v1, v2)
    v = np.clip(np.nan_to_num(v, nan=0.5), 0.0, 1.0)
    base = xa + v[:, None] * e
    ruling = (1 - v)[:, None] * da + v[:, None] * db
    ruling /= np.maximum(np.linalg.norm(ruling, axis=1, keepdims=True), 1e-300)
    u = np.sum((points - base) * ruling, axis=1)
    slope_a, slope_b = lines.slope(ka), lines.slope(kb)
    height = (1 - v) * lines.start_h[ka] + v * lines.start_h[kb] + ((1 - v) * slope_a + v * slope_b) * u
    if fill == "cone":
        apex, s_a, s_b = _line_intersection(xa, da, xb, db)
        h_a, h_b = lines.start_h[ka] + slope_a * s_a, lines.start_h[kb] + slope_b * s_b
        drop = 0.5 * (np.abs(slope_a * s_a) + np.abs(slope_b * s_b))
        ok = (s_a < 0) & (s_b < 0) & (np.abs(h_a - h_b) <= 0.05 * drop) & (slope_a * slope_b > 0)
        cone = 0.5 * (h_a + h_b) + 0.5 * (slope_a + slope_b) * np.linalg.norm(points - apex, axis=1)
        height = np.where(ok, cone, height)
    return height, v


def _line_intersection(xa, da, xb, db):
    """Intersection ``xa + s da = xb + t db`` of two lines: point, s, t (NaN when parallel)."""
    denom = cross2(da, db)
    rel = xb - xa
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(np.abs(denom) > 1e-12, cross2(rel, db) / denom, np.nan)
        t = np.where(np.abs(denom) > 1e-12, cross2(rel, da) / denom, np.nan)
    return xa + s[:, None] * da, s, t


def _segment_distance(p, s, e):
    d = e - s
    length2 = np.sum(d * d, axis=1)
    t = np.clip(np.sum((p - s) * d, axis=1) / np.maximum(length2, 1e-300), 0, 1)
    return np.linalg.norm(p - s - t[:, None] * d, axis=1)

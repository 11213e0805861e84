"""The PROP-SFS engine on a height field: alpha image + height image -> corrected heights, mesh, redundancy.

This is the thesis' algorithm on its own terms (an orthographic view along
e3, heights ``h(x)`` over continuous coordinates ``x = sc(i, j)``):

A. masked 3 x 3 smoothing of the alpha image (``n_smooth`` passes);
B. quantisation into iso-alpha domains;
C. recursive watershed into parts with one seed each;
D. per part and level, the region ``D_i`` (seed component of ``s_0 ∪ .. ∪
   s_i`` opened by the 3 x 3 square, holes filled, nested in ``D_(i-1)``) and
   its boundary curve;
E. seed initialisation from the height image;
F. propagation annulus by annulus (:mod:`leafsfs.propagate`);
G. per pixel the median of its candidate heights, their count and spread,
   the redundancy ratios rppp_n and the mesh.

:func:`leafsfs.reconstruct` wraps it for scans (local frame, calibration).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from matplotlib.path import Path as MplPath
from scipy import ndimage
from scipy.spatial import Delaunay, cKDTree

from leafsfs.contour import open_region
from leafsfs.curves import Curve, extract_curve, project_on_curve
from leafsfs.errors import SfsError
from leafsfs.grid import PixelGrid
from leafsfs.mesh import MeshBuilder
from leafsfs.params import VARIANTS, SfsParams
from leafsfs.propagate import Workspace, propagate_annulus
from leafsfs.quantize import assign_levels, quantile_thresholds, shell_fractions
from leafsfs.seed import initial_state, seed_harmonics
from leafsfs.segment import split_parts


def smooth_alpha(alpha: np.ndarray, mask: np.ndarray, passes: int) -> np.ndarray:
    """Repeated normalised 3 x 3 mean of ``alpha`` over ``mask`` (digest §3.1, A13); NaN off the mask.

    Parameters
    ----------
    alpha : ndarray, 2-D
        Incidence angle of every pixel, rad.
    mask : ndarray of bool, 2-D
        Pixels averaged (and the only ones given a value).
    passes : int
        Number of 3 x 3 smoothing passes (0 keeps ``alpha`` on the mask).

    Returns
    -------
    ndarray, 2-D
        Smoothed alpha, rad.
    """
    weight = ndimage.uniform_filter(mask.astype(float), size=3, mode="nearest")
    values = np.where(mask, alpha, 0.0)
    for _ in range(passes):
        values = np.where(mask, ndimage.uniform_filter(values, size=3, mode="nearest") / np.maximum(weight, 1e-12), 0)
    return np.where(mask, values, np.nan)


@dataclass
class HeightResult:
    """Outputs of :func:`reconstruct_heights` on the pixel grid.

    Attributes
    ----------
    height : ndarray, 2-D
        Corrected height: median of the candidates, or the rim extrapolation; NaN where none.
    count : ndarray of int, 2-D
        Number of PROP-SFS candidate heights per pixel (seed pixels: 1).
    spread : ndarray, 2-D
        Largest minus smallest candidate (0 for one candidate, NaN for none).
    seed : ndarray of bool, 2-D
        Pixels that keep their measured height (inside a seed curve).
    extrapolated : ndarray of bool, 2-D
        Pixels filled by the rim extrapolation (``params.rim_px``).
    mask : ndarray of bool, 2-D
        The object's pixels.
    alpha : ndarray, 2-D
        Smoothed alpha image, rad.
    levels, parts : ndarray of int, 2-D
        Iso-alpha domain and watershed part of each pixel.
    thresholds : ndarray
        Quantisation thresholds, rad.
    vertices : ndarray, (V, 3)
        Mesh vertices ``(x1, x2, h)`` in continuous coordinates.
    vertex_pixels : ndarray, (V, 2)
        Their pixel positions.
    faces : ndarray of int, (F, 3)
        Mesh triangles.
    curves : list of (part, level, alpha, points_px)
        The boundary curves used (for plots).
    stats : dict
        Counters of the propagation (lines, crossings, buffered lines, ...).
    """

    height: np.ndarray
    count: np.ndarray
    spread: np.ndarray
    seed: np.ndarray
    extrapolated: np.ndarray
    mask: np.ndarray
    alpha: np.ndarray
    levels: np.ndarray
    parts: np.ndarray
    thresholds: np.ndarray
    vertices: np.ndarray
    vertex_pixels: np.ndarray
    faces: np.ndarray
    curves: list = field(default_factory=list)
    stats: dict = field(default_factory=dict)

    def rppp(self, n_max: int = 3) -> dict[str, float]:
        """Redundancy ratios: fraction of object pixels with exactly n candidates, ``rppp_0 .. rppp_n_max``,
        plus ``rppp_more`` for more than ``n_max``."""
        counts = self.count[self.mask]
        total = max(len(counts), 1)
        out = {f"rppp_{n}": float(np.sum(counts == n) / total) for n in range(n_max + 1)}
        out["rppp_more"] = float(np.sum(counts > n_max) / total)
        return out

    @property
    def completeness(self) -> float:
        """Fraction of object pixels with at least one PROP-SFS candidate."""
        return float(np.mean(self.count[self.mask] > 0)) if self.mask.any() else 0.0


def domain_thresholds(alpha: np.ndarray, mask: np.ndarray, params: SfsParams,
                      reliable: np.ndarray | None = None) -> np.ndarray:
    """Quantisation thresholds (rad, last = pi/2) for an object's smoothed alpha values.

    The shell rule measures the object ``mask``; the quantiles are those of its
    ``reliable`` pixels (default: all of them).

    Parameters
    ----------
    alpha : ndarray, 2-D
        Smoothed alpha image, rad.
    mask : ndarray of bool, 2-D
        The object's pixels.
    params : SfsParams
        Quantisation rule (``quantization``: fixed thresholds in degrees, the
        shell rule or fixed area fractions) and its parameters.
    reliable : ndarray of bool, 2-D, optional
        Pixels whose alpha values set the quantiles (default, or when empty: ``mask``).

    Returns
    -------
    ndarray
        Increasing thresholds, rad.
    """
    reliable = mask if reliable is None or not reliable.any() else reliable
    if params.quantization == "fixed":
        return np.append(np.radians(params.thresholds_deg), np.pi / 2)
    if params.quantization == "shell":
        eps_alpha, eps_seed = shell_fractions(mask, params.shell_set)
    else:
        eps_alpha, eps_seed = params.eps_alpha, params.eps_seed
    return quantile_thresholds(alpha[reliable], eps_alpha, eps_seed)


def reconstruct_heights(alpha: np.ndarray, height: np.ndarray, mask: np.ndarray | None = None,
                        grid: PixelGrid | None = None, variant: str = "buffer",
                        params: SfsParams | None = None, fusion=None,
                        unreliable: np.ndarray | None = None) -> HeightResult:
    """Run PROP-SFS on an alpha image and a height image.

    Parameters
    ----------
    alpha : ndarray, 2-D
        Incidence angle of every pixel, rad (before smoothing).
    height : ndarray, 2-D
        Measured heights (NaN = none). Only the seeds and their surroundings
        are used by the thesis variants; ``fused`` uses all of it.
    mask : ndarray of bool, 2-D, optional
        Object pixels (default: where alpha is finite).
    grid : PixelGrid, optional
        Pixel-to-continuous map (default: unit square pixels).
    variant : {"simple", "sps", "buffer", "fused"}
        Propagation variant.
    params : SfsParams, optional
        Parameters (default :class:`SfsParams`).
    fusion : leafsfs.fusion.Fusion, optional
        Measurement model of the fused variant (built from ``params`` when omitted).
    unreliable : ndarray of bool, 2-D, optional
        Object pixels whose alpha and height are not to be trusted (e.g. the
        mixed points at edges): they are left out of the smoothing and of
        every use of the measured heights, and join the outermost domain.

    Returns
    -------
    HeightResult

    Raises
    ------
    SfsError
        On inconsistent shapes, an empty object or an unknown variant.

    Examples
    --------
    A spherical cap (sphere radius 4 cm) seen along its axis over a disk of
    radius 2 cm, on 1 mm pixels. The alpha image covers the disk; the
    measured heights only its central 1 cm, yet the propagation gives every
    pixel a height within half a millimetre of the truth. Domains of 10 % of
    the area each: the default shell rule would make nearly all of an object
    this small (41 pixels across) its seed.

    >>> import numpy as np
    >>> from leafsfs import SfsParams, reconstruct_heights
    >>> from leafsfs.grid import PixelGrid
    >>> y, x = np.mgrid[-20:21, -20:21] * 0.001                 # m
    >>> r = np.hypot(x, y)
    >>> mask = r <= 0.02
    >>> truth = np.sqrt(0.04**2 - np.minimum(r, 0.02) ** 2)     # heights, m
    >>> alpha = np.where(mask, np.arcsin(np.minimum(r, 0.02) / 0.04), np.nan)  # rad
    >>> measured = np.where(r < 0.01, truth, np.nan)
    >>> grid = PixelGrid(0.001 * np.eye(2), (-0.02, -0.02))
    >>> params = SfsParams(quantization="percentile", eps_seed=0.1, eps_alpha=0.1)
    >>> result = reconstruct_heights(alpha, measured, mask, grid, params=params)
    >>> error = np.abs(result.height - truth)[mask]
    >>> bool(np.isfinite(error).all()), bool(error.max() < 0.5e-3)
    (True, True)
    """
    params = params or SfsParams()
    grid = grid or PixelGrid()
    alpha = np.asarray(alpha, dtype=float)
    height = np.asarray(height, dtype=float)
    if alpha.ndim != 2 or height.shape != alpha.shape:
        raise SfsError(f"alpha and height must be 2-D images of one shape, got {alpha.shape} and {height.shape}")
    mask = np.isfinite(alpha) if mask is None else np.asarray(mask)
    if mask.shape != alpha.shape or mask.dtype != bool:
        raise SfsError(f"mask must be a boolean image of shape {alpha.shape}, got {mask.dtype} {mask.shape}")
    if variant not in VARIANTS:
        raise SfsError(f"unknown PROP-SFS variant {variant!r}; choose one of {', '.join(VARIANTS)}")
    unreliable = np.zeros(alpha.shape, bool) if unreliable is None else np.asarray(unreliable, bool)
    if unreliable.shape != alpha.shape:
        raise SfsError(f"unreliable must be a boolean image of shape {alpha.shape}, got {unreliable.shape}")
    unreliable = unreliable & mask
    mask = mask & (np.isfinite(alpha) | unreliable)
    if mask.sum() < 9:
        raise SfsError(f"the object has {int(mask.sum())} pixels with a valid alpha; PROP-SFS needs at least 9")
    valid = mask & np.isfinite(height) & ~unreliable
    if not valid.any():
        raise SfsError("no object pixel has a measured height (range); the seeds cannot be initialised")
    if variant == "fused" and fusion is None:
        from leafsfs.fusion import Fusion
        fusion = Fusion(height, valid, grid, params)

    smoothed = smooth_alpha(np.clip(alpha, 0, np.pi / 2), mask & ~unreliable, params.n_smooth)
    smoothed[unreliable] = np.pi / 2
    thresholds = domain_thresholds(smoothed, mask, params, mask & ~unreliable)
    if unreliable.any() and (mask & ~unreliable).any():
        # The unreliable pixels form the outermost domain of their own, even where the quantiles leave one domain.
        top = float(np.max(smoothed[mask & ~unreliable]))
        thresholds = np.unique(np.append(thresholds[thresholds < top], [top, np.pi / 2]))
    levels = assign_levels(smoothed, mask, thresholds)
    parts = split_parts(np.where(mask, smoothed, np.pi), levels, params.min_seed_px, params.orphans)
    shape = alpha.shape
    pixels, values, curves, anchors, meshes = [], [], [], [], []
    seed = np.zeros(shape, dtype=bool)
    stats: dict = {"parts": int(parts.max())}
    for k, box in enumerate(ndimage.find_objects(parts), start=1):
        if box is None:
            continue
        # Work on the part's bounding box (plus a margin for the LSR neighbourhoods).
        margin = int(math.ceil(params.lsr_radius_px)) + 1
        box = tuple(slice(max(b.start - margin, 0), min(b.stop + margin, n)) for b, n in zip(box, shape))
        origin = np.array([box[0].start, box[1].start])
        sub_grid = PixelGrid(grid.matrix, grid.offset + grid.matrix @ origin)
        part = parts[box] == k
        ws = Workspace(sub_grid, part.shape, part.ravel().copy(), MeshBuilder(), variant, params.fill,
                       params.buffer_rule, params.crossing_window, params.toggle_window,
                       fusion if variant == "fused" else None, stats)
        out = _run_part(part, smoothed[box], levels[box], height[box], valid[box], unreliable[box], sub_grid,
                        params, ws, k, thresholds)
        if out is None:
            continue
        part_pixels, part_values, part_seed, part_curves, part_anchors = out
        seed[box] |= part_seed
        for local in part_pixels:
            rows, cols = np.divmod(local, part.shape[1])
            pixels.append((rows + origin[0]) * shape[1] + cols + origin[1])
        values += part_values
        curves += [(kk, level, alpha_i, points_px + origin) for kk, level, alpha_i, points_px in part_curves]
        anchors += part_anchors
        meshes.append((ws.mesh.arrays(), origin))
    pixel = np.concatenate(pixels) if pixels else np.zeros(0, int)
    value = np.concatenate(values) if values else np.zeros(0)
    median, count, spread = _merge_candidates(pixel, value, shape)
    extrapolated = _rim(median, count, mask, grid, anchors, params.rim_px)
    vertices, vertex_pixels, faces = _merge_meshes(meshes)
    stats["toggles"] = stats.get("toggles", 0)
    if fusion is not None:
        stats.update(fusion.stats)
    return HeightResult(median, count, spread, seed, extrapolated, mask, smoothed, levels, parts, thresholds,
                        vertices, vertex_pixels, faces, curves, stats)


def _domain_alpha(values: np.ndarray, params: SfsParams, thresholds: np.ndarray, level: int) -> float:
    """Alpha of domain ``level``: median or mean of its pixels, or its lower or upper bound among the
    ``thresholds`` (rad), clamped to alpha_max, plus the bias (digest A1)."""
    if params.alpha_rule == "upper":
        base = float(thresholds[level])
    elif params.alpha_rule == "lower":
        base = float(thresholds[level - 1]) if level > 0 else 0.0
    else:
        base = float(np.median(values) if params.alpha_rule == "median" else np.mean(values))
    base = min(base, math.radians(params.alpha_max_deg)) + math.radians(params.alpha_bias_deg)
    return float(np.clip(base, 0.0, math.radians(89.0)))


def _regions(part: np.ndarray, levels: np.ndarray, anchor: tuple[int, int]):
    """Nested regions ``D_i`` of a part's chain: ``(level, region)`` for every level where the region grows."""
    previous = None
    for level in np.unique(levels[part]):
        raw = part & (levels <= level)
        grown = open_region(raw) if previous is None else open_region(raw) | previous
        labels, _ = ndimage.label(grown)
        if labels[anchor] == 0:  # the opening removed the seed: keep it unopened
            labels, _ = ndimage.label(raw if previous is None else raw | previous)
        region = ndimage.binary_fill_holes(labels == labels[anchor])
        if previous is None:
            for _ in range(3):  # a seed thinner than 3 pixels has no proper curve: grow it within the part
                if open_region(region).any():
                    break
                region = ndimage.binary_dilation(region, np.ones((3, 3), bool)) & part
        if previous is not None and region.sum() == previous.sum():
            continue
        yield int(level), region
        previous = region


def _run_part(part, smoothed, levels, height, valid, unreliable, grid: PixelGrid, params: SfsParams, ws: Workspace,
              k: int, thresholds: np.ndarray):
    # The seed is anchored at the lowest-alpha pixel of the largest piece of the lowest domain: a stray pixel of that
    # domain apart from its body (a noisy rim pulse) would seed from a patch with too few measured heights.
    pieces, _ = ndimage.label(part & (levels == levels[part].min()))
    body = pieces == np.argmax(np.bincount(pieces.ravel())[1:]) + 1
    candidates = np.argwhere(body)
    anchor = tuple(candidates[np.argmin(smoothed[body])])
    chain = list(_regions(part, levels, anchor))
    seed_level, seed_region = chain[0]
    seed_curve = extract_curve(seed_region, grid, params.tangents)
    if seed_curve is None:
        return None
    harmonics = seed_harmonics(seed_curve, int(seed_region.sum()), params.seed_cutoff, params.seed_peaks)
    state = initial_state(seed_curve, height, valid, grid, harmonics, params.lsr_radius_px, params.toggle_window)
    if state is None:
        return None
    state.vertex = ws.mesh.add(state.points, state.points_px, state.height)
    state.variance[:] = params.sigma_range_m**2
    inside = _inside_curve(part, seed_curve, grid)
    # Every pixel of the seed domain keeps its measured height (thesis: h = Mh on the seed), also those that the
    # opening of the curve extraction left outside the seed curve (1-2 px strips).
    seed_pixels = (inside | (part & (levels <= seed_level))) & valid
    ws.allowed &= ~(inside | seed_pixels).ravel()
    _seed_mesh(ws.mesh, seed_curve, state.vertex, inside & valid, height, grid)
    pixels = [np.flatnonzero(seed_pixels)]
    values = [height[seed_pixels]]
    curves = [(k, seed_level, float("nan"), seed_curve.points_px)]
    anchors = [state]
    previous = seed_region
    # A first domain without reliable pixels propagates with the alpha of the seed's reliable rim.
    rim = seed_region & ~ndimage.binary_erosion(seed_region) & ~unreliable
    alpha = None
    if rim.any():
        alpha = _domain_alpha(smoothed[rim], params, thresholds, seed_level)
        spread = float(np.std(np.tan(np.minimum(smoothed[rim], math.radians(params.alpha_max_deg)))))
    for level, region in chain[1:]:
        # The domain's alpha from its reliable pixels (else the new reliable ones', else the previous domain's,
        # else any new pixel's).
        known = region & ~previous & np.isfinite(smoothed)
        new = known & ~unreliable
        in_domain = new & (levels == level)
        pool = in_domain if in_domain.any() else (new if new.any() else known)
        if (new.any() or alpha is None) and pool.any():
            alpha = _domain_alpha(smoothed[pool], params, thresholds, level)
            spread = float(np.std(np.tan(np.minimum(smoothed[pool], math.radians(params.alpha_max_deg)))))
        outer = extract_curve(region, grid, params.tangents)
        previous = region
        if outer is None or alpha is None:
            continue
        curves.append((k, level, alpha, outer.points_px))
        state, pixel, value = propagate_annulus(state, outer, alpha, ws, spread)
        pixels.append(pixel)
        values.append(value)
        if state is None:
            break
        ws.count("toggles", np.sum(state.sign == 0))
        anchors.append(state)
    return pixels, values, seed_pixels, curves, anchors


def _inside_curve(part: np.ndarray, curve: Curve, grid: PixelGrid) -> np.ndarray:
    """Pixels of ``part`` whose centres lie inside or on the closed curve."""
    rows, cols = np.nonzero(part)
    centres = grid.to_continuous(np.stack([rows, cols], axis=1).astype(float))
    inside = MplPath(curve.points).contains_points(centres)
    # Only pixels next to the curve's own pixels can lie exactly on it.
    band = np.zeros(part.shape, dtype=bool)
    band[np.clip(curve.pixels[:, 0], 0, part.shape[0] - 1), np.clip(curve.pixels[:, 1], 0, part.shape[1] - 1)] = True
    near = ndimage.binary_dilation(band, np.ones((3, 3), bool))[rows, cols] & ~inside
    if near.any():
        inside[near] = project_on_curve(centres[near], curve)[1] < 1e-9
    out = np.zeros(part.shape, dtype=bool)
    out[rows[inside], cols[inside]] = True
    return out


def _seed_mesh(mesh: MeshBuilder, curve: Curve, curve_ids: np.ndarray, seed_pixels: np.ndarray,
               height: np.ndarray, grid: PixelGrid) -> None:
    """Triangulate the seed: its curve and the measured pixel centres inside it (Delaunay, kept inside the curve)."""
    rows, cols = np.nonzero(seed_pixels)
    centres_px = np.stack([rows, cols], axis=1).astype(float)
    if len(centres_px):
        keep = cKDTree(curve.points_px).query(centres_px)[0] > 1e-6  # no duplicate of a curve point
        centres_px, rows, cols = centres_px[keep], rows[keep], cols[keep]
    ids = np.concatenate([curve_ids, mesh.add(grid.to_continuous(centres_px), centres_px, height[rows, cols])])
    points = np.concatenate([curve.points, grid.to_continuous(centres_px)])
    if len(points) < 3:
        return
    try:
        triangles = Delaunay(points).simplices
    except Exception:  # qhull: degenerate (collinear) point sets have no triangulation
        return
    centroids = points[triangles].mean(axis=1)
    mesh.add_faces(ids[triangles[MplPath(curve.points).contains_points(centroids)]])


def _merge_meshes(meshes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Concatenate the parts' meshes (vertex pixel positions back in full-image coordinates)."""
    if not meshes:
        return np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 3), int)
    offsets = np.cumsum([0] + [len(v) for (v, _, _), _ in meshes])
    vertices = np.concatenate([v for (v, _, _), _ in meshes])
    vertex_pixels = np.concatenate([px + origin for (_, px, _), origin in meshes])
    faces = np.concatenate([f + off for ((_, _, f), _), off in zip(meshes, offsets)])
    return vertices, vertex_pixels, faces


def _merge_candidates(pixel: np.ndarray, value: np.ndarray, shape) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel: median of its candidates, their number and their range (max - min)."""
    size = shape[0] * shape[1]
    count = np.bincount(pixel, minlength=size)
    median = np.full(size, np.nan)
    spread = np.full(size, np.nan)
    if len(pixel):
        order = np.lexsort((value, pixel))
        sorted_values = value[order]
        start = np.concatenate([[0], np.cumsum(count)[:-1]])
        has = count > 0
        lo = start[has] + (count[has] - 1) // 2
        hi = start[has] + count[has] // 2
        median[has] = 0.5 * (sorted_values[lo] + sorted_values[hi])
        spread[has] = sorted_values[start[has] + count[has] - 1] - sorted_values[start[has]]
    return median.reshape(shape), count.reshape(shape), spread.reshape(shape)


def _rim(median: np.ndarray, count: np.ndarray, mask: np.ndarray, grid: PixelGrid, states: list,
         rim_px: int) -> np.ndarray:
    """Fill object pixels near reconstructed ones from the nearest curve point's tangent plane (in place)."""
    extrapolated = np.zeros(mask.shape, dtype=bool)
    covered = count > 0
    if rim_px == 0 or not states or not covered.any():
        return extrapolated
    near = ndimage.binary_dilation(covered, np.ones((3, 3), bool), iterations=rim_px)
    todo = mask & ~covered & near
    if not todo.any():
        return extrapolated
    points = np.concatenate([s.points for s in states])
    heights = np.concatenate([s.height for s in states])
    gradients = np.concatenate([s.gradient for s in states])
    rows, cols = np.nonzero(todo)
    centres = grid.to_continuous(np.stack([rows, cols], axis=1).astype(float))
    _, nearest = cKDTree(points).query(centres)
    median[rows, cols] = heights[nearest] + np.sum(gradients[nearest] * (centres - points[nearest]), axis=1)
    extrapolated[rows, cols] = True
    return extrapolated

"""Procedural leaves: parametric blade, petiole, bending, cupping, twist and wrinkles.

A leaf is built in its own frame from a flat blade and then deformed:

1. **Outline.** The half-width along the midrib is
   ``w(s) = W (1 - d (1 - cos 2πns) / 2) s^a (1 - s)^b / m`` for ``s = u / L`` in
   ``[0, 1]``, with ``m`` the maximum of ``s^a (1 - s)^b`` (reached at
   ``s = a / (a + b)``). ``a < 1`` gives a rounded base, ``b > 1`` a tapering,
   acuminate apex; ``a / (a + b) < 0.5`` puts the widest point below the middle
   (ovate). ``d`` and ``n`` add an optional crenate-serrate margin.
2. **Wrinkles.** A normal offset ``A sin(2π u / λ + φ) sin(π |v| / w)``:
   interveinal bulges that vanish on the midrib and the margin.
3. **Roll** (cupping). The cross-section is wrapped on a circle of curvature
   ``roll / W`` (the margin at the widest point turns up by ``roll`` rad).
4. **Twist.** The cross-section turns about the midrib by ``twist · s``.
5. **Bend.** The midrib is a curve whose tangent elevation is
   ``-bend · s²`` (the tip droops away from the adaxial side); it is built
   from chords of exact length, so bending alone (like rolling alone) is an
   isometry and keeps the blade area.
6. **Petiole.** A thin open tube continuing the midrib backwards from the
   blade base.

Roll combined with bend gives the saddle shape that most pear leaves have.
The leaf is then put in its **canonical frame**: origin at the blade's area
centroid, +x along the midrib chord (blade base to apex), +z on the adaxial
side with the mean normal in the x-z plane. Scene poses place that frame.

**Facet rule.** The blade is a structured grid of ``n_u`` rows by ``n_v``
columns (fans at the base and apex). Rows cut each leaf's margin into equal
arcs of at most ``f`` (so they are denser where the outline turns, at a
rounded base), and ``n_v = 2 ⌈W / f⌉``: grid sides never exceed ``f`` (cell
diagonals ``√2 f``, up to ``2 f`` where the width changes fastest); single leaves
use ``f`` = :func:`~scenes.primitives.facet_size_m` at their distance (1/4 of
the beam footprint diameter). Populations (trees, orchards) may use a
coarser ``f`` to keep the triangle count manageable.

**Truth** (:func:`leaf_truths`, from the final 3-D mesh): one-sided blade area,
area-weighted mean unit normal of the adaxial side, midrib-chord elevation
and azimuth, the 3-D outline polygon, blade length and half-width. The mesh's
per-face labels (``LEAF_LABELS``) tell blade from petiole triangles.

Pear (Conference) defaults (:data:`PEAR`, :func:`sample_pear_leaf`): blade
length 6.47 cm (sd 0.5) and half-width 2.19 cm (sd 0.38) from the ten lab
leaves of Balduzzi et al. 2011 (Sensors 11:1657, §2.2.2). The outline
exponents, petiole, bend, roll, twist and wrinkle ranges are assumptions
chosen to look like Conference leaves (ovate, short-acuminate, slightly
saddle-shaped, wrinkled at the millimetre scale).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import integrate

from scenes.errors import SceneError
from scenes.primitives import cross
from scenes.scene import Material, SceneObject

#: Names of the per-face labels of a leaf mesh (``SceneObject.face_labels`` indexes this tuple).
LEAF_LABELS = ("blade", "petiole")
BLADE, PETIOLE = 0, 1

#: Sides of the petiole tube.
PETIOLE_SIDES = 6


@dataclass(frozen=True)
class LeafShape:
    """Parameters of one leaf (metres and radians).

    Parameters
    ----------
    length_m : float
        Blade length L along the midrib, m.
    half_width_m : float
        Largest half-width W of the blade, m.
    base_exponent, apex_exponent : float
        Outline exponents ``a`` and ``b`` (see the module docstring).
    serration_depth : float
        Depth of the margin teeth as a fraction of the local half-width (0: entire margin).
    serration_teeth : int
        Number of teeth per side.
    petiole_length_m, petiole_radius_m : float
        Petiole tube; length 0 means no petiole.
    bend : float
        Turn of the midrib tangent from base to apex, rad (positive: the tip droops).
    roll : float
        Turn of the margin at the widest point, rad (positive: edges curl to the adaxial side).
    twist : float
        Rotation of the cross-section at the apex about the midrib, rad.
    wrinkle_amplitude_m, wrinkle_wavelength_m : float
        Amplitude and along-midrib wavelength of the wrinkles, m.
    wrinkle_phase : float
        Phase of the wrinkles, rad.
    """

    length_m: float = 0.0647
    half_width_m: float = 0.0219
    base_exponent: float = 0.7
    apex_exponent: float = 1.15
    serration_depth: float = 0.0
    serration_teeth: int = 30
    petiole_length_m: float = 0.025
    petiole_radius_m: float = 0.0008
    bend: float = 0.3
    roll: float = 0.25
    twist: float = 0.0
    wrinkle_amplitude_m: float = 0.0002
    wrinkle_wavelength_m: float = 0.01
    wrinkle_phase: float = 0.0

    def __post_init__(self):
        for key in ("length_m", "half_width_m", "base_exponent", "apex_exponent", "wrinkle_wavelength_m"):
            _check(self, key, lambda v: v > 0, "a positive number")
        for key in ("petiole_length_m", "petiole_radius_m", "wrinkle_amplitude_m"):
            _check(self, key, lambda v: v >= 0, "a non-negative number")
        for key in ("bend", "roll", "twist", "wrinkle_phase"):
            _check(self, key, lambda v: True, "a finite number (rad)")
        _check(self, "serration_depth", lambda v: 0 <= v < 1, "a number in [0, 1)")
        if isinstance(self.serration_teeth, bool) or not isinstance(self.serration_teeth, int) \
                or self.serration_teeth < 1:
            raise SceneError(f"leaf serration_teeth must be a positive integer, got {self.serration_teeth!r}")
        if self.half_width_m > self.length_m:
            raise SceneError(f"leaf half_width_m ({self.half_width_m}) must not exceed length_m ({self.length_m})")
        if abs(self.roll) > math.pi / 2 or abs(self.bend) > math.pi / 2:
            raise SceneError(f"leaf roll and bend must lie in [-pi/2, pi/2] rad, got {self.roll}, {self.bend}")
        if self.petiole_length_m > 0 and self.petiole_radius_m <= 0:
            raise SceneError("leaf petiole_radius_m must be positive when there is a petiole")

    def replace(self, **changes) -> "LeafShape":
        """A copy with some parameters changed (validated)."""
        unknown = sorted(set(changes) - {f.name for f in dataclasses.fields(self)})
        if unknown:
            raise SceneError(f"unknown leaf parameter(s) {unknown}; allowed: {sorted(leaf_parameter_names())}")
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """All parameters as JSON-ready data."""
        return dataclasses.asdict(self)


def _check(shape, key, ok, what):
    value = getattr(shape, key)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not ok(value):
        raise SceneError(f"leaf {key} must be {what}, got {value!r}")


def leaf_parameter_names() -> tuple[str, ...]:
    """Names of the :class:`LeafShape` parameters."""
    return tuple(f.name for f in dataclasses.fields(LeafShape))


#: Conference pear leaf with the mean lab size and a mild saddle shape.
PEAR = LeafShape()

#: Lab statistics of Conference pear blades (Balduzzi et al. 2011, §2.2.2): mean and sd, m.
PEAR_LENGTH_M = (0.0647, 0.005)
PEAR_HALF_WIDTH_M = (0.0219, 0.0038)


def sample_pear_leaves(rng: np.random.Generator, size_factors) -> list[LeafShape]:
    """Random Conference pear leaves, one per entry of ``size_factors``.

    Blade length and half-width are normal with the lab means and sds (times
    the leaf's size factor, e.g. a shoot-position or population effect),
    clipped to 60-140 % of the mean; the half-width is at most half the
    length. Assumed shape ranges: base exponent U(0.6, 0.85), apex exponent
    U(1.0, 1.3), bend U(0, 0.6) rad, roll U(-0.1, 0.5) rad, twist N(0, 0.12)
    rad, wrinkle amplitude U(0.1, 0.4) mm, wavelength U(8, 14) mm, phase
    U(0, 2π).

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness (same state, same leaves).
    size_factors : array_like, shape (N,)
        Scale of each leaf's length, width and petiole.

    Returns
    -------
    list of LeafShape
        N leaves.
    """
    size = np.atleast_1d(np.asarray(size_factors, dtype=float))
    n = len(size)
    length = size * PEAR_LENGTH_M[0] * np.clip(rng.normal(1.0, PEAR_LENGTH_M[1] / PEAR_LENGTH_M[0], n), 0.6, 1.4)
    half_width = size * PEAR_HALF_WIDTH_M[0] * np.clip(
        rng.normal(1.0, PEAR_HALF_WIDTH_M[1] / PEAR_HALF_WIDTH_M[0], n), 0.6, 1.4)
    shape = rng.uniform([0.6, 1.0, 0.0, -0.1, 0.0001, 0.008, 0.0], [0.85, 1.3, 0.6, 0.5, 0.0004, 0.014, 2 * np.pi],
                        (n, 7))
    twist = rng.normal(0.0, 0.12, n)
    return [LeafShape(length_m=float(length[i]), half_width_m=float(min(half_width[i], 0.5 * length[i])),
                      base_exponent=float(shape[i, 0]), apex_exponent=float(shape[i, 1]), bend=float(shape[i, 2]),
                      roll=float(shape[i, 3]), twist=float(twist[i]), wrinkle_amplitude_m=float(shape[i, 4]),
                      wrinkle_wavelength_m=float(shape[i, 5]), wrinkle_phase=float(shape[i, 6]),
                      petiole_length_m=PEAR.petiole_length_m * float(size[i]), petiole_radius_m=PEAR.petiole_radius_m)
            for i in range(n)]


def sample_pear_leaf(rng: np.random.Generator, size_factor: float = 1.0) -> LeafShape:
    """One random Conference pear leaf (see :func:`sample_pear_leaves`).

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness.
    size_factor : float
        Scale of the leaf's length, width and petiole.

    Returns
    -------
    LeafShape
    """
    return sample_pear_leaves(rng, [size_factor])[0]


def _stack(shapes, key) -> np.ndarray:
    return np.array([getattr(shape, key) for shape in shapes], dtype=float)[:, None]


def _widths(shapes: list[LeafShape], s) -> np.ndarray:
    """Half-widths ``(N, M)`` of ``N`` leaves at relative positions ``s`` (``(M,)`` or ``(N, M)``), m."""
    s = np.clip(np.asarray(s, dtype=float), 0.0, 1.0)
    a, b = _stack(shapes, "base_exponent"), _stack(shapes, "apex_exponent")
    depth, teeth = _stack(shapes, "serration_depth"), _stack(shapes, "serration_teeth")
    peak = (a / (a + b)) ** a * (b / (a + b)) ** b
    margin = 1.0 - depth * 0.5 * (1.0 - np.cos(2 * np.pi * teeth * s))
    return _stack(shapes, "half_width_m") * margin * s**a * (1.0 - s) ** b / peak


def width_profile(shape: LeafShape, s) -> np.ndarray:
    """Blade half-width ``w(s)`` at relative positions ``s = u / L`` along the midrib.

    Parameters
    ----------
    shape : LeafShape
        The leaf.
    s : float or array_like, shape (M,)
        Relative positions, clipped to [0, 1] (0: blade base, 1: apex).

    Returns
    -------
    ndarray, shape (M,)
        Half-widths, m.
    """
    return _widths([shape], np.atleast_1d(s))[0]


def blade_area_m2(shape: LeafShape) -> float:
    """Exact one-sided area of the flat blade, ``2 ∫ w(u) du``, m² (by adaptive quadrature)."""
    value, _ = integrate.quad(lambda s: width_profile(shape, s)[0], 0.0, 1.0,
                              limit=50 + 20 * shape.serration_teeth, epsabs=0.0, epsrel=1e-10)
    return 2.0 * shape.length_m * value


#: Fine positions along the midrib (denser at the tips) on which margin arc lengths are measured.
_FINE_S = 0.5 * (1.0 - np.cos(np.pi * np.linspace(0.0, 1.0, 257)))


def _margin_arc(shapes: list[LeafShape]) -> np.ndarray:
    """Cumulative arc length ``(N, M)`` of each leaf's flat margin ``(u, w(u))`` at :data:`_FINE_S`, m."""
    step = np.hypot(_stack(shapes, "length_m") * np.diff(_FINE_S), np.diff(_widths(shapes, _FINE_S), axis=1))
    return np.concatenate([np.zeros((len(shapes), 1)), np.cumsum(step, axis=1)], axis=1)


def leaf_grids(shapes: list[LeafShape], facet_m, arc: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Grids ``(n_u, n_v)`` of blades whose margin and grid spacing stay within ``facet_m`` (the facet rule).

    ``n_u`` rows split the margin into arcs of at most ``facet_m`` (which also
    bounds the spacing along the midrib), ``n_v`` columns split the widest
    row into steps of at most ``facet_m``.

    Parameters
    ----------
    shapes : list of LeafShape
        The N leaves.
    facet_m : float or array_like, shape (N,)
        Largest facet size of each leaf, m.
    arc : ndarray, shape (N, M), optional
        :func:`_margin_arc` of the shapes if already known, m.

    Returns
    -------
    n_u, n_v : ndarray, shape (N,), int
        Rows (at least 6) and columns (even, at least 4) of each blade grid.
    """
    facet = np.broadcast_to(np.asarray(facet_m, dtype=float), (len(shapes),))
    if not np.all((facet > 0) & np.isfinite(facet)):
        raise SceneError(f"leaf facet must be a positive number (m), got {facet_m!r}")
    arc = _margin_arc(shapes) if arc is None else arc
    n_u = np.maximum(6, np.ceil(arc[:, -1] / facet)).astype(int)
    n_v = 2 * np.maximum(2, np.ceil(_stack(shapes, "half_width_m")[:, 0] / facet)).astype(int)
    return n_u, n_v


def leaf_resolution(shape: LeafShape, facet_m: float) -> tuple[int, int]:
    """Grid ``(n_u, n_v)`` of one blade (see :func:`leaf_grids`).

    Parameters
    ----------
    shape : LeafShape
        The leaf.
    facet_m : float
        Largest facet size, m.

    Returns
    -------
    n_u, n_v : int
        Rows and columns of the blade grid.
    """
    n_u, n_v = leaf_grids([shape], facet_m)
    return int(n_u[0]), int(n_v[0])


def _row_positions(arc: np.ndarray, n_u: int) -> np.ndarray:
    """Relative positions ``(N, n_u + 1)`` of the grid rows: equal arc lengths of each leaf's margin."""
    return np.array([np.interp(np.linspace(0.0, a[-1], n_u + 1), a, _FINE_S) for a in arc])


@dataclass(frozen=True)
class LeafTemplate:
    """Mesh topology shared by all leaves with the same grid.

    Vertex order: blade base, ``n_u - 1`` interior rows of ``n_v + 1``
    vertices, blade apex, then two petiole rings.
    """

    n_u: int
    n_v: int
    t: np.ndarray        # (Vb,) relative lateral position in [-1, 1] of each blade vertex
    row: np.ndarray      # (Vb,) row index into the n_u + 1 rows (0 = base, n_u = apex)
    faces: np.ndarray    # (F, 3) blade faces then petiole faces
    labels: np.ndarray   # (F,) BLADE or PETIOLE
    outline: np.ndarray  # vertex indices of the margin polygon (closed implicitly)
    apex: int


@lru_cache(maxsize=64)
def leaf_template(n_u: int, n_v: int, petiole: bool = True) -> LeafTemplate:
    """The mesh topology of a blade of ``n_u x n_v`` cells (plus an optional petiole).

    Parameters
    ----------
    n_u : int
        Rows of cells along the midrib, >= 2.
    n_v : int
        Columns of cells across the blade, even and >= 2.
    petiole : bool
        Add the faces of a petiole tube of :data:`PETIOLE_SIDES` sides.

    Returns
    -------
    LeafTemplate
        Shared (cached) topology; do not modify its arrays.
    """
    if n_u < 2 or n_v < 2 or n_v % 2:
        raise SceneError(f"leaf grid needs n_u >= 2 and an even n_v >= 2, got {n_u} x {n_v}")
    cols = n_v + 1
    t_cols = np.linspace(-1.0, 1.0, cols)
    interior = np.arange(1, n_u)
    t = np.concatenate([[0.0], np.tile(t_cols, n_u - 1), [0.0]])
    row = np.concatenate([[0], np.repeat(interior, cols), [n_u]])
    apex = len(t) - 1

    grid = 1 + np.arange((n_u - 1) * cols).reshape(n_u - 1, cols)  # rows along s (x), columns along t (y)
    a, b = grid[:-1, :-1].ravel(), grid[:-1, 1:].ravel()
    c, d = grid[1:, :-1].ravel(), grid[1:, 1:].ravel()
    # Counter-clockwise seen from +z with s along +x and t along +y: (row i, col j) -> (i+1, j) -> (i+1, j+1).
    quads = [np.stack([a, c, d], 1), np.stack([a, d, b], 1)]
    first, last = grid[0], grid[-1]
    base_fan = np.stack([np.zeros(n_v, dtype=np.int64), first[:-1], first[1:]], 1)
    apex_fan = np.stack([np.full(n_v, apex), last[1:], last[:-1]], 1)
    blade = np.concatenate(quads + [base_fan, apex_fan]).astype(np.int64)
    faces, labels = [blade], [np.full(len(blade), BLADE)]
    if petiole:
        ring = len(t) + np.arange(2 * PETIOLE_SIDES).reshape(2, PETIOLE_SIDES)
        nxt = np.roll(ring, -1, axis=1)
        tube = np.concatenate([np.stack([ring[0], ring[1], nxt[1]], 1), np.stack([ring[0], nxt[1], nxt[0]], 1)])
        faces.append(tube)
        labels.append(np.full(len(tube), PETIOLE))
    step = max(1, math.ceil((n_u - 1) / 32))
    left, right = grid[::step, 0], grid[::step, -1]
    outline = np.concatenate([[0], right, [apex], left[::-1]])
    return LeafTemplate(n_u, n_v, t, row, np.concatenate(faces), np.concatenate(labels), outline, apex)


def leaf_vertices(shapes: list[LeafShape], template: LeafTemplate,
                  arc: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Vertices of many leaves sharing one template, in their canonical frames (vectorised).

    Parameters
    ----------
    shapes : list of LeafShape
        The N leaves.
    template : LeafTemplate
        Their common topology (:func:`leaf_template`).
    arc : ndarray, shape (N, M), optional
        :func:`_margin_arc` of the shapes if already known, m.

    Returns
    -------
    vertices : ndarray, shape (N, V, 3)
        Canonical-frame coordinates, m.
    petiole_base : ndarray, shape (N, 3)
        Free end of the petiole (the blade base if there is none), canonical frame, m.
    """
    s_rows = _row_positions(_margin_arc(shapes) if arc is None else arc, template.n_u)
    s, t = s_rows[:, template.row], template.t[None, :]
    length, half_width = _stack(shapes, "length_m"), _stack(shapes, "half_width_m")
    u, v = length * s, t * _widths(shapes, s)

    # Wrinkles along the local normal, then roll (wrap the cross-section on a circle), then twist.
    wrinkle = _stack(shapes, "wrinkle_amplitude_m") * np.sin(
        2 * np.pi * u / _stack(shapes, "wrinkle_wavelength_m") + _stack(shapes, "wrinkle_phase")) \
        * np.sin(np.pi * np.abs(t))
    kappa = _stack(shapes, "roll") / half_width
    y = v * np.sinc(kappa * v / np.pi) - wrinkle * np.sin(kappa * v)
    z = 0.5 * kappa * v**2 * np.sinc(kappa * v / (2 * np.pi)) ** 2 + wrinkle * np.cos(kappa * v)
    tau = _stack(shapes, "twist") * s
    y, z = y * np.cos(tau) - z * np.sin(tau), y * np.sin(tau) + z * np.cos(tau)

    # Bend: midrib polyline from chords of exact length at the mid-row tangent elevation -bend s².
    bend = _stack(shapes, "bend")
    s_mid = 0.5 * (s_rows[:, 1:] + s_rows[:, :-1])
    theta_mid = -bend * s_mid**2
    du = length * np.diff(s_rows, axis=1)
    midrib = np.zeros((len(shapes), template.n_u + 1, 3))
    midrib[:, 1:, 0] = np.cumsum(du * np.cos(theta_mid), axis=1)
    midrib[:, 1:, 2] = np.cumsum(du * np.sin(theta_mid), axis=1)
    theta = (-bend * s_rows**2)[:, template.row]
    blade = midrib[:, template.row] + np.stack([-z * np.sin(theta), y, z * np.cos(theta)], axis=-1)

    # Petiole: a straight tube continuing the midrib backwards from the base (tangent +x there).
    petiole_length, radius = _stack(shapes, "petiole_length_m"), _stack(shapes, "petiole_radius_m")
    angle = 2 * np.pi * np.arange(PETIOLE_SIDES) / PETIOLE_SIDES
    ring = np.stack([np.zeros_like(angle), np.cos(angle), np.sin(angle)], -1)[None] * radius[..., None]
    ring_base = ring - np.array([1.0, 0.0, 0.0]) * petiole_length[..., None]
    has_petiole = len(template.faces) > np.count_nonzero(template.labels == BLADE)
    parts = [blade, ring_base, ring] if has_petiole else [blade]
    vertices = np.concatenate(parts, axis=1)
    petiole_base = np.concatenate([-petiole_length, np.zeros((len(shapes), 2))], axis=1)
    return _to_canonical(vertices, petiole_base, template)


def _to_canonical(vertices, petiole_base, template):
    """Move leaves to their canonical frames (centroid origin, chord +x, mean normal in x-z, +z adaxial)."""
    blade_faces = template.faces[template.labels == BLADE]
    tri = vertices[:, blade_faces]
    crossed = cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
    area = 0.5 * np.linalg.norm(crossed, axis=-1)
    centroid = np.einsum("nf,nfk->nk", area, tri.mean(axis=2)) / area.sum(axis=1, keepdims=True)
    ex = vertices[:, template.apex] - vertices[:, 0]
    ex /= np.linalg.norm(ex, axis=-1, keepdims=True)
    normal = crossed.sum(axis=1)
    ez = normal - np.sum(normal * ex, axis=-1, keepdims=True) * ex
    ez /= np.linalg.norm(ez, axis=-1, keepdims=True)
    ey = cross(ez, ex)
    rows = np.stack([ex, ey, ez], axis=1)  # (N, 3, 3): world-to-canonical
    canonical = np.einsum("nij,nvj->nvi", rows, vertices - centroid[:, None])
    return canonical, np.einsum("nij,nj->ni", rows, petiole_base - centroid)


def leaf_truths(vertices: np.ndarray, template: LeafTemplate, shapes: list[LeafShape]) -> list[dict]:
    """Ground truth of leaves from their final (world) vertices (vectorised).

    Parameters
    ----------
    vertices : ndarray, shape (N, V, 3)
        World coordinates of the N leaves' vertices, m.
    template : LeafTemplate
        Their common topology.
    shapes : list of LeafShape
        Their shape parameters (for ``length_m`` and ``half_width_m``).

    Returns
    -------
    list of dict
        Per leaf: ``area_m2`` (one-sided blade area of the mesh), ``normal``
        (unit, area-weighted mean of the adaxial blade normals),
        ``elevation_deg`` (midrib chord, base to apex, above horizontal,
        [-90, 90]), ``azimuth_deg`` (its azimuth from +x counter-clockwise,
        [0, 360)), ``outline`` (3-D margin polygon, m), ``length_m``,
        ``half_width_m`` and ``labels`` (names of the per-face labels).
    """
    tri = vertices[:, template.faces[template.labels == BLADE]]
    crossed = cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
    area = 0.5 * np.linalg.norm(crossed, axis=-1).sum(axis=1)
    normal = crossed.sum(axis=1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    chord = vertices[:, template.apex] - vertices[:, 0]
    chord /= np.linalg.norm(chord, axis=-1, keepdims=True)
    elevation = np.degrees(np.arcsin(np.clip(chord[:, 2], -1.0, 1.0)))
    azimuth = np.degrees(np.arctan2(chord[:, 1], chord[:, 0])) % 360.0
    outline = np.round(vertices[:, template.outline], 7)
    return [{"area_m2": float(area[i]), "normal": normal[i].tolist(), "elevation_deg": float(elevation[i]),
             "azimuth_deg": float(azimuth[i]), "outline": outline[i].tolist(), "length_m": shape.length_m,
             "half_width_m": shape.half_width_m, "labels": list(LEAF_LABELS)} for i, shape in enumerate(shapes)]


def leaf_objects(shapes: list[LeafShape], rotations, positions, names: list[str], materials: list[Material],
                 facet_m, group: str | list[str] = "", extra_truth: list[dict] | None = None,
                 anchor: str = "centroid") -> list[SceneObject]:
    """Leaves placed in the world, one :class:`SceneObject` each (vectorised over leaves).

    Leaves whose grids come out the same (see :func:`leaf_resolution`) are
    built together.

    Parameters
    ----------
    shapes : list of LeafShape
        One per leaf.
    rotations : array_like, shape (N, 3, 3)
        Canonical-to-world rotation of each leaf.
    positions : array_like, shape (N, 3)
        World position of each leaf's anchor, m.
    names, materials : list
        Object name and material of each leaf.
    facet_m : float or array_like, shape (N,)
        Largest facet size of each leaf, m.
    group : str or list of str
        Group of the objects (one for all, or one per leaf).
    extra_truth : list of dict, optional
        Additional truth fields per leaf.
    anchor : {"centroid", "petiole"}
        What ``positions`` locate: the blade's area centroid (the canonical
        origin) or the free end of the petiole.

    Returns
    -------
    list of SceneObject
        One ``"leaf"`` object per shape (blade and petiole in one mesh, world coordinates, m), in input
        order, with the truth of :func:`leaf_truths` and per-face labels.
    """
    if anchor not in ("centroid", "petiole"):
        raise SceneError(f"leaf anchor must be 'centroid' or 'petiole', got {anchor!r}")
    rotations, positions = np.asarray(rotations, float), np.asarray(positions, float)
    arc = _margin_arc(shapes)
    keys = list(zip(*(k.tolist() for k in leaf_grids(shapes, facet_m, arc))))
    objects: list[SceneObject | None] = [None] * len(shapes)
    for key in sorted(set(keys)):
        members = [i for i, k in enumerate(keys) if k == key]
        batch = [shapes[i] for i in members]
        template = leaf_template(*key, petiole=any(shape.petiole_length_m > 0 for shape in batch))
        local, petiole_base = leaf_vertices(batch, template, arc[members])
        rot = rotations[members]
        shift = positions[members]
        if anchor == "petiole":
            shift = shift - np.einsum("nij,nj->ni", rot, petiole_base)
        world = np.einsum("nij,nvj->nvi", rot, local) + shift[:, None]
        for j, (i, truth) in enumerate(zip(members, leaf_truths(world, template, batch))):
            if extra_truth:
                truth.update(extra_truth[i])
            objects[i] = SceneObject(names[i], "leaf", world[j], template.faces, materials[i], truth=truth,
                                     group=group if isinstance(group, str) else group[i],
                                     face_labels=template.labels)
    return objects


def leaf_frame(normal, midrib) -> np.ndarray:
    """Canonical-to-world rotation(s) putting a leaf's +z along ``normal`` and +x along ``midrib``.

    Parameters
    ----------
    normal : array_like, shape (3,) or (N, 3)
        Adaxial normal (need not be unit length).
    midrib : array_like, shape (3,) or (N, 3)
        Midrib direction; projected onto the plane perpendicular to ``normal``
        (must not be parallel to it).

    Returns
    -------
    ndarray, shape (3, 3) or (N, 3, 3)
        Rotation matrices with columns ``(x, y, z)`` of the canonical frame in world coordinates.
    """
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    m = np.asarray(midrib, dtype=float)
    m = m - np.sum(m * n, axis=-1, keepdims=True) * n
    norm = np.linalg.norm(m, axis=-1, keepdims=True)
    if np.any(norm < 1e-9):
        raise SceneError("a leaf's midrib direction is parallel to its normal")
    m = m / norm
    return np.stack([m, cross(n, m), n], axis=-1)

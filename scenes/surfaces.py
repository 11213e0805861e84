"""Analytic test surfaces: exact height fields for shape-from-shading tests.

The surfaces of the PROP-SFS thesis' synthetic experiments (Balduzzi, Ch. 5
§3; ``prop-sfs.md`` §5.2), each as a :class:`HeightField`: exact heights,
exact partial derivatives, unit normals and the incidence angle ``alpha``
between the normal and +z (the viewing and lighting direction of the
orthographic, hot-spot set-up). They can be sampled on pixel grids (for
reconstruction tests) and turned into triangle meshes, or placed as a
:class:`~scenes.scene.SceneObject` in front of the scanner
(:func:`surface_object`) for simulated scans.

Surfaces (``SURFACE_NAMES``; units are those of the thesis' figures, i.e.
pixels, unless stated):

``plane``
    ``h = tan(tilt) (x cos(azimuth) + y sin(azimuth))`` on ``[-1, 1]²``.
``hemisphere``
    Radius 20 (thesis §3.3), on the closed disk of that radius.
``ellipsoid``
    Upper envelope of an ellipsoid of diameters 30, 15, 10 (semi-axes 15,
    7.5, 5) whose long axis is raised by ``elevation`` = π/8 after a ``roll``
    of π/6 about it (thesis §3.1); the domain is the silhouette's bounding box
    (about 1 unit per pixel gives the ≈ 40 x 40 px of A20).
``cone``
    Circular cone of constant slope: ``h = tan(slope) (radius - r)``.
``saddle``
    ``h = c (x² - y²)`` on ``[-1, 1]²`` (project choice A20: the thesis does not
    give its saddle).
``monkey-saddle``
    ``h = c (x³ - 3 x y²)`` on ``[-1, 1]²`` (project choice, as above).
``complex``
    Eq. 3.3, ``h = (4 sin x cos y + 3 cos(2x + π/8) sin(y/2 + π/5)
    + 2 cos(x/3) sin 4y + 4 cos 2x sin y) / 10`` on ``[-π, π]²`` (domain: A20).
``vase``
    Eqs. 3.5-3.6 (Durou et al.'s vase): ``h = sqrt(f(x)² - y²)`` where
    ``f(x)² >= y²``, else 0, with the corrected domain ``x ∈ [-0.554, -0.127]``,
    ``y ∈ [-0.22, 0.22]`` (erratum A21: the printed domain divided by 10).
``multi-seed``
    Sum of Gaussian bumps and pits on ``[-1, 1]²``, giving several summits,
    sinks and saddles (project choice A20; the thesis gives no equation).
"""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from scenes.errors import SceneError
from scenes.pose import Pose, facing_pose
from scenes.primitives import grid_faces, square_to_disk
from scenes.scene import Material, SceneObject

Domain = tuple[tuple[float, float], tuple[float, float]]


@dataclass(frozen=True, eq=False)
class HeightField:
    """An exact height field ``z = h(x, y)`` over a rectangular domain.

    Parameters
    ----------
    name : str
        Surface name (one of ``SURFACE_NAMES`` for the built-in ones).
    domain : ((x0, x1), (y0, y1))
        Bounding rectangle of the surface, in surface units.
    height_fn, gradient_fn : callable
        Exact ``h(x, y)`` and ``(dh/dx, dh/dy)``, evaluated only where the
        surface is supported.
    support_fn : callable, optional
        Boolean mask of where the surface is defined inside ``domain``
        (default: the whole rectangle).
    normal_fn : callable, optional
        Unit normal ``(..., 3)`` with a non-negative z component, for surfaces
        whose gradient is infinite on their rim (default: from the gradient).
    chart : callable, optional
        Map from the square ``[-1, 1]²`` onto the support, used by
        :meth:`mesh` (default: affine onto ``domain``).
    params : dict
        The parameters the surface was built with (JSON-ready).
    """

    name: str
    domain: Domain
    height_fn: Callable = field(repr=False)
    gradient_fn: Callable = field(repr=False)
    support_fn: Callable | None = field(default=None, repr=False)
    normal_fn: Callable | None = field(default=None, repr=False)
    chart: Callable | None = field(default=None, repr=False)
    params: dict = field(default_factory=dict)

    def support(self, x, y) -> np.ndarray:
        """True where the surface is defined (inside the domain and the surface's own support).

        Parameters
        ----------
        x, y : array_like
            Surface coordinates (surface units, broadcast against each other).

        Returns
        -------
        ndarray of bool
            Broadcast shape of ``x`` and ``y``.
        """
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        (x0, x1), (y0, y1) = self.domain
        inside = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
        if self.support_fn is not None:
            inside &= self.support_fn(x, y)
        return inside

    def height(self, x, y) -> np.ndarray:
        """Exact height ``h(x, y)``; NaN outside the support.

        Parameters
        ----------
        x, y : array_like
            Surface coordinates (surface units, broadcast against each other).

        Returns
        -------
        ndarray
            Heights, surface units, broadcast shape of ``x`` and ``y``.
        """
        x, y, inside = self._inside(x, y)
        out = np.full(x.shape, np.nan)
        out[inside] = self.height_fn(x[inside], y[inside])
        return out

    def gradient(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Exact partial derivatives ``(p, q) = (dh/dx, dh/dy)``; NaN outside the support.

        Parameters
        ----------
        x, y : array_like
            Surface coordinates (surface units, broadcast against each other).

        Returns
        -------
        p, q : ndarray
            Slopes (dimensionless; may be infinite on a rim), broadcast shape of ``x`` and ``y``.
        """
        x, y, inside = self._inside(x, y)
        p, q = np.full(x.shape, np.nan), np.full(x.shape, np.nan)
        with np.errstate(divide="ignore", invalid="ignore"):
            p[inside], q[inside] = self.gradient_fn(x[inside], y[inside])
        return p, q

    def normal(self, x, y) -> np.ndarray:
        """Unit upward normal ``(-p, -q, 1) / sqrt(1 + p² + q²)``; NaN outside the support.

        Parameters
        ----------
        x, y : array_like
            Surface coordinates (surface units, broadcast against each other).

        Returns
        -------
        ndarray, shape (..., 3)
            Unit normals with z >= 0 (``...``: broadcast shape of ``x`` and ``y``).
        """
        x, y, inside = self._inside(x, y)
        out = np.full(x.shape + (3,), np.nan)
        if self.normal_fn is not None:
            out[inside] = self.normal_fn(x[inside], y[inside])
        else:
            p, q = self.gradient_fn(x[inside], y[inside])
            n = np.stack([-p, -q, np.ones_like(p)], axis=-1)
            out[inside] = n / np.linalg.norm(n, axis=-1, keepdims=True)
        return out

    def alpha(self, x, y) -> np.ndarray:
        """Incidence angle between the normal and +z; NaN outside the support.

        Parameters
        ----------
        x, y : array_like
            Surface coordinates (surface units, broadcast against each other).

        Returns
        -------
        ndarray
            Angles, rad in ``[0, π/2]``, broadcast shape of ``x`` and ``y``.
        """
        return np.arccos(np.clip(self.normal(x, y)[..., 2], 0.0, 1.0))

    def sample(self, nx: int, ny: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The surface on a grid of ``ny`` rows by ``nx`` columns of pixel centres.

        Pixel ``(i, j)`` covers ``[x0 + j dx, x0 + (j + 1) dx] x [y0 + i dy, ...]``
        with ``dx = (x1 - x0) / nx``; its value is taken at the centre.

        Parameters
        ----------
        nx, ny : int
            Columns and rows of pixels over the domain, each >= 1.

        Returns
        -------
        x, y : ndarray, shape (ny, nx)
            Pixel-centre coordinates (rows = y, columns = x), surface units.
        h : ndarray, shape (ny, nx)
            Height, surface units, NaN outside the support.
        mask : ndarray of bool, shape (ny, nx)
            Where the surface is defined.
        """
        nx, ny = _positive_int(nx, "nx"), _positive_int(ny, "ny")
        (x0, x1), (y0, y1) = self.domain
        xs = x0 + (np.arange(nx) + 0.5) * (x1 - x0) / nx
        ys = y0 + (np.arange(ny) + 0.5) * (y1 - y0) / ny
        x, y = np.meshgrid(xs, ys)
        return x, y, self.height(x, y), self.support(x, y)

    def mesh(self, resolution: int | tuple[int, int] = 101) -> tuple[np.ndarray, np.ndarray]:
        """Triangle mesh of the surface, vertices exactly on it.

        Parameters
        ----------
        resolution : int or (int, int)
            Vertices along each axis of the chart (``(nx, ny)`` or one value
            for both), at least 2.

        Returns
        -------
        vertices : ndarray, shape (V, 3)
            ``(x, y, h(x, y))`` in surface units.
        faces : ndarray, shape (F, 3)
            Counter-clockwise seen from +z (face normals point up).
        """
        nx, ny = (resolution, resolution) if np.isscalar(resolution) else resolution
        nx, ny = _positive_int(nx, "resolution"), _positive_int(ny, "resolution")
        if nx < 2 or ny < 2:
            raise SceneError(f"mesh resolution must be at least 2 vertices per axis, got {resolution!r}")
        u, v = np.meshgrid(np.linspace(-1.0, 1.0, nx), np.linspace(-1.0, 1.0, ny))
        if self.chart is not None:
            x, y = self.chart(u, v)
        else:
            (x0, x1), (y0, y1) = self.domain
            x, y = x0 + (u + 1) * 0.5 * (x1 - x0), y0 + (v + 1) * 0.5 * (y1 - y0)
        x, y = x.ravel(), y.ravel()
        faces = grid_faces(ny, nx)
        if self.chart is None:  # a chart maps onto the support by construction (rim vertices included)
            faces = faces[self.support(x, y)[faces].all(axis=1)]
        if len(faces) == 0:
            raise SceneError(f"surface {self.name!r}: no triangle of the {nx} x {ny} mesh lies on the support")
        used = np.unique(faces)
        remap = np.full(len(x), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        vertices = np.stack([x[used], y[used], self.height_fn(x[used], y[used])], axis=1)
        return vertices, remap[faces]

    def _inside(self, x, y):
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        return x, y, self.support(x, y)


def _positive_int(value, what: str) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 1:
        raise SceneError(f"{what} must be a positive integer, got {value!r}")
    return int(value)


def _positive(value, what: str) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise SceneError(f"{what} must be a positive number, got {value!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise SceneError(f"{what} must be a positive number, got {value!r}")
    return value


def _finite(value, what: str) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise SceneError(f"{what} must be a finite number, got {value!r}") from None
    if not math.isfinite(value):
        raise SceneError(f"{what} must be a finite number, got {value!r}")
    return value


#: Relative slack of round supports, so that rim vertices computed in floating point count as inside.
_RIM_TOLERANCE = 1.0 + 1e-12


# --- the surfaces ---------------------------------------------------------------------------------------------


def plane(tilt: float = math.pi / 6, azimuth: float = 0.0) -> HeightField:
    """Tilted plane on ``[-1, 1]²``, rising towards ``azimuth``.

    Parameters
    ----------
    tilt : float
        Slope angle, rad in ``[0, π/2)`` (also the plane's incidence ``alpha``).
    azimuth : float
        Direction of steepest ascent, rad counter-clockwise from +x.

    Returns
    -------
    HeightField
    """
    tilt, azimuth = _finite(tilt, "plane tilt"), _finite(azimuth, "plane azimuth")
    if not 0 <= tilt < math.pi / 2:
        raise SceneError(f"plane tilt must lie in [0, pi/2) rad, got {tilt!r}")
    gx, gy = math.tan(tilt) * math.cos(azimuth), math.tan(tilt) * math.sin(azimuth)
    return HeightField(
        "plane", ((-1.0, 1.0), (-1.0, 1.0)),
        height_fn=lambda x, y: gx * x + gy * y,
        gradient_fn=lambda x, y: (np.full_like(x, gx), np.full_like(y, gy)),
        params={"tilt": tilt, "azimuth": azimuth},
    )


def hemisphere(radius: float = 20.0) -> HeightField:
    """Upper half of a sphere of ``radius`` centred at the origin, on the closed disk."""
    r = _positive(radius, "hemisphere radius")
    return HeightField(
        "hemisphere", ((-r, r), (-r, r)),
        height_fn=lambda x, y: np.sqrt(np.maximum(r * r - x * x - y * y, 0.0)),
        gradient_fn=lambda x, y: _sphere_gradient(x, y, r),
        support_fn=lambda x, y: x * x + y * y <= r * r * _RIM_TOLERANCE,
        normal_fn=lambda x, y: np.stack([x, y, np.sqrt(np.maximum(r * r - x * x - y * y, 0.0))], -1) / r,
        chart=lambda u, v: tuple(r * c for c in square_to_disk(u, v)),
        params={"radius": r},
    )


def _sphere_gradient(x, y, r):
    z = np.sqrt(np.maximum(r * r - x * x - y * y, 0.0))
    return -x / z, -y / z


def ellipsoid(diameters=(30.0, 15.0, 10.0), elevation: float = math.pi / 8, roll: float = math.pi / 6) -> HeightField:
    """Upper envelope of an inclined ellipsoid centred at the origin.

    Parameters
    ----------
    diameters : (float, float, float)
        Principal diameters; the first axis starts along +x, the second along
        +y, the third along +z.
    elevation : float
        Angle (rad) by which the first axis is raised towards +z, applied after
        the roll.
    roll : float
        Rotation (rad) of the ellipsoid about its first axis.

    Notes
    -----
    With rotation ``R = Ry(-elevation) Rx(roll)`` and
    ``A = R diag(4/d²) Rᵀ``, the surface is ``{X : Xᵀ A X = 1}``; the height is
    the upper root of the quadratic in z and the normal is along ``A X``.

    Returns
    -------
    HeightField
    """
    try:
        semi = np.array([_positive(d, "ellipsoid diameter") for d in diameters]) / 2
    except TypeError:
        raise SceneError(f"ellipsoid diameters must be three positive numbers, got {diameters!r}") from None
    if semi.shape != (3,):
        raise SceneError(f"ellipsoid diameters must be three positive numbers, got {diameters!r}")
    elevation, roll = _finite(elevation, "ellipsoid elevation"), _finite(roll, "ellipsoid roll")
    ce, se, cr, sr = math.cos(elevation), math.sin(elevation), math.cos(roll), math.sin(roll)
    rot = np.array([[ce, 0, -se], [0, 1, 0], [se, 0, ce]]) @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    a = rot @ np.diag(1 / semi**2) @ rot.T
    shape2 = (rot @ np.diag(semi**2) @ rot.T)[:2, :2]  # silhouette: [x y] shape2⁻¹ [x y]ᵀ <= 1
    chol = np.linalg.cholesky(shape2)
    half = np.sqrt(np.diag(shape2))

    def discriminant(x, y):
        b = a[0, 2] * x + a[1, 2] * y
        c = a[0, 0] * x * x + 2 * a[0, 1] * x * y + a[1, 1] * y * y - 1.0
        return b, b * b - a[2, 2] * c

    def height(x, y):
        b, disc = discriminant(x, y)
        return (-b + np.sqrt(np.maximum(disc, 0.0))) / a[2, 2]

    def direction(x, y):
        z = height(x, y)
        return np.stack([a[0, 0] * x + a[0, 1] * y + a[0, 2] * z, a[0, 1] * x + a[1, 1] * y + a[1, 2] * z,
                         a[0, 2] * x + a[1, 2] * y + a[2, 2] * z], axis=-1)

    def gradient(x, y):
        n = direction(x, y)
        return -n[..., 0] / n[..., 2], -n[..., 1] / n[..., 2]

    def chart(u, v):
        dx, dy = square_to_disk(u, v)
        return chol[0, 0] * dx, chol[1, 0] * dx + chol[1, 1] * dy

    def normal(x, y):
        n = direction(x, y)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    return HeightField(
        "ellipsoid", ((-float(half[0]), float(half[0])), (-float(half[1]), float(half[1]))),
        height_fn=height, gradient_fn=gradient,
        support_fn=lambda x, y: discriminant(x, y)[1] >= (1.0 - _RIM_TOLERANCE) * a[2, 2],
        normal_fn=normal, chart=chart,
        params={"diameters": [float(d) for d in 2 * semi], "elevation": elevation, "roll": roll},
    )


def cone(radius: float = 20.0, slope: float = math.pi / 6) -> HeightField:
    """Circular cone ``h = tan(slope) (radius - r)`` on the disk of ``radius``.

    Every point but the apex has incidence ``alpha = slope``: the cone is a
    single iso-alpha region (a sand-pile surface). The apex has no tangent
    plane; :meth:`HeightField.gradient` reports ``(0, 0)`` there.

    Parameters
    ----------
    radius : float
        Base radius, surface units (pixels), > 0.
    slope : float
        Slope angle of the flank, rad in ``(0, π/2)``.

    Returns
    -------
    HeightField
    """
    r0 = _positive(radius, "cone radius")
    slope = _finite(slope, "cone slope")
    if not 0 < slope < math.pi / 2:
        raise SceneError(f"cone slope must lie in (0, pi/2) rad, got {slope!r}")
    k = math.tan(slope)

    def gradient(x, y):
        r = np.hypot(x, y)
        safe = np.where(r > 0, r, 1.0)
        return np.where(r > 0, -k * x / safe, 0.0), np.where(r > 0, -k * y / safe, 0.0)

    return HeightField(
        "cone", ((-r0, r0), (-r0, r0)),
        height_fn=lambda x, y: k * (r0 - np.hypot(x, y)),
        gradient_fn=gradient,
        support_fn=lambda x, y: x * x + y * y <= r0 * r0 * _RIM_TOLERANCE,
        chart=lambda u, v: tuple(r0 * c for c in square_to_disk(u, v)),
        params={"radius": r0, "slope": slope},
    )


def saddle(curvature: float = 0.5) -> HeightField:
    """Hyperbolic paraboloid ``h = c (x² - y²)`` on ``[-1, 1]²`` (``c = curvature``)."""
    c = _finite(curvature, "saddle curvature")
    return HeightField(
        "saddle", ((-1.0, 1.0), (-1.0, 1.0)),
        height_fn=lambda x, y: c * (x * x - y * y),
        gradient_fn=lambda x, y: (2 * c * x, -2 * c * y),
        params={"curvature": c},
    )


def monkey_saddle(curvature: float = 0.25) -> HeightField:
    """Monkey saddle ``h = c (x³ - 3 x y²)`` on ``[-1, 1]²`` (three valleys, three ridges)."""
    c = _finite(curvature, "monkey-saddle curvature")
    return HeightField(
        "monkey-saddle", ((-1.0, 1.0), (-1.0, 1.0)),
        height_fn=lambda x, y: c * (x**3 - 3 * x * y * y),
        gradient_fn=lambda x, y: (3 * c * (x * x - y * y), -6 * c * x * y),
        params={"curvature": c},
    )


def complex_surface() -> HeightField:
    """The "complex surface" of the thesis' eq. 3.3 on ``[-π, π]²``."""

    def height(x, y):
        return 0.1 * (4 * np.sin(x) * np.cos(y) + 3 * np.cos(2 * x + np.pi / 8) * np.sin(y / 2 + np.pi / 5)
                      + 2 * np.cos(x / 3) * np.sin(4 * y) + 4 * np.cos(2 * x) * np.sin(y))

    def gradient(x, y):
        p = 0.1 * (4 * np.cos(x) * np.cos(y) - 6 * np.sin(2 * x + np.pi / 8) * np.sin(y / 2 + np.pi / 5)
                   - (2 / 3) * np.sin(x / 3) * np.sin(4 * y) - 8 * np.sin(2 * x) * np.sin(y))
        q = 0.1 * (-4 * np.sin(x) * np.sin(y) + 1.5 * np.cos(2 * x + np.pi / 8) * np.cos(y / 2 + np.pi / 5)
                   + 8 * np.cos(x / 3) * np.cos(4 * y) + 4 * np.cos(2 * x) * np.cos(y))
        return p, q

    return HeightField("complex", ((-np.pi, np.pi), (-np.pi, np.pi)), height, gradient)


#: Coefficients of the vase profile f(x) (eq. 3.5), highest degree first.
VASE_PROFILE = np.array([-138.24, 92.16, 84.48, -48.64, -17.60, 6.4, 3.2]) / 12.8


def vase() -> HeightField:
    """The vase neck of eqs. 3.5-3.6 on the corrected domain (erratum A21).

    ``h = sqrt(f(x)² - y²)`` where ``f(x)² >= y²`` (the vase body), 0 elsewhere
    (the flat floor). The gradient is 0 on the floor and unbounded at the rim
    ``|y| = f(x)``.
    """
    f = np.poly1d(VASE_PROFILE)
    df = f.deriv()

    def height(x, y):
        return np.sqrt(np.maximum(f(x) ** 2 - y * y, 0.0))

    def gradient(x, y):
        z = height(x, y)
        body = z > 0
        safe = np.where(body, z, 1.0)
        return np.where(body, f(x) * df(x) / safe, 0.0), np.where(body, -y / safe, 0.0)

    return HeightField("vase", ((-0.554, -0.127), (-0.22, 0.22)), height, gradient)


#: Default features of the multi-seed surface: (centre x, centre y, amplitude, width), two bumps and two pits.
MULTI_SEED_FEATURES = ((0.45, 0.40, 0.35, 0.30), (-0.50, -0.35, 0.30, 0.28),
                       (-0.45, 0.50, -0.30, 0.25), (0.50, -0.45, -0.35, 0.30))


def multi_seed(seed: int | None = None, n_features: int = 4) -> HeightField:
    """Sum of Gaussian bumps and pits on ``[-1, 1]²``: ``h = Σ a_k exp(-|x - c_k|² / (2 w_k²))``.

    Parameters
    ----------
    seed : int, optional
        ``None`` gives the fixed :data:`MULTI_SEED_FEATURES`; an integer draws
        ``n_features`` features (alternately bump and pit, centres in
        ``[-0.7, 0.7]²``, amplitudes 0.2-0.4, widths 0.2-0.35) from
        ``numpy.random.default_rng(seed)``.
    n_features : int
        Number of random features (only with ``seed``).

    Returns
    -------
    HeightField
    """
    if seed is None:
        features = np.array(MULTI_SEED_FEATURES)
    else:
        n = _positive_int(n_features, "multi-seed n_features")
        if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise SceneError(f"multi-seed seed must be a non-negative integer or None, got {seed!r}")
        rng = np.random.default_rng(int(seed))
        sign = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
        features = np.column_stack([rng.uniform(-0.7, 0.7, (n, 2)), sign * rng.uniform(0.2, 0.4, n),
                                    rng.uniform(0.2, 0.35, n)])
    cx, cy, amp, width = (features[:, k] for k in range(4))

    def terms(x, y):
        dx, dy = x[..., None] - cx, y[..., None] - cy
        return dx, dy, amp * np.exp(-(dx * dx + dy * dy) / (2 * width**2))

    def height(x, y):
        return terms(x, y)[2].sum(axis=-1)

    def gradient(x, y):
        dx, dy, g = terms(x, y)
        return (-g * dx / width**2).sum(axis=-1), (-g * dy / width**2).sum(axis=-1)

    return HeightField("multi-seed", ((-1.0, 1.0), (-1.0, 1.0)), height, gradient,
                       params={"seed": seed, "n_features": int(n_features)})


_BUILDERS: dict[str, Callable[..., HeightField]] = {
    "plane": plane,
    "hemisphere": hemisphere,
    "ellipsoid": ellipsoid,
    "cone": cone,
    "saddle": saddle,
    "monkey-saddle": monkey_saddle,
    "complex": complex_surface,
    "vase": vase,
    "multi-seed": multi_seed,
}

#: Names accepted by :func:`get_surface`.
SURFACE_NAMES: tuple[str, ...] = tuple(_BUILDERS)


def surface_parameters(name: str) -> dict:
    """Parameter names of surface ``name`` with their defaults (radians for angles)."""
    builder = _builder(name)
    return {k: p.default for k, p in inspect.signature(builder).parameters.items()}


def get_surface(name: str, **params) -> HeightField:
    """The analytic surface ``name`` (see ``SURFACE_NAMES``) with optional parameters.

    Parameters
    ----------
    name : str
        One of ``SURFACE_NAMES``.
    **params
        Parameters of the surface's builder (:func:`plane`, :func:`hemisphere`,
        :func:`ellipsoid`, ...); angles in radians, lengths in surface units.

    Returns
    -------
    HeightField

    Raises
    ------
    SceneError
        For an unknown name or parameter, or an invalid value.

    Examples
    --------
    >>> surface = get_surface("hemisphere", radius=20)
    >>> float(surface.height(0.0, 0.0))
    20.0
    """
    allowed = surface_parameters(name)
    unknown = sorted(set(params) - set(allowed))
    if unknown:
        raise SceneError(f"surface {name!r} has no parameter(s) {unknown}; allowed: {sorted(allowed) or 'none'}")
    return _builder(name)(**params)


def _builder(name: str) -> Callable[..., HeightField]:
    if name not in _BUILDERS:
        raise SceneError(f"unknown surface {name!r}; allowed: {', '.join(SURFACE_NAMES)}")
    return _BUILDERS[name]


def surface_mesh(surface: HeightField, size_m: float, resolution: int = 201):
    """The surface as a mesh in its scaled local frame (domain centre at the origin, metres).

    A surface point ``(x, y, h)`` goes to ``s (x - xc, y - yc, h)`` with
    ``s = size_m / (longest domain side)`` and ``(xc, yc)`` the domain centre.

    Parameters
    ----------
    surface : HeightField
        The surface.
    size_m : float
        World size of the longest side of the domain, m.
    resolution : int
        Mesh vertices per axis (see :meth:`HeightField.mesh`).

    Returns
    -------
    vertices : ndarray, shape (V, 3)
        Local coordinates, m.
    faces : ndarray, shape (F, 3)
    scale : float
        ``s``, metres per surface unit.
    center : ndarray, shape (2,)
        ``(xc, yc)`` in surface units.
    """
    size_m = _positive(size_m, "surface size_m")
    (x0, x1), (y0, y1) = surface.domain
    scale = size_m / max(x1 - x0, y1 - y0)
    center = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    local, faces = surface.mesh(resolution)
    return scale * (local - np.array([center[0], center[1], 0.0])), faces, scale, center


def surface_truth(surface: HeightField, pose: Pose, scale: float, center) -> dict:
    """Truth of a posed surface: its name, parameters and the frame mapping scans back to it.

    ``frame``: ``origin`` (world position of the domain centre at height 0),
    ``axes`` (rows: world directions of surface x, y, z), ``scale`` (m per
    surface unit) and ``center`` (domain centre, surface units), so that a
    world point ``p`` has surface coordinates
    ``(p - origin) @ axes.T / scale + (xc, yc, 0)``.

    Parameters
    ----------
    surface : HeightField
        The surface.
    pose : Pose
        Local (scaled, see :func:`surface_mesh`) frame to world; its scale multiplies ``scale``.
    scale : float
        Metres per surface unit of the local mesh.
    center : array_like, shape (2,)
        Domain centre ``(xc, yc)``, surface units.

    Returns
    -------
    dict
        JSON-ready ``{"surface", "params", "frame"}``.
    """
    return {
        "surface": surface.name,
        "params": surface.params,
        "frame": {"origin": pose.translation.tolist(), "axes": pose.rotation.T.tolist(),
                  "scale": float(scale * pose.scale), "center": [float(c) for c in center]},
    }


def surface_object(name: str, distance_m: float, size_m: float, *, params: dict | None = None,
                   direction=(1.0, 0.0, 0.0), scanner_position=(0.0, 0.0, 0.0), resolution: int = 201,
                   material: Material | None = None, object_name: str | None = None) -> SceneObject:
    """An analytic surface as a mesh in front of the scanner, its +z axis pointing at the scanner.

    The domain centre (at height 0) lies ``distance_m`` from the scanner
    along ``direction``; surface +z points back at the scanner and surface +y
    is as close to world up as possible. See :func:`surface_mesh` for the
    scaling and :func:`surface_truth` for the recorded frame.

    Parameters
    ----------
    name : str
        Surface name (``SURFACE_NAMES``).
    distance_m : float
        Distance from the scanner to the domain centre at height 0, m.
    size_m : float
        World size of the longest side of the surface's domain, m.
    params : dict, optional
        Surface parameters for :func:`get_surface`.
    direction : array_like, shape (3,)
        Direction from the scanner to the surface (world frame).
    scanner_position : array_like, shape (3,)
        Scanner position, m.
    resolution : int
        Mesh vertices per axis (see :meth:`HeightField.mesh`).
    material : Material, optional
        Default: Lambertian reflectance 0.5.
    object_name : str, optional
        Object name (default: the surface name).

    Returns
    -------
    SceneObject
        Type ``"surface"``, world coordinates (m), with the truth of :func:`surface_truth`.
    """
    surface = get_surface(name, **(params or {}))
    distance_m = _positive(distance_m, "surface distance_m")
    direction = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    pose = facing_pose(np.asarray(scanner_position, dtype=float) + distance_m * direction, -direction)
    local, faces, scale, center = surface_mesh(surface, size_m, resolution)
    return SceneObject(object_name or name, "surface", pose.apply(local), faces,
                       material or Material("lambert-0.5", 0.5), truth=surface_truth(surface, pose, scale, center))

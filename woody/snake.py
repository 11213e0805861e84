"""Generalised open active contours in the 4-D Hough space (STEP steps 3-5).

A snake is a polyline of k vertices in Hough *index* space (cell units: one
unit is ``cell_m`` along x, y, z and ``radius_step_m`` along r; spec D-S3).
Ravaglia et al. 2017 (Computers & Graphics 66, Sect. 3.3-3.5) minimise

    E = integral of [ alpha |c'|^2 + beta |c''|^2 + E_d(c) |c'| ] du        (their eq. 7)

whose data term is weighted by the length element, so that the data force
only acts across the curve (their eqs. 11-13). The time step is the
semi-implicit Euler scheme of Kass et al. (their eq. 15):

    c(t) = (A + gamma I)^-1 ( gamma c(t-1) - v1 + w v2 ),

with ``A`` the pentadiagonal matrix of the elastic terms (free ends: it is
the gradient of the discrete energy ``alpha sum |D1 c|^2 + beta sum |D2 c|^2``,
which gives the natural boundary rows; spec A.7).

Data energy (their eq. 8), with ``H`` the Hough score, ``H_m``/``H_M`` its
global extremes and ``h_m``/``h_M`` those of the cell's 3^4 neighbourhood:

    E_d = a (H_m - H) / (H_M - H_m) + (1 - a) (h_m - H) / (h_M - h_m),

in [-1, 0]. An empty cell has ``E_d = 0`` (its own score is the local and
global minimum), so ``E_d`` is stored only on occupied cells.

Growth (their Sect. 3.5) happens between minimisations: at each free end the
top-scoring cells of a cone around the end tangent are the attractors, their
uncentred PCA (UPCA) gives the growth direction, and the end stops when the
dominant share of the UPCA spectrum falls below a threshold (the spec's
reading D-S7: the *largest* eigenvalue), when the cone holds no occupied
cell, when it leaves the grid, or when the caller reports a conflict.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.linalg import solve_banded

from woody.errors import WoodyError
from woody.hough import NEIGHBOUR_OFFSETS, HoughSpace


@dataclass(frozen=True)
class SnakeParams:
    """Snake settings, all in Hough cell units.

    The paper reports none of these values; the defaults are the spec's
    starting points (D-S6, D-S7, D-S8) tuned on the synthetic cylinder and
    curved tube (see ``woody experiments``).

    Attributes
    ----------
    alpha, beta : float
        Weights of the elastic (|c'|^2) and bending (|c''|^2) energies.
    gamma : float
        Inverse time step of the semi-implicit scheme.
    balance : float
        ``a`` of eq. 8: weight of the global against the local contrast, in [0, 1].
    cone_deg : float
        Half-angle of the growth cone, degrees.
    cone_cells : float
        Length of the growth cone, cells.
    attractors : int
        Number of top-scoring cone cells that vote for the growth direction.
    step_cells : float
        Length added per growth step, cells.
    grow_interval : int
        Growth steps between two minimisations.
    iterations, final_iterations : int
        Minimisation steps after each growth interval and at the end.
    sigma_stop : float
        An end stops growing when the largest UPCA eigenvalue holds less than
        this share of the spectrum.
    energy_stop : float
        An end also stops when ``E_d`` at the new vertex is above this value,
        i.e. the contour has left the score ridge (an addition to the paper's
        criteria, which never fire inside a narrow cone; -1 < value <= 0).
    max_vertices : int
        Hard cap on the length of one snake.
    """

    alpha: float = 0.6
    beta: float = 0.1
    gamma: float = 1.0
    balance: float = 0.5
    cone_deg: float = 35.0
    cone_cells: float = 4.0
    attractors: int = 15
    step_cells: float = 1.0
    grow_interval: int = 5
    iterations: int = 20
    final_iterations: int = 100
    sigma_stop: float = 0.6
    energy_stop: float = -0.1
    max_vertices: int = 20_000

    def __post_init__(self):
        checks = [("alpha", self.alpha >= 0), ("beta", self.beta >= 0), ("gamma", self.gamma > 0),
                  ("balance", 0 <= self.balance <= 1), ("cone_deg", 0 < self.cone_deg < 90),
                  ("cone_cells", 1 <= self.cone_cells <= 20), ("attractors", self.attractors >= 1),
                  ("step_cells", 0 < self.step_cells <= self.cone_cells), ("grow_interval", self.grow_interval >= 1),
                  ("iterations", self.iterations >= 0), ("final_iterations", self.final_iterations >= 0),
                  ("sigma_stop", 0 <= self.sigma_stop < 1), ("energy_stop", -1 < self.energy_stop <= 0),
                  ("max_vertices", self.max_vertices >= 3)]
        bad = [name for name, ok in checks if not ok]
        if bad:
            raise WoodyError(f"invalid snake parameter(s) {', '.join(f'{n}={getattr(self, n)!r}' for n in bad)}; "
                             "see woody.snake.SnakeParams for the allowed ranges")


def data_energy(hs: HoughSpace, h_min: np.ndarray, h_max: np.ndarray, balance: float) -> np.ndarray:
    """Eq. 8 on every occupied cell (aligned with ``hs.keys``); empty cells have energy 0.

    Parameters
    ----------
    hs : HoughSpace
        The accumulator (its vote counts are the score ``H``).
    h_min, h_max : ndarray of int, (m,)
        Lowest and highest score over each occupied cell's 3^4 neighbourhood
        (:meth:`HoughSpace.neighbourhood`), votes.
    balance : float
        ``a`` of eq. 8: weight of the global against the local contrast, in [0, 1].

    Returns
    -------
    ndarray, (m,)
        ``E_d`` of each occupied cell, dimensionless in [-1, 0].
    """
    score = hs.counts.astype(float)
    top = score.max() if len(score) else 1.0
    spread = (h_max - h_min).astype(float)
    local = np.divide(h_min - score, spread, out=np.zeros_like(score), where=spread > 0)
    return balance * (-score / top) + (1.0 - balance) * local


def upca(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Uncentred PCA: eigenvalues (ascending) and eigenvectors (columns) of ``sum v v^T``."""
    return np.linalg.eigh(vectors.T @ vectors)


def seed_segment(hs: HoughSpace, seed: np.ndarray) -> np.ndarray:
    """Initial three-vertex snake through a seed cell along the UPCA axis of its weighted neighbours (eq. A.8).

    Parameters
    ----------
    hs : HoughSpace
        The accumulator.
    seed : ndarray of int, (4,)
        Seed cell indices (x, y, z, r).

    Returns
    -------
    ndarray, (3, 4)
        Vertices one cell apart, index space.
    """
    neighbours = seed + NEIGHBOUR_OFFSETS
    score = hs.values_at(hs.counts, neighbours).astype(float)
    offsets = NEIGHBOUR_OFFSETS.astype(float)
    d = score[:, None] * offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
    _, vectors = upca(d)
    axis = vectors[:, -1]
    return np.array([seed - axis, seed.astype(float), seed + axis])


def _ball_offsets(radius: float) -> np.ndarray:
    reach = int(np.ceil(radius)) + 1
    grid = np.array(list(itertools.product(range(-reach, reach + 1), repeat=4)), dtype=np.int64)
    return grid[np.linalg.norm(grid, axis=1) <= radius + 1.0]


class Snake:
    """One contour evolving in a Hough space (state: its vertices and which ends still grow)."""

    def __init__(self, hs: HoughSpace, energy: np.ndarray, params: SnakeParams):
        self.hs, self.energy, self.params = hs, energy, params
        self._ball = _ball_offsets(params.cone_cells)
        self._cos_cone = np.cos(np.radians(params.cone_deg))
        self._bands: dict[int, np.ndarray] = {}

    # -- energy minimisation --------------------------------------------------------------------

    def _system(self, k: int) -> np.ndarray:
        """Banded form of ``A + gamma I`` for k vertices with free ends."""
        if k not in self._bands:
            p = self.params
            main, off1, off2 = np.zeros(k), np.zeros(k - 1), np.zeros(k - 2)
            # D1^T D1 (rows -1, 1) times 2 alpha, plus D2^T D2 (rows 1, -2, 1) times 2 beta.
            main[:-1] += 2 * p.alpha
            main[1:] += 2 * p.alpha
            off1 -= 2 * p.alpha
            for shift, weight in ((0, 1.0), (1, 4.0), (2, 1.0)):
                main[shift:k - 2 + shift] += 2 * p.beta * weight
            off1[:k - 2] -= 4 * p.beta
            off1[1:] -= 4 * p.beta
            off2 += 2 * p.beta
            bands = np.zeros((5, k))
            bands[0, 2:], bands[1, 1:], bands[2], bands[3, :-1], bands[4, :-2] = off2, off1, main + p.gamma, off1, off2
            self._bands[k] = bands
        return self._bands[k]

    def energy_and_gradient(self, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``E_d`` at the vertices and its gradient by central differences of one cell."""
        k = len(c)
        unit = np.eye(4)
        probes = np.concatenate([c] + [c + e for e in unit] + [c - e for e in unit])
        values = self.hs.interpolate(self.energy, probes).reshape(9, k)
        gradient = 0.5 * (values[1:5] - values[5:9]).T
        return values[0], gradient

    def minimise(self, c: np.ndarray, iterations: int) -> np.ndarray:
        """Run ``iterations`` semi-implicit steps of eq. 15 on the polyline ``c``.

        Parameters
        ----------
        c : ndarray, (k, 4)
            Vertices, Hough index space (cell units).
        iterations : int
            Number of steps (0, or fewer than 3 vertices, returns ``c``).

        Returns
        -------
        ndarray, (k, 4)
            The moved vertices, index space.
        """
        k = len(c)
        if k < 3 or iterations == 0:
            return c
        bands, gamma = self._system(k), self.params.gamma
        for _ in range(iterations):
            e_d, grad = self.energy_and_gradient(c)
            d1 = np.gradient(c, axis=0)
            d2 = np.zeros_like(c)
            d2[1:-1] = c[:-2] - 2 * c[1:-1] + c[2:]
            speed = np.maximum(np.linalg.norm(d1, axis=1, keepdims=True), 1e-9)
            tangent = d1 / speed
            v1 = speed * grad - np.sum(grad * d1, axis=1, keepdims=True) * tangent
            v2 = speed * d2 - np.sum(d2 * d1, axis=1, keepdims=True) * tangent
            w = e_d[:, None] / speed ** 2
            moved = solve_banded((2, 2), bands, gamma * c - v1 + w * v2)
            # The ends move only across the curve: free-end elastic rows would otherwise pull them in.
            for end in (0, -1):
                shift = moved[end] - c[end]
                moved[end] -= (shift @ tangent[end]) * tangent[end]
            c = moved
        return c

    # -- growth ---------------------------------------------------------------------------------

    def grow_direction(self, end: np.ndarray, tangent: np.ndarray) -> tuple[np.ndarray | None, float]:
        """Growth direction at an end and the dominant UPCA share, or ``(None, 0)`` when the cone is empty.

        Parameters
        ----------
        end : ndarray, (4,)
            The end vertex, index space (cell units).
        tangent : ndarray, (4,)
            Unit outward tangent at the end: the axis of the growth cone.

        Returns
        -------
        direction : ndarray, (4,) or None
            Unit growth direction (on the tangent's side), index space.
        share : float
            Largest UPCA eigenvalue over the sum of all four, in [0, 1].
        """
        cells = np.rint(end).astype(np.int64) + self._ball
        vectors = cells - end
        length = np.linalg.norm(vectors, axis=1)
        in_cone = (length > 0.5) & (length <= self.params.cone_cells) & \
                  (vectors @ tangent >= self._cos_cone * length)
        cells, vectors, length = cells[in_cone], vectors[in_cone], length[in_cone]
        score = self.hs.values_at(self.hs.counts, cells).astype(float)
        top = np.argsort(-score)[:self.params.attractors]
        top = top[score[top] > 0]
        if len(top) == 0:
            return None, 0.0
        d = score[top, None] * vectors[top] / length[top, None]
        values, vecs = upca(d)
        direction = vecs[:, -1]
        if direction @ tangent < 0:
            direction = -direction
        return direction, float(values[-1] / max(values.sum(), 1e-300))

    def grow(self, seed: np.ndarray, conflict: Callable[[np.ndarray], bool] | None = None) -> tuple[np.ndarray, dict]:
        """Grow a snake from a seed cell, minimising every ``grow_interval`` steps (no final minimisation).

        Parameters
        ----------
        seed : ndarray, (4,), int
            Seed cell indices.
        conflict : callable, optional
            ``conflict(vertex)`` returns True when a new vertex (index space)
            collides with an accepted tuboid; the end then stops there.

        Returns
        -------
        vertices : ndarray, (k, 4)
            Polyline, index space.
        info : dict
            Why each end stopped (``stop_start``, ``stop_end``) and the growth steps taken.
        """
        p = self.params
        c = seed_segment(self.hs, np.asarray(seed, np.int64))
        growing = {0: True, -1: True}
        reasons = {0: "cap", -1: "cap"}
        steps = 0
        while any(growing.values()) and len(c) < p.max_vertices:
            for side in (0, -1):
                if not growing[side]:
                    continue
                end, previous = (c[0], c[1]) if side == 0 else (c[-1], c[-2])
                tangent = end - previous
                tangent /= max(np.linalg.norm(tangent), 1e-12)
                reason, new = self._try_grow(end, tangent, conflict)
                if reason:
                    growing[side], reasons[side] = False, reason
                    continue
                c = np.vstack([new[None], c]) if side == 0 else np.vstack([c, new[None]])
            steps += 1
            if steps % p.grow_interval == 0:
                c = self.minimise(resample(c, 1.0), p.iterations)
        return c, {"stop_start": reasons[0], "stop_end": reasons[-1], "growth_steps": steps}

    def run(self, seed: np.ndarray, conflict: Callable[[np.ndarray], bool] | None = None) -> tuple[np.ndarray, dict]:
        """:meth:`grow`, then the final ``final_iterations`` minimisation steps.

        Parameters
        ----------
        seed : ndarray, (4,), int
            Seed cell indices.
        conflict : callable, optional
            ``conflict(vertex)`` is True when a new vertex (index space)
            collides with an accepted tuboid (see :meth:`grow`).

        Returns
        -------
        vertices : ndarray, (k, 4)
            Polyline, index space.
        info : dict
            As :meth:`grow`.
        """
        c, info = self.grow(seed, conflict)
        return self.minimise(resample(c, 1.0), self.params.final_iterations), info

    def _try_grow(self, end, tangent, conflict) -> tuple[str, np.ndarray | None]:
        p = self.params
        direction, sigma = self.grow_direction(end, tangent)
        if direction is None:
            return "empty cone", None
        if sigma < p.sigma_stop:
            return "no dominant direction", None
        new = end + p.step_cells * direction
        if not self.hs.grid.interior(np.rint(new).astype(np.int64)):
            return "grid boundary", None
        if self.hs.interpolate(self.energy, new[None])[0] > p.energy_stop:
            return "left the ridge", None
        if conflict is not None and conflict(new):
            return "conflict", None
        return "", new


def resample(c: np.ndarray, spacing: float) -> np.ndarray:
    """The polyline resampled at (nearly) uniform arc length ``spacing``, end points kept.

    Parameters
    ----------
    c : ndarray, (k, d)
        Vertices (any unit; index space for snakes).
    spacing : float
        Target distance between vertices, same unit.

    Returns
    -------
    ndarray, (m, d)
        At least 3 vertices (``c`` itself if it has fewer than 2 or no length).
    """
    seg = np.linalg.norm(np.diff(c, axis=0), axis=1)
    total = seg.sum()
    if len(c) < 2 or total == 0:
        return c
    s = np.concatenate([[0.0], np.cumsum(seg)])
    count = max(int(round(total / spacing)) + 1, 3)
    targets = np.linspace(0.0, total, count)
    return np.column_stack([np.interp(targets, s, c[:, i]) for i in range(c.shape[1])])

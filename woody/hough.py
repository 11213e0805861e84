"""Point–normal circle Hough transform into a sparse 4-D accumulator (STEP step 1).

Ravaglia et al. 2017 (Computers & Graphics 66, Sect. 3.2) drop the circle
orientation and vote in a 4-D space of circle centre and radius
``(c_x, c_y, c_z, r)``: a point ``p`` with outward normal ``n`` lies on every
circle of centre ``p - lambda n`` and radius ``lambda`` (their eq. 5), or on
both half-lines ``p +- lambda n`` when the normal's sign is unknown (eq. 6).
Each point therefore votes along a discrete line, for ``lambda`` in
``[r_min, r_max]``.

Grid rules of the paper: the x, y, z cell must be at least twice the radius
cell (``cell_m >= 2 radius_step_m``) and the radius cell smaller than the
smallest radius sought (``radius_step_m < r_min_m``).

Storage is sparse: a cell is one int64 key (radius index most significant,
then z, y, x), keys are kept sorted with their vote counts, and every lookup
is a binary search. Because the radius index leads, the votes of each radius
bin can be counted on their own and the results concatenated in order, so
memory grows with the number of occupied cells, not with the bounding box
(the paper's dense (10 m)^3 example needs 1.9e9 cells, 7.5 GB). The grid has
one empty cell of padding on every side, so the 3^4 neighbourhood of an
occupied cell never leaves the grid and neighbour keys are key offsets.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from woody.errors import WoodyError

#: Offsets of the "direct 4-D neighbourhood": the 3^4 - 1 = 80 cells around a cell
#: (the paper does not size it; this is the spec's recommendation D-S4).
NEIGHBOUR_OFFSETS = np.array([o for o in itertools.product((-1, 0, 1), repeat=4) if any(o)], dtype=np.int64)

#: The 16 corners of a 4-D cell, for quadrilinear interpolation.
_CORNERS = np.array(list(itertools.product((0, 1), repeat=4)), dtype=np.int64)


@dataclass(frozen=True)
class HoughGrid:
    """Geometry of the 4-D accumulator.

    Index space: cell ``(ix, iy, iz, ir)`` has its centre at
    ``origin + (ix, iy, iz) * cell_m`` and radius ``r_min_m + (ir - 1) *
    radius_step_m``; indices 0 and ``shape - 1`` are the empty padding.

    Attributes
    ----------
    origin : ndarray, (3,)
        Centre of cell (0, 0, 0), m.
    cell_m : float
        Cell size in x, y, z, m.
    radius_step_m : float
        Cell size in r, m.
    r_min_m : float
        Radius of the first radius bin, m.
    shape : tuple of 4 int
        Cells along x, y, z, r, padding included.
    """

    origin: np.ndarray
    cell_m: float
    radius_step_m: float
    r_min_m: float
    shape: tuple[int, int, int, int]

    @classmethod
    def around(cls, points: np.ndarray, cell_m: float, radius_step_m: float, r_min_m: float,
               r_max_m: float) -> "HoughGrid":
        """The grid covering ``points`` padded by ``r_max_m`` (every possible vote).

        Parameters
        ----------
        points : ndarray, (n, 3)
            Coordinates, m.
        cell_m : float
            Cell size in x, y, z, m (at least ``2 radius_step_m``).
        radius_step_m : float
            Cell size in r, m (below ``r_min_m``).
        r_min_m, r_max_m : float
            Smallest and largest radius sought, m.

        Returns
        -------
        HoughGrid

        Raises
        ------
        WoodyError
            If a size is not positive, ``r_max_m <= r_min_m``, or the paper's
            two grid conditions fail.
        """
        for name, value in (("cell_m", cell_m), ("radius_step_m", radius_step_m), ("r_min_m", r_min_m)):
            if not (np.isfinite(value) and value > 0):
                raise WoodyError(f"{name} must be a positive length in metres, got {value}")
        if not (np.isfinite(r_max_m) and r_max_m > r_min_m):
            raise WoodyError(f"r_max_m must exceed r_min_m = {r_min_m} m, got {r_max_m}")
        if cell_m < 2 * radius_step_m * (1 - 1e-9):
            raise WoodyError(f"Hough grid: the x, y, z cell ({cell_m} m) must be at least twice the radius cell "
                             f"({radius_step_m} m)")
        if radius_step_m >= r_min_m:
            raise WoodyError(f"Hough grid: the radius cell ({radius_step_m} m) must be smaller than the smallest "
                             f"radius r_min_m ({r_min_m} m)")
        n_r = int(round((r_max_m - r_min_m) / radius_step_m)) + 1
        low = points.min(axis=0) - r_max_m - cell_m
        span = points.max(axis=0) + r_max_m + cell_m - low
        n_xyz = np.ceil(span / cell_m).astype(np.int64) + 2
        shape = (int(n_xyz[0]), int(n_xyz[1]), int(n_xyz[2]), n_r + 2)
        if np.prod(np.array(shape, dtype=float)) >= 2.0 ** 62:
            raise WoodyError(f"Hough grid of {shape} cells is too large to index; use larger cells")
        return cls(np.asarray(low, float), float(cell_m), float(radius_step_m), float(r_min_m), shape)

    @property
    def radii(self) -> np.ndarray:
        """Radius of each real radius bin (indices 1 .. shape[3] - 2), m."""
        return self.r_min_m + np.arange(self.shape[3] - 2) * self.radius_step_m

    @property
    def strides(self) -> np.ndarray:
        """Key increment of one step along x, y, z, r."""
        nx, ny, nz, _ = self.shape
        return np.array([1, nx, nx * ny, nx * ny * nz], dtype=np.int64)

    def to_index(self, xyzr: np.ndarray) -> np.ndarray:
        """Continuous index coordinates of metric ``(x, y, z, r)`` rows."""
        xyzr = np.asarray(xyzr, float)
        out = np.empty_like(xyzr)
        out[..., :3] = (xyzr[..., :3] - self.origin) / self.cell_m
        out[..., 3] = (xyzr[..., 3] - self.r_min_m) / self.radius_step_m + 1.0
        return out

    def to_metric(self, index: np.ndarray) -> np.ndarray:
        """Metric ``(x, y, z, r)`` of continuous index coordinates."""
        index = np.asarray(index, float)
        out = np.empty_like(index)
        out[..., :3] = self.origin + index[..., :3] * self.cell_m
        out[..., 3] = self.r_min_m + (index[..., 3] - 1.0) * self.radius_step_m
        return out

    def pack(self, index: np.ndarray) -> np.ndarray:
        """int64 keys of integer cell indices ``(..., 4)``."""
        return np.asarray(index, np.int64) @ self.strides

    def unpack(self, keys: np.ndarray) -> np.ndarray:
        """Integer cell indices ``(m, 4)`` of keys."""
        keys = np.asarray(keys, np.int64)
        nx, ny, nz, _ = self.shape
        return np.column_stack([keys % nx, keys // nx % ny, keys // (nx * ny) % nz, keys // (nx * ny * nz)])

    def interior(self, index: np.ndarray) -> np.ndarray:
        """Whether integer indices lie inside the grid, padding excluded."""
        index = np.asarray(index)
        return ((index >= 1) & (index <= np.array(self.shape) - 2)).all(axis=-1)


@dataclass
class HoughSpace:
    """A sparse 4-D accumulator: sorted cell keys and their vote counts.

    Attributes
    ----------
    grid : HoughGrid
        Geometry.
    keys : ndarray, (m,), int64
        Occupied cells, sorted.
    counts : ndarray, (m,), int32
        Votes per cell.
    """

    grid: HoughGrid
    keys: np.ndarray
    counts: np.ndarray

    @property
    def nbytes(self) -> int:
        """Memory held by the accumulator, bytes."""
        return int(self.keys.nbytes + self.counts.nbytes)

    def find(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions of ``keys`` in the accumulator and whether each is occupied."""
        keys = np.asarray(keys, np.int64)
        if len(self.keys) == 0:
            return np.zeros(keys.shape, np.int64), np.zeros(keys.shape, bool)
        pos = np.minimum(np.searchsorted(self.keys, keys), len(self.keys) - 1)
        return pos, self.keys[pos] == keys

    def values_at(self, values: np.ndarray, index: np.ndarray) -> np.ndarray:
        """Per-cell ``values`` (aligned with :attr:`keys`) at integer indices; 0 for empty or outside cells.

        Parameters
        ----------
        values : ndarray, (m,)
            One value per occupied cell (e.g. :attr:`counts`, votes, or an energy).
        index : ndarray of int, (..., 4)
            Cell indices (x, y, z, r).

        Returns
        -------
        ndarray, (...)
            The values, in the unit of ``values``.
        """
        index = np.asarray(index, np.int64)
        inside = self.grid.interior(index)
        pos, found = self.find(self.grid.pack(np.where(inside[..., None], index, 0)))
        return np.where(found & inside, values[pos], 0)

    def interpolate(self, values: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Quadrilinear interpolation of per-cell ``values`` at continuous indices ``u``.

        Parameters
        ----------
        values : ndarray, (m,)
            One value per occupied cell (empty cells count as 0).
        u : ndarray, (n, 4)
            Continuous index coordinates (cell units, :meth:`HoughGrid.to_index`).

        Returns
        -------
        ndarray, (n,)
            Interpolated values, in the unit of ``values``.
        """
        u = np.asarray(u, float)
        base = np.floor(u).astype(np.int64)
        frac = u - base
        weights = np.prod(np.where(_CORNERS[:, None, :], frac[None], 1.0 - frac[None]), axis=2)
        return np.einsum("cm,cm->m", weights, self.values_at(values, base[None] + _CORNERS[:, None, :]))

    def neighbourhood(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Local maxima and the min and max score over each occupied cell's 3^4 neighbourhood.

        The neighbourhood includes the cell itself and its empty neighbours
        (score 0). A plateau of equal scores keeps one maximum: a cell must
        beat its neighbours of lower key strictly and the others or equal them.

        Returns
        -------
        is_max : ndarray of bool
        h_min, h_max : ndarray of int32
            Aligned with :attr:`keys`.
        """
        counts = self.counts
        h_max = counts.copy()
        present = np.ones(len(counts), np.int32)
        h_min_present = counts.copy()
        is_max = np.ones(len(counts), bool)
        for offset in self.grid.pack(NEIGHBOUR_OFFSETS):
            pos, found = self.find(self.keys + offset)
            neighbour = np.where(found, counts[pos], 0)
            np.maximum(h_max, neighbour, out=h_max)
            present += found
            np.minimum(h_min_present, np.where(found, neighbour, h_min_present), out=h_min_present)
            is_max &= (counts > neighbour) if offset < 0 else (counts >= neighbour)
        h_min = np.where(present == len(NEIGHBOUR_OFFSETS) + 1, h_min_present, 0).astype(np.int32)
        return is_max, h_min, h_max


def hough_transform(points: np.ndarray, normals: np.ndarray, grid: HoughGrid, oriented: bool = True,
                    samples_per_bin: int = 1, min_votes: int = 2) -> HoughSpace:
    """Accumulate point–normal votes in a sparse 4-D Hough space.

    Parameters
    ----------
    points, normals : ndarray, (n, 3)
        Coordinates (m) and unit normals.
    grid : HoughGrid
        Accumulator geometry.
    oriented : bool
        ``True``: normals point outwards and each point votes on the half-line
        ``p - lambda n`` (paper eq. 5); ``False``: on both half-lines (eq. 6).
    samples_per_bin : int
        Samples of ``lambda`` per radius bin (1: the bin centre; 2: at +-1/4
        bin, a point voting at most once per cell). Since the radius cell is
        at most half the x, y, z cell, one sample per bin already visits
        nearly every cell an exact 4-D line traversal would.
    min_votes : int
        Cells with fewer votes are dropped (the paper filters "low interest"
        cells without saying how; this threshold is the spec's D-S5).

    Returns
    -------
    HoughSpace
    """
    if samples_per_bin not in (1, 2):
        raise WoodyError(f"samples_per_bin must be 1 or 2, got {samples_per_bin}")
    if min_votes < 1:
        raise WoodyError(f"min_votes must be at least 1, got {min_votes}")
    signs = (-1.0,) if oriented else (-1.0, 1.0)
    shifts = (0.0,) if samples_per_bin == 1 else (-0.25, 0.25)
    strides = grid.strides
    relative = (points - grid.origin) / grid.cell_m
    keys_out, counts_out = [], []
    for bin_index, radius in enumerate(grid.radii):
        votes = []
        for sign in signs:
            previous = None
            for shift in shifts:
                lam = radius + shift * grid.radius_step_m
                cell = np.rint(relative + (sign * lam / grid.cell_m) * normals).astype(np.int64) @ strides[:3]
                # A point's two samples in one bin may fall in the same cell: count it once.
                votes.append(cell if previous is None else cell[cell != previous])
                previous = cell
        keys, counts = np.unique(np.concatenate(votes), return_counts=True)
        keep = counts >= min_votes
        keys_out.append(keys[keep] + (bin_index + 1) * strides[3])
        counts_out.append(counts[keep].astype(np.int32))
    return HoughSpace(grid, np.concatenate(keys_out), np.concatenate(counts_out))

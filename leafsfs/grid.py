"""The pixel grid and its metric: the map ``sc`` from pixel indices to continuous coordinates.

PROP-SFS works in continuous coordinates ``x = sc(i, j)`` where slopes are
metric (thesis ch.5 eq 2.1, generalised here to any affine map ``x = A (i, j)
+ b``; see :mod:`leafsfs.frame` for scans). This module also holds the
sampling helpers that read the height image at sub-pixel positions and fit
local least-squares planes to it (the thesis' LSR, radius 5 px).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage


@dataclass(frozen=True)
class PixelGrid:
    """Affine map ``x = matrix @ (row, col) + offset`` from pixel indices to continuous coordinates.

    Parameters
    ----------
    matrix : array_like, (2, 2)
        Columns are the continuous-coordinate steps of one row and one
        column (for a plain square grid of spacing ``s``: ``s * I``).
    offset : array_like, (2,)
        Continuous coordinates of pixel (0, 0).
    """

    matrix: np.ndarray = field(default_factory=lambda: np.eye(2))
    offset: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def __post_init__(self):
        object.__setattr__(self, "matrix", np.asarray(self.matrix, dtype=float).reshape(2, 2))
        object.__setattr__(self, "offset", np.asarray(self.offset, dtype=float).reshape(2))

    @property
    def flips(self) -> bool:
        """Whether the map reverses orientation (negative determinant)."""
        return bool(np.linalg.det(self.matrix) < 0)

    @property
    def pixel_size(self) -> float:
        """Geometric mean size of a pixel in continuous units."""
        return float(np.sqrt(abs(np.linalg.det(self.matrix))))

    def to_continuous(self, pixels: np.ndarray) -> np.ndarray:
        """Continuous coordinates of pixel positions ``(n, 2)``."""
        return pixels @ self.matrix.T + self.offset

    def to_pixels(self, points: np.ndarray) -> np.ndarray:
        """Pixel positions of continuous points ``(n, 2)``."""
        return np.linalg.solve(self.matrix, (points - self.offset).T).T

    def directions(self, pixel_vectors: np.ndarray) -> np.ndarray:
        """Unit continuous directions of pixel-space vectors ``(n, 2)``."""
        vectors = pixel_vectors @ self.matrix.T
        return vectors / np.linalg.norm(vectors, axis=1, keepdims=True)


def bilinear(image: np.ndarray, valid: np.ndarray, points_px: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` at sub-pixel positions, using only ``valid`` pixels (weights renormalised).

    Returns NaN where none of the four neighbours is valid.

    Parameters
    ----------
    image : ndarray, 2-D
        Values to sample (e.g. heights, m).
    valid : ndarray of bool, 2-D
        Pixels that may be used.
    points_px : ndarray, (n, 2)
        Sub-pixel positions (row, col), pixels.

    Returns
    -------
    ndarray, (n,)
        Samples, in the image's unit.
    """
    rows, cols = image.shape
    base = np.floor(points_px).astype(int)
    frac = points_px - base
    total = np.zeros(len(points_px))
    weight = np.zeros(len(points_px))
    for di in (0, 1):
        for dj in (0, 1):
            i, j = base[:, 0] + di, base[:, 1] + dj
            inside = (i >= 0) & (i < rows) & (j >= 0) & (j < cols)
            ic, jc = np.clip(i, 0, rows - 1), np.clip(j, 0, cols - 1)
            ok = inside & valid[ic, jc]
            w = np.where(di, frac[:, 0], 1 - frac[:, 0]) * np.where(dj, frac[:, 1], 1 - frac[:, 1])
            w = np.where(ok, w, 0.0)
            total += w * np.where(ok, image[ic, jc], 0.0)
            weight += w
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(weight > 1e-12, total / weight, np.nan)


@dataclass
class LocalPlanes:
    """Least-squares planes ``h = c0 + grad . (x - x_centre)`` fitted around pixels.

    Attributes
    ----------
    height : ndarray, (n,)
        Plane height at the centre pixel.
    gradient : ndarray, (n, 2)
        Height gradient in continuous coordinates.
    covariance : ndarray, (n, 2, 2)
        Covariance of the gradient from the regression residuals.
    rms : ndarray, (n,)
        Residual standard deviation.
    count : ndarray, (n,)
        Number of pixels used; fits with too few are NaN.
    """

    height: np.ndarray
    gradient: np.ndarray
    covariance: np.ndarray
    rms: np.ndarray
    count: np.ndarray


def local_planes(image: np.ndarray, valid: np.ndarray, grid: PixelGrid, centres: np.ndarray,
                 radius_px: float, order: int = 1) -> LocalPlanes:
    """Fit a plane to the valid pixels within ``radius_px`` of each centre pixel (the thesis' local LSR).

    With ``order=2`` a quadratic surface is fitted instead and its tangent
    plane at the centre is returned: its gradient is not biased by the
    curvature of the surface across the neighbourhood.

    Parameters
    ----------
    image : ndarray, 2-D
        Height image (e.g. the range image in the local frame).
    valid : ndarray of bool, 2-D
        Pixels that may be used.
    grid : PixelGrid
        Pixel-to-continuous map (gradients are per continuous unit).
    centres : ndarray of int, (n, 2)
        Centre pixels (row, col).
    radius_px : float
        Neighbourhood radius, pixels.
    order : {1, 2}
        Degree of the fitted polynomial surface.

    Returns
    -------
    LocalPlanes
        One plane per centre (heights in the image's unit, gradients per continuous unit).
    """
    return local_planes_of([image], valid, grid, centres, radius_px, order)[0]


def local_planes_of(images: list, valid: np.ndarray, grid: PixelGrid, centres: np.ndarray,
                    radius_px: float, order: int = 1, spread: bool = True) -> list:
    """:func:`local_planes` of several images on the same valid pixels and centres (the normal equations once).

    Parameters
    ----------
    images : list of ndarray, 2-D
        Images of the same shape (e.g. range, m, and intensity, DN).
    valid : ndarray of bool, 2-D
        Pixels that may be used.
    grid : PixelGrid
        Pixel-to-continuous map (gradients are per continuous unit).
    centres : ndarray of int, (n, 2)
        Centre pixels (row, col).
    radius_px : float
        Neighbourhood radius, pixels.
    order : {1, 2}
        Degree of the fitted polynomial surface.
    spread : bool
        Whether the residuals' RMS and the gradient's covariance are computed
        (False: they are NaN, and their cost, most of the fit's, is saved).

    Returns
    -------
    list of LocalPlanes
        Per image, one plane per centre, the same as :func:`local_planes` of that image.
    """
    r = int(np.floor(radius_px))
    di, dj = np.mgrid[-r:r + 1, -r:r + 1]
    keep = di**2 + dj**2 <= radius_px**2 + 1e-9
    offsets = np.stack([di[keep], dj[keep]], axis=1)
    # The images padded (invalid) so that every neighbourhood lies inside: one flat index per neighbour.
    pad = max(r, r - int(centres.min(initial=0)), *(r + int(centres[:, a].max(initial=0)) + 1 - valid.shape[a]
                                                    for a in (0, 1)))
    width = valid.shape[1] + 2 * pad
    flat = ((centres[:, 0] + pad) * width + centres[:, 1] + pad)[:, None] + (offsets[:, 0] * width + offsets[:, 1])
    w = np.pad(valid, pad).ravel()[flat].astype(float)
    dx = offsets @ grid.matrix.T  # continuous offsets, (k, 2)
    columns = [np.ones(len(offsets)), dx[:, 0], dx[:, 1]]
    if order == 2:
        columns += [dx[:, 0] ** 2, dx[:, 0] * dx[:, 1], dx[:, 1] ** 2]
    design = np.stack(columns, axis=1)  # (k, 3 or 6)
    terms = design.shape[1]
    # The weights are 0 or 1, so the products of two operands are those of three; the sums run over k in order,
    # or in any order (a matrix product) where they are sums of integers that are exact in floating point.
    outer = (design[:, :, None] * design[:, None, :]).reshape(len(design), terms * terms)
    exact = np.array_equal(outer, np.round(outer)) and np.abs(outer).sum() < 2.0 ** 52
    normal = (w @ outer if exact else np.einsum("nk,kc->nc", w, outer)).reshape(len(w), terms, terms)
    count = w.sum(axis=1)
    ok = (count >= terms + 1) & (np.abs(np.linalg.det(normal)) > 1e-300)
    normal[~ok] = np.eye(terms)
    inverse = np.linalg.inv(normal) if spread else None
    nan = np.where(ok, 1.0, np.nan)
    planes = []
    for image in images:
        h = np.where(w > 0, np.pad(image, pad).ravel()[flat], 0.0)
        rhs = np.einsum("nk,ka->na", h, design)  # h is 0 where the weight is: w h = h
        coef = np.linalg.solve(normal, rhs[..., None])[..., 0]
        if spread:
            resid = h - coef @ design.T
            dof = np.maximum(count - terms, 1)
            rms = np.sqrt(np.sum(w * resid**2, axis=1) / dof)
            covariance = rms[:, None, None] ** 2 * inverse[:, 1:3, 1:3]
        else:
            rms, covariance = np.full(len(w), np.nan), np.full((len(w), 2, 2), np.nan)
        planes.append(LocalPlanes(coef[:, 0] * nan, coef[:, 1:3] * nan[:, None], covariance * nan[:, None, None],
                                  rms * nan, count))
    return planes


def gaussian_planes(height: np.ndarray, known: np.ndarray, sigma_px: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gaussian-weighted least-squares planes of the known heights around every pixel.

    Unlike a normalised Gaussian mean, a local plane reproduces a sloping
    surface up to the region's border (a mean flattens a steep leaf seen
    edge-on wherever its window reaches past the border), and extrapolates
    it over the pixels just outside.

    Parameters
    ----------
    height : ndarray, 2-D
        Heights (any value where not known).
    known : ndarray of bool, 2-D
        Pixels whose heights are used.
    sigma_px : float
        Standard deviation of the Gaussian weight, pixels.

    Returns
    -------
    height, slope, fitted : ndarray
        Plane height at every pixel; its gradient per pixel step ``(rows,
        cols, 2)`` (along rows, along columns); whether a plane could be
        fitted there (enough known pixels around, not all on a line).
    """
    radius = max(1, int(math.ceil(3 * sigma_px)))
    offsets = np.arange(-radius, radius + 1, dtype=float)
    gauss = np.exp(-0.5 * (offsets / sigma_px) ** 2)
    kernels = [gauss, offsets * gauss, offsets**2 * gauss]

    w = known.astype(float)
    h = np.where(known, height, 0.0)
    m = window_moments(w, kernels, ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)))
    normal = np.stack([np.stack([m[0, 0], m[1, 0], m[0, 1]], -1), np.stack([m[1, 0], m[2, 0], m[1, 1]], -1),
                       np.stack([m[0, 1], m[1, 1], m[0, 2]], -1)], -2)
    mh = window_moments(h, kernels, ((0, 0), (1, 0), (0, 1)))
    rhs = np.stack([mh[0, 0], mh[1, 0], mh[0, 1]], -1)
    full = gauss.sum() ** 2  # the weight of a whole window
    det = np.linalg.det(normal)
    fitted = (m[0, 0] > 0.1 * full) & (det > 1e-3 * full**3 * sigma_px**4)
    normal[~fitted] = np.eye(3)
    coef = np.linalg.solve(normal, rhs[..., None])[..., 0]
    return coef[..., 0], coef[..., 1:], fitted


def window_moments(image: np.ndarray, kernels: list, pairs, at=None) -> dict:
    """Window sums of ``image * du^a * dv^b`` for each ``(a, b)`` of ``pairs``, by separable filters.

    The filter along the rows is the same for every ``b`` of one ``a``, so it
    runs once per ``a`` and only one row-filtered image is held at a time.

    Parameters
    ----------
    image : ndarray, 2-D
        Values (0 where none).
    kernels : list of ndarray
        ``kernels[k]``: the window's weights times the offset to the power ``k`` (offsets in pixels).
    pairs : sequence of (int, int)
        Powers ``(a, b)`` of the row and column offsets.
    at : index, optional
        Keep only these pixels of each sum (default: the whole image).

    Returns
    -------
    dict
        ``(a, b)`` -> the sums (the image's shape, or ``image[at]``'s).
    """
    out = {}
    for a in sorted({a for a, _ in pairs}):
        rows = ndimage.correlate1d(image, kernels[a], axis=0, mode="constant")
        for b in [b for row, b in pairs if row == a]:
            whole = ndimage.correlate1d(rows, kernels[b], axis=1, mode="constant")
            out[a, b] = whole if at is None else whole[at]
    return out

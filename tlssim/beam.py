"""Sampling one pulse's beam with sub-rays.

The beam is described in normalised cross-section coordinates ``(u, v)``:
a point at ``(u, v)`` lies at ``w(z)·(u·e_psi + v·e_theta)`` from the beam axis
at distance ``z``, where ``w(z) = w0 + z·tan(delta)`` is the 1/e² radius
(:meth:`ScannerModel.beam_radius_m`). A sub-ray therefore starts at
``w0·(u, v)`` in the exit aperture and leaves with the angular offset
``tan(delta)·(u, v)``, so its position and its power weight refer to the same
definition of the divergence at every distance.

The default layout splits the beam into cells of equal power: a central disc
and rings of ``6, 12, 18, ...`` cells (``19 = 1 + 6 + 12``). Each sub-ray sits
at its cell's power median (radially) and centre angle, and carries the cell's
exact share of the profile's power, so the weights integrate the Gaussian.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tlssim.errors import ScanError


@dataclass(frozen=True)
class BeamSamples:
    """Sub-ray layout of one pulse.

    Attributes
    ----------
    u, v : ndarray, shape (S,)
        Normalised offsets across the beam along ``e_psi`` and ``e_theta`` (in
        units of the 1/e² radius). Sub-ray 0 is the central one.
    weight : ndarray, shape (S,)
        Share of the pulse power carried by each sub-ray; sums to 1.
    ring : ndarray, shape (S,)
        Ring index of each sub-ray (0 = centre).
    """

    u: np.ndarray
    v: np.ndarray
    weight: np.ndarray
    ring: np.ndarray

    @property
    def count(self) -> int:
        """Number of sub-rays."""
        return len(self.weight)


def ring_counts(n_subrays: int) -> list[int]:
    """Sub-rays per ring: 1 at the centre, then ``6k`` on ring ``k``; the last ring takes the remainder."""
    if n_subrays < 1:
        raise ScanError(f"n_subrays must be >= 1, got {n_subrays}")
    counts = [1]
    k = 1
    while sum(counts) < n_subrays:
        counts.append(min(6 * k, n_subrays - sum(counts)))
        k += 1
    return counts


def _cumulative_power(profile: str):
    """Fraction of the beam power inside normalised radius r, and its inverse."""
    if profile == "gaussian":
        return (lambda r: 1.0 - np.exp(-2.0 * r**2)), (lambda p: np.sqrt(-0.5 * np.log1p(-p)))
    if profile == "tophat":  # uniform irradiance over the 1/e² disc
        return (lambda r: np.minimum(r, 1.0) ** 2), (lambda p: np.sqrt(p))
    raise ScanError(f"beam_profile must be 'gaussian' or 'tophat', got {profile!r}")


def sample_beam(n_subrays: int, profile: str = "gaussian") -> BeamSamples:
    """Equal-power ring layout of ``n_subrays`` sub-rays.

    Parameters
    ----------
    n_subrays : int
        Number of sub-rays (1 gives a single central ray).
    profile : {"gaussian", "tophat"}
        Irradiance profile of the beam.

    Returns
    -------
    BeamSamples
        Offsets in units of the 1/e² radius and power weights.

    Examples
    --------
    >>> s = sample_beam(19)
    >>> s.count, round(float(s.weight.sum()), 12)
    (19, 1.0)
    """
    _, radius_at = _cumulative_power(profile)
    counts = ring_counts(n_subrays)
    bounds = np.cumsum([0] + counts) / n_subrays  # cumulative power at ring edges
    u, v, ring = [0.0], [0.0], [0]
    for k, count in enumerate(counts[1:], start=1):
        r = float(radius_at(0.5 * (bounds[k] + bounds[k + 1])))
        phase = 0.5 * math.pi * (k % 2) / count  # stagger alternate rings
        angles = phase + 2.0 * math.pi * (np.arange(count) + 0.5) / count
        u.extend(r * np.cos(angles))
        v.extend(r * np.sin(angles))
        ring.extend([k] * count)
    weight = np.full(n_subrays, 1.0 / n_subrays)
    return BeamSamples(np.array(u), np.array(v), weight, np.array(ring))

"""Sampling one pulse's beam with sub-rays.

The beam is described in normalised cross-section coordinates ``(u, v)``:
a point at ``(u, v)`` lies at ``w(z)·(u·e_psi + v·e_theta)`` from the beam axis
at distance ``z``, where ``w(z) = w0 + z·tan(delta)`` is the 1/e² radius
(:meth:`ScannerModel.beam_radius_m`). A sub-ray therefore starts at
``w0·(u, v)`` in the exit aperture and leaves with the angular offset
``tan(delta)·(u, v)``, so its position and its power weight refer to the same
definition of the divergence at every distance.

The default layout splits the beam into cells of equal power: a central disc
and rings of ``6, 12, 18, ...`` cells (``19 = 1 + 6 + 12``). Each sub-ray carries
its cell's exact share of the profile's power (so the weights integrate the
Gaussian), sits at its cell's centre angle and at the radius whose square is
the ring's power-weighted mean of ``r²``. That radius keeps the second moment
of the beam, hence the footprint size, exact for any number of sub-rays (the
central sub-ray, kept on the axis, drops the tiny second moment of its disc).
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


def _ring_radii(bounds: np.ndarray, profile: str) -> np.ndarray:
    """Radius preserving the mean ``r²`` of the power between cumulative-power bounds.

    Parameters
    ----------
    bounds : ndarray
        Cumulative power fractions at the ring edges, from 0 to 1.
    profile : {"gaussian", "tophat"}
        Irradiance profile.

    Returns
    -------
    ndarray
        One radius per ring, in units of the 1/e² radius.
    """
    lo, hi = bounds[:-1], bounds[1:]
    if profile == "gaussian":
        # s = r² is exponentially distributed with rate 2 (irradiance exp(-2 r²));
        # its mean over [A, B], written with the cumulative powers p = 1 - exp(-2 s).
        s_lo = -0.5 * np.log1p(-lo)
        s_hi = np.where(hi < 1.0, -0.5 * np.log1p(-np.minimum(hi, 1.0 - 1e-16)), 0.0)
        tail_hi = np.where(hi < 1.0, (1.0 - hi) * s_hi, 0.0)
        mean_s = 0.5 + ((1.0 - lo) * s_lo - tail_hi) / (hi - lo)
    elif profile == "tophat":  # uniform irradiance over the 1/e² disc: s uniform on [0, 1]
        mean_s = 0.5 * (lo + hi)
    else:
        raise ScanError(f"beam_profile must be 'gaussian' or 'tophat', got {profile!r}")
    return np.sqrt(mean_s)


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
    counts = ring_counts(n_subrays)
    bounds = np.cumsum([0] + counts) / n_subrays  # cumulative power at ring edges
    radii = _ring_radii(bounds, profile)
    u, v, ring = [0.0], [0.0], [0]
    for k, count in enumerate(counts[1:], start=1):
        r = float(radii[k])
        phase = 0.5 * math.pi * (k % 2) / count  # stagger alternate rings
        angles = phase + 2.0 * math.pi * (np.arange(count) + 0.5) / count
        u.extend(r * np.cos(angles))
        v.extend(r * np.sin(angles))
        ring.extend([k] * count)
    weight = np.full(n_subrays, 1.0 / n_subrays)
    return BeamSamples(np.array(u), np.array(v), weight, np.array(ring))


def footprint_axes_m(model, distance_m: float, incidence_rad: float) -> tuple[float, float]:
    """Major and minor axes of the beam's 1/e² footprint on a plane (thesis ch.6 eq. 1.4).

    Parameters
    ----------
    model : ScannerModel
        Supplies the exit radius ``r`` and the divergence half-angle ``delta``.
    distance_m : float
        Distance from the scanner to the footprint centre along the beam, m.
    incidence_rad : float
        Incidence angle of the beam on the plane, rad, in [0, pi/2).

    Returns
    -------
    major, minor : float
        ``2r/cos(a) + ((d + r tan a)/cos(a - delta) + (d - r tan a)/cos(a + delta))·sin(delta)``
        and ``2r + 2d·sin(delta)``, m. With the FARO LS880 preset this gives
        4.1 mm at 0 deg and 46.5 mm at 85 deg at 2.16 m (the published values).
    """
    r, d, a = model.beam_waist_radius_m, float(distance_m), float(incidence_rad)
    delta = math.radians(model.divergence_deg)
    if not 0.0 <= a < 0.5 * math.pi:
        raise ScanError(f"incidence must lie in [0, 90) degrees, got {math.degrees(a):.3g}")
    major = 2 * r / math.cos(a) + ((d + r * math.tan(a)) / math.cos(a - delta)
                                  + (d - r * math.tan(a)) / math.cos(a + delta)) * math.sin(delta)
    return major, 2 * r + 2 * d * math.sin(delta)

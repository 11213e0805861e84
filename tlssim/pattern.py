"""Scanner pose and scan windows: where the beams go.

Frames follow the project convention: in the scanner frame, the azimuth
``theta`` turns about +z from +x and the zenith ``psi`` is measured from +z
(``psi = 90 deg`` is horizontal). Image rows are ``psi``, columns ``theta``.
The pose maps the scanner frame to the world frame:
``world = position + rotation @ scanner``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tlssim.errors import ScanError
from tlssim.scanner import ScannerModel


def rotation_from_yaw_pitch_roll(yaw_deg: float = 0.0, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """Rotation matrix ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (angles in degrees).

    Parameters
    ----------
    yaw_deg : float
        Rotation about z, degrees.
    pitch_deg : float
        Rotation about y, degrees.
    roll_deg : float
        Rotation about x, degrees.

    Returns
    -------
    ndarray
        Rotation matrix, shape ``(3, 3)``.
    """
    y, p, r = (math.radians(a) for a in (yaw_deg, pitch_deg, roll_deg))
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    return rz @ ry @ rx


@dataclass(frozen=True)
class ScannerPose:
    """Position and orientation of the scanner in the world.

    Parameters
    ----------
    position : array_like, shape (3,)
        Optical centre in world coordinates, m.
    rotation : array_like, shape (3, 3)
        Rotation from the scanner frame to the world frame (identity: the
        scanner's +z is the world's up, azimuth 0 looks along world +x).
    """

    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        position = np.asarray(self.position, dtype=float)
        rotation = np.asarray(self.rotation, dtype=float)
        if position.shape != (3,) or not np.all(np.isfinite(position)):
            raise ScanError(f"scanner position must be three finite numbers (m), got {self.position!r}")
        if rotation.shape != (3, 3) or not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) \
                or np.linalg.det(rotation) < 0:
            raise ScanError("scanner rotation must be a proper 3 x 3 rotation matrix")
        object.__setattr__(self, "position", position)
        object.__setattr__(self, "rotation", rotation)


@dataclass(frozen=True)
class ScanWindow:
    """A rectangular window of the scan grid.

    Parameters
    ----------
    theta_deg : (float, float)
        Azimuth range, degrees; columns run from the first to the last value.
    psi_deg : (float, float)
        Zenith range, degrees; rows run from the first to the last value.
    step_deg : float or (float, float)
        Angular step, degrees: one value for both axes, or ``(theta, psi)``.
    """

    theta_deg: tuple[float, float]
    psi_deg: tuple[float, float]
    step_deg: float | tuple[float, float] = 0.018

    def __post_init__(self):
        for key in ("theta_deg", "psi_deg"):
            value = getattr(self, key)
            try:
                lo, hi = (float(v) for v in value)
            except (TypeError, ValueError):
                raise ScanError(f"window {key} must be two numbers [lo, hi] in degrees, got {value!r}") from None
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ScanError(f"window {key} must be finite with lo <= hi, got {value!r}")
            object.__setattr__(self, key, (lo, hi))
        steps = self.step_deg if isinstance(self.step_deg, (tuple, list)) else (self.step_deg, self.step_deg)
        try:
            steps = tuple(float(s) for s in steps)
        except (TypeError, ValueError):
            raise ScanError(f"window step_deg must be a positive number, got {self.step_deg!r}") from None
        if len(steps) != 2 or not all(math.isfinite(s) and s > 0 for s in steps):
            raise ScanError(f"window step_deg must be a positive number (or two), got {self.step_deg!r}")
        object.__setattr__(self, "step_deg", steps)

    @property
    def shape(self) -> tuple[int, int]:
        """Grid shape ``(rows, cols) = (n_psi, n_theta)``."""
        return (_count(self.psi_deg, self.step_deg[1]), _count(self.theta_deg, self.step_deg[0]))

    def angles(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis values ``(theta, psi)`` of the grid columns and rows, radians."""
        n_psi, n_theta = self.shape
        theta = np.radians(self.theta_deg[0] + self.step_deg[0] * np.arange(n_theta))
        psi = np.radians(self.psi_deg[0] + self.step_deg[1] * np.arange(n_psi))
        return theta, psi

    def check_within(self, model: ScannerModel) -> None:
        """Raise :class:`ScanError` if the window leaves the scanner's field of view."""
        lo, hi = model.psi_limits_deg
        if self.psi_deg[0] < lo or self.psi_deg[1] > hi:
            raise ScanError(
                f"window psi_deg {list(self.psi_deg)} leaves the field of view of {model.name!r}: "
                f"zenith must lie in [{lo:g}, {hi:g}] deg"
            )
        if self.theta_deg[1] - self.theta_deg[0] > model.theta_limits_deg[1] - model.theta_limits_deg[0]:
            raise ScanError(
                f"window theta_deg {list(self.theta_deg)} is wider than the azimuth coverage of {model.name!r} "
                f"({model.theta_limits_deg[1] - model.theta_limits_deg[0]:g} deg)"
            )

    def to_dict(self) -> dict:
        """JSON-ready description."""
        return {"theta_deg": list(self.theta_deg), "psi_deg": list(self.psi_deg), "step_deg": list(self.step_deg)}


def _count(limits, step) -> int:
    return int(math.floor((limits[1] - limits[0]) / step + 1e-9)) + 1


def beam_axis(theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Beam direction in the scanner frame (:func:`beam_frame`'s first vector, without the two across it).

    Parameters
    ----------
    theta, psi : ndarray
        Azimuth and zenith of each beam, radians (same shape).

    Returns
    -------
    ndarray, shape (..., 3)
        Unit beam directions.
    """
    sp = np.sin(psi)
    return np.stack([sp * np.cos(theta), sp * np.sin(theta), np.cos(psi)], axis=-1)


def beam_frame(theta: np.ndarray, psi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Beam axis and the two unit vectors across it, in the scanner frame.

    Parameters
    ----------
    theta, psi : ndarray
        Azimuth and zenith of each beam, radians (same shape).

    Returns
    -------
    axis, e_psi, e_theta : ndarray, shape (..., 3)
        The beam direction, the direction of increasing ``psi`` (the fast,
        mirror axis) and of increasing ``theta``.
    """
    st, ct, sp, cp = np.sin(theta), np.cos(theta), np.sin(psi), np.cos(psi)
    axis = beam_axis(theta, psi)
    e_psi = np.stack([cp * ct, cp * st, -sp], axis=-1)
    e_theta = np.stack([-st, ct, np.zeros_like(st)], axis=-1)
    return axis, e_psi, e_theta


def grid_directions(theta_axis: np.ndarray, psi_axis: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """World-frame beam directions of a regular grid, shape ``(len(psi_axis), len(theta_axis), 3)``.

    Uses the separability of the grid (one sine and cosine per row and per
    column), which is much cheaper than :func:`beam_frame` on 2-D arrays.

    Parameters
    ----------
    theta_axis : ndarray
        Azimuth of each column, rad.
    psi_axis : ndarray
        Zenith angle of each row, rad.
    rotation : ndarray
        Scanner-to-world rotation matrix, shape ``(3, 3)``.

    Returns
    -------
    ndarray
        Unit direction vectors (dimensionless).
    """
    sp, cp = np.sin(psi_axis)[:, None], np.cos(psi_axis)[:, None]
    st, ct = np.sin(theta_axis)[None, :], np.cos(theta_axis)[None, :]
    local = np.empty((len(psi_axis), len(theta_axis), 3))
    local[..., 0] = sp * ct
    local[..., 1] = sp * st
    local[..., 2] = cp
    return local if np.array_equal(rotation, np.eye(3)) else local @ rotation.T

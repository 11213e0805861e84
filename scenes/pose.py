"""Object poses: where an object's local frame sits in the world.

A scene entry's ``pose`` is one of two forms.

**Facing form** (``center`` plus ``facing``): the local +z axis points at
the scanner (``facing: scanner``) or along a given vector, and local +y is as
close to world up as possible (local +x is then horizontal). Optional:

- ``spin_deg``: rotation about local +z, applied first (e.g. turns a leaf's
  midrib within its plane);
- ``incidence_deg`` with ``rotation_axis``: the object is then tilted by that
  angle about an axis through ``center`` perpendicular to the facing
  direction -- the one closest to vertical (``vertical``, the default), the
  horizontal one (``horizontal``) or the one closest to a given vector -- so
  the angle between local +z and the facing direction is exactly the
  incidence (right-hand rule about the axis);
- ``scale``.

**Explicit form**: ``translate`` (m), ``rotate`` (``{axis, angle_deg}`` or a
list of them, applied in order) and ``scale``: ``world = translate + R (scale
local)``.

An empty pose is the identity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from scenes.errors import SceneError
from scenes.fields import Fields, vector
from scenes.primitives import orthonormal_frame


@dataclass(frozen=True)
class Pose:
    """A similarity transform ``world = translation + scale · rotation @ local``."""

    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale: float = 1.0

    def apply(self, points) -> np.ndarray:
        """Map local points ``(..., 3)`` to the world, m."""
        return self.translation + self.scale * np.asarray(points, dtype=float) @ self.rotation.T

    def rotate(self, directions) -> np.ndarray:
        """Map local directions ``(..., 3)`` to the world (no translation or scale)."""
        return np.asarray(directions, dtype=float) @ self.rotation.T

    def then(self, outer: "Pose") -> "Pose":
        """The pose ``outer ∘ self`` (first this pose, then ``outer``)."""
        return Pose(outer.rotation @ self.rotation, outer.apply(self.translation), outer.scale * self.scale)


IDENTITY = Pose()

_FACING_KEYS = {"center", "facing", "incidence_deg", "rotation_axis", "spin_deg"}
_EXPLICIT_KEYS = {"translate", "rotate"}


def facing_pose(center, facing, incidence=0.0, rotation_axis="vertical", spin=0.0, scale=1.0) -> Pose:
    """Pose whose local +z points along ``facing``, tilted by ``incidence`` (rad).

    Parameters
    ----------
    center : array_like, shape (3,)
        World position of the local origin, m.
    facing : array_like, shape (3,)
        Direction local +z points to before the tilt.
    incidence : float
        Tilt of local +z away from ``facing``, rad.
    rotation_axis : {"vertical", "horizontal"} or array_like
        Tilt axis (projected perpendicular to ``facing``).
    spin : float
        Rotation about local +z applied first, rad.
    scale : float
        Uniform scale.

    Returns
    -------
    Pose
        Local to world, with the given uniform scale.
    """
    center = np.asarray(center, dtype=float)
    u, v, n = orthonormal_frame(facing)
    base = np.stack([u, v, n], axis=1)
    if isinstance(rotation_axis, str):
        if rotation_axis not in ("vertical", "horizontal"):
            raise SceneError(f"rotation_axis must be 'vertical', 'horizontal' or a vector, got {rotation_axis!r}")
        # v is the direction perpendicular to n closest to world up; u is horizontal.
        axis = v if rotation_axis == "vertical" else u
    else:
        axis = np.asarray(rotation_axis, dtype=float)
        axis = axis - np.dot(axis, n) * n
        if np.linalg.norm(axis) < 1e-9:
            raise SceneError(f"rotation_axis {list(rotation_axis)} is parallel to the facing direction")
        axis /= np.linalg.norm(axis)
    tilt = Rotation.from_rotvec(incidence * axis).as_matrix()
    rotation = tilt @ base @ Rotation.from_rotvec([0.0, 0.0, spin]).as_matrix()
    return Pose(rotation, center, float(scale))


def pose_from_spec(spec, scanner_position, where: str) -> Pose:
    """A :class:`Pose` from a scene file's ``pose`` mapping (see the module docstring).

    Parameters
    ----------
    spec : dict or None
        The pose mapping; ``None`` or ``{}`` is the identity.
    scanner_position : array_like, shape (3,)
        Scanner position, for ``facing: scanner``.
    where : str
        Location for error messages.

    Returns
    -------
    Pose
        Local to world.
    """
    if spec is None:
        return IDENTITY
    f = Fields(spec, f"{where}, pose")
    keys = set(spec)
    if keys & _FACING_KEYS and keys & _EXPLICIT_KEYS:
        raise SceneError(f"{f.where}: use either center/facing/incidence_deg/rotation_axis/spin_deg or "
                         f"translate/rotate, not both (got {sorted(keys)})")
    scale = f.number("scale", 1.0, positive=True)
    if keys & _FACING_KEYS:
        center = f.vector("center", unit="m")
        facing = f.raw("facing", "scanner")
        if facing == "scanner":
            facing = np.asarray(scanner_position, dtype=float) - center
            if np.linalg.norm(facing) < 1e-9:
                raise f.error("facing", "the object's center coincides with the scanner position")
        else:
            facing = f.vector("facing")
            if np.linalg.norm(facing) == 0:
                raise f.error("facing", "must be 'scanner' or a non-zero vector")
        incidence = f.number("incidence_deg", 0.0, low=-90.0, high=90.0, unit="deg")
        axis = f.raw("rotation_axis", "vertical")
        if axis not in ("vertical", "horizontal"):
            bad = f.error("rotation_axis", f"got {axis!r}; allowed: vertical, horizontal, or a vector [x, y, z]")
            axis = vector(axis, 3, lambda msg: bad)
        spin = f.number("spin_deg", 0.0, unit="deg")
        f.finish()
        try:
            return facing_pose(center, facing, math.radians(incidence), axis, math.radians(spin), scale)
        except SceneError as exc:
            raise SceneError(f"{f.where}: {exc}") from None
    translation = f.vector("translate", default=[0.0, 0.0, 0.0], unit="m")
    rotation = np.eye(3)
    steps = f.raw("rotate", [])
    for k, step in enumerate(steps if isinstance(steps, list) else [steps]):
        r = Fields(step, f"{f.where}, rotate" + (f"[{k}]" if isinstance(steps, list) else ""))
        axis = r.vector("axis")
        if np.linalg.norm(axis) == 0:
            raise r.error("axis", "must be a non-zero vector")
        angle = r.number("angle_deg", unit="deg")
        r.finish()
        rotation = Rotation.from_rotvec(math.radians(angle) * axis / np.linalg.norm(axis)).as_matrix() @ rotation
    f.finish()
    return Pose(rotation, translation, scale)

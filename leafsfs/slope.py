"""Greatest-slope geometry of iso-alpha regions (thesis ch.5 eqs 2.7-2.12, appendix II).

On a surface ``h(x)`` whose normal makes the angle ``alpha`` with the view
axis e3, the greatest-slope (GS) direction has elevation ``alpha``. Given a
curve on the surface with horizontal unit tangent ``t`` and 3-D tangent of
elevation ``gamma``, the horizontal *descending* GS direction ``g`` makes the
angle ``phi`` with ``t`` (eq 2.7)::

    phi = s * | v * pi - acos(tan|gamma| / tan alpha) |,   v = 1 if gamma >= 0 else 0

where the sign ``s`` (eq 2.6) says on which side of the curve ``g`` lies
(+1 left, -1 right, 0 toggle point). Then ``g = R(phi) t`` (eq 2.8) and
``G = (cos(alpha) g, -sin(alpha))`` (eq 2.9).

For a counter-clockwise curve (interior on the left) the propagation must go
outward (digest A2): along ``d = -s g``, so the height changes by
``s * tan(alpha)`` per unit of horizontal distance (descending outward
around a summit, ``s = -1``; ascending around a sink, ``s = +1``). At a
toggle point the propagation follows the level curve, i.e. the outward
normal of the curve, with the height unchanged (eq 2.11).

All functions are vectorised over the leading axis; angles in radians,
directions as unit vectors.
"""

from __future__ import annotations

import numpy as np


def rotate(vectors: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotate 2-D vectors counter-clockwise.

    Parameters
    ----------
    vectors : ndarray, (n, 2)
        Vectors to rotate (any length unit; lengths are kept).
    angles : ndarray, (n,)
        Counter-clockwise rotation of each vector, rad.

    Returns
    -------
    ndarray, (n, 2)
        The rotated vectors.
    """
    c, s = np.cos(angles), np.sin(angles)
    return np.stack([c * vectors[:, 0] - s * vectors[:, 1], s * vectors[:, 0] + c * vectors[:, 1]], axis=1)


def cross2(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """2-D cross product ``u_x v_y - u_y v_x`` (positive when ``v`` is left of ``u``).

    Parameters
    ----------
    u, v : ndarray, (..., 2)
        Vectors (broadcast over the leading axes; any length unit).

    Returns
    -------
    ndarray, (...)
        The cross product, in the product of the two vectors' units.
    """
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def outward_normal(t: np.ndarray) -> np.ndarray:
    """Right-hand normal ``R(-pi/2) t`` of a counter-clockwise curve: it points outward."""
    return np.stack([t[:, 1], -t[:, 0]], axis=1)


def gs_azimuth(gamma: np.ndarray, alpha: np.ndarray, sign: np.ndarray) -> np.ndarray:
    """Angle ``phi`` from the curve tangent to the descending GS direction (eq 2.7), radians in [-pi, pi].

    ``tan|gamma| / tan(alpha)`` is clamped to [0, 1]: noise can make the curve
    steeper than the region allows (digest §3.6.3 step 2).

    Parameters
    ----------
    gamma : ndarray, (n,)
        Elevation of the curve's 3-D tangent, rad (positive rising along the curve).
    alpha : ndarray, (n,)
        Angle between the surface normal and the view axis e3, rad, in (0, pi/2].
    sign : ndarray, (n,)
        Side of the curve on which the descending GS direction lies (eq 2.6):
        +1 left, -1 right, 0 at a toggle point.

    Returns
    -------
    ndarray, (n,)
        ``phi``, rad.
    """
    ratio = np.clip(np.tan(np.abs(gamma)) / np.tan(alpha), 0.0, 1.0)
    return sign * np.abs(np.where(gamma >= 0, np.pi, 0.0) - np.arccos(ratio))


def descending_direction(t: np.ndarray, gamma: np.ndarray, alpha: np.ndarray, sign: np.ndarray) -> np.ndarray:
    """Horizontal unit descending GS direction ``g = R(phi) t`` (eqs 2.7-2.8).

    Parameters
    ----------
    t : ndarray, (n, 2)
        Horizontal unit tangents of the curve.
    gamma : ndarray, (n,)
        Elevation of the curve's 3-D tangent, rad.
    alpha : ndarray, (n,)
        Angle between the surface normal and the view axis, rad.
    sign : ndarray, (n,)
        Side of the GS direction (eq 2.6): +1 left, -1 right, 0 toggle.

    Returns
    -------
    ndarray, (n, 2)
        Unit horizontal descending GS directions.
    """
    return rotate(t, gs_azimuth(gamma, alpha, sign))


def gs_vector(g: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Unit 3-D descending GS vector ``(cos(alpha) g, -sin(alpha))`` (eq 2.9).

    Parameters
    ----------
    g : ndarray, (n, 2)
        Horizontal unit descending GS directions.
    alpha : ndarray, (n,)
        Angle between the surface normal and the view axis, rad.

    Returns
    -------
    ndarray, (n, 3)
        Unit GS vectors (the third component is along the view axis e3).
    """
    return np.column_stack([np.cos(alpha)[:, None] * g, -np.sin(alpha)])


def propagation_direction(t: np.ndarray, g: np.ndarray, sign: np.ndarray) -> np.ndarray:
    """Outward horizontal propagation direction: ``-sign * g``, or the outward normal at toggles (``sign = 0``).

    Parameters
    ----------
    t : ndarray, (n, 2)
        Horizontal unit tangents of the counter-clockwise curve.
    g : ndarray, (n, 2)
        Horizontal unit descending GS directions.
    sign : ndarray, (n,)
        Side of the GS direction (eq 2.6): +1 left, -1 right, 0 toggle.

    Returns
    -------
    ndarray, (n, 2)
        Unit horizontal propagation directions.
    """
    return np.where((sign == 0)[:, None], outward_normal(t), -sign[:, None] * g)


def sps_normal(gradient: np.ndarray) -> np.ndarray:
    """Upward unit normal ``(-grad h, 1) / norm`` of the plane with height gradient ``gradient`` ``(n, 2)``."""
    normal = np.column_stack([-gradient, np.ones(len(gradient))])
    return normal / np.linalg.norm(normal, axis=1, keepdims=True)


def curve_tangent_3d(t: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """3-D unit tangent of a curve with horizontal tangent ``t`` lying on a surface of normal ``normal`` (eq 2.12).

    Closed form of ``T = sgn(x) (k x N)`` (``k`` the principal normal of the
    curve's projection): ``T ∝ (t, -(N_x t_x + N_y t_y) / N_z)``, oriented so
    that its horizontal part is ``+t``. ``normal`` must have ``N_z > 0``.

    Parameters
    ----------
    t : ndarray, (n, 2)
        Horizontal unit tangents of the curve.
    normal : ndarray, (n, 3)
        Unit surface normals with a positive third (view-axis) component.

    Returns
    -------
    ndarray, (n, 3)
        Unit 3-D tangents.
    """
    rise = -(normal[:, 0] * t[:, 0] + normal[:, 1] * t[:, 1]) / normal[:, 2]
    tangent = np.column_stack([t, rise])
    return tangent / np.linalg.norm(tangent, axis=1, keepdims=True)


def toggle_gradient(t: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    """Height gradient of the toggle plane (thesis ch.5 step 5): it contains the curve tangent and the level line.

    At a toggle point the GS is tangent to the curve, so the plane through
    ``T = (t, tan gamma)`` and the horizontal outward normal has gradient
    ``tan(gamma) t``.

    Parameters
    ----------
    t : ndarray, (n, 2)
        Horizontal unit tangents of the curve.
    gamma : ndarray, (n,)
        Elevation of the curve's 3-D tangent, rad.

    Returns
    -------
    ndarray, (n, 2)
        Height gradient, height units per continuous unit (m/m in a scan's local frame).
    """
    return np.tan(gamma)[:, None] * t

"""Optional non-Lambertian reflectance: a Mitsuba BSDF evaluated at the backscatter direction.

The receiver of a TLS is coaxial with the beam, so only the BSDF value at
``w_o = w_i`` (the hot-spot direction) matters. For an isotropic BSDF it
depends on the incidence angle alone, so it is tabulated once per object on a
grid of incidence angles (with Mitsuba's ``scalar_rgb`` variant) and the
tracing kernel interpolates the table: the effective reflectance
``rho_eff(alpha) = pi·f_r(w_i, w_i)`` replaces ``rho`` in
``P = w·rho·cos(alpha)·g(d)``. A Lambertian surface of reflectance ``rho``
has ``rho_eff = rho`` at every angle, which is what the rows of the objects
that keep the Lambertian model hold.

The object's reflectance is inserted as the plugin's diffuse reflectance
(:data:`REFLECTANCE_KEYS`); the other plugin parameters come from
``ScannerModel.bsdf``.
"""

from __future__ import annotations

import math

import numpy as np

from tlssim.errors import ScanError

#: Incidence-angle nodes of the tables: 0 to 90 degrees in 0.5 degree steps.
TABLE_ANGLES = 181

#: Parameter of each supported Mitsuba plugin that receives the object's reflectance.
REFLECTANCE_KEYS = {"diffuse": "reflectance", "plastic": "diffuse_reflectance",
                    "roughplastic": "diffuse_reflectance", "principled": "base_color"}


def table_angles() -> np.ndarray:
    """Incidence angles of the table nodes, rad."""
    return np.linspace(0.0, 0.5 * math.pi, TABLE_ANGLES)


def backscatter_reflectance(plugin: dict, reflectance: float) -> np.ndarray:
    """Effective reflectance ``pi·f_r(w_i, w_i)`` of a BSDF at the table angles.

    Parameters
    ----------
    plugin : dict
        Mitsuba BSDF plugin description (``type`` among :data:`REFLECTANCE_KEYS`).
    reflectance : float
        Diffuse reflectance of the material at the scanner wavelength.

    Returns
    -------
    ndarray, shape (TABLE_ANGLES,)
        Effective reflectance at each node (the last node is evaluated just
        short of grazing incidence).
    """
    import drjit as dr
    import mitsuba as mi

    kind = plugin.get("type")
    if kind not in REFLECTANCE_KEYS:
        raise ScanError(f"bsdf type {kind!r} is not supported; allowed: {', '.join(sorted(REFLECTANCE_KEYS))}")
    spec = {**plugin, REFLECTANCE_KEYS[kind]: {"type": "rgb", "value": float(reflectance)}}
    angles = np.minimum(table_angles(), math.radians(89.9))
    with mi.scoped_set_variant("scalar_rgb"):
        try:
            bsdf = mi.load_dict(spec)
        except Exception as exc:  # Mitsuba reports bad plugin parameters as RuntimeError
            raise ScanError(f"bsdf {plugin!r} cannot be loaded by Mitsuba: {exc}") from None
        context = mi.BSDFContext()
        values = []
        for angle in angles:
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
            si.wi = mi.Vector3f(math.sin(angle), 0.0, math.cos(angle))
            values.append(math.pi * bsdf.eval(context, si, si.wi)[0] / math.cos(angle))
    return np.array(values)


def reflectance_table(plugin: dict, reflectance: np.ndarray, uses_bsdf: np.ndarray) -> np.ndarray:
    """Effective-reflectance table of every object against incidence.

    Objects with ``uses_bsdf`` False keep their Lambertian reflectance (a
    constant row); the BSDF is evaluated once per distinct reflectance.

    Parameters
    ----------
    plugin : dict
        Mitsuba BSDF plugin description (``type`` among :data:`REFLECTANCE_KEYS`).
    reflectance : ndarray, shape (n_objects,)
        Diffuse reflectance of every object, in [0, 1].
    uses_bsdf : ndarray of bool, shape (n_objects,)
        Which objects get the BSDF.

    Returns
    -------
    ndarray, shape (n_objects, TABLE_ANGLES), float64
        Effective reflectance ``pi·f_r`` at the incidence angles of :func:`table_angles`.
    """
    table = np.repeat(np.asarray(reflectance, dtype=np.float64)[:, None], TABLE_ANGLES, axis=1)
    for value in np.unique(np.asarray(reflectance)[uses_bsdf]):
        table[uses_bsdf & (reflectance == value)] = backscatter_reflectance(plugin, float(value))
    return table

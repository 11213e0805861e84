"""Library of materials at the scanner wavelength (785 nm), with their sources.

Every entry is Lambertian; ``reflectance`` is the hemispherical reflectance
at 785 nm. Entries used for populations of objects (leaves, bark) also carry
a between-object standard deviation, drawn per object by
:func:`sample_material` so that no two leaves of a tree are exactly alike.

=================  ===========  =====  ===============================================================
name               reflectance  sd     source / assumption
=================  ===========  =====  ===============================================================
spectralon-99      0.99         --     99 % Spectralon panel; Balduzzi et al. 2011 (Sensors 11:1657) §2.2.1
canson-83          0.83         --     matte Canson paper, measured at 785 nm with an HR1024 spectroradiometer (same source)
canson-80          0.80         --     same source
canson-68          0.68         --     same source
canson-48          0.48         --     same source
canson-3           0.03         --     same source
greycard-22        0.22         --     Kodak grey card (same source)
paint-3            0.03         --     matte board painted to 3 % (same source)
pear-leaf          0.48         0.03   Conference pear leaf, adaxial side; 0.48 from the project brief
                                       (issue 3); sd and transmittance 0.42 are assumptions typical of
                                       broadleaves in the NIR plateau (absorption ≈ 0.1)
bark               0.35         0.05   assumption: smooth young pear/apple bark, NIR plateau
soil               0.25         --     assumption: bare loamy orchard soil, moist, at 785 nm
wall               0.60         --     assumption: light painted plaster at 785 nm
=================  ===========  =====  ===============================================================
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.errors import SceneError
from scenes.scene import Material


@dataclass(frozen=True)
class LibraryMaterial:
    """A library entry: nominal material plus between-object variation and its source."""

    material: Material
    reflectance_sd: float
    source: str


_CALIBRATION_SOURCE = "Balduzzi et al. 2011, Sensors 11:1657, sect. 2.2.1: measured at 785 nm (HR1024)"

_LIBRARY: dict[str, LibraryMaterial] = {
    entry.material.name: entry
    for entry in (
        LibraryMaterial(Material("spectralon-99", 0.99), 0.0, _CALIBRATION_SOURCE),
        LibraryMaterial(Material("canson-83", 0.83), 0.0, _CALIBRATION_SOURCE),
        LibraryMaterial(Material("canson-80", 0.80), 0.0, _CALIBRATION_SOURCE),
        LibraryMaterial(Material("canson-68", 0.68), 0.0, _CALIBRATION_SOURCE),
        LibraryMaterial(Material("canson-48", 0.48), 0.0, _CALIBRATION_SOURCE),
        LibraryMaterial(Material("canson-3", 0.03), 0.0, _CALIBRATION_SOURCE),
        LibraryMaterial(Material("greycard-22", 0.22), 0.0, _CALIBRATION_SOURCE),
        LibraryMaterial(Material("paint-3", 0.03), 0.0, _CALIBRATION_SOURCE),
        LibraryMaterial(Material("pear-leaf", 0.48, 0.42), 0.03,
                        "reflectance 0.48: project brief (issue 3); sd 0.03 and transmittance 0.42: assumptions "
                        "(broadleaf NIR plateau, absorption about 0.1)"),
        LibraryMaterial(Material("bark", 0.35), 0.05, "assumption: smooth young pome-fruit bark at 785 nm"),
        LibraryMaterial(Material("soil", 0.25), 0.0, "assumption: moist loamy orchard soil at 785 nm"),
        LibraryMaterial(Material("wall", 0.60), 0.0, "assumption: light painted plaster at 785 nm"),
    )
}

#: Names of the library materials.
MATERIAL_NAMES: tuple[str, ...] = tuple(_LIBRARY)


def library_entry(name: str) -> LibraryMaterial:
    """The library entry ``name`` (nominal material, variation, source).

    Raises
    ------
    SceneError
        If the name is not in the library (the message lists it).
    """
    if name not in _LIBRARY:
        raise SceneError(f"unknown material {name!r}; library: {', '.join(MATERIAL_NAMES)}")
    return _LIBRARY[name]


def get_material(name: str) -> Material:
    """The nominal library material ``name`` (see the module table)."""
    return library_entry(name).material


def sample_material(name: str, rng: np.random.Generator) -> Material:
    """A per-object draw of library material ``name``.

    The reflectance is drawn from a normal distribution with the entry's
    between-object standard deviation, clipped to ``[0.01, 0.99]`` and to
    ``1 - transmittance``; entries without variation come back unchanged.

    Parameters
    ----------
    name : str
        Library name (see the module table).
    rng : numpy.random.Generator
        Source of the draw (not used for entries without variation).

    Returns
    -------
    Material
        Same name and transmittance as the nominal entry.
    """
    entry = library_entry(name)
    nominal = entry.material
    if entry.reflectance_sd == 0:
        return nominal
    top = min(0.99, 1.0 - nominal.transmittance)
    value = float(np.clip(rng.normal(nominal.reflectance, entry.reflectance_sd), 0.01, top))
    return Material(nominal.name, value, nominal.transmittance)


def material_from_spec(spec, where: str = "material") -> Material:
    """A material from a scene-file value: a library name or a mapping.

    Parameters
    ----------
    spec : str or dict
        A library name (``"paint-3"``), or ``{reflectance, transmittance?,
        name?}``, or ``{library: name}`` with optional ``reflectance`` /
        ``transmittance`` overrides.
    where : str
        Location used in error messages.

    Returns
    -------
    Material
    """
    if isinstance(spec, str):
        try:
            return get_material(spec)
        except SceneError as exc:
            raise SceneError(f"{where}: {exc}") from None
    if not isinstance(spec, dict):
        raise SceneError(f"{where}: expected a library name or a mapping with 'reflectance', got {spec!r}")
    unknown = sorted(set(spec) - {"name", "library", "reflectance", "transmittance"})
    if unknown:
        raise SceneError(f"{where}: unknown field(s) {unknown}; allowed: library, name, reflectance, transmittance")
    base = get_material(spec["library"]) if "library" in spec else None
    if base is None and "reflectance" not in spec:
        raise SceneError(f"{where}: give 'reflectance' (a number in [0, 1]) or a library name")
    reflectance = spec.get("reflectance", base.reflectance if base else None)
    transmittance = spec.get("transmittance", base.transmittance if base else 0.0)
    for key, value in (("reflectance", reflectance), ("transmittance", transmittance)):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SceneError(f"{where}: {key} must be a number in [0, 1], got {value!r}")
    name = spec.get("name") or (base.name if base else f"lambert-{reflectance:g}")
    try:
        return Material(str(name), float(reflectance), float(transmittance))
    except SceneError as exc:
        raise SceneError(f"{where}: {exc}") from None


def material_to_spec(material: Material):
    """Scene-file value of ``material``: its library name when it is a nominal library entry."""
    if material.name in _LIBRARY and _LIBRARY[material.name].material == material:
        return material.name
    spec = {"name": material.name, "reflectance": material.reflectance}
    if material.transmittance:
        spec["transmittance"] = material.transmittance
    return spec

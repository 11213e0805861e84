"""Built-in calibration scenes: the reflectance-panel series and the leaf goniometer.

Both reproduce the laboratory set-ups of Balduzzi et al. 2011 (Sensors
11:1657, sec. 2.2) that calibrate the FARO LS880 intensity:

- ``panel-series``: Lambertian panels of reflectance 0.99, 0.83, 0.80, 0.68,
  0.48, 0.22 and 0.03, each perpendicular to the beam at 0.35 ... 10 m. Every
  (reflectance, distance) pair gets its own panel in its own direction, so
  that one small window with a coarse step scans them all; each panel spans
  :data:`PANEL_SPAN_DEG` as seen from the scanner (12 mm at 0.35 m ... 35 cm
  at 10 m), enough for pulses whose footprint lies wholly on it.
- ``goniometer``: a flat half pear leaf (6.47 cm long, 2.19 cm wide, the
  measured means; reflectance 0.48) lying on a 3 % black platform 2.16 m from
  the scanner, turned about the vertical axis (one series) and about the
  horizontal axis (another) so that the incidence runs 0-85 deg in 5 deg
  steps. The 36 stations sit side by side in one window at the instrument's
  own step.

Object names carry the set-up (:func:`panel_name`, :func:`leaf_name`), so
that the calibration code (:mod:`tlssim.calibration`) can read them back from
a scan's ``object_names``. :func:`panel_row` builds further panel set-ups
(reflectance, distance, incidence) for precision and dropout experiments.
"""

from __future__ import annotations

import math
import re

import numpy as np

from scenes.library import register
from scenes.materials import get_material
from scenes.primitives import rectangle
from scenes.scene import Material, Scene, SceneObject

#: Panel materials of the series (library names, :mod:`scenes.materials`) by reflectance.
PANEL_MATERIALS = {0.99: "spectralon-99", 0.83: "canson-83", 0.80: "canson-80", 0.68: "canson-68",
                   0.48: "canson-48", 0.22: "greycard-22", 0.03: "canson-3"}
PANEL_REFLECTANCES = tuple(PANEL_MATERIALS)
PANEL_DISTANCES_M = (0.35, 0.45, 0.6, 0.75, 0.8, 1.0, 1.5, 1.85, 2.15, 2.6, 3.6, 5.0, 7.5, 10.0)
#: Angular size of every panel and spacing of the panel grid, degrees.
PANEL_SPAN_DEG, PANEL_PITCH_DEG = 2.0, 2.4
#: Step of the panel-series window, degrees (a few dozen pulses per panel).
PANEL_STEP_DEG = 0.1

GONIOMETER_DISTANCE_M = 2.16
GONIOMETER_ANGLES_DEG = tuple(range(0, 90, 5))
GONIOMETER_AXES = ("vertical", "horizontal")
#: Half pear leaf after Sensors 2011 sec. 2.2.2: length and width (the measured half-width), m.
LEAF_LENGTH_M, LEAF_WIDTH_M = 0.0647, 0.0219
#: Library materials of the leaf (reflectance 0.48, transmittance 0.42) and of the black platform (3 %).
LEAF_MATERIAL, PLATFORM_MATERIAL = "pear-leaf", "paint-3"
#: Platform margin around the leaf and gap between leaf and platform, m.
PLATFORM_MARGIN_M, PLATFORM_GAP_M = 0.015, 0.001
#: Spacing of the goniometer stations (azimuth, zenith), degrees.
STATION_PITCH_DEG = (2.8, 1.6)

_PANEL = re.compile(r"^panel-rho(?P<rho>[0-9.]+)-d(?P<d>[0-9.]+)m$")
_LEAF = re.compile(r"^leaf-(?P<axis>vertical|horizontal)-(?P<deg>[0-9]+)deg$")


def panel_name(reflectance: float, distance_m: float) -> str:
    """Object name of a calibration panel, e.g. ``panel-rho0.99-d3.60m``.

    Parameters
    ----------
    reflectance : float
        Panel reflectance in [0, 1] (written with two decimals).
    distance_m : float
        Panel distance from the scanner, m (written with two decimals).

    Returns
    -------
    str
    """
    return f"panel-rho{reflectance:.2f}-d{distance_m:.2f}m"


def parse_panel_name(name: str) -> tuple[float, float] | None:
    """``(reflectance, distance_m)`` of a panel name, ``None`` for other objects."""
    match = _PANEL.match(name)
    return None if match is None else (float(match["rho"]), float(match["d"]))


def leaf_name(axis: str, angle_deg: int) -> str:
    """Object name of a goniometer leaf, e.g. ``leaf-vertical-45deg``.

    Parameters
    ----------
    axis : str
        Goniometer axis, ``"vertical"`` or ``"horizontal"``.
    angle_deg : int
        Nominal incidence angle, degrees.

    Returns
    -------
    str
    """
    return f"leaf-{axis}-{angle_deg:02d}deg"


def parse_leaf_name(name: str) -> tuple[str, float] | None:
    """``(axis, nominal incidence in degrees)`` of a goniometer leaf name, ``None`` for other objects."""
    match = _LEAF.match(name)
    return None if match is None else (match["axis"], float(match["deg"]))


def _direction(theta_deg: float, psi_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Line of sight and the horizontal and upward unit vectors across it."""
    t, p = math.radians(theta_deg), math.radians(psi_deg)
    axis = np.array([math.sin(p) * math.cos(t), math.sin(p) * math.sin(t), math.cos(p)])
    across = np.array([-math.sin(t), math.cos(t), 0.0])
    up = -np.array([math.cos(p) * math.cos(t), math.cos(p) * math.sin(t), -math.sin(p)])
    return axis, across, up


def _grid_angles(count: int, pitch: float, centre: float) -> np.ndarray:
    return centre + pitch * (np.arange(count) - 0.5 * (count - 1))


@register("panel-series", "Lambertian panels (rho 0.99 ... 0.03) perpendicular at 0.35 ... 10 m: intensity calibration")
def panel_series() -> Scene:
    thetas = _grid_angles(len(PANEL_DISTANCES_M), PANEL_PITCH_DEG, 0.0)
    psis = _grid_angles(len(PANEL_REFLECTANCES), PANEL_PITCH_DEG, 90.0)
    objects = []
    for rho, psi in zip(PANEL_REFLECTANCES, psis):
        for distance, theta in zip(PANEL_DISTANCES_M, thetas):
            axis, _, up = _direction(theta, psi)
            side = 2.0 * distance * math.tan(math.radians(0.5 * PANEL_SPAN_DEG))
            vertices, faces = rectangle(distance * axis, -axis, (side, side), up=up)
            objects.append(SceneObject(panel_name(rho, distance), "panel", vertices, faces,
                                       get_material(PANEL_MATERIALS[rho]), truth={"normal": list(-axis)}))
    # The window reaches half a degree beyond the outer cells, past the footprint of the nearest panels.
    half = (0.5 * len(PANEL_DISTANCES_M) * PANEL_PITCH_DEG + 0.5, 0.5 * len(PANEL_REFLECTANCES) * PANEL_PITCH_DEG + 0.5)
    return Scene(objects=objects, scanner={
        "preset": "faro-ls880",
        "position": [0.0, 0.0, 0.0],
        # The laboratory series starts at 0.35 m, inside the LS880's 0.6 m minimum range (digest 7.6).
        "min_range_m": 0.3,
        "window": {"theta_deg": [-half[0], half[0]], "psi_deg": [90.0 - half[1], 90.0 + half[1]],
                   "step_deg": PANEL_STEP_DEG},
    })


def panel_row(panels, span_deg: float = 0.5, gap_deg: float = 0.2, step_deg: float | None = None) -> Scene:
    """Lambertian panels side by side along the horizon, each in its own direction.

    Parameters
    ----------
    panels : sequence of (reflectance, distance_m, incidence_deg)
        One panel each, centred at ``distance_m`` and turned about the
        vertical by the incidence angle; its width is stretched by
        ``1 / cos(incidence)`` so that every panel spans ``span_deg`` as seen
        from the scanner.
    span_deg, gap_deg : float
        Angular size of the panels and gap between them, degrees.
    step_deg : float, optional
        Window step (default: the scanner's).

    Returns
    -------
    Scene
        Objects named ``panel-<i>`` with their reflectance, distance and
        incidence in ``truth``; the window covers all panels with a margin
        of one gap.
    """
    pitch = span_deg + gap_deg
    thetas = _grid_angles(len(panels), pitch, 0.0)
    objects = []
    for i, ((rho, distance, incidence), theta) in enumerate(zip(panels, thetas)):
        axis, across, up = _direction(theta, 90.0)
        side = 2.0 * distance * math.tan(math.radians(0.5 * span_deg))
        normal = _rotation(up, math.radians(incidence)) @ -axis
        vertices, faces = rectangle(distance * axis, normal, (side / math.cos(math.radians(incidence)), side), up=up)
        objects.append(SceneObject(f"panel-{i}", "panel", vertices, faces, Material(f"lambert-{rho:g}", rho),
                                   truth={"normal": list(normal), "reflectance": rho, "distance_m": distance,
                                          "incidence_deg": incidence}))
    half = 0.5 * len(panels) * pitch + gap_deg, 0.5 * span_deg + gap_deg
    window = {"theta_deg": [-half[0], half[0]], "psi_deg": [90.0 - half[1], 90.0 + half[1]]}
    if step_deg is not None:
        window["step_deg"] = step_deg
    return Scene(objects=objects, scanner={"preset": "faro-ls880", "position": [0.0, 0.0, 0.0], "window": window},
                 name="panel-row")


def _half_leaf(samples: int = 24) -> np.ndarray:
    """Outline of a flat half leaf in its plane (u along the midrib, v across), centred on its bounding box, m."""
    t = np.linspace(0.0, math.pi, samples)
    u = 0.5 * LEAF_LENGTH_M * np.cos(t)
    v = LEAF_WIDTH_M * (np.sin(t) - 0.5)
    return np.stack([u, v], axis=1)


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix about a unit ``axis`` by ``angle`` radians (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * k @ k


@register("goniometer", "half pear leaf (rho 0.48) on a 3 % platform at 2.16 m, incidence 0-85 deg about two axes")
def goniometer() -> Scene:
    outline = _half_leaf()
    # Fan from the bounding-box centre over the curved margin, closed by the straight midrib.
    fan = np.array([[0, i, i + 1] for i in range(1, len(outline))] + [[0, len(outline), 1]])
    thetas = _grid_angles(len(GONIOMETER_AXES), STATION_PITCH_DEG[0], 0.0)
    psis = _grid_angles(len(GONIOMETER_ANGLES_DEG), STATION_PITCH_DEG[1], 90.0)
    leaf_material, platform_material = get_material(LEAF_MATERIAL), get_material(PLATFORM_MATERIAL)
    objects = []
    for rotation_axis, theta in zip(GONIOMETER_AXES, thetas):
        for angle, psi in zip(GONIOMETER_ANGLES_DEG, psis):
            axis, across, up = _direction(theta, psi)
            centre = GONIOMETER_DISTANCE_M * axis
            turn = _rotation(up if rotation_axis == "vertical" else across, math.radians(angle))
            normal = turn @ -axis
            points = np.vstack([[0.0, 0.0], outline])
            leaf = centre + (points[:, :1] * across + points[:, 1:] * up) @ turn.T
            size = (LEAF_LENGTH_M + 2 * PLATFORM_MARGIN_M, LEAF_WIDTH_M + 2 * PLATFORM_MARGIN_M)
            plate, plate_faces = rectangle(centre - PLATFORM_GAP_M * normal, normal, size, up=turn @ up)
            truth = {"normal": list(normal), "incidence_deg": float(angle), "rotation_axis": rotation_axis}
            objects.append(SceneObject(leaf_name(rotation_axis, angle), "leaf", leaf, fan, leaf_material,
                                       truth={**truth, "length_m": LEAF_LENGTH_M, "half_width_m": LEAF_WIDTH_M}))
            objects.append(SceneObject(f"platform-{rotation_axis}-{angle:02d}deg", "plane", plate, plate_faces,
                                       platform_material, truth=truth))
    half = (0.5 * len(GONIOMETER_AXES) * STATION_PITCH_DEG[0], 0.5 * len(GONIOMETER_ANGLES_DEG) * STATION_PITCH_DEG[1])
    return Scene(objects=objects, scanner={
        "preset": "faro-ls880",
        "position": [0.0, 0.0, 0.0],
        "window": {"theta_deg": [-half[0], half[0]], "psi_deg": [90.0 - half[1], 90.0 + half[1]]},
    })

"""tlssim: a physically based simulator of phase-shift (AM-CW) terrestrial laser scanners.

The contract between simulation and reconstruction (:class:`Scan`,
:class:`ScannerPose`, :class:`ScanWindow`, :class:`ScannerModel` and the scan
file formats of :mod:`tlssim.formats`, the tiled scans of
:mod:`tlssim.tiled`) imports without the simulator: the simulator's names
(:func:`simulate`, :func:`simulate_tiled`, :class:`ScanSetup`,
:func:`setup_from_section`) load Mitsuba, Dr.Jit and the scene library on
first use.
"""

import importlib
import sys
import types

from tlssim.errors import ScanError
from tlssim.pattern import ScannerPose, ScanWindow
from tlssim.scan import Scan, ScannerDescription
from tlssim.scanner import ScannerModel, get_preset, preset_names, register_preset
from tlssim.tiled import TiledScan, open_scan, open_tiled

#: Names served from :mod:`tlssim.simulate`, imported on first access (PEP 562).
_SIMULATOR_NAMES = ("ScanSetup", "setup_from_section", "simulate", "simulate_tiled")

__all__ = ["Scan", "ScanError", "ScannerDescription", "ScanSetup", "ScannerModel", "ScannerPose", "ScanWindow", "get_preset",
           "preset_names", "register_preset", "setup_from_section", "simulate", "simulate_tiled", "TiledScan", "open_scan",
           "open_tiled"]


def __getattr__(name: str):
    if name not in _SIMULATOR_NAMES:
        raise AttributeError(f"module 'tlssim' has no attribute {name!r}")
    module = importlib.import_module("tlssim.simulate")
    for lazy in _SIMULATOR_NAMES:
        setattr(sys.modules[__name__], lazy, getattr(module, lazy))
    return globals()[name]


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    """The package keeps ``tlssim.simulate`` the function when its submodule of the same name is imported.

    The import system binds a submodule to its package's attribute after
    loading it; without this, ``import tlssim.simulate`` (or ``from
    tlssim.simulate import ...``) would turn ``tlssim.simulate`` into the
    module. The module stays in ``sys.modules["tlssim.simulate"]``.
    """

    def __setattr__(self, name, value):
        if name == "simulate" and isinstance(value, types.ModuleType):
            value = value.simulate
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package

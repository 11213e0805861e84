"""tlssim: a physically based simulator of phase-shift (AM-CW) terrestrial laser scanners."""

from tlssim.errors import ScanError
from tlssim.pattern import ScannerPose, ScanWindow
from tlssim.scan import Scan
from tlssim.scanner import ScannerModel, get_preset, preset_names, register_preset
from tlssim.simulate import ScanSetup, setup_from_section, simulate

__all__ = ["Scan", "ScanError", "ScanSetup", "ScannerModel", "ScannerPose", "ScanWindow", "get_preset",
           "preset_names", "register_preset", "setup_from_section", "simulate"]

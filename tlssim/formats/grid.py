"""Helpers shared by the scan formats: scanner-frame coordinates and grid angles."""

from __future__ import annotations

import warnings

import numpy as np

from tlssim.pattern import ScannerPose, beam_frame
from tlssim.scan import Scan


def local_points(scan: Scan) -> np.ndarray:
    """Points of every grid cell in the scanner frame, m; cells without a return get their unit beam direction."""
    measured = (scan.xyz - scan.pose.position) @ scan.pose.rotation
    direction, _, _ = beam_frame(scan.theta, scan.psi)
    return np.where(scan.valid[..., None], measured, direction)


def angles_of(local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth ``theta`` (continued along each row) and zenith ``psi`` of scanner-frame vectors, rad."""
    theta = np.arctan2(local[..., 1], local[..., 0])
    psi = np.arccos(np.clip(local[..., 2] / np.linalg.norm(local, axis=-1), -1.0, 1.0))
    return _unwrap_rows(theta), psi


def complete_angles(theta: np.ndarray, psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fill cells of unknown direction (NaN) from the grid's column azimuths and row zeniths.

    A scan grid has one azimuth per column and one zenith per row; missing
    columns or rows (no direction anywhere in them) are filled from a
    straight-line fit of the known ones against their index.
    """
    if not (np.isnan(theta).any() or np.isnan(psi).any()):
        return theta, psi
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns or rows
        column_theta = _fill_line(np.nanmedian(theta, axis=0))
        row_psi = _fill_line(np.nanmedian(psi, axis=1))
    return (np.where(np.isnan(theta), column_theta[None, :], theta),
            np.where(np.isnan(psi), row_psi[:, None], psi))


def scan_from_local(local: np.ndarray, valid: np.ndarray, intensity: np.ndarray, pose: ScannerPose,
                    theta: np.ndarray, psi: np.ndarray, meta: dict) -> Scan:
    """A truth-less :class:`Scan` from scanner-frame points on the grid."""
    range_m = np.where(valid, np.linalg.norm(local, axis=-1), np.nan)
    xyz = np.where(valid[..., None], local @ pose.rotation.T + pose.position, np.nan)
    intensity = np.where(valid, intensity, np.nan).astype(np.float32)
    return Scan(range=range_m, intensity=intensity, theta=theta, psi=psi, xyz=xyz, pose=pose, meta=meta)


def _unwrap_rows(theta: np.ndarray) -> np.ndarray:
    known = np.where(np.isnan(theta), np.nanmedian(theta) if np.isfinite(theta).any() else 0.0, theta)
    return np.where(np.isnan(theta), np.nan, np.unwrap(known, axis=-1))


def _fill_line(values: np.ndarray) -> np.ndarray:
    known = np.isfinite(values)
    if known.all() or not known.any():
        return values
    index = np.arange(len(values))
    if known.sum() == 1:
        return np.where(known, values, values[known][0])
    slope, intercept = np.polyfit(index[known], values[known], 1)
    return np.where(known, values, intercept + slope * index)

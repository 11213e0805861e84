"""The simulated calibration experiment: scan the calibration targets with a scanner model and fit the inverse model.

The two experiments of Balduzzi et al. 2011 (panels of seven reflectances
from 0.35 to 10 m; a leaf on a goniometer turned from 0 to 85 deg) are
simulated with :func:`tlssim.simulate` on the built-in scenes
``panel-series`` and ``goniometer``, reduced to tables by
:mod:`tlssim.calibration` and fitted by :mod:`leafsfs.calibration`. The
result is the :class:`leafsfs.calibration.Calibration` that the PROP-SFS
variants receive (reconstruction itself never simulates).

Calibrations are cached in memory per ``(model, seed)`` and, when
``cache_dir`` (or the ``TLSBENCH_CACHE_DIR`` environment variable) names a
directory, as JSON files keyed by the model, the seed and the source code of
the packages that produce them (hashed once per process).

``tlsbench experiment calibration -o calibration.json`` writes one for a
preset or for the scanner model recorded in a scan, with its tables.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from pathlib import Path

import scenes
from benchmarks.errors import BenchError
from leafsfs.calibration import Calibration, fit_calibration
from tlssim.calibration import goniometer_table, panel_table, save_table
from tlssim.scan import Scan
from tlssim.scanner import ScannerModel, get_preset
from tlssim.simulate import setup_from_section, simulate

#: Built-in scenes of the two experiments, in the order the fit needs them.
SCENES = ("panel-series", "goniometer")
#: Packages whose source decides the calibration (the on-disk cache key covers them).
_SOURCES = ("tlssim", "scenes", "leafsfs/calibration.py")

_MEMORY: dict[tuple[ScannerModel, int], Calibration] = {}


def simulate_tables(model: ScannerModel, seed: int = 0) -> tuple[dict, dict]:
    """Simulate both experiments with ``model`` and measure their tables.

    Parameters
    ----------
    model : ScannerModel
        The scanner; the scenes' set-ups (pose, window, the panel series'
        shorter minimum range) apply on top of it.
    seed : int
        Seed of both simulations.

    Returns
    -------
    panels, goniometer : dict of ndarray
        :func:`tlssim.calibration.panel_table` and
        :func:`tlssim.calibration.goniometer_table`.
    """
    scans = []
    for name in SCENES:
        scene = scenes.build(name)
        scans.append(simulate(scene, setup_from_section(scene.scanner, model=model), seed=seed, progress=False))
    return panel_table(scans[0]), goniometer_table(scans[1])


def simulated_calibration(model: ScannerModel, seed: int = 0, cache_dir=None) -> Calibration:
    """The calibration of ``model`` from simulated panels and goniometer (cached).

    Parameters
    ----------
    model : ScannerModel
        The scanner to calibrate.
    seed : int
        Seed of both simulations.
    cache_dir : str or Path, optional
        Directory of the on-disk cache (default: ``TLSBENCH_CACHE_DIR``, none if unset).
    """
    key = (model, int(seed))
    if key in _MEMORY:
        return _MEMORY[key]
    cache_dir = cache_dir or os.environ.get("TLSBENCH_CACHE_DIR")
    path = Path(cache_dir) / f"calibration-{_cache_key(model, seed)}.json" if cache_dir else None
    if path is not None and path.is_file():
        calibration = Calibration.load(path)
    else:
        panels, goniometer = simulate_tables(model, int(seed))
        calibration = fit_calibration(panels, goniometer, scanner_model=model.to_dict())
        if path is not None:
            calibration.save(path)
    _MEMORY[key] = calibration
    return calibration


def _cache_key(model: ScannerModel, seed: int) -> str:
    digest = hashlib.sha256(json.dumps([model.to_dict(), int(seed)], sort_keys=True).encode())
    digest.update(_source_digest().encode())
    return digest.hexdigest()[:20]


@functools.cache
def _source_digest() -> str:
    """Hash of the source files that decide a calibration, computed once per process."""
    root = Path(__file__).resolve().parents[2]
    digest = hashlib.sha256()
    for name in _SOURCES:
        path = root / name
        for source in sorted(path.rglob("*.py")) if path.is_dir() else [path]:
            digest.update(source.read_bytes())
    return digest.hexdigest()


def add_parser(sub) -> None:
    """Register ``calibration`` with the ``tlsbench experiment`` sub-commands."""
    p = sub.add_parser("calibration", help="simulate the panel and goniometer experiments and fit the calibration",
                       description="Simulate the panel-series and goniometer scenes with a scanner model, measure "
                                   "their tables and fit the intensity calibration that leafsfs reconstruct takes.")
    source = p.add_mutually_exclusive_group()
    source.add_argument("--preset", default="faro-ls880", help="scanner preset (default faro-ls880)")
    source.add_argument("--scan", help="use the scanner model recorded in this scan (.npz)")
    p.add_argument("--seed", type=int, default=0, help="seed of both simulations (default 0)")
    p.add_argument("-o", "--output", default="calibration.json",
                   help="calibration file (default calibration.json); the tables go next to it")
    p.set_defaults(func=run)


def run(args) -> int:
    """Simulate, fit and write the calibration and its two tables."""
    if args.scan:
        scan = Scan.load(args.scan)
        if scan.scanner.model is None:
            raise BenchError(f"{args.scan}: the scan records no scanner model; give --preset")
        model = scan.scanner.model
    else:
        model = get_preset(args.preset)
    panels, goniometer = simulate_tables(model, args.seed)
    calibration = fit_calibration(panels, goniometer, scanner_model=model.to_dict())
    output = Path(args.output)
    stem = output.with_suffix("")
    paths = [calibration.save(output),
             save_table(panels, stem.with_name(stem.name + "-panels.json"), "panels", model.to_dict()),
             save_table(goniometer, stem.with_name(stem.name + "-goniometer.json"), "goniometer", model.to_dict())]
    print(f"f99({calibration.curve.reference_distance_m} m) = {calibration.curve.reference_dn:.1f} DN, "
          f"{len(goniometer['name'])} goniometer stations; wrote {', '.join(str(p) for p in paths)}")
    return 0

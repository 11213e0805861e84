"""Pulse-by-pulse comparison of two scans of the same grid (two backends, versions or seeds).

:func:`compare_scans` reports, per layer, how many pulses both scans returned,
how many only one did, and the distribution of the absolute differences; for
the layers in metres it also counts the pulses that differ by more than a
tolerance. It is what ``tlssim diff A B`` prints, and how the CUDA backend is
checked against the LLVM one (README, "GPU path"; every measurement in
docs/notebook/tlssim.md, "GPU path").
"""

from __future__ import annotations

import numpy as np

from tlssim.errors import ScanError
from tlssim.scan import Scan

#: Layers compared, with their unit; pulses differing are counted in the ``m`` layers (beyond the tolerance) and
#: in the ``id`` layer (any difference).
LAYERS = {"range": "m", "xyz": "m", "intensity": "DN", "truth_range": "m", "truth_id": "id",
          "mixed_fraction": "1", "incidence": "rad"}


def compare_scans(a: Scan, b: Scan, tolerance_m: float = 1e-3) -> dict:
    """Compare two scans of the same grid pulse by pulse.

    Parameters
    ----------
    a, b : Scan
        The scans; their grids must have the same shape. Truth layers are
        compared where both scans carry them.
    tolerance_m : float
        Difference above which a pulse counts as differing in the layers in
        metres (``range``, ``xyz``: largest coordinate, ``truth_range``), m.

    Returns
    -------
    dict
        ``{"shape": [rows, cols], "tolerance_m": ..., "layers": {name: stats}}``;
        ``stats`` holds ``unit``, ``compared`` (pulses finite in both),
        ``only_a`` and ``only_b`` (finite in one scan only), ``equal``
        (fraction of the compared pulses with identical values), ``max``,
        ``p99`` and ``median`` of the absolute difference (in ``unit``), and
        ``differing``: pulses beyond the tolerance in the layers in metres,
        with another object id in ``truth_id``.

    Raises
    ------
    ScanError
        If the grids differ in shape or ``tolerance_m`` is not positive.

    Examples
    --------
    >>> import numpy as np
    >>> grid = np.ones((2, 2))
    >>> scan = Scan(grid, grid.astype(np.float32), grid, grid, np.ones((2, 2, 3)))
    >>> compare_scans(scan, scan)["layers"]["range"]["differing"]
    0
    """
    if a.shape != b.shape:
        raise ScanError(f"the scans' grids differ: {a.shape[0]} x {a.shape[1]} against {b.shape[0]} x {b.shape[1]} "
                        "pulses; only scans of the same window and step can be compared")
    if not tolerance_m > 0:
        raise ScanError(f"tolerance must be > 0 m, got {tolerance_m}")
    layers = {}
    for name, unit in LAYERS.items():
        va, vb = getattr(a, name), getattr(b, name)
        if va is None or vb is None:
            continue
        va, vb = np.asarray(va, dtype=float), np.asarray(vb, dtype=float)
        if name == "truth_id":  # -1 marks no object
            va, vb = np.where(va < 0, np.nan, va), np.where(vb < 0, np.nan, vb)
        if va.ndim == 3:  # xyz: a pulse is finite when all coordinates are, its difference the largest one
            fa, fb = np.isfinite(va).all(axis=2), np.isfinite(vb).all(axis=2)
            diff = np.abs(va - vb).max(axis=2)
        else:
            fa, fb = np.isfinite(va), np.isfinite(vb)
            diff = np.abs(va - vb)
        both = fa & fb
        d = diff[both]
        stats = {"unit": unit, "compared": int(both.sum()), "only_a": int((fa & ~fb).sum()),
                 "only_b": int((fb & ~fa).sum()), "equal": float(np.mean(d == 0)) if d.size else 1.0,
                 "max": float(d.max()) if d.size else 0.0,
                 "p99": float(np.percentile(d, 99)) if d.size else 0.0,
                 "median": float(np.median(d)) if d.size else 0.0}
        if unit in ("m", "id"):
            stats["differing"] = int((d > (tolerance_m if unit == "m" else 0)).sum())
        layers[name] = stats
    return {"shape": list(a.shape), "tolerance_m": tolerance_m, "layers": layers}

"""Stress sweeps: ROP, range noise and intensity against one scan parameter at a time.

A sweep is an ordinary run whose suite (``sweep-<kind>``) holds one case per
value of the swept parameter (times ``repeats`` seeds), so it runs, stores
and resumes like any suite. :func:`sweep_table` reads the per-leaf scan
properties back (ROP at both thresholds, range noise σ, intensity, density)
with the ROP left by each variant, and :func:`write_sweep` writes the table
(CSV) and the plot (PNG).

The swept parameter is either a scene-generator parameter (distance,
incidence, reflectance, leaf length) or a scanner-model override (beam
divergence, which sets the footprint diameter, and the angular step).
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from benchmarks.errors import BenchError
from benchmarks.generators import check_scene
from benchmarks.suite import Case, Suite, case_seed, check_scanner
from tlssim.scanner import get_preset


@dataclass(frozen=True)
class SweepKind:
    """One sweepable parameter.

    Attributes
    ----------
    where : {"scene", "scanner"}
        Whether the parameter belongs to the scene generator or the scanner model.
    key : str
        Parameter name.
    label : str
        Axis label (with unit).
    values : tuple of float
        Default values.
    """

    where: str
    key: str
    label: str
    values: tuple[float, ...]


SWEEPS = {
    "distance": SweepKind("scene", "distance_m", "distance (m)", (0.8, 1.5, 2.5, 3.5, 5.0)),
    "incidence": SweepKind("scene", "incidence_deg", "incidence angle (deg)", (0.0, 20.0, 40.0, 60.0, 70.0, 80.0)),
    "footprint": SweepKind("scanner", "divergence_deg", "beam divergence half-angle (deg)",
                           (0.007, 0.014, 0.028, 0.056)),
    "step": SweepKind("scanner", "step_deg", "angular step (deg)", (0.009, 0.018, 0.036, 0.072)),
    "reflectance": SweepKind("scene", "reflectance", "leaf reflectance", (0.1, 0.25, 0.48, 0.7, 0.9)),
    "leaf-size": SweepKind("scene", "length_m", "leaf length (m)", (0.03, 0.045, 0.065, 0.09, 0.12)),
}

#: Columns of a sweep table taken from the raw scan (mean over the leaves of each value).
_SCAN_COLUMNS = ("rop_before", "rop_before_1cm", "sigma_range_m", "intensity_dn", "points_per_cm2", "n_points")


def sweep_kind(kind: str) -> SweepKind:
    """The sweep ``kind`` (raises :class:`BenchError` listing the kinds)."""
    if kind not in SWEEPS:
        raise BenchError(f"unknown sweep {kind!r}; available: {', '.join(SWEEPS)}")
    return SWEEPS[kind]


def sweep_suite(kind: str, scene: str = "single-leaf", values=None, params: dict | None = None,
                scanner: dict | None = None, repeats: int = 1) -> Suite:
    """The suite of a sweep: one case per value and repeat.

    Parameters
    ----------
    kind : str
        A key of :data:`SWEEPS`.
    scene : str
        Scene generator (it must accept the swept parameter for scene sweeps).
    values : sequence of float, optional
        Values of the parameter (default: the kind's).
    params : dict, optional
        Fixed generator parameters (e.g. ``{"distance_m": 3}``).
    scanner : dict, optional
        Fixed scanner overrides.
    repeats : int
        Cases per value, with different simulation seeds.
    """
    spec = sweep_kind(kind)
    values = tuple(spec.values if values is None else values)
    if not values:
        raise BenchError("a sweep needs at least one value")
    if not (isinstance(repeats, int) and repeats >= 1):
        raise BenchError(f"repeats must be a positive integer, got {repeats!r}")
    cases = []
    for value in values:
        for repeat in range(repeats):
            case_scene = {"generator": scene, **(params or {})}
            case_scanner = dict(scanner or {})
            (case_scene if spec.where == "scene" else case_scanner)[spec.key] = value
            check_scene(case_scene)
            check_scanner(case_scanner)
            name = f"{kind}={value:g}" + (f"#{repeat + 1}" if repeats > 1 else "")
            cases.append(Case(name, case_scene, case_scanner, case_seed(name)))
    return Suite(f"sweep-{kind}", f"{kind} sweep on {scene}", tuple(cases), f"sweep:{kind}")


def sweep_of(suite_name: str) -> str:
    """The sweep kind of a sweep suite's name (``sweep-<kind>``, as :func:`sweep_suite` names it)."""
    kind = suite_name.removeprefix("sweep-")
    sweep_kind(kind)
    return kind


def sweep_value(kind: str, case_spec: dict) -> float:
    """The swept value of a stored case.

    Parameters
    ----------
    kind : str
        Sweep kind (:func:`sweep_kind`).
    case_spec : dict
        Stored case specification.

    Returns
    -------
    float
        The swept value, in the unit of the swept key.
    """
    spec = sweep_kind(kind)
    return float((case_spec["scene"] if spec.where == "scene" else case_spec["scanner"])[spec.key])


def sweep_table(rows: list[dict], kind: str) -> list[dict]:
    """Per swept value: the raw scan's properties and the ROP each variant leaves.

    Columns: ``value``; for footprint sweeps ``footprint_mm`` (1/e² diameter
    at the leaf); ``n_targets``; the means over leaves of ``rop_before``,
    ``rop_before_1cm``, ``sigma_range_m``, ``intensity_dn``,
    ``points_per_cm2``, ``n_points``; ``rop_after:<variant>`` for every
    variant except ``raw``.

    Parameters
    ----------
    rows : list of dict
        Result rows of a sweep run (rows with an error are skipped).
    kind : str
        Sweep kind (:func:`sweep_kind`).

    Returns
    -------
    list of dict
        One row per swept value, sorted by value (each column in the unit its name gives).
    """
    by_value: dict[float, list[dict]] = {}
    for row in rows:
        if not row["error"]:
            by_value.setdefault(sweep_value(kind, row["case_spec"]), []).append(row)
    table = []
    for value in sorted(by_value):
        group = by_value[value]
        reference = [leaf for r in group if r["variant"] == group[0]["variant"] for leaf in r["metrics"]["targets"]]
        entry = {"value": value}
        if kind == "footprint":
            model = get_preset("faro-ls880", **group[0]["case_spec"]["scanner"])
            ranges = [leaf["range_m"] for leaf in reference]
            entry["footprint_mm"] = 2e3 * model.beam_radius_m(float(np.mean(ranges))) if ranges else None
        entry["n_targets"] = len(reference)
        for key in _SCAN_COLUMNS:
            entry[key] = _mean(reference, key)
        for variant in dict.fromkeys(r["variant"] for r in group):
            if variant != "raw":
                leaves = [leaf for r in group if r["variant"] == variant for leaf in r["metrics"]["targets"]]
                entry[f"rop_after:{variant}"] = _mean(leaves, "rop_after")
        table.append(entry)
    return table


def _mean(leaves: list[dict], key: str):
    values = [leaf[key] for leaf in leaves if leaf.get(key) is not None]
    return float(np.mean(values)) if values else None


def plot_sweep(table: list[dict], kind: str) -> Figure:
    """Three panels against the swept value: ROP (raw at both τ, and after each variant), range noise, intensity.

    Parameters
    ----------
    table : list of dict
        Rows of :func:`sweep_table`.
    kind : str
        Sweep kind (:func:`sweep_kind`).

    Returns
    -------
    Figure
        The three panels.
    """
    spec = sweep_kind(kind)
    x = [row["value"] for row in table]

    def column(key):
        return [np.nan if row.get(key) is None else row[key] for row in table]

    figure = Figure(figsize=(12, 3.6), layout="constrained")
    rop, noise, intensity = figure.subplots(1, 3)
    rop.plot(x, column("rop_before"), "o-", color="black", label="raw, τ = max(3σ, 2 mm)")
    rop.plot(x, column("rop_before_1cm"), "s--", color="grey", label="raw, τ = 1 cm")
    for key in [k for k in table[0] if k.startswith("rop_after:")] if table else []:
        rop.plot(x, column(key), ".-", label=key.split(":", 1)[1])
    rop.set(xlabel=spec.label, ylabel="ROP (outliers / points)", title="ROP")
    rop.legend(fontsize=7)
    noise.plot(x, np.array(column("sigma_range_m")) * 1e3, "o-")
    noise.set(xlabel=spec.label, ylabel="σ range on pure leaf returns (mm)", title="range noise")
    intensity.plot(x, column("intensity_dn"), "o-")
    intensity.set(xlabel=spec.label, ylabel="median intensity (DN)", title="intensity")
    if kind == "footprint" and table and table[0].get("footprint_mm") is not None:
        for axes in (rop, noise, intensity):
            top = axes.secondary_xaxis("top", functions=_footprint_axis(table))
            top.set_xlabel("footprint diameter at the leaf (mm)", fontsize=8)
    return figure


def _footprint_axis(table):
    values = np.array([row["value"] for row in table])
    footprint = np.array([row["footprint_mm"] for row in table])
    return (lambda v: np.interp(v, values, footprint), lambda f: np.interp(f, footprint, values))


def write_sweep(table: list[dict], kind: str, outdir) -> tuple[Path, Path]:
    """Write ``sweep-<kind>.csv`` and ``sweep-<kind>.png`` into ``outdir``; return their paths.

    Parameters
    ----------
    table : list of dict
        Rows of :func:`sweep_table`.
    kind : str
        Sweep kind (:func:`sweep_kind`).
    outdir : str or Path
        Output folder (created if missing).

    Returns
    -------
    tuple of Path
        The CSV and PNG files.
    """
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    columns = list(dict.fromkeys(k for row in table for k in row))
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, columns)
    writer.writeheader()
    writer.writerows(table)
    csv_path = outdir / f"sweep-{kind}.csv"
    csv_path.write_text(buffer.getvalue())
    png_path = outdir / f"sweep-{kind}.png"
    plot_sweep(table, kind).savefig(png_path, dpi=110)
    return csv_path, png_path


def format_table(table: list[dict]) -> str:
    """A sweep table as aligned text (numbers to 4 significant digits)."""
    columns = list(dict.fromkeys(k for row in table for k in row))
    cells = [columns] + [["" if row.get(c) is None else f"{row[c]:.4g}" for c in columns] for row in table]
    widths = [max(len(line[i]) for line in cells) for i in range(len(columns))]
    return "\n".join("  ".join(c.rjust(w) for c, w in zip(line, widths)) for line in cells)

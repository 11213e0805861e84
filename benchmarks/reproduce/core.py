"""Rows, verdicts and the registry of the reproduction experiments.

A reproduction experiment turns one published table or figure of the
sources into :class:`Row` objects: the published value (or ``None`` where
the source keeps it back, or gives only a trend), ours, the tolerance with
the reason for it, and where the number comes from. :func:`verdict` decides
each row; :func:`register` adds an experiment to :data:`EXPERIMENTS` under
its name.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Callable

from benchmarks.errors import BenchError

#: Verdicts of a row: counted ones (within / outside) and rows that only report ours.
WITHIN, OUTSIDE, REPORTED = "within", "outside", "reported"


@dataclass(frozen=True)
class Row:
    """One published number (or claim) against ours.

    Attributes
    ----------
    key : str
        Row name, unique within its experiment (e.g. ``"48%/mean shift"``).
    quantity : str
        What is compared (rows of one quantity share a plot panel).
    unit : str
        Unit of ``published``, ``ours`` and ``tolerance``.
    ours : float
        Our value (NaN when it could not be measured: then outside).
    published : float or None
        The source's value; ``None`` where the source gives none (held back,
        or a trend only).
    tolerance : float or None
        Largest accepted ``|ours - published|``, in ``unit``.
    tolerance_note : str
        Why that tolerance (its source or the assumption behind it).
    source : str
        Where the published value or claim stands (paper, table, column).
    claim : str
        For rows without a published number: the published trend or statement
        that ``holds`` tests (empty otherwise).
    holds : bool or None
        Whether our numbers show the claim (``None``: ours is only reported).
    x : float or None
        Abscissa of the row in the experiment's plot (e.g. distance, bias).
    series : str
        Curve of the plot the row belongs to (e.g. a material or a rule).
    note : str
        Explanation of a difference (erratum, modelling assumption, defect).
    """

    key: str
    quantity: str
    unit: str
    ours: float
    published: float | None = None
    tolerance: float | None = None
    tolerance_note: str = ""
    source: str = ""
    claim: str = ""
    holds: bool | None = None
    x: float | None = None
    series: str = ""
    note: str = ""

    @property
    def verdict(self) -> str:
        """``within`` / ``outside`` the tolerance (or the claim holds / fails); ``reported`` when nothing is
        compared."""
        return verdict(self.ours, self.published, self.tolerance, self.holds)

    def as_dict(self) -> dict:
        """The row's fields and its verdict (JSON-ready, NaN kept as a float)."""
        return {**asdict(self), "verdict": self.verdict}


def verdict(ours: float, published: float | None, tolerance: float | None, holds: bool | None = None) -> str:
    """Verdict of one comparison.

    Parameters
    ----------
    ours : float
        Our value (NaN counts as outside).
    published : float or None
        The published value; ``None``: no number to compare.
    tolerance : float or None
        Largest accepted absolute difference, same unit (>= 0).
    holds : bool or None
        For rows without a published number: whether the published claim holds.

    Returns
    -------
    str
        :data:`WITHIN`, :data:`OUTSIDE` or :data:`REPORTED`.
    """
    if published is not None:
        if tolerance is None or tolerance < 0 or not math.isfinite(tolerance):
            raise BenchError(f"a published value needs a finite tolerance >= 0, got {tolerance!r}")
        if ours is None or not math.isfinite(ours):
            return OUTSIDE
        return WITHIN if abs(ours - published) <= tolerance else OUTSIDE
    if holds is None:
        return REPORTED
    return WITHIN if holds else OUTSIDE


def count_within(rows: list[Row]) -> tuple[int, int]:
    """``(N, M)``: rows within tolerance and rows compared (reported-only rows are not counted)."""
    compared = [r for r in rows if r.verdict != REPORTED]
    return sum(r.verdict == WITHIN for r in compared), len(compared)


@dataclass(frozen=True)
class Experiment:
    """A registered reproduction of one published table or figure.

    Attributes
    ----------
    name : str
        Command-line name (``tlsbench reproduce NAME``).
    title : str
        The table or figure reproduced, with its source.
    run : callable
        ``run(quick: bool, seed: int) -> list[Row]``; ``quick`` runs a tiny
        version (tests, ``--quick``). It may also return ``(rows, figures)``,
        ``figures`` a dict of extra matplotlib figures by name (pictures the
        rows cannot carry, e.g. error matrices), written as
        ``NAME-<name>.png`` and shown on the page.
    description : str
        What is simulated and how ours is measured.
    findings : str
        Where ours departs from the source and why (measured), shown on the page.
    heavy : bool
        Too slow for ``--quick`` even in its tiny form (minutes per run on
        two shared cores): ``--quick`` runs it only when named.
    """

    name: str
    title: str
    run: Callable[[bool, int], list[Row]]
    description: str = ""
    findings: str = ""
    heavy: bool = False


#: Registered experiments by name, in registration order.
EXPERIMENTS: dict[str, Experiment] = {}


def register(name: str, title: str, description: str = "", findings: str = "", heavy: bool = False):
    """Decorator registering ``run(quick, seed) -> list[Row]`` as the experiment ``name``.

    Parameters
    ----------
    name : str
        Unique command-line name.
    title : str
        The table or figure reproduced, with its source.
    description : str
        What is simulated and measured.
    findings : str
        Explanations of the differences from the source.
    heavy : bool
        Left out of ``--quick`` unless named (see :class:`Experiment`).
    """
    def wrap(function):
        if name in EXPERIMENTS:
            raise BenchError(f"reproduction experiment {name!r} is registered twice")
        EXPERIMENTS[name] = Experiment(name, title, function, description, findings, heavy)
        return function
    return wrap


def select(names: list[str] | None, quick: bool = False) -> list[Experiment]:
    """The experiments named (all, in registration order, when ``names`` is empty).

    Parameters
    ----------
    names : list of str or None
        Experiment names, or prefixes ending in ``*`` (``step-*``).
    quick : bool
        Leave out the heavy experiments that are not named exactly.

    Raises
    ------
    BenchError
        For a name that matches no registered experiment.
    """
    if not names:
        return [e for e in EXPERIMENTS.values() if not (quick and e.heavy)]
    chosen: dict[str, Experiment] = {}
    for name in names:
        matches = [e for n, e in EXPERIMENTS.items() if n == name or name.endswith("*") and n.startswith(name[:-1])
                   and not (quick and e.heavy)]
        if not matches:
            raise BenchError(f"no reproduction experiment {name!r}" + (" outside the heavy ones (name them one by "
                             "one with --quick)" if quick else "") + f"; known: {', '.join(EXPERIMENTS)}")
        chosen.update({e.name: e for e in matches})
    return list(chosen.values())


@dataclass
class Outcome:
    """Rows of one experiment run, its run time in seconds, the error that stopped it (if any) and its extra
    figures (base64 PNG by name, see :class:`Experiment`)."""

    experiment: Experiment
    rows: list[Row] = field(default_factory=list)
    seconds: float = 0.0
    error: str = ""
    images: dict[str, str] = field(default_factory=dict)

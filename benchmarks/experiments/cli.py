"""The ``tlsbench experiment NAME`` and ``tlsbench perf NAME`` commands.

Every module of :data:`EXPERIMENT_MODULES` and :data:`PERF_MODULES`
registers one named command with ``add_parser(subparsers)``; the command's
function takes the parsed arguments and returns the exit status.
"""

from __future__ import annotations

import importlib

#: Modules of ``tlsbench experiment NAME`` (each registers one NAME).
EXPERIMENT_MODULES: tuple[str, ...] = ("benchmarks.experiments.calibration", "benchmarks.experiments.sfs_compare",
                                        "benchmarks.experiments.woody_experiments", "benchmarks.experiments.dbh_stems",
                                        "benchmarks.experiments.woody_real")
#: Modules of ``tlsbench perf NAME``.
PERF_MODULES: tuple[str, ...] = ("benchmarks.experiments.scenes_perf", "benchmarks.experiments.simulator_perf",
                                 "benchmarks.experiments.sfs_perf", "benchmarks.experiments.woody_perf")


def add_parsers(sub) -> None:
    """Add the ``experiment`` and ``perf`` commands, with one sub-command per module, to ``sub``."""
    for command, modules, text in (("experiment", EXPERIMENT_MODULES, "run an experiment (tables, JSON, plots)"),
                                   ("perf", PERF_MODULES, "time and memory of a package's hot paths")):
        p = sub.add_parser(command, help=text, description=text)
        inner = p.add_subparsers(dest=f"{command}_name", required=True, metavar="NAME")
        for name in modules:
            importlib.import_module(name).add_parser(inner)

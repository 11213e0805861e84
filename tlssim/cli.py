"""The ``tlssim`` command line: ``tlssim COMMAND ...``.

Each command lives in its own module under :mod:`tlssim.commands` and
registers itself with ``add_parser(subparsers)``; add new modules to
:data:`COMMAND_MODULES`.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from tlssim.clitools import run_main

COMMAND_MODULES = (
    "tlssim.commands.scan",
    "tlssim.commands.scenes",
    "tlssim.commands.presets",
    "tlssim.commands.truth",
    "tlssim.commands.preview",
    "tlssim.commands.formats",
    "tlssim.commands.calibrate",
    "tlssim.commands.diff",
)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every registered command."""
    parser = argparse.ArgumentParser(prog="tlssim", description="Simulate phase-shift terrestrial laser scans.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``tlssim`` console script."""
    return run_main(build_parser(), argv if argv is not None else sys.argv[1:])


if __name__ == "__main__":
    raise SystemExit(main())

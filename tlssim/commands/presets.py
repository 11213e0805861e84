"""``tlssim presets``: the scanner presets and where every parameter comes from."""

from __future__ import annotations

from tlssim.scanner import get_preset, parameter_table, preset_names


def add_parser(sub) -> None:
    p = sub.add_parser("presets", help="list scanner presets, or show one preset's parameters and sources",
                       description="List the scanner presets; with a name, print its parameters as a Markdown "
                                   "table with the source or assumption behind each value.")
    p.add_argument("name", nargs="?", help="preset to show")
    p.set_defaults(func=run)


def run(args) -> int:
    if args.name is None:
        print("\n".join(preset_names()))
    else:
        print(parameter_table(get_preset(args.name)))
    return 0

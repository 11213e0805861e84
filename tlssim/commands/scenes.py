"""``tlssim scenes``: list the built-in scenes."""

from __future__ import annotations

import scenes


def add_parser(sub) -> None:
    p = sub.add_parser("scenes", help="list the built-in scenes", description="List the built-in scenes.")
    p.set_defaults(func=run)


def run(args) -> int:
    descriptions = scenes.describe()
    width = max(len(name) for name in descriptions)
    for name, text in descriptions.items():
        print(f"{name:<{width}}  {text}")
    return 0

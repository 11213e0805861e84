"""Experiments and performance harnesses, run as ``tlsbench experiment NAME`` and ``tlsbench perf NAME``.

They drive the algorithm packages from above, as the benchmarks do: the
packages below never import them. Each module registers its command with
``add_parser(subparsers)`` (see :mod:`benchmarks.experiments.cli`).
"""

"""Reproduction of the sources' published tables and figures (``tlsbench reproduce``).

:mod:`benchmarks.reproduce.core` holds the row type, the verdict and the
registry; one module per source registers its experiments
(:mod:`~benchmarks.reproduce.sensors2011`, :mod:`~benchmarks.reproduce.thesis_ch5`,
:mod:`~benchmarks.reproduce.thesis_ch7`,
:mod:`~benchmarks.reproduce.thesis_ch2`, :mod:`~benchmarks.reproduce.woody_papers`);
:mod:`~benchmarks.reproduce.output` writes text, CSV, PNG and store rows and
:mod:`~benchmarks.reproduce.page` the ``reproduction.html`` page.
"""

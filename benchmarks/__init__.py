"""benchmarks: the continuous benchmarking harness (suites, variants, metrics, store, reports).

Modules: :mod:`~benchmarks.suite` (YAML suites and cases), :mod:`~benchmarks.generators`
(parametric scenes), :mod:`~benchmarks.registry` (reconstruction variants),
:mod:`~benchmarks.metrics` and :mod:`~benchmarks.scoring` (metric definitions and
scoring against the scene truth), :mod:`~benchmarks.runner` (local or Dask execution),
:mod:`~benchmarks.store` (SQLite results), :mod:`~benchmarks.summary`,
:mod:`~benchmarks.report`, :mod:`~benchmarks.compare`, :mod:`~benchmarks.sweeps` and the
``tlsbench`` command line (:mod:`~benchmarks.cli`).
"""

from benchmarks.errors import BenchError

__all__ = ["BenchError"]

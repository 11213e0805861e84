"""benchmarks: the continuous benchmarking harness (suites, variants, metrics, store, reports)."""

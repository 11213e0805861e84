"""Built-in benchmark suites (YAML files read by :func:`benchmarks.suite.load_suite`)."""

"""The one exception type of the benchmarks package."""


class BenchError(ValueError):
    """A suite, case, variant, store or report request is invalid; the message says what and what is allowed."""

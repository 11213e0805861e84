"""The one exception type of the tlssim package."""


class ScanError(ValueError):
    """A scanner model, scan set-up, scan file or backend problem; the message says what and what is allowed."""

"""The one exception type of the leafsfs package."""


class SfsError(ValueError):
    """A scan, mask, calibration or parameter given to leafsfs is invalid; the message says what and what is allowed."""

"""The one exception type of the leafsfs package."""


class SfsError(ValueError):
    """A PROP-SFS input, parameter or calibration problem; the message says what and what is allowed."""

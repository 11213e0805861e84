"""The one exception type of the woody package."""


class WoodyError(ValueError):
    """A point cloud, file or parameter given to woody is invalid; the message says what and what is allowed."""

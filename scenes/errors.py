"""The one exception type of the scenes package."""


class SceneError(ValueError):
    """A scene, scene file or object description is invalid; the message says what and what is allowed."""

"""Validation of scene-description fields, with messages that say where and what is allowed.

:class:`Fields` wraps one mapping of a scene description (an object entry,
a pose, a tree's options) together with its location (``"scene.yaml:
object #2 'leaf1' (leaf)"``). Its typed getters raise
:class:`~scenes.errors.SceneError` naming the location, the field, the bad
value and what is allowed; :meth:`Fields.finish` rejects fields nobody read.
"""

from __future__ import annotations

import math

import numpy as np

from scenes.errors import SceneError

#: Marks a required field.
REQUIRED = object()


class Fields:
    """Typed, located access to the fields of one mapping.

    Parameters
    ----------
    data : dict
        The mapping (not modified).
    where : str
        Location for error messages.
    """

    def __init__(self, data, where: str):
        if not isinstance(data, dict):
            raise SceneError(f"{where}: expected a mapping of fields, got {data!r}")
        self.data, self.where, self.used = data, where, set()

    def __contains__(self, key) -> bool:
        self.used.add(key)  # asking about a field makes it a known (allowed) one
        return key in self.data

    def error(self, key: str, message: str) -> SceneError:
        """A :class:`SceneError` about field ``key``.

        Parameters
        ----------
        key : str
            Field name.
        message : str
            What is wrong and what is allowed.

        Returns
        -------
        SceneError
            To be raised by the caller; its message names the location and the field.
        """
        return SceneError(f"{self.where}: field {key!r}: {message}")

    def raw(self, key: str, default=REQUIRED):
        """The value of ``key`` as given (``default`` when absent); marks the field as read.

        Parameters
        ----------
        key : str
            Field name.
        default : object, optional
            Value when the field is absent; :data:`REQUIRED` (the default) makes it required.

        Returns
        -------
        object
            The unchecked value.
        """
        self.used.add(key)
        if key in self.data:
            return self.data[key]
        if default is REQUIRED:
            raise SceneError(f"{self.where}: missing required field {key!r}")
        return default

    def number(self, key: str, default=REQUIRED, *, low=None, high=None, positive=False, integer=False,
               unit: str = ""):
        """A finite number (optionally an integer, positive, or within ``[low, high]``).

        Parameters
        ----------
        key : str
            Field name.
        default : object, optional
            Value when the field is absent (a ``None`` default is returned as is); :data:`REQUIRED` makes it
            required.
        low, high : float, optional
            Inclusive bounds.
        positive : bool
            Require a value > 0.
        integer : bool
            Require an integral value (returned as ``int``).
        unit : str
            Unit named in error messages (e.g. ``"m"``, ``"deg"``); the value is not converted.

        Returns
        -------
        float or int or None
        """
        value = self.raw(key, default)
        if value is None and default is None:
            return None
        return _number(value, lambda msg: self.error(key, msg), low=low, high=high, positive=positive,
                       integer=integer, unit=unit)

    def vector(self, key: str, n: int = 3, default=REQUIRED, *, positive=False, unit: str = "") -> np.ndarray:
        """A list of ``n`` finite numbers.

        Parameters
        ----------
        key : str
            Field name.
        n : int
            Required length.
        default : object, optional
            Value when the field is absent; :data:`REQUIRED` (the default) makes it required.
        positive : bool
            Require every element > 0.
        unit : str
            Unit named in error messages; the values are not converted.

        Returns
        -------
        ndarray, shape (n,), float
        """
        value = self.raw(key, default)
        return vector(value, n, lambda msg: self.error(key, msg), positive=positive, unit=unit)

    def choice(self, key: str, allowed, default=REQUIRED):
        """One of ``allowed``.

        Parameters
        ----------
        key : str
            Field name.
        allowed : collection
            The allowed values (listed in the error message).
        default : object, optional
            Value when the field is absent; :data:`REQUIRED` (the default) makes it required.

        Returns
        -------
        object
            The value, unchanged.
        """
        value = self.raw(key, default)
        if value not in allowed:
            raise self.error(key, f"got {value!r}; allowed: {', '.join(map(str, allowed))}")
        return value

    def flag(self, key: str, default: bool) -> bool:
        """A boolean.

        Parameters
        ----------
        key : str
            Field name.
        default : bool
            Value when the field is absent.

        Returns
        -------
        bool
        """
        value = self.raw(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"must be true or false, got {value!r}")
        return value

    def text(self, key: str, default=REQUIRED) -> str:
        """A non-empty string.

        Parameters
        ----------
        key : str
            Field name.
        default : object, optional
            Value when the field is absent; :data:`REQUIRED` (the default) makes it required.

        Returns
        -------
        str
        """
        value = self.raw(key, default)
        if not isinstance(value, str) or not value:
            raise self.error(key, f"must be a non-empty string, got {value!r}")
        return value

    def sub(self, key: str, default=REQUIRED) -> "Fields":
        """The mapping under ``key`` as :class:`Fields` (located at ``"<where>, <key>"``).

        Parameters
        ----------
        key : str
            Field name.
        default : object, optional
            Value when the field is absent; :data:`REQUIRED` (the default) makes it required.

        Returns
        -------
        Fields
        """
        value = self.raw(key, default)
        if not isinstance(value, dict):
            raise self.error(key, f"must be a mapping, got {value!r}")
        return Fields(value, f"{self.where}, {key}")

    def finish(self, allowed_extra=()) -> None:
        """Reject fields that were never read."""
        unknown = sorted(set(self.data) - self.used - set(allowed_extra), key=str)
        if unknown:
            allowed = sorted(self.used | set(allowed_extra), key=str)
            raise SceneError(f"{self.where}: unknown field(s) {unknown}; allowed: {', '.join(allowed)}")


def _number(value, error, *, low=None, high=None, positive=False, integer=False, unit=""):
    what = ("an integer" if integer else "a number") + (f" ({unit})" if unit else "")
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise error(f"must be {what}, got {value!r}")
    if integer and float(value) != int(value):
        raise error(f"must be {what}, got {value!r}")
    value = int(value) if integer else float(value)
    if not math.isfinite(value):
        raise error(f"must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise error(f"must be positive, got {value!r}")
    if low is not None and value < low or high is not None and value > high:
        raise error(f"must lie in [{low if low is not None else '-inf'}, {high if high is not None else 'inf'}], "
                    f"got {value!r}")
    return value


def vector(value, n: int, error, *, positive=False, unit: str = "") -> np.ndarray:
    """``value`` as ``n`` finite numbers.

    Parameters
    ----------
    value : list, tuple or ndarray
        The numbers as given.
    n : int
        Required length.
    error : callable
        ``error(message)`` builds the exception to raise.
    positive : bool
        Require every element > 0.
    unit : str
        Unit named in error messages; the values are not converted.

    Returns
    -------
    ndarray, shape (n,), float
    """
    what = f"a list of {n} numbers" + (f" ({unit})" if unit else "")
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise error(f"must be {what}, got {value!r}")
    out = np.array([_number(v, lambda msg: error(f"must be {what}, got {value!r}")) for v in value])
    if positive and np.any(out <= 0):
        raise error(f"must be {n} positive numbers, got {value!r}")
    return out

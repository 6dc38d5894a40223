"""Strict TOML input: every key typed, checked and accounted for.

Scene files and dataset configs are read with :class:`Section`: a value of
the wrong type, out of range or missing, and a key nobody asked for, are
errors that name the file, the table, the key and the value (with a
"did you mean" for typos)::

    data = read_toml(path, SceneError)
    sec = Section(data["sensor"], f"{path}: [sensor]", SceneError)
    exposure = sec.get("exposure_s", float, default=1.0, check=positive, what="seconds")
    sec.finish()   # unknown keys → error
"""

from __future__ import annotations

import difflib
import math
import tomllib
from pathlib import Path

import numpy as np

from jaxlc.errors import JaxlcError

#: Kinds :meth:`Section.get` understands besides Python types (float, int, str, bool, list, dict).
VECTOR_KINDS = {"vec3": 3, "vec4": 4}


def read_toml(path: str | Path, error: type[Exception] = JaxlcError) -> tuple[dict, str]:
    """The parsed document and its text; a missing or malformed file raises ``error``."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{str(path)!r} does not exist")
    try:
        text = path.read_text(encoding="utf-8")
        return tomllib.loads(text), text
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: not valid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a UTF-8 text file ({exc.reason})") from exc


def show(value) -> str:
    """A value as it appears in an error message."""
    return np.array2string(value, separator=", ") if isinstance(value, np.ndarray) else repr(value)


def _is_number(x) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


class Section:
    """Typed access to one TOML table that remembers which keys were used.

    Args:
        data: the table (a dict; anything else is an error).
        where: how messages name it, e.g. ``"scene.toml: [attitude]"``.
        error: the exception class raised for bad input.
    """

    def __init__(self, data, where: str, error: type[Exception] = JaxlcError):
        self.error = error
        if not isinstance(data, dict):
            raise error(f"{where} must be a table, got {data!r}")
        self.data, self.where, self.used = data, where, set()

    def has(self, key) -> bool:
        """Whether ``key`` is present (and counts it as used)."""
        self.used.add(key)
        return key in self.data

    def _missing(self, key, default, what, extra=""):
        if default is ...:
            hint = f" ({what})" if what else ""
            raise self.error(f"{self.where}: missing required key {key!r}{hint}{extra}")
        return default

    def get(self, key, kind, *, default=..., check=None, what=""):
        """The value of ``key`` as ``kind``, checked by ``check(value) -> problem | None``.

        Kinds: ``float`` (any finite number), ``int`` (whole numbers), ``str``,
        ``bool``, ``list``, ``dict``, ``"vec3"``/``"vec4"`` (finite numbers →
        float64 array), ``"strings"`` (a string or a list of them → tuple),
        ``"ints"`` (a list of whole numbers → tuple).
        """
        self.used.add(key)
        if key not in self.data:
            return self._missing(key, default, what)
        value = self.data[key]
        hint = f" ({what})" if what else ""
        bad = f"{self.where}: {key} = {value!r}"
        if kind is float:
            if not _is_number(value):
                raise self.error(f"{bad} must be a number{hint}")
            value = float(value)
            if not math.isfinite(value):
                raise self.error(f"{bad} must be finite")
        elif kind is int:
            if not isinstance(value, int) or isinstance(value, bool):
                raise self.error(f"{bad} must be a whole number{hint}")
        elif kind in VECTOR_KINDS:
            size = VECTOR_KINDS[kind]
            ok = isinstance(value, list) and len(value) == size and all(map(_is_number, value))
            if not ok or not all(math.isfinite(x) for x in value):
                raise self.error(f"{bad} must be a list of {size} finite numbers{hint}")
            value = np.asarray(value, dtype=np.float64)
        elif kind == "strings":
            value = [value] if isinstance(value, str) else value
            if not (isinstance(value, list) and value and all(isinstance(x, str) for x in value)):
                raise self.error(f"{bad} must be a string or a list of strings{hint}")
            value = tuple(value)
        elif kind == "ints":
            ok = isinstance(value, list) and value
            if not (ok and all(isinstance(x, int) and not isinstance(x, bool) for x in value)):
                raise self.error(f"{bad} must be a list of integers{hint}")
            value = tuple(value)
        elif not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
            raise self.error(f"{bad} must be of type {kind.__name__}{hint}")
        if check is not None:
            problem = check(value)
            if problem:
                raise self.error(f"{self.where}: {key} = {show(value)} {problem}{hint}")
        return value

    def range(self, key, lo, hi, *, default=..., positive=False, what=""):
        """A number (fixed) or ``[low, high]`` inside [lo, hi] → (low, high)."""
        self.used.add(key)
        if key not in self.data:
            return self._missing(key, default, what, ": a number or [low, high]")
        value = self.data[key]

        def number(x):
            return _is_number(x) and math.isfinite(x)

        if number(value):
            pair = (float(value), float(value))
        elif isinstance(value, list) and len(value) == 2 and all(number(x) for x in value):
            pair = (float(value[0]), float(value[1]))
        else:
            raise self.error(
                f"{self.where}: {key} = {value!r} must be a number or [low, high] (two numbers)"
            )
        if pair[0] > pair[1]:
            raise self.error(
                f"{self.where}: {key} = {value!r} is not a range: low {pair[0]:g} > high "
                f"{pair[1]:g}; write [low, high]"
            )
        if pair[0] < lo or pair[1] > hi or (positive and pair[0] <= 0):
            bound = f"({lo:g}, {hi:g}]" if positive else f"[{lo:g}, {hi:g}]"
            raise self.error(f"{self.where}: {key} = {value!r} must lie in {bound}")
        return pair

    def finish(self):
        """Raise for the first key that was never asked for (with a close match)."""
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            key = unknown[0]
            close = difflib.get_close_matches(key, sorted(self.used), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            allowed = ", ".join(sorted(self.used))
            raise self.error(f"{self.where}: unknown key {key!r}{hint} (allowed here: {allowed})")


# Checks: each returns None when the value is fine, else what is wrong with it.


def in_range(lo, hi):
    return lambda x: None if lo <= x <= hi else f"is outside [{lo:g}, {hi:g}]"


def positive(x):
    return None if x > 0 else "must be > 0"


def nonnegative(x):
    return None if x >= 0 else "must be ≥ 0"


def nonzero_vector(x):
    return None if np.linalg.norm(x) > 1e-12 else "must not be the zero vector"


def choice(*allowed):
    return lambda x: None if x in allowed else f"must be one of {', '.join(map(repr, allowed))}"


def whole(lo, hi):
    """A whole number in [lo, hi] (given as an integer or an integral float)."""
    return lambda x: (
        None
        if float(x).is_integer() and lo <= x <= hi
        else f"must be a whole number in [{lo:,}, {hi:,}]"
    )

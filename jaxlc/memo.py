"""Per-process memos of host-side derivations, keyed by their arguments' identity.

Every curve of a dataset shard, and every call of a fit's model, prepares its
scene anew (:func:`jaxlc.rendering.prepare.prepare`), but the mesh, its facets and
its shadow-table layout are shared by every size and spin of one shape (derived
once per file, :func:`jaxlc.body.mesh.load_body`). What is derived from them alone —
the table's layout and cache key, the facets in the table's order, their tangent
frames — is memoized here instead of being recomputed per curve (S4: ~2 ms a curve of
host work).

Arguments that hold arrays (a mesh, facets) are keyed by identity and kept alive by
the memo, so an id is never reused while its entry stands; numpy arrays by their
bytes; anything else by value. Results are shared between callers: arrays in them
are made read-only.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np


def _key(arg):
    if isinstance(arg, np.ndarray):
        return ("array", arg.dtype.str, arg.shape, arg.tobytes())
    try:
        hash(arg)
    except TypeError:  # e.g. a frozen dataclass of arrays
        return ("id", id(arg))
    return ("value", arg)


def _freeze(out):
    if isinstance(out, np.ndarray):
        out.flags.writeable = False
    elif isinstance(out, tuple):
        for x in out:
            _freeze(x)
    elif dataclasses.is_dataclass(out) and not isinstance(out, type):
        for field in dataclasses.fields(out):
            _freeze(getattr(out, field.name))
    return out


def remember(memo: dict, key, value, maxsize: int):
    """Put ``value`` into the dict ``memo`` under ``key``, first dropping its oldest entries
    while it holds ``maxsize`` (first in, first out); returns ``value``."""
    while len(memo) >= maxsize:
        memo.pop(next(iter(memo)))
    memo[key] = value
    return value


def identity_memo(maxsize: int = 8):
    """Decorator: remember the last ``maxsize`` results of a function of positional
    arguments (first in, first out). ``f.cache_clear()`` empties it.

    The function must return new arrays, not its arguments' own: they are made read-only.

    Example:
        >>> @identity_memo()
        ... def layout(mesh, facets, settings): ...
    """

    def decorate(fn):
        memo: dict = {}

        @functools.wraps(fn)
        def wrapper(*args):
            key = tuple(_key(a) for a in args)
            hit = memo.get(key)
            if hit is not None:
                return hit[1]
            out = _freeze(fn(*args))
            remember(memo, key, (args, out), maxsize)  # the arguments pin their ids
            return out

        wrapper.cache_clear = memo.clear
        return wrapper

    return decorate

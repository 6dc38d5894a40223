"""Errors a user can fix.

Every message names the input, the offending value and the fix, e.g.
``scene.toml: [attitude] period_s = -1.0 must be > 0 (spin period in seconds)``.
The CLI prints these as one line and exits non-zero; anything else is a bug and
keeps its traceback.
"""

from __future__ import annotations


class JaxlcError(ValueError):
    """Bad input: the message says what, where, and how to fix it."""


class SceneError(JaxlcError):
    """A scene file (TOML) is malformed, incomplete or out of range."""


class TableError(JaxlcError):
    """A geometry or light-curve table is malformed."""


class MeshError(JaxlcError):
    """A shape model cannot be read or has no usable faces."""

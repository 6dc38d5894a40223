"""One cache root for everything jaxlc keeps between runs.

``$JAXLC_CACHE_DIR`` when set, else ``$XDG_CACHE_HOME/jaxlc``, else
``~/.cache/jaxlc``. Below it, one folder per kind:

* ``shadow/`` — shadow visibility tables, keyed by the mesh's content and the
  settings (:mod:`jaxlc.body.shadow`);
* ``xla/`` — JAX's persistent compilation cache (:func:`jaxlc.xla.enable_persistent_cache`;
  ``$JAXLC_XLA_CACHE=off`` turns it off).

Everything there can be deleted at any time; it is made again when needed.
"""

from __future__ import annotations

import os
from pathlib import Path

#: Environment variable that moves the whole cache.
CACHE_ENV = "JAXLC_CACHE_DIR"


def cache_root() -> Path:
    """The folder all of jaxlc's caches live in (see the module docstring)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "jaxlc"


def cache_dir(kind: str) -> Path:
    """The folder of one kind of cached data, e.g. ``cache_dir("shadow")`` (not created)."""
    return cache_root() / kind

"""JAX's persistent compilation cache for jaxlc's long jobs.

A spin fit compiles its batched solvers and samplers afresh in every new
process (tens of seconds on two cores); with the cache on, a second fit of a
scene of the same layout loads them from disk instead.
"""

from __future__ import annotations

import os
from pathlib import Path

#: Environment variable naming the cache folder ("off" disables it).
CACHE_ENV = "JAXLC_XLA_CACHE"


def default_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "jaxlc" / "xla"


def enable(path: str | Path | None = None) -> Path | None:
    """Turn on the persistent cache (once per process) and return its folder.

    Args:
        path: the folder; default ``$JAXLC_XLA_CACHE`` or ``~/.cache/jaxlc/xla``.

    Returns:
        The folder in use, or None when ``$JAXLC_XLA_CACHE`` is ``off``.
    """
    import jax

    env = os.environ.get(CACHE_ENV, "")
    if path is None and env.lower() == "off":
        return None
    current = jax.config.jax_compilation_cache_dir
    if current is not None:
        return Path(current)
    folder = Path(path or env or default_dir())
    folder.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    return folder

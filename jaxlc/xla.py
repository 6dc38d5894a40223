"""How jaxlc compiles its kernels: XLA options for the CPU and the persistent cache.

* :func:`compiler_options` — per-compilation options for the facet kernels on
  this backend. XLA:CPU hands row reductions to YNNPACK, which splits the
  facet sum into several (samples × facets) arrays in memory; with that off it
  is one fused, vectorised loop (about 1.4× faster on the 2-core reference
  machine, ``experiments/bench_render.py``). Only ever applied on the CPU.
* :func:`jit` and :func:`filter_jit` — ``jax.jit`` / ``equinox.filter_jit``
  with those options (fixed on the first call, so importing jaxlc compiles
  nothing).
* :func:`enable_persistent_cache` — JAX's compilation cache under
  :func:`jaxlc.io.cache.cache_dir` ``("xla")``: a spin fit or a dataset worker
  loads its compiled solvers instead of compiling them again in every process.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

from jaxlc.io.cache import cache_dir

#: XLA options of the facet kernels on the CPU backend (see the module docstring).
#: Not ``xla_cpu_prefer_vector_width = 512``: the facet loop ran ~1.25× faster with it
#: on an AVX-512 machine, but this XLA then miscompiles ``jnp.arctan`` (zeros and
#: shuffled values for 64 elements; wrong tumble Jacobians, LM searches that fail).
CPU_COMPILER_OPTIONS = {"xla_cpu_experimental_ynn_fusion_type": ""}
#: ``JAXLC_XLA_CACHE=off`` turns the persistent compilation cache off.
XLA_CACHE_ENV = "JAXLC_XLA_CACHE"


@functools.cache
def compiler_options() -> dict | None:
    """Per-compilation XLA options for the facet kernels on this backend (or None).

    Use them when jitting your own functions around the kernel:
    ``jax.jit(f, compiler_options=jaxlc.xla.compiler_options())``.
    """
    import jax

    if jax.default_backend() != "cpu":
        return None
    try:  # an XLA that no longer knows the option: plain compilation
        jax.jit(lambda x: x + 1, compiler_options=CPU_COMPILER_OPTIONS)(1.0)
    except Exception:
        return None
    return dict(CPU_COMPILER_OPTIONS)


def _lazy(make):
    """Decorator: build the compiled function on the first call (after JAX is set up)."""

    def decorate(fn):
        compiled = None

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            nonlocal compiled
            if compiled is None:
                compiled = make(fn)
            return compiled(*args, **kwargs)

        return wrapper

    return decorate


def jit(fn=None, **kwargs):
    """``jax.jit`` with :func:`compiler_options`; ``kwargs`` as for ``jax.jit``.

    Example:
        >>> f = jaxlc.xla.jit(jaxlc.rendering.kernel.exposure_intensity)
    """
    if fn is None:
        return functools.partial(jit, **kwargs)
    import jax

    return _lazy(lambda f: jax.jit(f, compiler_options=compiler_options(), **kwargs))(fn)


def filter_jit(fn):
    """``equinox.filter_jit`` with :func:`compiler_options`.

    For functions of pytrees that hold a facet model (fit models,
    log-posteriors): on the CPU the facet sum and its derivatives run 1.4-2.4×
    faster compiled this way (measured on S4 in the spin fit).
    """
    import equinox as eqx

    return _lazy(lambda f: eqx.filter_jit(f, compiler_options=compiler_options()))(fn)


def enable_persistent_cache(path: str | Path | None = None) -> Path | None:
    """Turn on JAX's persistent compilation cache (once per process); return its folder.

    Args:
        path: the folder; default ``cache_dir("xla")``.

    Returns:
        The folder in use, or None when ``$JAXLC_XLA_CACHE`` is ``off``.
    """
    import jax

    if path is None and os.environ.get(XLA_CACHE_ENV, "").lower() == "off":
        return None
    current = jax.config.jax_compilation_cache_dir
    if current is not None:
        return Path(current)
    folder = Path(path) if path is not None else cache_dir("xla")
    folder.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    return folder

"""How jaxlc compiles its kernels: XLA options for the CPU and the persistent cache.

* :func:`compiler_options` — per-compilation options for the facet kernels on
  this backend. XLA:CPU hands row reductions to YNNPACK, which splits the
  facet sum into several (samples × facets) arrays in memory; with that off it
  is one fused, vectorised loop (about 1.4× faster on the 2-core reference
  machine, ``experiments/bench_render.py``). Only ever applied on the CPU.
* :func:`jit` and :func:`filter_jit` — ``jax.jit`` / ``equinox.filter_jit``
  with those options (fixed on the first call, so importing jaxlc compiles
  nothing).
* :func:`wide_jit` — :func:`jit` with 512-bit vectors for programs free of
  inverse trigonometric functions (which this XLA miscompiles so): the render
  and dataset kernels of spinning bodies.
* :func:`enable_persistent_cache` — JAX's compilation cache under
  :func:`jaxlc.io.cache.cache_dir` ``("xla")``: a spin fit or a dataset worker
  loads its compiled solvers instead of compiling them again in every process.
"""

from __future__ import annotations

import functools
import os
import re
from pathlib import Path

from jaxlc.io.cache import cache_dir

#: XLA options of the facet kernels on the CPU backend (see the module docstring).
#: Not ``xla_cpu_prefer_vector_width = 512``: the facet loop ran ~1.25× faster with it
#: on an AVX-512 machine, but this XLA then miscompiles ``jnp.arctan`` (zeros and
#: shuffled values for 64 elements; wrong tumble Jacobians, LM searches that fail);
#: :func:`wide_jit` uses it where the program has no arctan.
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


#: XLA option of :func:`wide_jit`: 512-bit vectors for the facet loop (where the CPU has them).
WIDE_COMPILER_OPTIONS = {"xla_cpu_prefer_vector_width": 512}
#: Primitives that :func:`wide_jit` never compiles with 512-bit vectors: this XLA
#: miscompiles ``jnp.arctan`` so, and the other inverse trigonometric functions are
#: made of it (a tumbling body's attitude holds ``atan`` and ``asin``).
NARROW_ONLY = re.compile(r"\b(atan2?|asinh?|acosh?|atanh)\b")


@functools.cache
def wide_options() -> dict | None:
    """:func:`compiler_options` with :data:`WIDE_COMPILER_OPTIONS`, or None where that is not
    available (another backend, an XLA without the option)."""
    import jax

    base = compiler_options()
    if base is None:
        return None
    options = {**base, **WIDE_COMPILER_OPTIONS}
    try:
        jax.jit(lambda x: x * 2.0, compiler_options=options)(1.0)
    except Exception:
        return None
    return options


def wide_is_safe(fn, args, static_argnums=()) -> bool:
    """Whether ``fn(*args)`` traces to a program free of :data:`NARROW_ONLY` primitives."""
    import jax

    text = str(jax.make_jaxpr(fn, static_argnums=static_argnums)(*args))
    return NARROW_ONLY.search(text) is None


def wide_jit(fn, static_argnums=()):
    """:func:`jit` compiled for 512-bit vectors where that is safe, for kernels whose time
    is the facet sum: S4's facet sum ran 2.4× and its bulk renders 1.3× faster so on
    an AVX-512 machine (``experiments/bench_render.py``). Each new signature (the
    arguments' tree structure, shapes and dtypes, static values) is traced once to
    check it (:func:`wide_is_safe`); one with an inverse trigonometric function
    (:data:`NARROW_ONLY`) is compiled as :func:`jit` compiles it.
    """
    import jax

    static_argnums = tuple(static_argnums)
    narrow = jit(fn, static_argnums=static_argnums)
    wide = _lazy(
        lambda f: jax.jit(f, compiler_options=wide_options(), static_argnums=static_argnums)
    )(fn)
    safe: dict = {}

    @functools.wraps(fn)
    def wrapper(*args):
        dynamic = [a for i, a in enumerate(args) if i not in static_argnums]
        leaves, tree = jax.tree_util.tree_flatten(dynamic)
        key = (tree, tuple(_leaf_key(x) for x in leaves), tuple(args[i] for i in static_argnums))
        if key not in safe:
            safe[key] = wide_options() is not None and wide_is_safe(fn, args, static_argnums)
        return (wide if safe[key] else narrow)(*args)

    return wrapper


def filter_jit(fn):
    """``equinox.filter_jit`` with :func:`compiler_options`, and 512-bit vectors where that is
    safe, as :func:`wide_jit` decides it (non-array arguments are static).

    For functions of pytrees that hold a facet model (fit models,
    log-posteriors): on the CPU the facet sum and its derivatives run 1.4-2.4×
    faster compiled this way (measured on S4 in the spin fit).
    """
    import equinox as eqx
    import jax

    narrow = _lazy(lambda f: eqx.filter_jit(f, compiler_options=compiler_options()))(fn)
    wide = _lazy(lambda f: eqx.filter_jit(f, compiler_options=wide_options()))(fn)
    safe: dict = {}

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        leaves, tree = jax.tree_util.tree_flatten((args, kwargs))
        key = (tree, tuple(_leaf_key(x) for x in leaves))
        if key not in safe:
            ok = wide_options() is not None
            if ok:
                text = str(eqx.filter_make_jaxpr(fn)(*args, **kwargs)[0])
                ok = NARROW_ONLY.search(text) is None
            safe[key] = ok
        return (wide if safe[key] else narrow)(*args, **kwargs)

    return wrapper


def _leaf_key(x):
    """A leaf's part of a compilation signature: shape and dtype of an array, the value
    of anything else (static under ``equinox.filter_jit``)."""
    if hasattr(x, "shape") and hasattr(x, "dtype"):
        return (tuple(x.shape), str(x.dtype))
    return ("static", x if isinstance(x, int | float | bool | str | type(None)) else id(x))


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

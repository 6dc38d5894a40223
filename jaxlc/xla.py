"""How jaxlc compiles its kernels: XLA options for the CPU and the persistent cache.

* :func:`compiler_options` — per-compilation options for the facet kernels on
  this backend. XLA:CPU hands row reductions to YNNPACK, which splits the
  facet sum into several (samples × facets) arrays in memory; with that off it
  is one fused, vectorised loop (about 1.4× faster on the 2-core reference
  machine, ``experiments/bench_render.py``). Only ever applied on the CPU.
* :func:`jit` and :func:`filter_jit` — ``jax.jit`` / ``equinox.filter_jit``
  with those options (fixed on the first call, so importing jaxlc compiles
  nothing). :func:`jit` (the forward model: :func:`jaxlc.render`, dataset
  generation) also asks for 512-bit vectors wherever the traced computation
  holds no arctangent (:func:`wide_options`, :func:`wide_safe`).
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
#: 512-bit vectors are not among them: this XLA then miscompiles ``jnp.arctan`` (zeros
#: and shuffled values for 64 float32 elements; wrong tumble Jacobians, LM searches that
#: fail). :func:`jit` adds them only where the computation holds no arctangent.
CPU_COMPILER_OPTIONS = {"xla_cpu_experimental_ynn_fusion_type": ""}
#: Added by :func:`jit` where it is safe (:func:`wide_safe`): the facet loop with
#: 512-bit vectors — the S4 kernel with shadows 1.6× faster in the dataset path on the
#: AVX-512 reference machine (59 → 37 ms a curve), its output bit-identical
#: (``JAXLC_XLA_WIDE=off python experiments/profile_shard.py`` against the default).
WIDE_VECTOR_OPTIONS = {"xla_cpu_prefer_vector_width": 512}
#: Primitives that this XLA miscompiles with 512-bit vectors (``atan``, above) or
#: that lower through it; a computation that holds one keeps the plain options.
WIDE_UNSAFE_PRIMITIVES = frozenset({"atan", "atan2"})
#: ``JAXLC_XLA_WIDE=off`` keeps every kernel at the plain options.
XLA_WIDE_ENV = "JAXLC_XLA_WIDE"
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


def wide_options() -> dict | None:
    """:func:`compiler_options` with 512-bit vectors (:data:`WIDE_VECTOR_OPTIONS`), or None
    off the CPU or when ``$JAXLC_XLA_WIDE`` is ``off``."""
    base = compiler_options()
    if base is None or os.environ.get(XLA_WIDE_ENV, "").lower() == "off":
        return None
    return {**base, **WIDE_VECTOR_OPTIONS}


def primitive_names(jaxpr) -> set[str]:
    """Names of every primitive in a (closed) jaxpr, its sub-jaxprs included (the
    branches of a ``cond``, the bodies of ``scan`` and ``while``, inner ``jit`` calls)."""
    names: set[str] = set()
    stack = [jaxpr]
    while stack:
        j = stack.pop()
        j = getattr(j, "jaxpr", j)  # a ClosedJaxpr's jaxpr
        for eqn in getattr(j, "eqns", ()):
            names.add(eqn.primitive.name)
            for value in eqn.params.values():
                items = value if isinstance(value, (tuple, list)) else (value,)
                stack.extend(v for v in items if hasattr(getattr(v, "jaxpr", v), "eqns"))
    return names


def wide_safe(jaxpr) -> bool:
    """Whether a computation may be compiled with 512-bit vectors: it holds none of
    :data:`WIDE_UNSAFE_PRIMITIVES`."""
    return not (primitive_names(jaxpr) & WIDE_UNSAFE_PRIMITIVES)


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

    compiled: dict = {}  # "plain", "wide" (None: not used) and a choice per argument structure

    @functools.wraps(fn)
    def wrapper(*args, **kw):
        if not compiled:
            wide = wide_options()
            compiled["plain"] = jax.jit(fn, compiler_options=compiler_options(), **kwargs)
            compiled["wide"] = jax.jit(fn, compiler_options=wide, **kwargs) if wide else None
        if compiled["wide"] is None:
            return compiled["plain"](*args, **kw)
        # which primitives are traced depends on the arguments' types and static fields
        # (an attitude that solves Kepler-like equations, a shadow table or none): their
        # tree structure, checked once each by tracing (no compilation)
        key = jax.tree_util.tree_structure((args, kw))
        if key not in compiled:
            safe = wide_safe(compiled["plain"].trace(*args, **kw).jaxpr)
            compiled[key] = compiled["wide"] if safe else compiled["plain"]
        return compiled[key](*args, **kw)

    return wrapper


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

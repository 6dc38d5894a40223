"""jaxlc.xla: 512-bit vectors only where XLA compiles them right.

The reference for each check is an independent compilation: plain ``jax.jit``
(XLA's defaults) of the same function, or numpy.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxlc
from jaxlc import xla
from jaxlc.rendering.kernel import exposure_intensity
from jaxlc.rendering.prepare import prepare


def test_primitive_names_look_inside_branches_and_loops():
    def f(x):
        y = jax.lax.cond(x[0] > 0, jnp.arctan, jnp.sin, x)
        return jax.lax.map(jnp.cos, y)

    names = xla.primitive_names(jax.make_jaxpr(f)(jnp.ones(4)))
    assert {"atan", "cond", "cos", "sin"} <= names
    assert not xla.wide_safe(jax.make_jaxpr(f)(jnp.ones(4)))
    assert xla.wide_safe(jax.make_jaxpr(jnp.sin)(jnp.ones(4)))


def test_jit_keeps_arctan_right():
    """64 float32 arctangents: what 512-bit vectors broke on the AVX-512 reference
    machine (zeros and shuffled values); jit must not compile them that way."""
    x = np.linspace(0.1, 3.0, 64, dtype=np.float32)
    got = np.asarray(xla.jit(jnp.arctan)(x))
    np.testing.assert_allclose(got, np.arctan(x.astype(np.float64)), rtol=2e-6)
    inside = xla.jit(lambda v: jax.lax.map(lambda r: jnp.arctan(r), v.reshape(8, 8)).ravel())
    np.testing.assert_allclose(np.asarray(inside(x)), np.arctan(x.astype(np.float64)), rtol=2e-6)


def test_wide_vectors_can_be_turned_off(monkeypatch):
    monkeypatch.setenv(xla.XLA_WIDE_ENV, "off")
    assert xla.wide_options() is None
    monkeypatch.delenv(xla.XLA_WIDE_ENV)
    if xla.compiler_options() is not None:  # the CPU backend
        assert xla.wide_options()["xla_cpu_prefer_vector_width"] == 512


@pytest.mark.parametrize(
    "scene",
    ["s4_falcon9", "s6_boxwing", "falcon9_tumble"],  # shadows (spin); a tumble (its arctan)
)
def test_kernel_matches_a_plain_compilation(scene):
    """The kernel through jaxlc.xla.jit (512-bit vectors where safe) against the same
    kernel compiled with XLA's defaults, over a pass with adaptive blur's instants."""
    geo = jaxlc.synthetic_geometry(duration_s=240.0, step_s=2.0, phase_end_deg=110)
    prep = prepare(jaxlc.load_scene(scene), geo, precision="float32", subsamples=3)
    got = np.asarray(xla.jit(exposure_intensity)(prep.object, prep.inputs), np.float64)
    ref = np.asarray(jax.jit(exposure_intensity)(prep.object, prep.inputs), np.float64)
    assert np.all(np.isfinite(got)) and np.any(ref > 0)
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-6 * ref.max())

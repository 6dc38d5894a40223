"""The fit's least squares in array operations (no LAPACK call that could hang XLA's pool).

References are numpy's LAPACK least squares on the same matrices.
"""

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
import pytest

from jaxlc.inference.batched_solve import lm_solver
from jaxlc.inference.householder import HouseholderQR, projection_norm2

SCALES = np.array([1.0, 1e3, 1e-2, 5.0, 1.0, 30.0])  # columns of very different sizes


def _system(seed, m=80):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(m, len(SCALES))) * SCALES, rng.normal(size=m)


@pytest.mark.parametrize("seed", range(4))
def test_solver_equals_numpy_least_squares(seed):
    """lineax with HouseholderQR (float32, under vmap) gives numpy's least-squares solution."""
    a, b = _system(seed)
    expected = np.linalg.lstsq(a, b, rcond=None)[0]
    op = lx.MatrixLinearOperator(jnp.asarray(a, jnp.float32))
    solve = jax.jit(jax.vmap(lambda v: lx.linear_solve(op, v, HouseholderQR()).value))
    got = np.asarray(solve(jnp.stack([jnp.asarray(b, jnp.float32), -jnp.asarray(b)])))
    np.testing.assert_allclose(got[0] * SCALES, expected * SCALES, atol=2e-5)
    np.testing.assert_allclose(got[1], -got[0], rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("dependent", ["none", "zero", "copy first", "copy last"])
def test_projection_is_the_least_squares_gain_whatever_the_rank(dependent):
    """‖b‖² − min ‖b − a x‖², with a column that is zero or a multiple of another (before
    or after it): the dependent column adds nothing."""
    a, b = _system(7)
    if dependent == "zero":
        a[:, 3] = 0.0
    elif dependent == "copy first":
        a[:, 3] = 2.0 * a[:, 0]
    elif dependent == "copy last":
        a[:, 0] = -3.0 * a[:, 5]
    best = np.linalg.lstsq(a, b, rcond=None)[0]
    expected = np.sum(b**2) - np.sum((b - a @ best) ** 2)
    assert np.isclose(projection_norm2(a, b, np), expected, rtol=1e-10)
    got32 = float(projection_norm2(jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32)))
    assert np.isclose(got32, expected, rtol=1e-4)


@pytest.mark.parametrize("stall", [True, False])
def test_fit_solver_has_no_lapack_call_and_solves(stall):
    """The fit's batched LM compiles without any custom call (LAPACK's batched QR/SVD
    ran on XLA's pool and could hang it) and fits an exponential exactly."""
    t = jnp.linspace(0.0, 2.0, 40)
    truth = jnp.asarray([1.5, -0.7, 0.2])

    def residuals(y, _args):
        return y[0] * jnp.exp(y[1] * t) + y[2] - (truth[0] * jnp.exp(truth[1] * t) + truth[2])

    solver = lm_solver(stall)
    args = (jnp.asarray(60), jnp.asarray(3)) if stall else None

    def one(y0):
        return optx.least_squares(residuals, solver, y0, args, max_steps=60, throw=False).value

    starts = jnp.asarray([[1.0, -1.0, 0.0], [2.0, -0.3, 0.5]])
    solve = jax.jit(jax.vmap(one))
    text = solve.lower(starts).compile().as_text()
    assert " custom-call(" not in text and "custom_call_target" not in text
    np.testing.assert_allclose(np.asarray(solve(starts)), np.tile(truth, (2, 1)), atol=2e-3)

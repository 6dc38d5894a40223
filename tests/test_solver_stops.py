"""When the fit's solvers stop, and how the search clusters its optima.

References are independent: a linear least-squares problem (whose optimum and
reductions numpy's lstsq gives exactly) and a plain pairwise-angle loop.
"""

import math

import jax.numpy as jnp
import numpy as np

from jaxlc.inference.batched_solve import promised_reduction
from jaxlc.inference.laplace import RECENTRE_TOLERANCE_CHI2, gauss_newton
from jaxlc.inference.search_starts import distinct_modes


def _linear_problem(seed=0, n=200):
    rng = np.random.default_rng(seed)
    jac = rng.normal(size=(n, 4)) * np.array([1.0, 30.0, 0.01, 0.0])  # a column of no effect
    b = rng.normal(size=n)
    return jac, b


def test_promised_reduction_is_the_linear_optimum_gain():
    """At x0 of r(x) = J x − b the undamped step promises ‖r‖² − min ‖J x − b‖², scaled
    columns and a column of no effect (a pole vector's length) notwithstanding."""
    jac, b = _linear_problem()
    x0 = np.array([0.3, -0.2, 5.0, 1.0])
    r = jac @ x0 - b
    best = np.linalg.lstsq(jac, b, rcond=None)[0]
    expected = np.sum(r**2) - np.sum((jac @ best - b) ** 2)
    got = float(promised_reduction(jnp.asarray(jac, jnp.float32), jnp.asarray(r, jnp.float32)))
    assert math.isclose(got, expected, rel_tol=1e-3)
    at_optimum = jac @ best - b
    floor = float(promised_reduction(jnp.asarray(jac), jnp.asarray(at_optimum)))
    assert floor < 1e-9 * np.sum(at_optimum**2)


def test_gauss_newton_stops_without_trying_a_step_that_promises_nothing():
    """A linear problem is solved by one step (to within the tolerance); there no
    further point is evaluated (each evaluation is a Jacobian of the exact model in a
    fit; before, nine damped retries were)."""
    jac, b = _linear_problem(1)
    calls = []

    def at(x):
        calls.append(x.copy())
        return jac @ x - b, jac

    _x, r, _ = gauss_newton(at, np.zeros(4), np.ones(len(b)))
    best = np.linalg.lstsq(jac, b, rcond=None)[0]
    excess = np.sum(r**2) - np.sum((jac @ best - b) ** 2)
    assert 0 <= excess < RECENTRE_TOLERANCE_CHI2  # the first step is slightly damped
    assert len(calls) == 2  # the start and the one step


def test_distinct_modes_match_a_pairwise_angle_loop():
    """Greedy clustering (best first; an optimum joins the first mode whose pole is
    within 10° and ln P within 0.01) against the loop written out with arccos angles."""

    def loop(theta, cost, max_modes):
        modes = []
        for k in np.argsort(cost, kind="stable"):
            if not np.isfinite(cost[k]):
                break
            for m in modes:
                a, b = theta[k, :3], m[0][:3]
                cos = a @ b / np.linalg.norm(a) / np.linalg.norm(b)
                if (
                    np.degrees(np.arccos(np.clip(cos, -1, 1))) < 10
                    and abs(theta[k, 3] - m[0][3]) < 0.01
                ):
                    m[2] += 1
                    break
            else:
                if len(modes) < max_modes:
                    modes.append([theta[k], cost[k], 1])
        return modes

    rng = np.random.default_rng(3)
    n = 600
    poles = rng.normal(size=(8, 3))[rng.integers(0, 8, n)] + 0.15 * rng.normal(size=(n, 3))
    ln_p = np.log(rng.choice([10.0, 20.0, 30.1], n)) + rng.normal(0, 0.006, n)
    theta = np.column_stack([poles, ln_p, rng.uniform(0, 6, n), rng.normal(size=n)])
    cost = rng.chisquare(3, n)
    cost[rng.integers(0, n, 10)] = np.inf
    for max_modes in (4, 30, n):
        want = loop(theta, cost, max_modes)
        got = distinct_modes(theta, cost, max_modes=max_modes)
        assert [(c, m) for _t, c, m in got] == [(c, m) for _t, c, m in want]
        assert all(np.array_equal(g[0], w[0]) for g, w in zip(got, want, strict=True))

"""The adaptive quadrature's nested rules against published values and exact integrals."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.polynomial import legendre

from jaxlc.rendering.patterson import (
    NESTED_LEVELS,
    added_fractions,
    error_divisor,
    largest_gap,
    level_count,
    level_rule,
    stacked_weights,
)

#: Patterson's 7-point rule on [−1, 1] (Patterson 1968, Math. Comp. 22, 847, table 1):
#: positive points and their weights.
PATTERSON_7 = (
    (0.0, 0.450916538658474142345110087045),
    (0.434243749346802558002071502844, 0.401397414775962222905051818618),
    (0.774596669241483377035853079956, 0.268488089868333440728569280666),
    (0.960491268708020283423507092629, 0.104656226026467265193823857192),
)


def test_seven_point_rule_is_pattersons():
    frac, w = level_rule(2)
    x, wx = 2 * frac - 1, 2 * w
    for node, weight in PATTERSON_7:
        i = int(np.argmin(np.abs(x - node)))
        assert x[i] == pytest.approx(node, abs=1e-13)
        assert wx[i] == pytest.approx(weight, abs=1e-13)
    assert len(x) == 7


@pytest.mark.parametrize("level", range(NESTED_LEVELS + 1))
def test_nested_rules_integrate_polynomials_of_their_degree_exactly(level):
    """Level k integrates every polynomial of degree ≤ 3·2ᵏ − 1 (3 points: 5, Gauss), and
    keeps every point of level k − 1; weights are positive and sum to 1."""
    frac, w = level_rule(level)
    n = level_count(level)
    assert len(frac) == n == 2 ** (level + 1) - 1
    degree = 1 if level == 0 else 3 * 2**level - 1
    x = 2 * frac - 1
    # ∫₀¹ P_j(2u − 1) du = δ_j0
    moments = w @ legendre.legvander(x, degree)
    assert moments[0] == pytest.approx(1.0, abs=1e-13)
    assert np.max(np.abs(moments[1:])) < 1e-11
    assert np.all(w > 0) and np.all(np.diff(frac) > 0)
    if level:
        old = level_rule(level - 1)[0]
        assert np.all(np.min(np.abs(frac[:, None] - old[None, :]), axis=0) < 1e-12)
        assert len(added_fractions(level)) == n - level_count(level - 1)


def test_compound_levels_and_stacked_weights():
    """A compound level is 2ᵏ⁻⁵ panels of the 63-point rule; the stacked weights of each
    level reproduce its rule over the values evaluated so far (a smooth integrand)."""

    def f(u):
        return np.exp(np.sin(7 * u)) + u**3

    from scipy.integrate import quad  # an independent (adaptive Gauss–Kronrod) reference

    exact = quad(f, 0, 1, epsabs=1e-13, epsrel=1e-13, limit=200)[0]
    values = [f(level_rule(0)[0])]
    for k in range(1, NESTED_LEVELS + 3):
        frac, w = level_rule(k)
        assert w.sum() == pytest.approx(1.0, abs=1e-13)
        if k <= NESTED_LEVELS:
            values.append(f(added_fractions(k)))
            got = np.concatenate(values) @ stacked_weights(k)
        else:
            assert len(frac) == 63 * 2 ** (k - NESTED_LEVELS)
            got = f(added_fractions(k)) @ stacked_weights(k)
        assert got == pytest.approx(f(frac) @ w, rel=1e-13)
        if k >= 4:
            assert got == pytest.approx(exact, rel=1e-10)
    assert largest_gap(3) < 1 / 8 < largest_gap(2)
    assert error_divisor(1) == pytest.approx(8.0)

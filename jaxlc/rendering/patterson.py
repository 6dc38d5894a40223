"""The nested quadrature of the adaptive sub-exposures: Gauss–Patterson rules on [0, 1].

Level 0 is the midpoint; level k ≤ :data:`NESTED_LEVELS` is the Gauss–Patterson
rule of 2ᵏ⁺¹ − 1 points (3, 7, 15, 31, 63), which keeps every point of level
k − 1 and adds 2ᵏ (Kronrod's extension of the 1-point Gauss rule is the 3-point
Gauss rule; Patterson's extensions of it integrate polynomials of degree
≈ 1.5 n exactly). A smooth integrand is resolved with far fewer instants than
by nested midpoints (3ᴸ points, error ∝ h²): over random spins of the standard
mix, the fewest instants per exposure that hold 1 mmag (an oracle's) are 2.9 (S3),
2.9 (S4), 28 (S5) and 8.0 (S6) against 7.8, 7.2, 64 and 9.6 for midpoints
(``experiments/quadrature_study.py``).
Levels above :data:`NESTED_LEVELS` split the exposure into 2ᵏ⁻⁵ equal panels with
the 63-point rule on each (126, 252, … points; not nested with the level below:
every point is new).

The rules' points are the roots of Patterson's extension polynomials, found
once (:func:`nested_rules`) by solving their orthogonality conditions in the
Legendre basis; the weights are interpolatory. Both are checked against the
published 7-point rule and for polynomial exactness (tests/test_patterson.py).

Example:
    >>> frac, w = level_rule(2)        # 7 fractions of the exposure, weights summing to 1
    >>> new = added_fractions(2)       # the 4 that level 2 adds to level 1
"""

from __future__ import annotations

import functools

import numpy as np
from numpy.polynomial import legendre

#: Levels of the nested family (level 5: 63 points); finer levels are compound rules.
NESTED_LEVELS = 5
#: Points of the rule of each nested level.
NESTED_COUNTS = tuple(2 ** (k + 1) - 1 for k in range(NESTED_LEVELS + 1))


def _extend(nodes: np.ndarray) -> np.ndarray:
    """Patterson's extension of a rule's points on [−1, 1]: the n + 1 roots of the
    polynomial q (degree n + 1) orthogonal to every polynomial of degree ≤ n under the
    weight p(x) = ∏(x − xᵢ), with the given points (sorted, symmetric)."""
    n = len(nodes)
    m = n + 1
    gx, gw = legendre.leggauss(4 * m + 8)  # exact for the degree-(n + 2m) integrands
    p = np.prod((gx[:, None] - nodes[None, :]) * 1.5, axis=1)
    p /= np.max(np.abs(p))
    basis = legendre.legvander(gx, m).T  # (m + 1, G): P_0 … P_m
    a = (basis[:m] * p * gw) @ basis.T  # a[k, j] = ∫ p P_j P_k
    coef = np.linalg.solve(a[:, :m], -a[:, m])  # q = P_m + Σ_j c_j P_j
    roots = np.sort(np.real(legendre.legroots(np.r_[coef, 1.0])))
    x = np.sort(np.concatenate([nodes, roots]))
    return 0.5 * (x - x[::-1])  # exactly symmetric


def _weights(x: np.ndarray) -> np.ndarray:
    """Interpolatory weights of points x on [−1, 1] (they integrate P_0 … P_{n−1} exactly)."""
    v = legendre.legvander(x, len(x) - 1).T
    rhs = np.zeros(len(x))
    rhs[0] = 2.0
    return np.linalg.solve(v, rhs)


@functools.cache
def nested_rules() -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """((fractions, weights), …) of levels 0 … :data:`NESTED_LEVELS` on [0, 1]
    (fractions sorted, weights summing to 1)."""
    x = np.zeros(1)
    out = [(np.array([0.5]), np.array([1.0]))]
    for _ in range(NESTED_LEVELS):
        x = _extend(x)
        out.append((0.5 * (x + 1.0), 0.5 * _weights(x)))
    return tuple(out)


def level_count(level: int) -> int:
    """Points of a level's rule (1, 3, 7, 15, 31, 63, then 63 · 2ᵏ⁻⁵)."""
    k = int(level)
    if k <= NESTED_LEVELS:
        return NESTED_COUNTS[k]
    return NESTED_COUNTS[-1] * 2 ** (k - NESTED_LEVELS)


def level_counts(levels) -> np.ndarray:
    """(N,) points of each level's rule for (N,) integer levels (:func:`level_count`)."""
    levels = np.asarray(levels, np.int64)
    return np.array([level_count(k) for k in range(int(levels.max(initial=0)) + 1)])[levels]


@functools.cache
def level_rule(level: int) -> tuple[np.ndarray, np.ndarray]:
    """(fractions of the exposure (n,), weights (n,)) of a level's rule, sorted."""
    k = int(level)
    if k <= NESTED_LEVELS:
        return nested_rules()[k]
    frac, w = nested_rules()[-1]
    panels = 2 ** (k - NESTED_LEVELS)
    start = np.arange(panels)[:, None] / panels
    return (start + frac[None, :] / panels).ravel(), np.tile(w / panels, panels)


@functools.cache
def added_fractions(level: int) -> np.ndarray:
    """The fractions level k ≥ 1 evaluates that level k − 1 did not (all of a compound level's)."""
    k = int(level)
    frac = level_rule(k)[0]
    if k > NESTED_LEVELS:
        return frac
    old = level_rule(k - 1)[0]
    keep = np.min(np.abs(frac[:, None] - old[None, :]), axis=1) > 1e-9
    return frac[keep]


@functools.cache
def stacked_weights(level: int) -> np.ndarray:
    """Weights of a level's rule over the values of levels 0 … k stacked in evaluation
    order (level 0's point, then each level's :func:`added_fractions`): the level's
    estimate is ``np.concatenate(values, axis=1) @ stacked_weights(k)``. A compound
    level (k > :data:`NESTED_LEVELS`) has only its own points."""
    k = int(level)
    frac, w = level_rule(k)
    if k > NESTED_LEVELS:
        return w
    order = np.concatenate([level_rule(0)[0], *(added_fractions(j) for j in range(1, k + 1))])
    pos = np.argmin(np.abs(order[:, None] - frac[None, :]), axis=0)
    out = np.zeros(len(order))
    out[pos] = w
    return out


def error_divisor(level: int) -> float:
    """D_k with ε_k ≈ |Q_k − Q_{k−1}| / D_k: the error falling as n⁻² with the instants,
    as it does across a kink (a shadow's interpolated edge, a facet turning off) for
    every rule, D_k = (n_k / n_{k−1})² − 1 (8 from the midpoint to 3 points, then ≈ 4.4,
    3.6, 3.3, 3.1, and 3 for each doubling of a compound level's panels). A smooth
    integrand converges far faster, so the estimate is then conservative (the nested
    midpoints' |M_L − M_{L−1}|/8 is the same law)."""
    k = int(level)
    return (level_count(k) / level_count(k - 1)) ** 2 - 1.0


@functools.cache
def largest_gap(level: int) -> float:
    """The largest distance between neighbouring points of a level, or from an end of the
    exposure to its nearest point, as a fraction of the exposure."""
    frac = level_rule(level)[0]
    return float(np.max(np.diff(np.concatenate([[0.0], frac, [1.0]]))))

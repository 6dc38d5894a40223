"""Jacobi elliptic functions and Carlson's symmetric elliptic integrals, in JAX.

JAX has no ``ellipj``, ``ellipk`` or ``elliprj``; the torque-free rigid body
(:mod:`jaxlc.body.tumble`) needs them inside traced, differentiated code. Every
function here is elementwise, jittable and vmappable, runs a fixed number of
iterations (no data-dependent loops) and has finite derivatives on its domain.

* :func:`jacobi_sn_cn_dn` — sn, cn, dn by the arithmetic-geometric mean and the
  descending Landen (Gauss) transformation (Abramowitz & Stegun 16.4). It takes
  the parameter m *and* the complementary parameter m₁ = 1 − m, so that
  near m = 1 (the separatrix of a tumbling body) m₁ keeps its full precision.
* :func:`carlson_rf`, :func:`carlson_rj` — Carlson's R_F and R_J by duplication
  (B. C. Carlson, "Numerical computation of real or complex elliptic
  integrals", Numer. Algorithms 10, 1995; DLMF 19.36). The ``*_from_roots``
  forms take √x, √y, √z instead of x, y, z: an argument that is a square
  (cn², as in K(m) = R_F(0, m₁, 1) or Π(n; φ | m)) then has a finite derivative
  at 0, where √x has none.

The complete integrals follow: K(m) = R_F(0, m₁, 1) and
Π(n | m) = K(m) + (n/3) R_J(0, m₁, 1, 1 − n).

Accuracy (``tests/test_tumble.py``, against ``scipy.special``): ~1e-15 relative
in float64 for 1e-15 ≤ m₁ ≤ 1 and |u| ≤ 6 K(m).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

#: AGM steps of :func:`jacobi_sn_cn_dn`: c_n falls quadratically once a_n ≈ b_n;
#: 12 steps reach c_n/a_n < 1e-30 for m₁ ≥ 1e-30.
AGM_STEPS = 12
#: … in float32, where m₁ ≥ 1e-6 (the separatrix guard of :mod:`jaxlc.body.free_body`):
#: 5 steps already give scipy's sn, cn, dn to float32 rounding, 4 do not (0.012).
AGM_STEPS_FLOAT32 = 6
#: Duplication steps of the Carlson integrals: each divides the spread of the
#: arguments by 4, and the series left after 12 steps is exact to float64 for
#: spreads of up to ~1e4 (x = 0 with m₁ ≥ 1e-30 included).
DUPLICATION_STEPS = 12
#: … in float32: the series' error falls as (spread / 4ᵏ)⁶, so 1e-7 instead of 1e-16
#: needs 2.5 steps fewer for the same spreads; 9 steps kept R_J within 4e-7 of scipy's
#: for p up to 1e3, 8 did not (1e-4).
DUPLICATION_STEPS_FLOAT32 = 10


def _steps(float64_steps: int, float32_steps: int, dtype) -> int:
    """A loop's step count for ``dtype`` (float32's own, else float64's)."""
    return float32_steps if jnp.dtype(dtype) == jnp.float32 else float64_steps


def jacobi_sn_cn_dn(u, m, m1) -> tuple[Float[Array, "..."], ...]:
    """Jacobi sn(u | m), cn(u | m), dn(u | m) for 0 ≤ m < 1 (elementwise, broadcast).

    Args:
        u: argument (any real; precise for |u| of a few K(m)).
        m: parameter k² in [0, 1).
        m1: complementary parameter 1 − m in (0, 1], computed by the caller
            without cancellation when m is close to 1.

    Returns:
        (sn, cn, dn), each of the broadcast shape.

    Example:
        >>> sn, cn, dn = jacobi_sn_cn_dn(0.3, 0.5, 0.5)   # scipy.special.ellipj(0.3, 0.5)[:3]
    """
    u, m, m1 = jnp.broadcast_arrays(*map(jnp.asarray, (u, m, m1)))
    b0 = jnp.sqrt(m1)
    c1 = m / (2.0 * (1.0 + b0))  # c₁ = (a₀ − b₀)/2 without the cancellation near m = 0

    def mean(carry, _):
        a, b, c = carry
        a, b = 0.5 * (a + b), jnp.sqrt(a * b)
        # c_{n+1} = c_n² / (4 a_{n+1}), a_{n+1} = (a_n + b_n)/2
        return (a, b, c * c / (2.0 * (a + b))), c / a

    steps = _steps(AGM_STEPS, AGM_STEPS_FLOAT32, b0.dtype)
    (a, _, _), ratios = jax.lax.scan(mean, (jnp.ones_like(b0), b0, c1), None, steps)

    def descend(phi, ratio):
        return 0.5 * (phi + jnp.arcsin(ratio * jnp.sin(phi))), None

    phi, _ = jax.lax.scan(descend, (2.0**steps) * a * u, ratios, reverse=True)
    sn, cn = jnp.sin(phi), jnp.cos(phi)
    return sn, cn, jnp.sqrt(m1 + m * cn * cn)  # dn² = 1 − m sn² = m₁ + m cn², no cancellation


def carlson_rc_one(e) -> Float[Array, "..."]:
    """R_C(1, 1 + e) for e > −1: atan(√e)/√e (e > 0), atanh(√−e)/√−e (e < 0), 1 at 0."""
    e = jnp.asarray(e)
    small = jnp.abs(e) < 1e-3
    safe = jnp.where(small, 1.0, e)  # keeps the unused branch (and its derivative) finite
    root = jnp.sqrt(jnp.abs(safe))
    closed = jnp.where(safe > 0, jnp.arctan(root) / root, jnp.arctanh(root) / root)
    series = 1.0 + e * (-1.0 / 3.0 + e * (1.0 / 5.0 + e * (-1.0 / 7.0 + e * (1.0 / 9.0))))
    return jnp.where(small, series, closed)


def _duplicate(roots, args):
    """One duplication step: λ from the roots, every argument → (argument + λ)/4, and
    the new roots (the first step's roots are the caller's, so one loop body serves)."""
    sx, sy, sz = roots
    lam = sx * sy + sx * sz + sy * sz
    args = tuple(0.25 * (v + lam) for v in args)
    return tuple(map(jnp.sqrt, args[:3])), args


def carlson_rf_from_roots(sx, sy, sz) -> Float[Array, "..."]:
    """R_F(x, y, z) given √x, √y, √z (≥ 0, at most one zero); elementwise, broadcast."""
    roots = jnp.broadcast_arrays(*map(jnp.asarray, (sx, sy, sz)))
    xyz = tuple(r * r for r in roots)
    steps = _steps(DUPLICATION_STEPS, DUPLICATION_STEPS_FLOAT32, xyz[0].dtype)
    _, (x, y, z) = jax.lax.fori_loop(0, steps, lambda _, c: _duplicate(*c), (tuple(roots), xyz))
    a = (x + y + z) / 3.0
    dx, dy = 1.0 - x / a, 1.0 - y / a
    dz = -(dx + dy)
    e2, e3 = dx * dy - dz * dz, dx * dy * dz
    return (1.0 - e2 / 10.0 + e3 / 14.0 + e2 * e2 / 24.0 - 3.0 * e2 * e3 / 44.0) / jnp.sqrt(a)


def carlson_rj_from_roots(sx, sy, sz, p) -> Float[Array, "..."]:
    """R_J(x, y, z, p) given √x, √y, √z (≥ 0, at most one zero) and p > 0."""
    sx, sy, sz, p = jnp.broadcast_arrays(*map(jnp.asarray, (sx, sy, sz, p)))
    x, y, z = sx * sx, sy * sy, sz * sz
    delta = (p - x) * (p - y) * (p - z)

    def step(k, carry):
        roots, args, total = carry
        sp = jnp.sqrt(args[3])
        d = (sp + roots[0]) * (sp + roots[1]) * (sp + roots[2])
        scale = 0.25**k
        total = total + scale * carlson_rc_one(scale**3 * delta / (d * d)) / d
        return (*_duplicate(roots, args), total)

    carry = ((sx, sy, sz), (x, y, z, p), jnp.zeros_like(p))
    steps = _steps(DUPLICATION_STEPS, DUPLICATION_STEPS_FLOAT32, p.dtype)
    _, (x, y, z, p), total = jax.lax.fori_loop(0, steps, step, carry)
    a = (x + y + z + 2.0 * p) / 5.0
    dx, dy, dz = 1.0 - x / a, 1.0 - y / a, 1.0 - z / a
    dp = -0.5 * (dx + dy + dz)
    e2 = dx * dy + dx * dz + dy * dz - 3.0 * dp * dp
    e3 = dx * dy * dz + 2.0 * e2 * dp + 4.0 * dp**3
    e4 = (2.0 * dx * dy * dz + e2 * dp + 3.0 * dp**3) * dp
    e5 = dx * dy * dz * dp * dp
    series = (
        1.0
        - 3.0 * e2 / 14.0
        + e3 / 6.0
        + 9.0 * e2 * e2 / 88.0
        - 3.0 * e4 / 22.0
        - 9.0 * e2 * e3 / 52.0
        + 3.0 * e5 / 26.0
    )
    return 0.25**steps * series / (a * jnp.sqrt(a)) + 6.0 * total


def carlson_rf(x, y, z) -> Float[Array, "..."]:
    """Carlson's R_F(x, y, z) for x, y, z ≥ 0, at most one zero (as ``scipy.special.elliprf``)."""
    return carlson_rf_from_roots(jnp.sqrt(x), jnp.sqrt(y), jnp.sqrt(z))


def carlson_rj(x, y, z, p) -> Float[Array, "..."]:
    """Carlson's R_J(x, y, z, p) for x, y, z ≥ 0 (at most one zero), p > 0
    (as ``scipy.special.elliprj``)."""
    return carlson_rj_from_roots(jnp.sqrt(x), jnp.sqrt(y), jnp.sqrt(z), p)


def ellipk(m, m1=None) -> Float[Array, "..."]:
    """Complete elliptic integral of the first kind K(m) = R_F(0, 1 − m, 1), m < 1.

    ``m1``: 1 − m when the caller has it without cancellation (near m = 1).
    """
    m = jnp.asarray(m)
    m1 = 1.0 - m if m1 is None else jnp.asarray(m1)
    return carlson_rf_from_roots(jnp.zeros_like(m1), jnp.sqrt(m1), jnp.ones_like(m1))

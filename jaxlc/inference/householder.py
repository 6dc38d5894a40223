"""Small dense least squares by Householder QR, written in array operations only.

The spin fit's Levenberg–Marquardt steps solve (N + P) × P systems with P ≤ 10 under
``vmap``. jaxlib hands a batched LAPACK QR (or SVD) to XLA's intra-op thread pool and
waits for it there; when XLA runs that call on a pool thread (after a parallel
kernel), every pool thread can end up waiting and the process hangs with idle CPUs
(seen on the 2-core reference machine: ``jaxlc fit s6_boxwing`` stopped for good in
its refinement after a kernel change). Here the QR is plain XLA (P unrolled
reflections of an (M, P) matrix, no custom call), so nothing waits on the pool, and
at these sizes it costs little beside the model's Jacobian.

* :func:`householder` — R and Qᵀb of a tall matrix (``numpy`` or ``jax.numpy``);
* :func:`solve_upper` — back substitution with R;
* :func:`projection_norm2` — ‖Q₁ᵀ b‖², the part of ‖b‖² a least-squares fit removes;
* :class:`HouseholderQR` — a lineax solver on it, for optimistix's LM.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
from jax.flatten_util import ravel_pytree

from jaxlc.errors import JaxlcError

#: A column whose part outside the span of the others is below this fraction of its
#: norm depends on them (:func:`projection_norm2` leaves it out).
RANK_TOLERANCE = 1e-5


def householder(a, b=None, xp=jnp, tol: float = 0.0):
    """Householder QR of a tall ``a`` (M, P), M ≥ P, applied to ``b`` (M, …) if given.

    A column whose part outside the span of the columns kept before it is at most
    ``tol`` × its norm is left out (not reflected; with ``tol = 0`` only an exactly
    dependent one), so that the rows of Qᵀb past the kept columns' count hold what
    no combination of the columns explains, whatever the rank.

    Returns:
        (R (P, P), Qᵀ b (M, …) or None, reflectors (M, P), their factors (P,), the number of
        columns kept): column k's reflection is I − β_k v_k v_kᵀ with v_k the
        reflectors' column k (β_k = 0 for a column left out). With every column kept
        R is upper triangular.
    """
    m, p = a.shape
    if m < p:
        raise JaxlcError(f"householder: a {m} × {p} matrix is not tall (M ≥ P needed)")
    rows = xp.arange(m)
    norms = xp.sqrt(xp.sum(a * a, axis=0))
    kept = xp.zeros((), dtype=rows.dtype)  # rows taken by the columns kept so far
    vs, betas = [], []
    for k in range(p):
        x = xp.where(rows >= kept, a[:, k], 0.0)
        norm = xp.sqrt(xp.sum(x * x))
        lead = xp.sum(xp.where(rows == kept, a[:, k], 0.0))
        v = x + xp.where(rows == kept, xp.where(lead >= 0, norm, -norm), 0.0)
        v2 = xp.sum(v * v)
        keep = (norm > tol * norms[k]) & (v2 > 0)
        beta = xp.where(keep, 2.0 / xp.where(v2 > 0, v2, 1.0), 0.0)
        a = a - beta * v[:, None] * (v @ a)[None, :]
        b = None if b is None else _reflect(b, v, beta)
        kept = kept + keep.astype(kept.dtype)
        vs.append(v)
        betas.append(beta)
    return a[:p], b, xp.stack(vs, axis=1), xp.stack(betas), kept


def _reflect(b, v, beta):
    """(I − β v vᵀ) b for b (M,) or (M, K)."""
    if b.ndim == 1:
        return b - beta * v * (v @ b)
    return b - beta * v[:, None] * (v @ b)[None, :]


def apply_qt(vs, betas, b):
    """Qᵀ b for the reflectors of :func:`householder`."""
    for k in range(vs.shape[1]):
        b = _reflect(b, vs[:, k], betas[k])
    return b


def solve_upper(r, y, xp=jnp):
    """x with R x = y (R (P, P) upper triangular, y (P,)) by back substitution."""
    p = r.shape[0]
    x = [None] * p
    for k in reversed(range(p)):
        acc = y[k] - sum((r[k, j] * x[j] for j in range(k + 1, p)), start=0.0)
        x[k] = acc / r[k, k]
    return xp.stack(x)


def projection_norm2(a, b, xp=jnp):
    """‖b‖² − min_x ‖b − a x‖² for a tall ``a`` (M, P) and ``b`` (M,): the squares of
    Qᵀb over the columns kept by :func:`householder` at :data:`RANK_TOLERANCE` (a
    column that depends on the others adds nothing, as an SVD's cut-off would)."""
    _, qtb, _, _, kept = householder(a, b, xp, RANK_TOLERANCE)
    return xp.sum(xp.where(xp.arange(a.shape[1]) < kept, qtb[: a.shape[1]], 0.0) ** 2)


class _QRState(eqx.Module):
    r: jax.Array
    vs: jax.Array
    betas: jax.Array
    structure: Any = eqx.field(static=True)


class HouseholderQR(lx.AbstractLinearSolver):
    """lineax's QR least squares for tall, full-rank operators, in array operations only
    (:func:`householder`; no LAPACK call: see the module docstring). Not transposable:
    optimistix's Levenberg–Marquardt does not differentiate through its steps."""

    def init(self, operator, options):
        del options
        r, _, vs, betas, _ = householder(operator.as_matrix())
        return _QRState(r, vs, betas, operator.in_structure())

    def compute(self, state, vector, options: dict[str, Any]):
        del options
        qtb = apply_qt(state.vs, state.betas, ravel_pytree(vector)[0])
        x = solve_upper(state.r, qtb[: state.r.shape[0]])
        zeros = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), state.structure)
        unravel = ravel_pytree(zeros)[1]
        return unravel(x), lx.RESULTS.successful, {}

    def transpose(self, state, options):
        raise NotImplementedError("HouseholderQR solves are not transposed (LM only)")

    def conj(self, state, options):
        raise NotImplementedError("HouseholderQR solves real systems only")

    def assume_full_rank(self):
        return True

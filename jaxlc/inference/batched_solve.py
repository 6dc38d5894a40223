"""Batched Levenberg–Marquardt solves of a spin model from many starts at once.

:func:`least_squares` runs one optimistix Levenberg–Marquardt solve per start in a
single batched solve (vmapped blocks under ``lax.map``), the search's short solves
and the refinement's stalling ones (:func:`stalling_lm`) alike. Solver outcomes are
data: every solve's optimistix ``result`` is kept and counted (:class:`SolveReport`),
so starts that did not converge are reported, not hidden behind an infinite cost.
:func:`cost_at` gives the same cost at given points without a solve.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc.inference.data import FitData, soft_clip
from jaxlc.inference.householder import HouseholderQR, projection_norm2
from jaxlc.inference.model import SpinModel
from jaxlc.xla import filter_jit

#: A refinement stops after this many rejected LM steps in a row (see :func:`stalling_lm`).
STALL_STEPS = 3
#: … or once the Gauss–Newton step from its point promises to lower the cost by less
#: than this many units of the cost per residual (χ² units at a good fit).
PROMISE_TOLERANCE = 0.01


@dataclasses.dataclass(frozen=True)
class SolveReport:
    """How a batch of LM solves ended (optimistix's ``result`` per solve).

    Attributes:
        stage: ``"search"``, ``"reversed"`` or ``"refine"``.
        solves: number of solves.
        converged: solves that met the tolerances (or, refining, stalled: :func:`stalling_lm`).
        max_steps: solves stopped at ``steps`` (usual in the short search).
        failed: solves with another outcome (singular, non-finite, …) or a
            non-finite cost: these are left out of the modes.
        steps: the step limit.
        samples, subsamples, facets: the size of the model solved on.
    """

    stage: str
    solves: int
    converged: int
    max_steps: int
    failed: int
    steps: int
    samples: int
    subsamples: int
    facets: int

    def describe(self) -> str:
        return (
            f"{self.stage}: {self.solves} solves on {self.samples} samples × {self.subsamples} "
            f"sub-exposures × {self.facets} facets: {self.converged} converged, "
            f"{self.max_steps} stopped at {self.steps} steps, {self.failed} failed"
        )


def dense_jvp(fn):
    """``fn`` (P,) → (N,) with a JVP rule that forms the (N, P) Jacobian by ``jacfwd``.

    optimistix linearises the residuals (``jax.linearize``), which keeps every
    (samples × facets) intermediate of the facet sum for later tangents: an LM
    step then costs 4-5× one fused ``jacfwd`` (S4: 267 vs 48 ms). With this rule
    the linearisation holds only the Jacobian and its linear map is a matrix
    product; values are those of ``jax.jacfwd(fn)``.
    """

    @jax.custom_jvp
    def wrapped(theta):
        return fn(theta)

    @wrapped.defjvp
    def _jvp(primals, tangents):
        (theta,), (dt,) = primals, tangents

        def value_twice(x):  # one trace of fn: the Jacobian's output and the value
            y = fn(x)
            return y, y

        jac, value = jax.jacfwd(value_twice, has_aux=True)(theta)
        return value, jac @ dt

    return wrapped


@functools.cache
def stalling_lm():
    """optimistix's Levenberg–Marquardt that also stops after a run of rejected steps
    (reported as converged) or at a step count, both per solve: its ``args`` are
    (steps, rejected steps in a row), :data:`STALL_STEPS` for the refinement.

    Its own test never passes on float32 residuals: it asks every residual to change
    by less than 1e-6 + 1e-5 |r| between accepted steps, below their rounding, and
    once at the optimum every step is rejected (the cost cannot fall) until
    ``max_steps``. S4's refinement spent half its 12 steps so; six S5 SBC cases and S4
    give the same near-best optima (Δχ² < 10, to 0.01) with the stop, 1.4–5× sooner.
    Each of those rejected steps still costs a Jacobian, so a solve also stops as soon
    as the undamped Gauss–Newton step from its accepted point promises less than
    :data:`PROMISE_TOLERANCE` × cost / N (:func:`promised_reduction`): at an optimum
    the linear model says so before any step is tried (S4: 3 Jacobians of ~0.16 s
    saved per refined optimum). A point stopped in a curved valley, where steps are
    rejected for the model's curvature, still promises much and goes on.
    The tumble's refinement does not use it: there the stop moved the cylinder round
    trip's P_ψ interval off the truth (p05 47.9815 s, truth 47.9752 s).
    """
    import optimistix as optx

    class StallingLevenbergMarquardt(optx.LevenbergMarquardt):
        def terminate(self, fn, y, args, options, state, tags):
            done, result = super().terminate(fn, y, args, options, state, tags)
            steps, stall = args
            stop = (state.num_steps_since_acceptance >= stall) | (state.num_steps >= steps)
            r = state.f_info.residual
            cost = jnp.sum(r**2)
            promise = promised_reduction(state.f_info.jac.as_matrix(), r)
            flat = (state.num_accepted_steps > 0) & (promise < PROMISE_TOLERANCE * cost / r.size)
            return done | stop | flat, result

    return StallingLevenbergMarquardt


def lm_solver(stall: bool):
    """The fit's Levenberg–Marquardt (:func:`stalling_lm` with ``stall``, else optimistix's
    own) with its steps solved by :class:`~jaxlc.inference.householder.HouseholderQR`:
    no LAPACK call in the loop (a batched one could hang XLA's thread pool)."""
    import optimistix as optx

    kind = stalling_lm() if stall else optx.LevenbergMarquardt
    return kind(rtol=1e-5, atol=1e-6, linear_solver=HouseholderQR())


def promised_reduction(jac, residual, xp=jnp):
    """‖r‖² − min_s ‖r + J s‖²: what the undamped Gauss–Newton step promises to take off
    the sum of squares of ``residual`` (N,) with Jacobian ``jac`` (N, P) (columns scaled
    to unit norm first; directions the residuals do not depend on, such as the length
    of a pole vector, are left out by the least-squares solve). ``xp``: ``jax.numpy``
    inside a solver, ``numpy`` on the host (:func:`jaxlc.inference.laplace.gauss_newton`)."""
    norm = xp.sqrt(xp.sum(jac**2, axis=0, keepdims=True))
    return projection_norm2(jac / xp.where(norm > 0, norm, 1.0), residual, xp)


@filter_jit
def _solve(model: SpinModel, mag, weight, starts, budget, max_steps: int, batch: int, stall: bool):
    """Batched optimistix LM (``lax.map`` over vmapped blocks of ``batch`` starts);
    ``stall``: :func:`stalling_lm`'s solver, each start with its (steps, stall) ``budget``
    row (``max_steps`` the ceiling).

    Compiled once per model layout, start count and batch size. The blocks
    bound memory: the shadow look-up under ``jacfwd`` holds (starts × samples
    × facets × tangents) values, ~29 GB for 1,024 starts of S4 in one vmap.
    """
    import optimistix as optx

    @dense_jvp
    def plain(theta):
        return (model.magnitudes(theta) - mag) * weight

    def residuals(theta, _args):
        return plain(theta)

    solver = lm_solver(stall)

    def run(start):
        y0, b = start
        sol = optx.least_squares(residuals, solver, y0, b, max_steps=max_steps, throw=False)
        r = residuals(sol.value, None)
        at_limit = sol.result == optx.RESULTS.nonlinear_max_steps_reached
        if stall:
            at_limit = at_limit | (sol.stats["num_steps"] >= b[0])
        converged = (sol.result == optx.RESULTS.successful) & ~at_limit
        return sol.value, jnp.sum(r**2), converged, at_limit

    def skip(start):  # a start given no steps: carried along, not evaluated
        no = jnp.zeros((), bool)
        return start[0], jnp.asarray(jnp.inf, mag.dtype), no, no

    def one(start):
        if not stall:
            return run(start)
        # one start at a time (batch 1) this is a real branch: the polish's carried
        # optima and the padding cost nothing; under vmap both branches run
        return jax.lax.cond(start[1][0] > 0, run, skip, start)

    return jax.lax.map(one, (starts, budget), batch_size=batch)


@filter_jit
def _cost(model: SpinModel, mag, weight, thetas):
    """(K,) Σ ((model − data) · weight)² at (K, P) device coordinates, one at a time."""
    return jax.lax.map(lambda th: jnp.sum(((model.magnitudes(th) - mag) * weight) ** 2), thetas)


def cost_at(model: SpinModel, data: FitData, thetas: np.ndarray) -> np.ndarray:
    """(K,) the cost :func:`least_squares` reports, at the (K, P) host coordinates themselves:
    residuals only, no solve and no Jacobian (the zero-step LM solve this replaced in the
    search linearised at each start, 6-7× the price on S4's exact model); +inf where not
    finite."""
    mag, weight = _weighted_data(data)
    cost = np.asarray(_cost(model, mag, weight, model.to_device(thetas)), np.float64)
    return np.where(np.isfinite(cost), cost, np.inf)


def _weighted_data(data: FitData):
    """The data magnitudes (softly clipped) and residual weights 1/σ (1 where σ is
    unknown), float32 on the device."""
    sigma = np.where(data.mag_err > 0, data.mag_err, 1.0)
    mag = jnp.asarray(soft_clip(data.mag, data.limit_mag), jnp.float32)
    return mag, jnp.asarray(1.0 / sigma, jnp.float32)


def block_size(starts: int, most: int) -> int:
    """How many starts are vmapped together: the largest divisor of ``starts`` up to
    ``most`` when it is at least half of that, else ``most`` (the caller pads).

    ``lax.map`` compiles a second body for a remainder block: with 1,024 search starts
    in blocks of 53 (the memory bound of S4's search model) that doubled the search's
    compilation (7.8 vs 4.5 s, loaded machine); blocks of 32 run as fast.
    """
    most = max(1, min(starts, most))
    best = max(d for d in range(1, most + 1) if starts % d == 0)
    return best if 2 * best >= most else most


def least_squares(
    model: SpinModel,
    data: FitData,
    starts: np.ndarray,
    max_steps: int = 20,
    stage: str = "",
    stall: bool = False,
    budget: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, SolveReport]:
    """Levenberg–Marquardt from every start at once (one batched optimistix solve).

    Args:
        model: the forward model over ``data``'s samples.
        starts: (K, P) LM host coordinates of ``model`` (P = 6 for a spin).
        max_steps: LM iterations (all starts run this many under ``vmap``); with
            ``stall`` the most any start may take (the compiled ceiling).
        stall: stop a solve after :data:`STALL_STEPS` rejected steps in a row
            (:func:`stalling_lm`; the spin refinement, not the search's short solves).
        budget: (K, 2) ints under ``stall``: each start's own steps (≤ ``max_steps``)
            and rejected steps in a row before it stops; default (``max_steps``,
            :data:`STALL_STEPS`) for every start. One compilation serves any budget.

    Returns:
        (K, P) optima, (K,) their sums of squared residuals (weights 1/σ with
        σ the data errors, or 1 mag where unknown; +inf where the solve failed or,
        under ``stall``, a start was given no steps: it is returned as it came)
        and the :class:`SolveReport`.
    """
    mag, weight = _weighted_data(data)
    per_start = len(model.inputs.weight) * model.obj.n_facets
    batch = block_size(len(starts), 2**21 // per_start)
    budget = np.asarray(
        np.tile([max_steps, STALL_STEPS], (len(starts), 1)) if budget is None else budget
    )
    k = len(starts)
    # padded with copies of the last start, given no steps: to a multiple of the batch
    # and, under ``stall``, of a power of two, so that fits with different numbers of
    # candidates share one compilation (S4's exact model: ~4 s each)
    size = max(1 << (k - 1).bit_length(), batch) if stall and k else k
    pad = size - k + (-size % batch)
    padded = np.concatenate([starts, np.repeat(starts[-1:], pad, axis=0)])
    steps = np.concatenate([budget, np.zeros((pad, 2), np.int64)])
    theta, cost, converged, at_limit = (
        x[:k]
        for x in _solve(
            model, mag, weight, model.to_device(padded), jnp.asarray(steps, jnp.int32),
            max_steps, batch, stall,
        )
    )  # fmt: skip
    theta, cost = model.from_device(theta), np.asarray(cost, np.float64)
    converged, at_limit = np.asarray(converged), np.asarray(at_limit)
    failed = ~np.isfinite(cost) | ~np.all(np.isfinite(theta), axis=1) | ~(converged | at_limit)
    cost = np.where(failed, np.inf, cost)
    run = budget[:, 0] > 0  # a start without steps is only carried along
    report = SolveReport(
        stage=stage,
        solves=int(np.count_nonzero(run)),
        converged=int(np.count_nonzero(converged & ~failed & run)),
        max_steps=int(np.count_nonzero(at_limit & ~failed & run)),
        failed=int(np.count_nonzero(failed & run)),
        steps=int(np.max(budget[:, 0], initial=0)) if stall else max_steps,
        samples=model.n,
        subsamples=model.subsamples,
        facets=model.obj.n_facets,
    )
    return theta, cost, report

"""Multi-start MAP search: batched Levenberg–Marquardt solves and their distinct optima.

:func:`multistart` runs ≥ 1,000 optimistix Levenberg–Marquardt solves in one
batched solve on a cheap model (facets clustered by normal, no shadows, 64 of
the samples, the same exposure model with at most 8 sub-exposures), seeded
by the periodogram, then as many again at the reversed (and the same) poles of the best
optima; the distinct optima are refined on the exact model and become
:class:`Mode` objects. Solver outcomes are data: every solve's optimistix
``result`` is kept and counted (:class:`SolveReport`), so starts that did not
converge are reported, not hidden behind an infinite cost.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc.errors import JaxlcError
from jaxlc.inference.data import FitData, soft_clip
from jaxlc.inference.model import (
    N_LM,
    SEARCH_DIRECTIONS,
    SpinModel,
    coarsen_facets,
    pole_radec_deg,
    spin_model,
)
from jaxlc.inference.search_starts import (
    CANDIDATE_FACTOR,
    EXTRA_PERIODS,
    better_half_turn,
    distinct_modes,
    match_offset,
    refinement_set,
    reversed_starts,
    start_points,
)
from jaxlc.scene import Scene
from jaxlc.xla import filter_jit

#: The search model's sub-exposures per exposure: at most its facets' share of
#: SEARCH_FACET_INSTANTS per sample, and at least SEARCH_MAX_SUBSAMPLES. A flat cap of 8
#: left the CubeSat's glints (1.8° lobes, a 10 s spin: ~50 instants per exposure)
#: unresolved: on noise-free data its true pole cost more in the search model than a
#: dozen wrong ones and was not refined (the README pipeline answered a pole 124° off
#: with weight 1), while the 1,205-facet S4 stage (154 merged facets) keeps 8.
SEARCH_MAX_SUBSAMPLES = 8
SEARCH_FACET_INSTANTS = 128
#: A refinement stops after this many rejected LM steps in a row (see :func:`stalling_lm`).
STALL_STEPS = 3
#: Refined optima within this Δχ² of the best are polished: refined on for up to
#: POLISH_STEPS more steps, stopping after POLISH_STALL_STEPS rejected ones in a row
#: (:func:`polish`).
POLISH_DELTA_CHI2 = 100.0
POLISH_STEPS = 28
POLISH_STALL_STEPS = 5


@dataclasses.dataclass(frozen=True)
class Mode:
    """A distinct optimum: LM coordinates, χ² on the model it was refined with, members."""

    theta_lm: np.ndarray
    chi2: float
    starts: int
    noise_mag: float

    @property
    def period_s(self) -> float:
        return float(math.exp(self.theta_lm[3]))

    @property
    def pole_radec_deg(self) -> tuple[float, float]:
        ra, dec = pole_radec_deg(self.theta_lm)
        return float(ra), float(dec)

    def describe(self, best_chi2: float) -> dict:
        ra, dec = self.pole_radec_deg
        return {
            "period_s": self.period_s,
            "pole_ra_deg": ra,
            "pole_dec_deg": dec,
            "phase_deg": float(np.degrees(np.mod(self.theta_lm[4], 2 * np.pi))),
            "dmag": float(self.theta_lm[5]),
            "chi2": self.chi2,
            "delta_chi2": self.chi2 - best_chi2,
            "noise_mag": self.noise_mag,
            "starts": self.starts,
        }


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
    The tumble's refinement does not use it: there the stop moved the cylinder round
    trip's P_ψ interval off the truth (p05 47.9815 s, truth 47.9752 s).
    """
    import optimistix as optx

    class StallingLevenbergMarquardt(optx.LevenbergMarquardt):
        def terminate(self, fn, y, args, options, state, tags):
            done, result = super().terminate(fn, y, args, options, state, tags)
            steps, stall = args
            stop = (state.num_steps_since_acceptance >= stall) | (state.num_steps >= steps)
            return done | stop, result

    return StallingLevenbergMarquardt


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

    solver = (stalling_lm() if stall else optx.LevenbergMarquardt)(rtol=1e-5, atol=1e-6)

    def one(start):
        y0, b = start
        sol = optx.least_squares(residuals, solver, y0, b, max_steps=max_steps, throw=False)
        r = residuals(sol.value, None)
        at_limit = sol.result == optx.RESULTS.nonlinear_max_steps_reached
        if stall:
            at_limit = at_limit | (sol.stats["num_steps"] >= b[0])
        converged = (sol.result == optx.RESULTS.successful) & ~at_limit
        return sol.value, jnp.sum(r**2), converged, at_limit

    return jax.lax.map(one, (starts, budget), batch_size=batch)


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
        σ the data errors, or 1 mag where unknown; +inf where the solve failed)
        and the :class:`SolveReport`.
    """
    sigma = np.where(data.mag_err > 0, data.mag_err, 1.0)
    mag = jnp.asarray(soft_clip(data.mag, data.limit_mag), jnp.float32)
    weight = jnp.asarray(1.0 / sigma, jnp.float32)
    per_start = len(model.inputs.weight) * model.obj.n_facets
    batch = block_size(len(starts), 2**21 // per_start)
    budget = np.asarray(
        np.tile([max_steps, STALL_STEPS], (len(starts), 1)) if budget is None else budget
    )
    k, pad = len(starts), -len(starts) % batch  # padded with copies of the last start
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


def polish(
    model: SpinModel, data: FitData, theta: np.ndarray, cost: np.ndarray, ceiling: int
) -> tuple[np.ndarray, np.ndarray, SolveReport]:
    """Refine on the optima (K, 6) within :data:`POLISH_DELTA_CHI2` of the best (in units
    of the data errors, or of the best optimum's residual variance without them) for up
    to :data:`POLISH_STEPS` steps and :data:`POLISH_STALL_STEPS` rejected ones in a row;
    the others are kept. Same solve and compilation as the refinement (``ceiling``).

    The refinement's short budget leaves some optima short of their minimum in a curved
    valley: in SBC case 91 the truth's mode, stopped 1.4° off at Δχ² 21 above the best,
    was not sampled and a pole 171° off got weight 1; 40 steps and a stop after 8
    rejections found it 22 below the best (a stop after 5 does too). Case 54 needed
    the steps, case 91 the later stop.
    """
    if not np.any(np.isfinite(cost)):
        none = SolveReport(
            stage="polish", solves=0, converged=0, max_steps=0, failed=0, steps=0,
            samples=model.n, subsamples=model.subsamples, facets=model.obj.n_facets,
        )  # fmt: skip
        return theta, cost, none
    scale = 1.0
    if np.all(data.mag_err == 0):
        scale = float(np.min(cost)) / max(data.n - N_LM, 1)
    # one optimum per distinct mode (refinements that met are polished once)
    leaders = {th.tobytes() for th, _c, _n in distinct_modes(theta, cost, max_modes=len(cost))}
    lead = np.array([th.tobytes() in leaders for th in theta])
    near = lead & ((cost - np.min(cost)) / scale < POLISH_DELTA_CHI2)
    budget = np.where(near[:, None], [POLISH_STEPS, POLISH_STALL_STEPS], 0)
    more, more_cost, report = least_squares(model, data, theta, ceiling, "polish", True, budget)
    better = near & (more_cost < cost)
    return (
        np.where(better[:, None], more, theta),
        np.where(better, more_cost, cost),
        report,
    )


#: Distinct search optima refined on the exact model. The coarse model ranks near-equal
#: optima of a symmetric body almost at random: with 8, the CubeSat's true pole of the
#: README pipeline (noise-free, 10 s spin) ranked below 8 others after the render's
#: quadrature moved its samples by < 1 mmag, and the fit answered a pole 124° off with
#: weight 1; 12 finds it (tests/test_consistency.py).
REFINED_MODES = 12


def search_subsamples(scene: Scene) -> int:
    """The search models' cap on sub-exposures per exposure for ``scene``'s shape (spin
    and tumble alike): :data:`SEARCH_FACET_INSTANTS` over its merged facets, at least
    :data:`SEARCH_MAX_SUBSAMPLES`."""
    merged = coarsen_facets(scene.body[1], SEARCH_DIRECTIONS).n_facets
    return max(SEARCH_MAX_SUBSAMPLES, SEARCH_FACET_INSTANTS // max(merged, 1))


def search_model(scene: Scene, data: FitData, period_s: float) -> SpinModel:
    """The search's model of ``data`` (a subset): facets merged into
    :data:`~jaxlc.inference.model.SEARCH_DIRECTIONS` normal bins, no shadows, the
    sub-exposures of a ``period_s`` spin up to :func:`search_subsamples`."""
    return spin_model(
        scene, data, period_s, exact=False, directions=SEARCH_DIRECTIONS,
        max_subsamples=search_subsamples(scene),
    )  # fmt: skip


def multistart(
    scene: Scene,
    data: FitData,
    seeds_period_s,
    n_starts: int = 1024,
    search_samples: int = 64,
    search_steps: int = 10,
    refine_steps: int = 12,
    max_modes: int = REFINED_MODES,
    rng: np.random.Generator | None = None,
    log=None,
) -> tuple[list[Mode], list[SolveReport]]:
    """Multi-start MAP: cheap-model search from ``n_starts``, exact-model refinement.

    The search model is the coarse one (128 normal bins, no shadows, sub-exposures
    capped by :data:`SEARCH_FACET_INSTANTS`, prepared for the shortest
    seed period) on ``search_samples`` samples spread over the curve, one at random
    per equal run (:meth:`FitData.stratified_subset`: a regular grid aliases): it
    only has to put starts into the right basins. A second solve of the same size starts
    at the reversed poles of the four best optima and at those poles themselves with
    phases spread over the turn (:func:`reversed_starts`), and at the best optimum of
    up to four other periods (:func:`refinement_set`); the ``max_modes`` best distinct
    optima of both and the best of up to :data:`EXTRA_PERIODS` other periods are
    then refined on the exact model (shadows, the render plan's sub-exposures for
    the shortest candidate period), and those that end near the best are refined
    further (:func:`polish`).

    Returns:
        Distinct modes on the exact model, best (lowest χ²) first, and the
        solver reports of the four stages (search, reversed, refine, polish).
    """
    rng = rng or np.random.default_rng(0)
    log = log or (lambda msg: None)
    sub = data.stratified_subset(search_samples, rng)
    coarse = search_model(scene, sub, min(seeds_period_s))
    starts = match_offset(coarse, sub, start_points(seeds_period_s, n_starts, rng))
    theta, cost, r1 = least_squares(coarse, sub, starts, search_steps, "search")
    first = distinct_modes(theta, cost, max_modes=CANDIDATE_FACTOR * max_modes)
    if not first:
        raise JaxlcError(
            f"spin fit: no search solve gave a finite fit ({r1.describe()}); check the "
            "light curve and geometry, or give --period-s"
        )
    # The reversed spin (pole −u) of a good optimum gives a nearly time-reversed
    # light curve, and a body symmetric about its axis has optima half a turn apart:
    # light curve: often as good, and often missed by random starts. A second
    # batched solve of the same size (no new compilation) starts there.
    # Its bases: the four best optima and the best of up to four other periods.
    bases = refinement_set(first, 4, 4)
    rev = match_offset(coarse, sub, reversed_starts([c[0] for c in bases], n_starts, rng))
    theta2, cost2, r2 = least_squares(coarse, sub, rev, search_steps, "reversed")
    candidates = refinement_set(
        distinct_modes(
            np.concatenate([theta, theta2]),
            np.concatenate([cost, cost2]),
            max_modes=CANDIDATE_FACTOR * max_modes,
        ),
        max_modes,
        EXTRA_PERIODS,
    )
    log(r1.describe())
    log(r2.describe())
    init = np.stack([c[0] for c in candidates])
    exact = spin_model(scene, data, float(np.exp(init[:, 3].min())), exact=True)
    ceiling = refine_steps + POLISH_STEPS  # one compilation for the twins and both stages

    def chi2(starts):  # at the starts themselves: no steps
        none = np.zeros((len(starts), 2), np.int64)
        return least_squares(exact, data, starts, ceiling, "", True, none)[1]

    init = better_half_turn(init, chi2)
    first = np.tile([refine_steps, STALL_STEPS], (len(init), 1))
    refined, rcost, r3 = least_squares(exact, data, init, ceiling, "refine", True, first)
    log(r3.describe())
    refined, rcost, r4 = polish(exact, data, refined, rcost, ceiling)
    log(r4.describe())
    modes = []
    for (_, _, members), r_th, r_c in zip(candidates, refined, rcost, strict=True):
        if not np.isfinite(r_c):
            continue
        noise = math.sqrt(r_c / max(data.n - N_LM, 1)) if np.all(data.mag_err == 0) else 0.0
        modes.append(Mode(theta_lm=r_th, chi2=float(r_c), starts=members, noise_mag=noise))
    if not modes:
        raise JaxlcError(
            f"spin fit: every one of the {len(candidates)} refined solves failed ("
            f"{r3.describe()}); check the light curve and geometry, or give --period-s"
        )
    # Refinement can land two candidates on one optimum: merge again.
    merged = distinct_modes(
        np.stack([m.theta_lm for m in modes]), np.array([m.chi2 for m in modes])
    )
    by_theta = {m.theta_lm.tobytes(): m for m in modes}
    out = [by_theta[th.tobytes()] for th, _c, _n in merged]
    return sorted(out, key=lambda m: m.chi2), [r1, r2, r3, r4]

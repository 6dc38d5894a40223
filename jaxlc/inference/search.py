"""Multi-start MAP search: batched Levenberg–Marquardt solves and their distinct optima.

:func:`multistart` runs ≥ 1,000 Levenberg–Marquardt solves in one batched solve
(:mod:`jaxlc.inference.batched_solve`, which also counts how each ended) on a cheap
model (facets clustered by normal, no shadows, 64 of the samples, the same exposure
model with sub-exposures within a facet-instant budget), seeded by the periodogram,
then as many again at the reversed (and the same) poles of the best optima; the
distinct optima are refined on the exact model and become :class:`Mode` objects.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from jaxlc.body.facet_merge import coarsen_facets
from jaxlc.errors import JaxlcError
from jaxlc.inference.batched_solve import STALL_STEPS, SolveReport, cost_at, least_squares
from jaxlc.inference.data import FitData
from jaxlc.inference.model import (
    N_LM,
    SEARCH_DIRECTIONS,
    SpinModel,
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

#: The search model's sub-exposures per exposure: at most its facets' share of
#: SEARCH_FACET_INSTANTS per sample, and at least SEARCH_MAX_SUBSAMPLES. A flat cap of 8
#: left the CubeSat's glints (1.8° lobes, a 10 s spin: ~50 instants per exposure)
#: unresolved: on noise-free data its true pole cost more in the search model than a
#: dozen wrong ones and was not refined (the README pipeline answered a pole 124° off
#: with weight 1), while the 1,205-facet S4 stage (154 merged facets) keeps 8.
SEARCH_MAX_SUBSAMPLES = 8
SEARCH_FACET_INSTANTS = 128
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
    ceiling = refine_steps + POLISH_STEPS  # one compilation for both stages

    init = better_half_turn(init, lambda starts: cost_at(exact, data, starts))
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

"""Spin-state inference: emcee around the MAP modes, and posterior summaries.

:func:`jaxlc.inference.fit.fit_spin` is what ``jaxlc fit`` runs:

1. periodogram (:mod:`jaxlc.inference.period`) → seed periods k · P_ls, k = 1…4 (a body
   with several maxima per turn puts the periodogram peak at a fraction of
   its period), and the three best peaks of a six-harmonic periodogram and
   their doubles (glinting bodies put little power in one sinusoid);
2. multi-start Levenberg–Marquardt (:func:`jaxlc.inference.search.multistart`) →
   distinct modes (mirror poles, period aliases), each with its χ²;
3. emcee (``vectorize=True`` on a jitted, vmapped log-probability) started in
   the Laplace ball of each mode within Δχ² < 10 of the best, with a mixture
   of an independence proposal (multivariate t fitted to the posterior in a
   short adaptation stage, :class:`IndependenceMove`) and emcee's
   differential-evolution move, run in blocks until the kept chain is ≥ 50
   integrated autocorrelation times τ long (or ``max_steps``). With the default
   ``sampler="auto"`` every mode is first importance-sampled from its Laplace
   approximation (:mod:`jaxlc.inference.importance`): a main mode with
   ``main_draws`` draws, kept when their effective size is at least
   :data:`MAIN_MIN_ESS_FRACTION` of them (the posterior is then near-Gaussian
   and the weights correct the rest, at a quarter of emcee's evaluations), a
   minor mode (Δχ² ≥ 6) with ``importance_draws``; emcee runs where the
   proposal misses;
4. summary (medians, 50 % and 90 % intervals, pole credible radii), samples
   (Parquet), a corner plot and the data with the fitted model.

The posterior and its priors: :mod:`jaxlc.inference.spin_posterior`; the
samplers see five coordinates, Δm integrated out analytically and drawn from
its conditional afterwards.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pandas as pd

from jaxlc.errors import JaxlcError
from jaxlc.inference.data import FitData
from jaxlc.inference.importance import MIN_ESS_FRACTION, importance_sample, t_log_pdf
from jaxlc.inference.laplace import (
    initial_ball,
    laplace_log_evidence,
)
from jaxlc.inference.model import (
    N_MC,
    SpinModel,
    angle_between_deg,
    mc_to_lm,
    pole_radec_deg,
)
from jaxlc.inference.offset_marginal import OffsetConditionals, marginal_ball, with_offset
from jaxlc.inference.search import Mode
from jaxlc.inference.spin_posterior import DMAG_MC, MarginalLogProb

#: The samplers of :class:`FitSettings`: importance sampling first ("auto") or emcee.
SAMPLERS = ("auto", "emcee")
#: Least effective sample size, as a fraction of the draws, for which a main mode's
#: importance sampling stands (a minor mode's: ``importance.MIN_ESS_FRACTION``).
MAIN_MIN_ESS_FRACTION = 0.5
#: Importance sampling stops once that effective size is reached, after at least this
#: fraction of the draws (S4's main mode: 252 of 360 draws for an effective size of 186).
MIN_DRAWS_FRACTION = 0.5


@dataclasses.dataclass(frozen=True)
class FitSettings:
    """Knobs of :func:`fit_spin` (≥ 1,000 starts; an emcee chain runs to ≥ 50 τ, an
    importance-sampled main mode needs an effective size ≥ half its draws)."""

    n_starts: int = 1024
    search_samples: int = 64
    search_steps: int = 10
    refine_steps: int = 12
    walkers: int = 12
    min_tau: float = 50.0
    max_steps: int = 6000
    adapt_steps: int = 30
    block_steps: int = 25
    mcmc_modes: int = 4
    mode_delta_chi2: float = 10.0
    importance_delta_chi2: float = 6.0  # modes this far above the best: importance-sampled
    importance_draws: int = 120
    sampler: str = "auto"  # "auto": importance sampling first, emcee where it misses
    main_draws: int = 360  # importance draws of a main mode (Δχ² < importance_delta_chi2)
    seed: int = 0
    period_s: float | None = None  # skip the periodogram: seed from this period
    body_period_s: float | None = None  # a tumble's T_ω (with period_s its P_ψ)
    min_period_s: float | None = None  # periodogram search range (default: 2.5 steps …
    max_period_s: float | None = None  # … to half the span)

    def __post_init__(self):
        if self.n_starts < 1:
            raise JaxlcError(f"n_starts = {self.n_starts} must be ≥ 1")
        if self.walkers < 2 * N_MC:
            raise JaxlcError(f"walkers = {self.walkers} must be ≥ {2 * N_MC} (2 × parameters)")
        if self.max_steps < self.block_steps:
            raise JaxlcError(f"max_steps = {self.max_steps} must be ≥ {self.block_steps}")
        if self.importance_draws < self.walkers:
            raise JaxlcError(
                f"importance_draws = {self.importance_draws} must be ≥ walkers = {self.walkers}"
            )
        if self.sampler not in SAMPLERS:
            raise JaxlcError(f"sampler = {self.sampler!r}: give one of {', '.join(SAMPLERS)}")
        if self.main_draws < self.walkers:
            raise JaxlcError(f"main_draws = {self.main_draws} must be ≥ walkers = {self.walkers}")
        if self.adapt_steps < 10:
            raise JaxlcError(f"adapt_steps = {self.adapt_steps} must be ≥ 10")


class OutsidePriorError(JaxlcError):
    """A mode whose Laplace ball cannot be pulled inside the prior (not sampled)."""


class IndependenceMove:
    """Metropolis–Hastings move proposing from a fixed multivariate t (ν = 8).

    The proposal is the Gaussian approximation of the posterior (centre and
    covariance, inflated 1.1×) with heavy tails; it does not depend on the
    walker's position, so a near-Gaussian posterior is sampled with τ of a
    few steps, where the stretch move needs tens. Used in a mixture with
    emcee's differential-evolution move, which handles what the t misses.
    """

    def __init__(self, mean: np.ndarray, cov: np.ndarray, df: float = 8.0, inflate: float = 1.1):
        import emcee

        self.mean = np.asarray(mean, np.float64)
        self.chol = np.linalg.cholesky(cov * inflate**2)
        self.df = df
        self.move = emcee.moves.MHMove(self._propose)

    def log_q(self, x: np.ndarray) -> np.ndarray:
        return t_log_pdf(x, self.mean, self.chol, self.df)

    def _propose(self, coords: np.ndarray, random) -> tuple[np.ndarray, np.ndarray]:
        n, d = coords.shape
        w = np.sqrt(self.df / random.chisquare(self.df, size=n))
        q = self.mean + (random.randn(n, d) @ self.chol.T) * w[:, None]
        return q, self.log_q(coords) - self.log_q(q)


def _moves(mean, cov):
    import emcee

    return [(IndependenceMove(mean, cov).move, 0.85), (emcee.moves.DEMove(), 0.15)]


def _sample_cov(x: np.ndarray, fallback: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mean = np.mean(x, axis=0)
    cov = np.cov(x, rowvar=False)
    try:
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return mean, fallback
    return mean, cov


def sample_mode(
    model: SpinModel,
    data: FitData,
    mode: Mode,
    settings: FitSettings,
    rng: np.random.Generator,
    log=None,
    progress=None,
    importance: bool = False,
) -> dict:
    """Sample the posterior around one mode; ``log(str)`` gets a line per stage,
    ``progress(steps, max_steps, length_tau)`` each emcee block.

    With ``settings.sampler == "auto"`` (or ``importance``: a minor mode) the
    Laplace approximation is first importance-sampled
    (:func:`jaxlc.inference.importance.importance_sample`): ``main_draws`` draws
    kept when their effective size is ≥ :data:`MAIN_MIN_ESS_FRACTION` of them, or
    for a minor mode ``importance_draws`` and
    :data:`~jaxlc.inference.importance.MIN_ESS_FRACTION` (drawing stops once that
    effective size is reached, after at least :data:`MIN_DRAWS_FRACTION` of the
    draws). Otherwise (or when
    those weights fall short) emcee (:func:`sample_posterior`): an adaptation stage of
    ``adapt_steps`` steps from the Laplace ball with the Laplace proposal
    (:class:`IndependenceMove` + DE), discarded; then the proposal refitted to
    the adaptation stage after its first sixth, fixed, and blocks of
    ``block_steps`` until the kept chain (all of stage two) is ≥ ``min_tau`` τ
    long (or ``max_steps``), τ estimated on the kept chain only.

    Returns:
        dict with ``chain`` (steps, walkers, 6), ``log_prob`` (steps, walkers),
        ``log_evidence`` (emcee: :func:`laplace_log_evidence`; importance: the
        mean weight), ``tau`` (6,), ``steps`` (kept), ``burn`` (discarded),
        ``acceptance``, ``chain_length_tau``, ``converged``, ``seconds``,
        ``method`` (``"emcee"`` or ``"importance"``, then with ``ess`` and
        ``draws``; τ, acceptance and length NaN).
    """
    log = log or (lambda msg: None)
    lp = MarginalLogProb(model, data, float(mode.theta_lm[3]))
    p0, centre, cov = marginal_ball(
        *initial_ball(model, data, mode, settings.walkers, rng), DMAG_MC
    )
    if not pull_inside(lp, p0, centre):
        raise OutsidePriorError(
            f"emcee: the mode at P = {mode.period_s:.6g} s has zero prior density "
            "(noise or Δm at a bound)"
        )
    if importance or settings.sampler == "auto":
        draws = settings.importance_draws if importance else settings.main_draws
        need = MIN_ESS_FRACTION if importance else MAIN_MIN_ESS_FRACTION
        run = importance_sample(
            lp, centre, cov, draws, settings.walkers, rng, need, int(MIN_DRAWS_FRACTION * draws)
        )
        log(f"  importance sampling: {run['draws']} draws, effective size {run['ess']:.0f}")
        if run["usable"]:
            return {**full_coordinates(run, lp, rng), "method": "importance"}
        log("  the Laplace proposal misses this mode: emcee instead")
    run = sample_posterior(lp, p0, centre, cov, settings, rng, log, progress)
    return {**full_coordinates(run, lp, rng), "method": "emcee"}


def full_coordinates(run: dict, lp: OffsetConditionals, rng) -> dict:
    """A run of a marginal posterior (Δm integrated out) in all MCMC coordinates: Δm
    drawn from its conditional (:func:`~jaxlc.inference.offset_marginal.with_offset`);
    its τ is NaN (the draws are independent)."""
    chain, log_prob = with_offset(run["chain"], run["log_prob"], lp, rng)
    return {
        **run,
        "chain": chain,
        "log_prob": log_prob,
        "tau": np.insert(run["tau"], lp.offset_index, np.nan),
    }


def pull_inside(lp, p0: np.ndarray, centre: np.ndarray, tries: int = 30) -> bool:
    """Pull walkers of ``p0`` (in place) halfway back to ``centre`` until ``lp`` is finite
    for all (a broad mode's Laplace ball can reach past the prior's bounds); False when
    ``tries`` halvings do not suffice."""
    for _ in range(tries):
        bad = ~np.isfinite(lp(p0))
        if not bad.any():
            return True
        p0[bad] = centre + 0.5 * (p0[bad] - centre)
    return False


def sample_posterior(
    lp,
    p0: np.ndarray,
    centre: np.ndarray,
    cov: np.ndarray,
    settings: FitSettings,
    rng,
    log=None,
    progress=None,
) -> dict:
    """emcee from walkers ``p0`` (W, D) in a mode's Laplace ball (``centre``, ``cov``)
    with the vectorised log-posterior ``lp`` ((W, D) → (W,)): the two stages of
    :func:`sample_mode`, for any fit model's coordinates (D = ``p0.shape[1]``)."""
    import emcee

    log = log or (lambda msg: None)
    progress = progress or (lambda steps, total, length: None)
    walkers, dim = p0.shape
    seed = int(rng.integers(2**31))

    def sampler(mean, c, stage):
        s = emcee.EnsembleSampler(walkers, dim, lp, vectorize=True, moves=_moves(mean, c))
        # reproducible: emcee draws from its own RandomState
        s.random_state = np.random.RandomState(seed + stage).get_state()
        return s

    t0 = time.perf_counter()
    adapt = sampler(centre, cov, 0)
    state = adapt.run_mcmc(p0, settings.adapt_steps, progress=False)
    # The walkers start in the Laplace ball, near equilibrium: all but the first
    # sixth of the stage fits the proposal.
    fitted = adapt.get_chain(discard=settings.adapt_steps // 6, flat=True)
    mean, cov2 = _sample_cov(fitted, cov)
    log(
        f"  emcee: adaptation {settings.adapt_steps} steps, acceptance "
        f"{np.mean(adapt.acceptance_fraction):.2f}"
    )
    main = sampler(mean, cov2, 1)
    tau = np.full(dim, np.inf)
    steps = 0
    length = 0.0
    while steps < settings.max_steps:
        state = main.run_mcmc(state, settings.block_steps, progress=False)
        steps += settings.block_steps
        # A walker that has not moved in the kept chain has no autocorrelation
        # (0/0): τ is NaN, the chain counts as too short and sampling goes on.
        with np.errstate(invalid="ignore", divide="ignore"):
            tau = emcee.autocorr.integrated_time(main.get_chain(), tol=0, quiet=True)
        tau = np.maximum(tau, 1.0)
        length = steps / np.max(tau) if np.all(np.isfinite(tau)) else 0.0
        progress(steps, settings.max_steps, length)
        if length >= settings.min_tau:
            break
    chain, log_prob = main.get_chain(), main.get_log_prob()
    log(f"  emcee: {steps} steps kept, τ = {np.round(tau, 1)}, length {length:.0f} τ")
    return {
        "chain": chain,
        "log_prob": log_prob,
        "log_evidence": laplace_log_evidence(chain.reshape(-1, dim), log_prob.reshape(-1)),
        "tau": tau,
        "steps": steps,
        "burn": settings.adapt_steps,
        "acceptance": float(np.mean(main.acceptance_fraction)),
        "chain_length_tau": float(length),
        "converged": bool(length >= settings.min_tau),
        "seconds": time.perf_counter() - t0,
    }


def mode_weights(log_evidence) -> np.ndarray:
    """Normalised posterior probabilities of the sampled modes."""
    z = np.asarray(log_evidence, np.float64)
    w = np.exp(z - np.max(z))
    return w / np.sum(w)


def samples_table(chain: np.ndarray, log_prob: np.ndarray, mode_id: int) -> pd.DataFrame:
    """Flatten a chain (steps, walkers, 6) into a table in user units."""
    steps, walkers, _ = chain.shape
    flat = chain.reshape(-1, N_MC)
    lm = mc_to_lm(flat)
    ra, dec = pole_radec_deg(lm)
    return pd.DataFrame(
        {
            "mode": mode_id,
            "step": np.repeat(np.arange(steps), walkers),
            "walker": np.tile(np.arange(walkers), steps),
            "pole_ra_deg": ra,
            "pole_dec_deg": dec,
            "period_s": np.exp(flat[:, 2]),
            "phase_deg": np.degrees(np.mod(flat[:, 3], 2 * np.pi)),
            "dmag": flat[:, 4],
            "noise_mag": np.exp(flat[:, 5]),
            "log_prob": log_prob.reshape(-1),
        }
    )


def percentiles(values) -> dict:
    """The 5, 25, 50, 75 and 95 % points of samples (``p05`` … ``p95``, ``median``)."""
    q = np.percentile(np.asarray(values, np.float64), [5, 25, 50, 75, 95])
    return dict(zip(("p05", "p25", "median", "p75", "p95"), map(float, q), strict=True))


def pole_unit(samples: pd.DataFrame) -> np.ndarray:
    """(N, 3) unit pole vectors of posterior samples."""
    return unit_vectors(samples["pole_ra_deg"], samples["pole_dec_deg"])


def unit_vectors(ra_deg, dec_deg) -> np.ndarray:
    """(N, 3) unit vectors of RA/Dec (deg)."""
    ra, dec = np.radians(np.asarray(ra_deg)), np.radians(np.asarray(dec_deg))
    return np.column_stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)])


def direction_summary(samples: pd.DataFrame, ra_col: str, dec_col: str, name: str) -> dict:
    """The mean direction of samples of a direction (RA/Dec columns, deg), the RA interval
    about it (wrapped), and the credible radii: ``{name}_mean``, ``{ra_col}``,
    ``{name}_radius_deg``."""
    u = unit_vectors(samples[ra_col], samples[dec_col])
    mean = u.mean(axis=0)
    mean /= np.linalg.norm(mean)
    ra = float(np.degrees(np.mod(np.arctan2(mean[1], mean[0]), 2 * np.pi)))
    dec = float(np.degrees(np.arcsin(mean[2])))
    sep = angle_between_deg(u, mean[None, :])
    dra = (samples[ra_col].to_numpy() - ra + 180.0) % 360.0 - 180.0
    q = percentiles(dra)
    return {
        ra_col: {k: (v + ra) % 360.0 for k, v in q.items()},
        dec_col: percentiles(samples[dec_col]),
        f"{name}_mean": {"ra_deg": ra, "dec_deg": dec},
        f"{name}_radius_deg": {
            "r50": float(np.percentile(sep, 50)),
            "r90": float(np.percentile(sep, 90)),
        },
    }


def interval_summary(samples: pd.DataFrame) -> dict:
    """Medians, 50 % and 90 % central intervals, and pole credible radii."""
    out = {col: percentiles(samples[col]) for col in ("period_s", "dmag", "noise_mag")}
    out.update(direction_summary(samples, "pole_ra_deg", "pole_dec_deg", "pole"))
    ph = np.radians(samples["phase_deg"].to_numpy())
    ph_mean = math.atan2(np.mean(np.sin(ph)), np.mean(np.cos(ph)))
    dph = (np.degrees(ph - ph_mean) + 180.0) % 360.0 - 180.0
    out["phase_deg"] = {k: (v + math.degrees(ph_mean)) % 360.0 for k, v in percentiles(dph).items()}
    return out

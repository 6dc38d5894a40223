"""Spin-state inference, part 2: emcee around the MAP modes, summaries, the whole fit.

:func:`fit_spin` is what ``jaxlc fit`` runs:

1. periodogram (:mod:`jaxlc.period`) → seed periods k · P_ls, k = 1…4 (a body
   with several maxima per turn puts the periodogram peak at a fraction of
   its period);
2. multi-start Levenberg–Marquardt (:func:`jaxlc.inference.multistart`) →
   distinct modes (mirror poles, period aliases), each with its χ²;
3. emcee (``vectorize=True`` on a jitted, vmapped log-probability) started in
   a small ball around each mode within Δχ² < 10 of the best, run in blocks
   until the chain is ≥ 50 integrated autocorrelation times τ long (or
   ``max_steps``);
4. summary (medians, 50 % and 90 % intervals, pole credible radii), samples
   (Parquet), a corner plot and the data with the fitted model.

Priors (MCMC coordinates, :data:`jaxlc.inference.MC_NAMES`): isotropic pole
(uniform λ and sin β), log-uniform period within a factor 3 of the mode's,
uniform phase, uniform Δm in [−10, 10] mag, log-uniform noise in
[10⁻³, 2] mag.
"""

from __future__ import annotations

import dataclasses
import math
import time

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from jaxlc import inference as inf
from jaxlc.errors import JaxlcError

NOISE_BOUNDS_MAG = (1e-3, 2.0)
DMAG_BOUNDS = (-10.0, 10.0)
PERIOD_PRIOR_FACTOR = 3.0


@dataclasses.dataclass(frozen=True)
class FitSettings:
    """Knobs of :func:`fit_spin` (defaults meet the issue's ≥ 1,000 starts and ≥ 50 τ)."""

    n_starts: int = 1024
    search_samples: int = 100
    search_steps: int = 15
    walkers: int = 16
    min_tau: float = 50.0
    max_steps: int = 6000
    block_steps: int = 250
    mcmc_modes: int = 2
    mode_delta_chi2: float = 10.0
    subsamples: int = 1
    seed: int = 0
    period_s: float | None = None  # skip the periodogram: seed from this period

    def __post_init__(self):
        if self.n_starts < 1:
            raise JaxlcError(f"n_starts = {self.n_starts} must be ≥ 1")
        if self.walkers < 2 * inf.N_MC:
            raise JaxlcError(f"walkers = {self.walkers} must be ≥ {2 * inf.N_MC} (2 × parameters)")
        if self.max_steps < self.block_steps:
            raise JaxlcError(f"max_steps = {self.max_steps} must be ≥ {self.block_steps}")


def log_prob_fn(model: inf.SpinModel, data: inf.FitData, ln_period_center: float):
    """Jitted, vmapped log-posterior of MCMC coordinates: (W, 6) → (W,) numpy."""
    arrays = inf.data_arrays(data)
    mag = jnp.asarray(inf.soft_clip(data.mag, data.limit_mag), jnp.float32)
    err2 = jnp.asarray(data.mag_err**2, jnp.float32)
    lnp_lo = ln_period_center - math.log(PERIOD_PRIOR_FACTOR)
    lnp_hi = ln_period_center + math.log(PERIOD_PRIOR_FACTOR)
    lo_s, hi_s = (math.log(b) for b in NOISE_BOUNDS_MAG)

    def one(theta):
        theta = theta.astype(jnp.float32)
        inside = (
            (jnp.abs(theta[1]) <= 1)
            & (theta[2] >= lnp_lo)
            & (theta[2] <= lnp_hi)
            & (theta[4] >= DMAG_BOUNDS[0])
            & (theta[4] <= DMAG_BOUNDS[1])
            & (theta[5] >= lo_s)
            & (theta[5] <= hi_s)
        )
        m = model.magnitudes(inf.mc_to_lm(theta), *arrays)
        var = err2 + jnp.exp(2 * theta[5])
        ll = -0.5 * jnp.sum((m - mag) ** 2 / var + jnp.log(2 * jnp.pi * var))
        return jnp.where(inside & jnp.isfinite(ll), ll, -jnp.inf)

    f = jax.jit(jax.vmap(one))

    def log_prob(thetas: np.ndarray) -> np.ndarray:
        return np.asarray(f(jnp.asarray(thetas, jnp.float32)), np.float64)

    return log_prob


def initial_ball(
    model: inf.SpinModel, data: inf.FitData, mode: inf.Mode, walkers: int, rng: np.random.Generator
) -> np.ndarray:
    """(walkers, 6) MCMC starts drawn from the Laplace approximation at a mode.

    Covariance σ² (JᵀJ)⁻¹ of the first five coordinates from the model's
    Jacobian (σ: the mode's noise, or the data errors); ln σ gets 1/√(2N).
    Starting in equilibrium keeps the burn-in, and τ, short.
    """
    noise = max(mode.noise_mag, 2 * NOISE_BOUNDS_MAG[0])
    centre = inf.lm_to_mc(mode.theta_lm, noise)
    arrays = inf.data_arrays(data)
    sigma = np.sqrt(data.mag_err**2 + noise**2)

    def mags(x5):
        th = jnp.concatenate([x5, jnp.asarray([np.log(noise)], jnp.float32)])
        return model.magnitudes(inf.mc_to_lm(th), *arrays)

    jac = np.asarray(jax.jacfwd(mags)(jnp.asarray(centre[:5], jnp.float32)), np.float64)
    jw = jac / sigma[:, None]
    fisher = jw.T @ jw + np.diag([1e-6, 1e-6, 1e-12, 1e-6, 1e-6])
    try:
        cov = np.linalg.inv(fisher)
        chol = np.linalg.cholesky(0.5 * (cov + cov.T))
    except np.linalg.LinAlgError:
        chol = np.diag([0.01, 0.005, 1e-5, 0.01, 0.005])
    p0 = np.empty((walkers, inf.N_MC))
    p0[:, :5] = centre[:5] + rng.standard_normal((walkers, 5)) @ chol.T
    p0[:, 5] = centre[5] + rng.standard_normal(walkers) / math.sqrt(2 * data.n)
    p0[:, 1] = np.clip(p0[:, 1], -0.999999, 0.999999)
    return p0


def run_emcee(
    model: inf.SpinModel,
    data: inf.FitData,
    mode: inf.Mode,
    settings: FitSettings,
    rng: np.random.Generator,
    log=None,
) -> dict:
    """Sample around one mode until ≥ ``min_tau`` τ (or ``max_steps``).

    Returns:
        dict with ``chain`` (steps, walkers, 6), ``log_prob`` (steps, walkers),
        ``tau`` (6,), ``steps``, ``burn``, ``acceptance``, ``chain_length_tau``,
        ``converged``, ``seconds``.
    """
    import emcee

    log = log or (lambda msg: None)
    lp = log_prob_fn(model, data, float(mode.theta_lm[3]))
    p0 = initial_ball(model, data, mode, settings.walkers, rng)
    if not np.all(np.isfinite(lp(p0))):
        raise JaxlcError("emcee: the starting ball has points outside the prior (report this)")
    sampler = emcee.EnsembleSampler(
        settings.walkers,
        inf.N_MC,
        lp,
        vectorize=True,
    )
    # reproducible: emcee draws from its own RandomState
    sampler.random_state = np.random.RandomState(int(rng.integers(2**31))).get_state()
    t0 = time.perf_counter()
    state = p0
    tau = np.full(inf.N_MC, np.inf)
    steps = 0
    while steps < settings.max_steps:
        state = sampler.run_mcmc(state, settings.block_steps, progress=False)
        steps += settings.block_steps
        # τ from the second half (the first half is burn-in)
        tau = emcee.autocorr.integrated_time(
            sampler.get_chain(discard=steps // 2), tol=0, quiet=True
        )
        length = steps / np.max(tau)
        log(f"  emcee: {steps} steps, τ = {np.round(tau, 1)}, length {length:.0f} τ")
        if length >= settings.min_tau and steps // 2 >= 10 * np.max(tau):
            break
    burn = steps // 2
    return {
        "chain": sampler.get_chain(discard=burn),
        "log_prob": sampler.get_log_prob(discard=burn),
        "tau": tau,
        "steps": steps,
        "burn": burn,
        "acceptance": float(np.mean(sampler.acceptance_fraction)),
        "chain_length_tau": float(steps / np.max(tau)),
        "converged": bool(steps / np.max(tau) >= settings.min_tau),
        "seconds": time.perf_counter() - t0,
    }


def samples_table(chain: np.ndarray, log_prob: np.ndarray, mode_id: int) -> pd.DataFrame:
    """Flatten a chain (steps, walkers, 6) into a table in user units."""
    steps, walkers, _ = chain.shape
    flat = chain.reshape(-1, inf.N_MC)
    lm = inf.mc_to_lm(flat)
    ra, dec = inf.pole_radec_deg(lm)
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


def pole_unit(samples: pd.DataFrame) -> np.ndarray:
    ra, dec = np.radians(samples["pole_ra_deg"]), np.radians(samples["pole_dec_deg"])
    return np.column_stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)])


def interval_summary(samples: pd.DataFrame) -> dict:
    """Medians, 50 % and 90 % central intervals, and pole credible radii."""
    out = {}
    for col in ("period_s", "dmag", "noise_mag", "pole_dec_deg"):
        q = np.percentile(samples[col], [5, 25, 50, 75, 95])
        out[col] = dict(zip(("p05", "p25", "median", "p75", "p95"), map(float, q), strict=True))
    u = pole_unit(samples)
    mean = u.mean(axis=0)
    mean /= np.linalg.norm(mean)
    ra = float(np.degrees(np.mod(np.arctan2(mean[1], mean[0]), 2 * np.pi)))
    dec = float(np.degrees(np.arcsin(mean[2])))
    sep = inf.angle_between_deg(u, mean[None, :])
    # RA interval about the mean direction (wrapped)
    dra = (samples["pole_ra_deg"].to_numpy() - ra + 180.0) % 360.0 - 180.0
    q = np.percentile(dra, [5, 25, 50, 75, 95]) + ra
    out["pole_ra_deg"] = dict(
        zip(("p05", "p25", "median", "p75", "p95"), map(float, q % 360.0), strict=True)
    )
    ph = np.radians(samples["phase_deg"].to_numpy())
    ph_mean = math.atan2(np.mean(np.sin(ph)), np.mean(np.cos(ph)))
    dph = (np.degrees(ph - ph_mean) + 180.0) % 360.0 - 180.0
    qp = np.percentile(dph, [5, 25, 50, 75, 95]) + math.degrees(ph_mean)
    out["phase_deg"] = dict(
        zip(("p05", "p25", "median", "p75", "p95"), map(float, qp % 360.0), strict=True)
    )
    out["pole_mean"] = {"ra_deg": ra, "dec_deg": dec}
    out["pole_radius_deg"] = {
        "r50": float(np.percentile(sep, 50)),
        "r90": float(np.percentile(sep, 90)),
    }
    return out

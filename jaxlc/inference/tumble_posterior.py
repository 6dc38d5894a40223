"""The tumble fit's posterior: log-probability, a mode's Laplace ball, sample summaries.

Priors (MCMC coordinates, :mod:`jaxlc.inference.tumble_model`): the moment
coordinates uniform in :data:`LN_MOMENT_RATIO_PRIOR`; ω log-uniform in
magnitude within a factor :data:`~jaxlc.inference.spin_posterior.PERIOD_PRIOR_FACTOR`
of the mode's and uniform in direction; a uniform attitude (Haar measure in
the rotation-vector chart, |δ| < π); Δm uniform in ±10 mag; noise
log-uniform in [10⁻³, 2] mag.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from jaxlc.inference import mcmc
from jaxlc.inference.data import FitData, soft_clip
from jaxlc.inference.laplace import NOISE_BOUNDS_MAG, gauss_newton, noise_moments
from jaxlc.inference.offset_marginal import OffsetConditionals, integrate_offset
from jaxlc.inference.spin_posterior import DMAG_BOUNDS, PERIOD_PRIOR_FACTOR
from jaxlc.inference.tumble_model import (
    N_TUMBLE_MC,
    TumbleModel,
    angular_momentum_radec_deg,
    lm_to_mc,
    mc_to_lm,
    motion_invariants,
    state_of,
)
from jaxlc.inference.tumble_search import TumbleMode
from jaxlc.rendering.kernel import time_chunk
from jaxlc.xla import filter_jit

#: Prior range of the moment coordinates x (ln S_i/S_z = 6 tanh(x/6): ratios within
#: 1/300 … 300; an axisymmetric body's light curve barely constrains them).
LN_MOMENT_RATIO_PRIOR = (-10.0, 10.0)


#: Index of Δm among the tumble's ten MCMC coordinates; the other nine are sampled.
DMAG_MC = 8


@filter_jit
def _marginal_log_prob(model: TumbleModel, mag, err2, q_mode, bounds, x9):
    """(W,) log-posterior of (W, 9) MCMC coordinates about ``q_mode`` with Δm integrated
    out, and Δm's conditional mean and sd there
    (:func:`~jaxlc.inference.offset_marginal.integrate_offset`)."""
    chunk = time_chunk(model.obj.n_facets * x9.shape[0])

    def one(x):
        theta = jnp.concatenate([x[:DMAG_MC], jnp.zeros(1, x.dtype), x[DMAG_MC:]])
        ln_rate = 0.5 * jnp.log(jnp.sum(theta[2:5] ** 2))
        angle = jnp.sqrt(jnp.sum(theta[5:8] ** 2) + 1e-30)
        raw = model.unclipped_magnitudes(mc_to_lm(theta, q_mode), chunk=chunk)
        ll, mean, sd = integrate_offset(raw, mag, err2, theta[9], model.limit_mag)
        inside = (
            jnp.all(theta[0:2] >= bounds[0, 0])
            & jnp.all(theta[0:2] <= bounds[1, 0])
            & (ln_rate >= bounds[0, 1])
            & (ln_rate <= bounds[1, 1])
            & (angle < jnp.pi)
            & (mean >= bounds[0, 2])
            & (mean <= bounds[1, 2])
            & (theta[9] >= bounds[0, 3])
            & (theta[9] <= bounds[1, 3])
        )
        # log-uniform |ω| (density ∝ |ω|⁻³ in ℝ³); Haar measure in the rotation vector
        prior = -3.0 * ln_rate + 2.0 * jnp.log(jnp.sin(0.5 * angle) / (0.5 * angle))
        return jnp.where(inside & jnp.isfinite(ll), ll + prior, -jnp.inf), mean, sd

    return jax.vmap(one)(x9)


class MarginalLogProb(OffsetConditionals):
    """The vectorised nine-coordinate log posterior of a mode, (W, 9) → (W,) numpy (the
    ten MCMC coordinates less Δm, integrated out; module priors), that keeps Δm's
    conditional (mean, sd) of every point it evaluated (for
    :func:`~jaxlc.inference.offset_marginal.with_offset`)."""

    def __init__(self, model: TumbleModel, data: FitData, centre: np.ndarray, q_mode):
        super().__init__(DMAG_MC)
        self.model = model
        self.mag = jnp.asarray(soft_clip(data.mag, data.limit_mag), jnp.float32)
        self.err2 = jnp.asarray(data.mag_err**2, jnp.float32)
        ln_rate = 0.5 * math.log(float(np.sum(centre[2:5] ** 2)))
        factor = math.log(PERIOD_PRIOR_FACTOR)
        noise = tuple(math.log(b) for b in NOISE_BOUNDS_MAG)
        self.bounds = jnp.asarray(
            [
                [LN_MOMENT_RATIO_PRIOR[0], ln_rate - factor, DMAG_BOUNDS[0], noise[0]],
                [LN_MOMENT_RATIO_PRIOR[1], ln_rate + factor, DMAG_BOUNDS[1], noise[1]],
            ],
            jnp.float32,
        )
        self.q_mode = jnp.asarray(q_mode, jnp.float32)

    def evaluate(self, x9: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(W,) log posterior of (W, 9) points and Δm's conditional mean and sd there
        (nothing remembered)."""
        ll, d, sd = _marginal_log_prob(
            self.model, self.mag, self.err2, self.q_mode, self.bounds, jnp.asarray(x9, jnp.float32)
        )
        return np.asarray(ll, np.float64), np.asarray(d), np.asarray(sd)

    def __call__(self, x9: np.ndarray) -> np.ndarray:
        x9 = np.ascontiguousarray(x9, np.float64)
        ll, d, sd = self.evaluate(x9)
        self.remember(x9, d, sd)
        return ll


@filter_jit
def _value_and_jacobian(model: TumbleModel, q_mode, x9):
    def mags(x):
        m = model.magnitudes(mc_to_lm(jnp.concatenate([x, jnp.zeros(1, x.dtype)]), q_mode))
        return m, m

    jac, value = jax.jacfwd(mags, has_aux=True)(x9)
    return value, jac


def initial_ball(model: TumbleModel, data: FitData, mode: TumbleMode, walkers: int, rng):
    """Walkers (W, 10) from the Laplace approximation at a mode, its centre (10,), the
    covariance (10, 10) and q_mode.

    The centre is first moved to the optimum of ``model`` (the sampled model's
    sub-exposures are chosen at the mode) by damped Gauss–Newton
    (:func:`~jaxlc.inference.laplace.gauss_newton`), weighting the residuals by the
    data's errors and the excess scatter at the mode (at least the prior's floor);
    covariance σ² (JᵀJ)⁻¹ of the first nine coordinates;
    ln σ gets the mean and variance of its own posterior given the residuals
    (:func:`~jaxlc.inference.laplace.noise_moments`).
    """
    centre, q_mode = lm_to_mc(mode.theta_lm, max(mode.noise_mag, NOISE_BOUNDS_MAG[0]))
    q = jnp.asarray(q_mode, jnp.float32)
    mag = soft_clip(data.mag, data.limit_mag)
    err2 = data.mag_err**2

    def at(x9):
        m, jac = _value_and_jacobian(model, q, jnp.asarray(x9, jnp.float32))
        return np.asarray(m, np.float64) - mag, np.asarray(jac, np.float64)

    def sigma_of(r):  # the data's errors and the residuals' excess scatter
        noise = math.sqrt(max(float(np.mean(r**2 - err2)), NOISE_BOUNDS_MAG[0] ** 2))
        return np.sqrt(err2 + noise**2)

    first = at(centre[:9])  # σ from the mode's own residuals, held through the steps
    x9, r, jac = gauss_newton(at, centre[:9].copy(), sigma_of(first[0]), start=first)
    sigma = sigma_of(r)
    centre[:9] = x9
    centre[9], noise_var = noise_moments(r, err2, N_TUMBLE_MC - 1)
    jw = jac / sigma[:, None]
    cov = np.zeros((N_TUMBLE_MC, N_TUMBLE_MC))
    try:
        c9 = np.linalg.inv(jw.T @ jw + 1e-8 * np.eye(9))
        c9 = 0.5 * (c9 + c9.T)
        np.linalg.cholesky(c9)
        cov[:9, :9] = c9
    except np.linalg.LinAlgError:
        cov[:9, :9] = np.diag(np.full(9, 1e-3))
    cov[9, 9] = noise_var
    p0 = centre + rng.standard_normal((walkers, N_TUMBLE_MC)) @ np.linalg.cholesky(cov).T
    return p0, centre, cov, q_mode


def samples_table(chain: np.ndarray, log_prob: np.ndarray, mode_id: int, q_mode, rate_ref):
    """A chain (steps, walkers, 10) as a table of what the states mean (user units)."""
    steps, walkers, _ = chain.shape
    flat = chain.reshape(-1, N_TUMBLE_MC)
    lm = mc_to_lm(flat, np.asarray(q_mode, np.float64))
    inertia, omega, q = state_of(lm, rate_ref)
    inv = motion_invariants(inertia, omega)
    ra, dec = angular_momentum_radec_deg(inertia, omega, q)
    return pd.DataFrame(
        {
            "mode": mode_id,
            "step": np.repeat(np.arange(steps), walkers),
            "walker": np.tile(np.arange(walkers), steps),
            "precession_period_s": inv["precession_period_s"],
            "body_period_s": inv["body_period_s"],
            "tumble_mode": np.where(inv["sam"], "SAM", "LAM"),
            "excitation": inv["excitation"],
            "l_ra_deg": ra,
            "l_dec_deg": dec,
            "inertia_x_over_z": inertia[:, 0] / inertia[:, 2],
            "inertia_y_over_z": inertia[:, 1] / inertia[:, 2],
            "dmag": flat[:, 8],
            "noise_mag": np.exp(flat[:, 9]),
            "log_prob": log_prob.reshape(-1),
        }
    )


def interval_summary(samples: pd.DataFrame) -> dict:
    """Medians and 50 %/90 % intervals, L's mean direction and credible radii, and the
    share of samples in each tumbling mode."""
    out = {
        col: mcmc.percentiles(samples[col])
        for col in (
            "precession_period_s",
            "body_period_s",
            "excitation",
            "inertia_x_over_z",
            "inertia_y_over_z",
            "dmag",
            "noise_mag",
        )
    }
    out.update(mcmc.direction_summary(samples, "l_ra_deg", "l_dec_deg", "l"))
    out["sam_fraction"] = float(np.mean(samples["tumble_mode"] == "SAM"))
    return out

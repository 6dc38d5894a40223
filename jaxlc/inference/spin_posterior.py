"""The spin fit's posterior, sampled with the magnitude offset Δm integrated out.

Δm enters every model magnitude additively, m = clip(m₀(θ) + Δm), so given the
other five MCMC coordinates (pole λ, sin β, ln P, φ, ln σ) its likelihood is a
Gaussian in Δm where the faint clip is inactive, and close to one where it is
not. :class:`MarginalLogProb` gives the five-coordinate posterior with Δm
integrated out (a Gauss–Hermite quadrature, exact for the Gaussian case) and
remembers Δm's conditional mean and spread at each point it evaluated;
:func:`with_dmag` turns a five-coordinate chain back into the six MCMC
coordinates by drawing Δm from a Gaussian with those moments
(Rao–Blackwellised: exact samples of the joint posterior where the clip is
inactive).

Why: Δm is what made the posterior curved. On an S5 SBC case (#42) the pole,
the phase and Δm trade off along a flat ridge on which Δm is a *quadratic*
function of the pole (a linear fit leaves 5× the residual of a quadratic); the
independence proposal's acceptance fell to 0.1 even when fitted to a long
chain, τ grew to hundreds of steps and the pole intervals came out too narrow.
Without Δm the five remaining coordinates are close to Gaussian.

Priors (MCMC coordinates, :data:`jaxlc.inference.model.MC_NAMES`): isotropic pole
(uniform λ and sin β), log-uniform period within a factor
:data:`PERIOD_PRIOR_FACTOR` of the mode's (at most the span), uniform phase,
uniform Δm in :data:`DMAG_BOUNDS` (its conditional mean must lie inside),
log-uniform noise in :data:`~jaxlc.inference.laplace.NOISE_BOUNDS_MAG`.

Example:
    >>> lp = MarginalLogProb(model, data, ln_period_center)
    >>> lp(x5)                      # (W, 5) → (W,) ln posterior
    >>> chain6, lp6 = with_dmag(chain5, log_prob5, lp, rng)
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc.inference.data import FitData, soft_clip
from jaxlc.inference.laplace import NOISE_BOUNDS_MAG
from jaxlc.inference.model import SpinModel, ln_period_ref, mc_to_lm, to_device
from jaxlc.rendering.kernel import time_chunk
from jaxlc.xla import filter_jit

DMAG_BOUNDS = (-10.0, 10.0)
PERIOD_PRIOR_FACTOR = 3.0
#: Index of Δm among the six MCMC coordinates; the other five are sampled.
DMAG_MC = 4
SAMPLED_MC = (0, 1, 2, 3, 5)
#: Gauss–Hermite nodes and ln weights of the integral over Δm.
_NODES, _WEIGHTS = np.polynomial.hermite.hermgauss(12)
HERMITE_X = _NODES.astype(np.float32)
HERMITE_LOG_W = np.log(_WEIGHTS).astype(np.float32)


@filter_jit
def marginal_log_prob(model: SpinModel, mag, err2, bounds, x5):
    """(W,) ln posterior of (W, 5) coordinates with Δm integrated out, and Δm's
    conditional mean and standard deviation there ((W,) each, mag).

    Δm* is the weighted mean offset of data and unclipped model, then one
    Gauss–Newton step through the clip; the integral over Δm (and Δm's moments)
    is a 12-point Gauss–Hermite quadrature about Δm* with the scale of the
    curvature there, H = Σ w c'² (c' the clip's slope): exact for an unclipped
    curve, whose integrand is Gaussian. ``bounds``: (2, 3) of ln P (device),
    ln σ, Δm.
    """
    # Blocks of samples small enough that all walkers' (samples × facets) arrays
    # stay in the cache: with one curve's block size each walker costs 2× more
    # (S4, 12 walkers: 16 vs 7.6 ms per walker).
    chunk = time_chunk(model.obj.n_facets * x5.shape[0])
    lim = model.limit_mag

    def one(x):
        theta = jnp.concatenate([x[:4], jnp.zeros(1, x.dtype), x[4:]])
        raw = model.unclipped_magnitudes(mc_to_lm(theta), chunk=chunk)
        var = err2 + jnp.exp(2 * x[4])
        w = 1.0 / var
        d0 = jnp.sum(w * (mag - raw)) / jnp.sum(w)
        m0, c0 = jax.jvp(lambda d: soft_clip(raw + d, lim), (d0,), (jnp.ones_like(d0),))
        d = d0 + jnp.sum(w * c0 * (mag - m0)) / jnp.sum(w * c0**2)
        _, c = jax.jvp(lambda d: soft_clip(raw + d, lim), (d,), (jnp.ones_like(d),))
        s = jax.lax.rsqrt(jnp.sum(w * c**2))
        # Gauss–Hermite quadrature about (d, s): exact for a Gaussian integrand,
        # accurate where the clip skews it.
        dk = d + jnp.sqrt(2.0) * s * HERMITE_X  # (K,)
        mk = soft_clip(raw[None, :] + dk[:, None], lim)
        llk = -0.5 * jnp.sum((mk - mag[None, :]) ** 2 * w[None, :], axis=1)
        llk = llk + HERMITE_X**2 + HERMITE_LOG_W
        ll = jax.scipy.special.logsumexp(llk) + jnp.log(jnp.sqrt(2.0) * s)
        ll = ll - 0.5 * jnp.sum(jnp.log(2 * jnp.pi * var))
        pk = jax.nn.softmax(llk)
        mean = jnp.sum(pk * dk)
        sd = jnp.sqrt(jnp.sum(pk * (dk - mean) ** 2))
        lo, hi = bounds[0], bounds[1]
        inside = (
            (jnp.abs(x[1]) <= 1)
            & (x[2] >= lo[0])
            & (x[2] <= hi[0])
            & (x[4] >= lo[1])
            & (x[4] <= hi[1])
            & (mean >= lo[2])
            & (mean <= hi[2])
        )
        return jnp.where(inside & jnp.isfinite(ll), ll, -jnp.inf), mean, sd

    return jax.vmap(one)(x5)


class MarginalLogProb:
    """The vectorised five-coordinate log posterior of a mode, (W, 5) → (W,) numpy,
    that keeps Δm's conditional (mean, sd) of every point it evaluated (for
    :func:`with_dmag`). The period prior: within a factor
    :data:`PERIOD_PRIOR_FACTOR` of ``ln_period_center``, at most the span."""

    def __init__(self, model: SpinModel, data: FitData, ln_period_center: float):
        self.model = model
        self.mag = jnp.asarray(soft_clip(data.mag, data.limit_mag), jnp.float32)
        self.err2 = jnp.asarray(data.mag_err**2, jnp.float32)
        ref = ln_period_ref(model)  # the device sees ln P relative to P_ref
        lnp = (
            ln_period_center - math.log(PERIOD_PRIOR_FACTOR),
            min(ln_period_center + math.log(PERIOD_PRIOR_FACTOR), math.log(data.span_s)),
        )
        noise = tuple(math.log(b) for b in NOISE_BOUNDS_MAG)
        self.bounds = jnp.asarray(
            [
                [lnp[0] - ref, noise[0], DMAG_BOUNDS[0]],
                [lnp[1] - ref, noise[1], DMAG_BOUNDS[1]],
            ],
            jnp.float32,
        )
        self.conditional: dict[bytes, tuple[float, float]] = {}

    def __call__(self, x5: np.ndarray) -> np.ndarray:
        x5 = np.ascontiguousarray(x5, np.float64)
        x6 = np.insert(x5, DMAG_MC, 0.0, axis=1)
        dev = to_device(self.model, x6, index=2)[:, list(SAMPLED_MC)]
        ll, d, sd = marginal_log_prob(self.model, self.mag, self.err2, self.bounds, dev)
        ll, d, sd = (np.asarray(a, np.float64) for a in (ll, d, sd))
        for row, di, si in zip(x5, d, sd, strict=True):
            self.conditional[row.tobytes()] = (float(di), float(si))
        return ll


def marginal_ball(p0: np.ndarray, centre: np.ndarray, cov: np.ndarray):
    """A six-coordinate Laplace ball (walkers, centre, covariance) without Δm: the
    Gaussian's marginal over the five sampled coordinates."""
    k = list(SAMPLED_MC)
    return np.ascontiguousarray(p0[:, k]), centre[k].copy(), cov[np.ix_(k, k)].copy()


def with_dmag(chain5: np.ndarray, log_prob5: np.ndarray, lp: MarginalLogProb, rng):
    """(steps, W, 5) chain and its marginal ln posterior → the (steps, W, 6) chain in
    MCMC coordinates with Δm drawn from its conditional at each sample, and the
    joint ln posterior there (marginal + ln N(Δm; mean, sd))."""
    flat = np.ascontiguousarray(chain5.reshape(-1, chain5.shape[-1]), np.float64)
    cond = np.array([lp.conditional[row.tobytes()] for row in flat])
    z = rng.standard_normal(len(flat))
    dmag = cond[:, 0] + cond[:, 1] * z
    log_prob = log_prob5.reshape(-1) - 0.5 * z**2 - np.log(cond[:, 1] * math.sqrt(2 * math.pi))
    chain6 = np.insert(flat, DMAG_MC, dmag, axis=1)
    return chain6.reshape(*chain5.shape[:-1], 6), log_prob.reshape(log_prob5.shape)

"""The spin fit's posterior, sampled with the magnitude offset Δm integrated out.

:class:`MarginalLogProb` gives the five-coordinate posterior (pole λ, sin β,
ln P, φ, ln σ) with Δm integrated out
(:func:`~jaxlc.inference.offset_marginal.integrate_offset`) and remembers Δm's
conditional mean and spread at each point it evaluated;
:func:`~jaxlc.inference.offset_marginal.with_offset` turns a five-coordinate
chain back into the six MCMC coordinates by drawing Δm from a Gaussian with
those moments.

Why: on an S5 SBC case (#42) the pole, the phase and Δm trade off along a flat
ridge on which Δm is a *quadratic* function of the pole (a linear fit leaves
5× the residual of a quadratic); the independence proposal's acceptance fell
to 0.1 even when fitted to a long chain, τ grew to hundreds of steps and the
pole intervals came out too narrow. Without Δm the five remaining coordinates
are close to Gaussian.

Priors (MCMC coordinates, :data:`jaxlc.inference.model.MC_NAMES`): isotropic pole
(uniform λ and sin β), log-uniform period within a factor
:data:`PERIOD_PRIOR_FACTOR` of the mode's (at most the span), uniform phase,
uniform Δm in :data:`DMAG_BOUNDS` (its conditional mean must lie inside),
log-uniform noise in :data:`~jaxlc.inference.laplace.NOISE_BOUNDS_MAG`.

Example:
    >>> lp = MarginalLogProb(model, data, ln_period_center)
    >>> lp(x5)                      # (W, 5) → (W,) ln posterior
    >>> chain6, lp6 = with_offset(chain5, log_prob5, lp, rng)
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc.inference.data import FitData, soft_clip
from jaxlc.inference.laplace import NOISE_BOUNDS_MAG
from jaxlc.inference.model import SpinModel, ln_period_ref, mc_to_lm, to_device
from jaxlc.inference.offset_marginal import OffsetConditionals, integrate_offset
from jaxlc.rendering.kernel import time_chunk
from jaxlc.xla import filter_jit

DMAG_BOUNDS = (-10.0, 10.0)
PERIOD_PRIOR_FACTOR = 3.0
#: Index of Δm among the six MCMC coordinates; the other five are sampled.
DMAG_MC = 4
SAMPLED_MC = (0, 1, 2, 3, 5)


@filter_jit
def marginal_log_prob(model: SpinModel, mag, err2, bounds, x5):
    """(W,) ln posterior of (W, 5) coordinates with Δm integrated out, and Δm's
    conditional mean and standard deviation there ((W,) each, mag;
    :func:`~jaxlc.inference.offset_marginal.integrate_offset`). ``bounds``: (2, 3)
    of ln P (device), ln σ, Δm.
    """
    # Blocks of samples small enough that all walkers' (samples × facets) arrays
    # stay in the cache: with one curve's block size each walker costs 2× more
    # (S4, 12 walkers: 16 vs 7.6 ms per walker).
    chunk = time_chunk(model.obj.n_facets * x5.shape[0])

    def one(x):
        theta = jnp.concatenate([x[:4], jnp.zeros(1, x.dtype), x[4:]])
        raw = model.unclipped_magnitudes(mc_to_lm(theta), chunk=chunk)
        ll, mean, sd = integrate_offset(raw, mag, err2, x[4], model.limit_mag)
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


class MarginalLogProb(OffsetConditionals):
    """The vectorised five-coordinate log posterior of a mode, (W, 5) → (W,) numpy,
    that keeps Δm's conditional (mean, sd) of every point it evaluated (for
    :func:`~jaxlc.inference.offset_marginal.with_offset`). The period prior: within a factor
    :data:`PERIOD_PRIOR_FACTOR` of ``ln_period_center``, at most the span."""

    def __init__(self, model: SpinModel, data: FitData, ln_period_center: float):
        super().__init__(DMAG_MC)
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

    def __call__(self, x5: np.ndarray) -> np.ndarray:
        x5 = np.ascontiguousarray(x5, np.float64)
        x6 = np.insert(x5, DMAG_MC, 0.0, axis=1)
        dev = to_device(self.model, x6, index=2)[:, list(SAMPLED_MC)]
        ll, d, sd = marginal_log_prob(self.model, self.mag, self.err2, self.bounds, dev)
        self.remember(x5, d, sd)
        return np.asarray(ll, np.float64)

"""The magnitude offset Δm integrated out of a fit's likelihood, for any fit model.

Δm enters every model magnitude additively, m = clip(m₀(θ) + Δm), so given the
other coordinates its likelihood is a Gaussian in Δm where the faint clip is
inactive, and close to one where it is not. :func:`integrate_offset` gives
ln ∫ L dΔm (a Gauss–Hermite quadrature, exact for the Gaussian case) and Δm's
conditional mean and spread; :class:`OffsetConditionals` remembers those
moments at every point a sampler evaluated, and :func:`with_offset` puts Δm
back into a chain by drawing it from them (Rao–Blackwellised: exact samples of
the joint posterior where the clip is inactive).

Why: Δm is what curves a fit's posterior. It trades off against every
coordinate that moves the mean brightness (a spin's pole, a tumble's moments
and attitude) along ridges on which it is a non-linear function of them; without
it the remaining coordinates are close to Gaussian. The spin fit
(:mod:`jaxlc.inference.spin_posterior`) and the tumble fit
(:mod:`jaxlc.inference.tumble_posterior`) both sample this marginal.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc.inference.data import soft_clip

#: Gauss–Hermite nodes and ln weights of the integral over Δm.
_NODES, _WEIGHTS = np.polynomial.hermite.hermgauss(12)
HERMITE_X = _NODES.astype(np.float32)
HERMITE_LOG_W = np.log(_WEIGHTS).astype(np.float32)


def integrate_offset(raw, mag, err2, ln_noise, limit_mag):
    """ln ∫ L(Δm) dΔm over the offset of one model curve, and Δm's conditional
    mean and standard deviation (scalars, mag); jittable, for ``vmap`` over points.

    Δm* is the weighted mean offset of data and unclipped model, then one
    Gauss–Newton step through the clip; the integral (and Δm's moments) is a
    12-point Gauss–Hermite quadrature about Δm* with the scale of the curvature
    there, H = Σ w c'² (c' the clip's slope): exact for an unclipped curve,
    whose integrand is Gaussian.

    Args:
        raw: (N,) model magnitudes before the faint clip, without Δm.
        mag: (N,) observed magnitudes, softly clipped at ``limit_mag``.
        err2: (N,) squared magnitude errors of the data.
        ln_noise: ln of the extra noise σ (mag), added in quadrature.
        limit_mag: faint clipping level.

    Returns:
        (ln L marginal, mean Δm, sd Δm); the ln L includes the Gaussian's
        normalisation Σ ln 2π(err² + σ²).
    """
    var = err2 + jnp.exp(2 * ln_noise)
    w = 1.0 / var
    d0 = jnp.sum(w * (mag - raw)) / jnp.sum(w)

    def clipped(d):
        return soft_clip(raw + d, limit_mag)

    m0, c0 = jax.jvp(clipped, (d0,), (jnp.ones_like(d0),))
    d = d0 + jnp.sum(w * c0 * (mag - m0)) / jnp.sum(w * c0**2)
    _, c = jax.jvp(clipped, (d,), (jnp.ones_like(d),))
    s = jax.lax.rsqrt(jnp.sum(w * c**2))
    # Gauss–Hermite quadrature about (d, s): exact for a Gaussian integrand,
    # accurate where the clip skews it.
    dk = d + jnp.sqrt(2.0) * s * HERMITE_X  # (K,)
    mk = soft_clip(raw[None, :] + dk[:, None], limit_mag)
    llk = -0.5 * jnp.sum((mk - mag[None, :]) ** 2 * w[None, :], axis=1)
    llk = llk + HERMITE_X**2 + HERMITE_LOG_W
    ll = jax.scipy.special.logsumexp(llk) + jnp.log(jnp.sqrt(2.0) * s)
    ll = ll - 0.5 * jnp.sum(jnp.log(2 * jnp.pi * var))
    pk = jax.nn.softmax(llk)
    mean = jnp.sum(pk * dk)
    sd = jnp.sqrt(jnp.sum(pk * (dk - mean) ** 2))
    return ll, mean, sd


class OffsetConditionals:
    """Δm's conditional (mean, sd) of every point a marginal log posterior evaluated,
    keyed by the point's float64 bytes (for :func:`with_offset`).

    Attributes:
        offset_index: where Δm goes back among the full coordinates.
        conditional: {point bytes: (mean, sd)}.
    """

    def __init__(self, offset_index: int):
        self.offset_index = offset_index
        self.conditional: dict[bytes, tuple[float, float]] = {}

    def remember(self, points: np.ndarray, mean, sd) -> None:
        """Store the moments of (W, D) float64 ``points``."""
        for row, di, si in zip(points, np.asarray(mean), np.asarray(sd), strict=True):
            self.conditional[row.tobytes()] = (float(di), float(si))


def marginal_ball(p0: np.ndarray, centre: np.ndarray, cov: np.ndarray, offset_index: int):
    """A Laplace ball (walkers, centre, covariance) without the coordinate
    ``offset_index``: the Gaussian's marginal over the others."""
    k = [i for i in range(p0.shape[1]) if i != offset_index]
    return np.ascontiguousarray(p0[:, k]), centre[k].copy(), cov[np.ix_(k, k)].copy()


def with_offset(chain: np.ndarray, log_prob: np.ndarray, lp: OffsetConditionals, rng):
    """(steps, W, D) chain and its marginal ln posterior → the (steps, W, D + 1) chain
    with Δm inserted at ``lp.offset_index``, drawn from its conditional at each
    sample, and the joint ln posterior there (marginal + ln N(Δm; mean, sd))."""
    shape = log_prob.shape
    flat = np.ascontiguousarray(chain.reshape(-1, chain.shape[-1]), np.float64)
    cond = np.array([lp.conditional[row.tobytes()] for row in flat])
    z = rng.standard_normal(len(flat))
    dmag = cond[:, 0] + cond[:, 1] * z
    log_prob = log_prob.reshape(-1) - 0.5 * z**2 - np.log(cond[:, 1] * math.sqrt(2 * math.pi))
    full = np.insert(flat, lp.offset_index, dmag, axis=1)
    return full.reshape(*chain.shape[:-1], chain.shape[-1] + 1), log_prob.reshape(shape)

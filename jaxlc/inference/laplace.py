"""The Laplace approximation of a spin-fit mode: its centre, Gaussian ball and evidence.

Each mode the MCMC samples (:mod:`jaxlc.inference.mcmc`) starts from here:
:func:`recentre` moves the mode found on one model to its optimum on the model
sampled (Levenberg–Marquardt on the model's Jacobian), :func:`initial_ball` draws the
walkers from the Gaussian σ² (JᵀJ)⁻¹ there, and :func:`laplace_log_evidence`
turns the samples back into the mode's evidence for the mixture weights.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc.inference.batched_solve import promised_reduction
from jaxlc.inference.data import FitData, soft_clip
from jaxlc.inference.model import N_MC, SpinModel, lm_to_mc, mc_to_lm, to_device
from jaxlc.inference.search import Mode
from jaxlc.xla import filter_jit

#: Bounds of the noise coordinate's prior (mag).
NOISE_BOUNDS_MAG = (1e-3, 2.0)


@filter_jit
def value_and_jacobian(model: SpinModel, x5):
    """(N,) magnitudes and (N, 5) ∂m/∂θ_mc[:5] (the noise coordinate does not enter them)."""

    def mags(x):
        m = model.magnitudes(mc_to_lm(jnp.concatenate([x, jnp.zeros(1, x.dtype)])))
        return m, m

    jac, value = jax.jacfwd(mags, has_aux=True)(x5)
    return value, jac


#: Cap on the damped Gauss–Newton steps that move a mode's centre to the sampled
#: model's optimum. A tumble's weak moment-ratio ridge took 63 steps to converge
#: (each lowering χ² by 0.1–16); 6 steps left its centre 4 σ off the posterior's mean.
RECENTRE_STEPS = 200
#: A step that does not lower χ² is retried with the damping raised tenfold, up to this
#: many times.
RECENTRE_DAMPING_TRIES = 8
#: The damping λ (relative to diag JᵀJ) of the first step, and its floor.
RECENTRE_DAMPING = (1e-3, 1e-9)
#: Recentring stops once a step lowers χ² by less than this.
RECENTRE_TOLERANCE_CHI2 = 0.01


def gauss_newton(at, x: np.ndarray, sigma: np.ndarray, project=None, start=None):
    """Levenberg–Marquardt from ``x`` (P,): minimise Σ (r/σ)² with ``at(x)`` → (r (N,),
    ∂r/∂x (N, P)) and ``sigma`` (N,) held fixed. Each step solves the Gauss–Newton
    system damped by λ diag(JᵀJ); a step that does not lower χ² is retried with λ
    raised tenfold (:data:`RECENTRE_DAMPING_TRIES` times), a step that does lowers λ
    tenfold. It stops when no damping helps, when χ² falls by less than
    :data:`RECENTRE_TOLERANCE_CHI2` or the undamped step of the linearised residuals
    promises less (no step is then evaluated), or after :data:`RECENTRE_STEPS` steps. ``project``
    maps a trial point into the coordinates' domain; ``start``: ``at(x)`` when the
    caller has it already (not evaluated again).

    A full step from a point near a curved optimum can overshoot: a tumble fit's first
    step raised χ² 561 → 600. Six halved Gauss–Newton steps then left another tumble
    fit's centre 4 σ along a curved ridge from the posterior's mean (χ² 600 → 575, the
    optimum 466): its chain accepted 4 % of the proposals, 8 τ in 300 steps. Damped
    steps to convergence reach it: acceptance 0.38, 31 τ
    (``tests/test_tumble_fit.py``'s round trip).

    Returns:
        The point, its residuals and Jacobian.
    """
    project = project or (lambda y: y)
    r, jac = at(x) if start is None else start
    chi2 = float(np.sum((r / sigma) ** 2))
    lam, floor = RECENTRE_DAMPING
    for _ in range(RECENTRE_STEPS):
        jw, rw = jac / sigma[:, None], r / sigma
        scale = np.sqrt(np.maximum(np.sum(jw**2, axis=0), 1e-30))
        # converged when even the undamped step promises less than the tolerance
        # (no point is then evaluated: in a fit each evaluation is a Jacobian)
        if float(promised_reduction(jw, rw, np)) < RECENTRE_TOLERANCE_CHI2:
            break
        for _try in range(RECENTRE_DAMPING_TRIES + 1):
            damped = np.vstack([jw, np.diag(math.sqrt(lam) * scale)])
            step, *_ = np.linalg.lstsq(damped, -np.append(rw, np.zeros(x.size)), rcond=None)
            trial = project(x + step)
            r2, jac2 = at(trial)
            chi2_2 = float(np.sum((r2 / sigma) ** 2))
            if np.isfinite(chi2_2) and chi2_2 < chi2:
                lam = max(lam / 10.0, floor)
                break
            lam *= 10.0
        else:
            break
        x, r, jac, gain, chi2 = trial, r2, jac2, chi2 - chi2_2, chi2_2
        if gain < RECENTRE_TOLERANCE_CHI2:
            break
    return x, r, jac


def recentre(model: SpinModel, data: FitData, centre: np.ndarray, sigma: np.ndarray):
    """The mode's optimum on the model sampled (:func:`gauss_newton` from ``centre``, MCMC
    coordinates), which may differ a little from the model it was found on (e.g.
    sub-exposures chosen at the mode). Returns the centre, its magnitudes' residuals
    and the Jacobian there."""
    mag = soft_clip(data.mag, data.limit_mag)

    def at(x5):
        c = np.concatenate([x5, centre[5:]])
        m, j = value_and_jacobian(model, to_device(model, c, index=2)[:5])
        return np.asarray(m, np.float64) - mag, np.asarray(j, np.float64)

    def project(x5):
        return np.concatenate([x5[:1], np.clip(x5[1:2], -0.999999, 0.999999), x5[2:]])

    x5, r, jac = gauss_newton(at, centre[:5].copy(), sigma, project)
    return np.concatenate([x5, centre[5:]]), r, jac


def noise_moments(residuals: np.ndarray, err2: np.ndarray, n_params: int) -> tuple[float, float]:
    """Mean and variance of the noise coordinate ln σ (σ: extra noise, mag, added to
    the data's errors in quadrature) under its log-uniform prior in
    :data:`NOISE_BOUNDS_MAG`, given a mode's residuals with its other coordinates
    held: the one-dimensional posterior on a grid (a coarse pass over the prior,
    then a fine one over where it is not negligible).

    Where the noise dominates the errors this is ln σ̂ ± 1/√(2N), the Laplace
    value; where the data's errors explain the residuals it is a broad plateau
    from the prior's floor up to the largest σ the residuals allow (σ ≪ error is
    invisible) — about 2 in ln σ for 1,000 samples of 0.05 mag errors, where
    1/(2N) would give a proposal 100× too narrow in it (every walker that
    wandered up the plateau then stalled: a tumble fit accepted 5 % of its
    independence proposals). Against the floor (a noise-free curve) it is the
    exponential of scale 1/N there.

    Args:
        residuals: (N,) model − data magnitudes at the mode.
        err2: (N,) squared errors of the data (mag²; zeros for none).
        n_params: coordinates fitted besides the noise (the residuals' χ² is
            scaled by N/(N − n_params) for them).

    Returns:
        (mean, variance) of ln σ.
    """
    r2 = np.asarray(residuals, np.float64) ** 2
    n = r2.size
    r2 = r2 * n / max(n - n_params, 1)
    err2 = np.broadcast_to(np.asarray(err2, np.float64), r2.shape)
    lo, hi = (math.log(b) for b in NOISE_BOUNDS_MAG)

    def posterior(grid):
        ll = np.empty(grid.size)
        for k in range(0, grid.size, 32):  # (32, N) blocks
            v = err2[None, :] + np.exp(2 * grid[k : k + 32])[:, None]
            ll[k : k + 32] = -0.5 * np.sum(r2 / v + np.log(v), axis=1)
        p = np.exp(ll - ll.max())
        p[[0, -1]] *= 0.5  # trapezoid weights: the mass may pile against a bound
        return p / p.sum()

    coarse = np.linspace(lo, hi, 257)
    p = posterior(coarse)
    step = coarse[1] - coarse[0]
    keep = np.flatnonzero(p > 1e-12 * p.max())
    fine = np.linspace(max(coarse[keep[0]] - step, lo), min(coarse[keep[-1]] + step, hi), 513)
    p = posterior(fine)
    mean = float(np.sum(p * fine))
    var = float(np.sum(p * (fine - mean) ** 2))
    return mean, max(var, (fine[1] - fine[0]) ** 2)


def initial_ball(
    model: SpinModel, data: FitData, mode: Mode, walkers: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """MCMC starts drawn from the Laplace approximation at a mode.

    The centre is first moved to the mode's optimum on ``model`` (:func:`recentre`).
    Covariance σ² (JᵀJ)⁻¹ of the first five coordinates from the model's
    Jacobian (σ: the mode's noise, or the data errors); ln σ gets the mean and
    variance of its own posterior given the residuals (:func:`noise_moments`).
    Starting in equilibrium keeps the burn-in short.

    Returns:
        (walkers, 6) starts, the (6,) centre and the (6, 6) covariance.
    """
    floor = NOISE_BOUNDS_MAG[0]
    noise = max(mode.noise_mag, floor)
    sigma = np.sqrt(data.mag_err**2 + noise**2)
    centre, r, jac = recentre(model, data, lm_to_mc(mode.theta_lm, noise), sigma)
    if np.all(data.mag_err == 0):  # the noise of a curve without errors, on this model
        noise = max(math.sqrt(float(np.sum(r**2)) / max(data.n - N_MC + 1, 1)), floor)
        sigma = np.full(data.n, noise)
    centre[5], noise_var = noise_moments(r, data.mag_err**2, N_MC - 1)

    jw = jac / sigma[:, None]
    fisher = jw.T @ jw + np.diag([1e-6, 1e-6, 1e-12, 1e-6, 1e-6])
    cov = np.zeros((N_MC, N_MC))
    try:
        c5 = np.linalg.inv(fisher)
        np.linalg.cholesky(0.5 * (c5 + c5.T))
        cov[:5, :5] = 0.5 * (c5 + c5.T)
    except np.linalg.LinAlgError:
        cov[:5, :5] = np.diag([0.01, 0.005, 1e-5, 0.01, 0.005]) ** 2
    cov[5, 5] = noise_var
    p0 = centre + rng.standard_normal((walkers, N_MC)) @ np.linalg.cholesky(cov).T
    p0[:, 1] = np.clip(p0[:, 1], -0.999999, 0.999999)
    return p0, centre, cov


def laplace_log_evidence(samples: np.ndarray, log_prob: np.ndarray) -> float:
    """ln Z of one mode from its samples, treating the mode as Gaussian.

    ln Z ≈ ln p(θ̂) + ½ ln det(2π Σ) with Σ the samples' covariance and
    ln p(θ̂) = E[ln p] + d/2 (exact for a Gaussian). Mode weights are
    exp(ln Z) normalised over the sampled modes.
    """
    d = samples.shape[1]
    ok = np.isfinite(log_prob)
    sign, logdet = np.linalg.slogdet(2 * np.pi * np.cov(samples[ok], rowvar=False))
    if sign <= 0 or not np.any(ok):
        return float("-inf")
    return float(np.mean(log_prob[ok]) + 0.5 * d + 0.5 * logdet)

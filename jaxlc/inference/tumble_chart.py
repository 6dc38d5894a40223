"""A chart of the tumble posterior in which its two periods are coordinates.

A light curve pins both periods of a tumble (P_ψ and T_ω) to ~10⁻⁴ while the
moments of inertia and ω may wander far along the surface of constant
periods, and in the MCMC coordinates of :mod:`jaxlc.inference.tumble_model`
(moment coordinates x, ω in units of the reference rate) that surface is
curved: on the shipped round trip a quadratic in the other coordinates
explains 3× more of ω's spread than a linear one, so emcee's affine moves and
its Gaussian independence proposal crawl (τ ≈ 100–190 steps). Here the two
periods replace two of ω's three coordinates; in these coordinates a
quadratic explains nothing a linear fit does not (≤ 4 %).

Chart coordinates y (9; the MCMC's less Δm, integrated out):

* 0, 1: x, the moment coordinates, unchanged;
* 2, 3: ln P_ψ and ln T_ω less the mode's;
* 4: a, ω's component along ``n3`` (reference-rate units);
* 5–7: the rotation vector δ about the mode's attitude, unchanged;
* 8: ln noise, unchanged.

ω = a n3 + s₁ n1 + s₂ n2 with n1 along the mode's ω (the time scale), n2 the
direction of ω in which ln(T_ω / P_ψ) grows fastest, normal to n1, and
n3 = n1 × n2; (s₁, s₂) solve ln P_ψ, ln T_ω = y₂, y₃ by Newton's method
(float64). The density of y is the posterior's times |∂ω/∂y| = 1 / |det
∂(ln P_ψ, ln T_ω)/∂(s₁, s₂)|.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc.body.free_body import torque_free_motion
from jaxlc.inference.offset_marginal import OffsetConditionals
from jaxlc.inference.tumble_model import bounded_ratios, moments_from_ratios

CHART_NAMES = (
    "x_sx_over_sz",
    "x_sy_over_sz",
    "d_ln_precession_period",
    "d_ln_body_period",
    "omega_n3",
    "rotation_x_rad",
    "rotation_y_rad",
    "rotation_z_rad",
    "ln_noise_mag",
)
#: Newton steps of the inverse map; its residual must end below :data:`NEWTON_TOL`.
NEWTON_STEPS = 12
NEWTON_TOL = 1e-9
#: Largest Newton step relative to |ω| (keeps a far proposal from jumping modes).
MAX_STEP = 0.25
#: Smallest (|ω| |∂ ln(T_ω/P_ψ)/∂ω| normal to ω)² at the mode for the chart to be used
#: (near a uniform rotation T_ω/P_ψ hardly depends on ω's direction).
MIN_CONDITION = 1e-6


def ln_periods(x2, omega, rate_ref):
    """(ln P_ψ, ln T_ω) of moment coordinates (2,) and ω (3,) in reference-rate units."""
    inertia = moments_from_ratios(bounded_ratios(x2))
    m = torque_free_motion(inertia, omega * rate_ref)
    ln_t = jnp.log(m.period_s)
    ok = ~m.uniform & jnp.isfinite(ln_t)
    return jnp.stack([ln_t + jnp.log(2.0 * jnp.pi / m.step_rad), ln_t]), ok


def _to_chart(old, basis, ref, rate_ref):
    lnp, ok = ln_periods(old[0:2], old[2:5], rate_ref)
    y = jnp.concatenate([old[0:2], lnp - ref, (basis[2] @ old[2:5])[None], old[5:9]])
    return y, ok


def _from_chart(y, basis, ref, rate_ref, s_start):
    target = y[2:4] + ref
    omega = lambda s: y[4] * basis[2] + s[0] * basis[0] + s[1] * basis[1]  # noqa: E731

    def residual(s):  # the residual twice (value and aux) and whether the motion has periods
        lnp, ok = ln_periods(y[0:2], omega(s), rate_ref)
        return lnp - target, (lnp - target, ok)

    newton = jax.jacfwd(residual, has_aux=True)  # one trace: Jacobian, residual, ok

    def step(s, _):
        jac, (f, _ok) = newton(s)
        ds = -_solve2(jac, f)
        scale = MAX_STEP * jnp.linalg.norm(omega(s)) / (jnp.linalg.norm(ds) + 1e-300)
        return s + ds * jnp.minimum(1.0, scale), None

    s, _ = jax.lax.scan(step, s_start, None, length=NEWTON_STEPS)
    jac, (f, ok) = newton(s)
    old = jnp.concatenate([y[0:2], omega(s), y[5:9]])
    return old, -jnp.log(jnp.abs(_det2(jac))), ok & jnp.all(jnp.abs(f) < NEWTON_TOL)


def _det2(a):
    """Determinant of a 2 × 2 matrix, written out: a batched LAPACK call under ``vmap``
    waits on XLA's thread pool and can hang it (see :mod:`jaxlc.inference.householder`)."""
    return a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]


def _solve2(a, b):
    """x with a x = b for a 2 × 2 ``a`` (Cramer's rule; no LAPACK call, see :func:`_det2`)."""
    det = _det2(a)
    return jnp.stack([a[1, 1] * b[0] - a[0, 1] * b[1], a[0, 0] * b[1] - a[1, 0] * b[0]]) / det


_to_chart_many = jax.jit(jax.vmap(_to_chart, in_axes=(0, None, None, None)))
_from_chart_many = jax.jit(jax.vmap(_from_chart, in_axes=(0, None, None, None, None)))
_chart_jacobian = jax.jit(jax.jacfwd(lambda old, b, r, k: _to_chart(old, b, r, k)[0]))
_ratio_gradient = jax.jit(jax.grad(lambda w, x2, k: jnp.diff(ln_periods(x2, w, k)[0])[0]))


def _f64(x) -> jax.Array:
    return jnp.asarray(np.asarray(x, np.float64))


class PeriodChart:
    """The chart about a mode (module docstring): ``to_chart``, ``from_chart`` and the
    Jacobian, host float64, vectorised over rows (K, 9).

    Args:
        centre: (9,) the mode's MCMC coordinates less Δm.
        rate_ref_rad_s: the unit of the ω coordinates.

    Raises:
        ValueError: at a uniform rotation or where the periods barely depend on ω's
            direction (:data:`MIN_CONDITION`): sample in the plain coordinates there.
    """

    def __init__(self, centre: np.ndarray, rate_ref_rad_s: float):
        centre = np.asarray(centre, np.float64)
        self.rate_ref = float(rate_ref_rad_s)
        w = centre[2:5]
        n1 = w / np.linalg.norm(w)
        with jax.enable_x64(True):
            g = np.asarray(_ratio_gradient(_f64(w), _f64(centre[0:2]), self.rate_ref))
            ref, ok = ln_periods(_f64(centre[0:2]), _f64(w), self.rate_ref)
            ref = np.asarray(ref)
        g = g - (g @ n1) * n1
        conditioned = np.linalg.norm(g) * np.linalg.norm(w) >= math.sqrt(MIN_CONDITION)
        if not (bool(ok) and np.all(np.isfinite(g)) and conditioned):
            raise ValueError("the tumble's periods do not fix two of ω's coordinates here")
        n2 = g / np.linalg.norm(g)
        self.basis = np.stack([n1, n2, np.cross(n1, n2)])
        self.ref = ref
        self.s_centre = self.basis[:2] @ w
        self.centre = centre
        self.centre_y = self.to_chart(centre[None])[0]
        if not self.from_chart(self.centre_y[None])[2][0]:
            raise ValueError("the period chart does not invert at its own centre")

    def _args(self):
        return _f64(self.basis), _f64(self.ref), self.rate_ref

    def to_chart(self, old: np.ndarray) -> np.ndarray:
        """(K, 9) MCMC coordinates (less Δm) → (K, 9) chart coordinates (NaN where the
        motion is a uniform rotation)."""
        with jax.enable_x64(True):
            y, ok = _to_chart_many(_f64(np.atleast_2d(old)), *self._args())
            y = np.array(y)
        y[~np.asarray(ok)] = np.nan
        return y

    def from_chart(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(K, 9) chart coordinates → MCMC coordinates (K, 9), ln |∂old/∂y| (K,) and
        whether Newton's method converged (K,) bool."""
        with jax.enable_x64(True):
            old, log_jac, ok = _from_chart_many(
                _f64(np.atleast_2d(y)), *self._args(), _f64(self.s_centre)
            )
            old, log_jac, ok = np.array(old), np.array(log_jac), np.array(ok)
        ok = ok & np.isfinite(log_jac) & np.all(np.isfinite(old), axis=1)
        return old, log_jac, ok

    def jacobian(self, old: np.ndarray) -> np.ndarray:
        """(9, 9) ∂y/∂old at one point (9,)."""
        with jax.enable_x64(True):
            return np.asarray(_chart_jacobian(_f64(old), *self._args()))

    def ball(self, p0: np.ndarray, cov: np.ndarray):
        """A Laplace ball about the chart's centre in MCMC coordinates (walkers,
        covariance) in the chart: the walkers mapped (a walker that does not map goes
        to the centre), the centre and the covariance J Σ Jᵀ."""
        jac = self.jacobian(self.centre)
        y0 = self.to_chart(p0)
        y0[~np.all(np.isfinite(y0), axis=1)] = self.centre_y
        return y0, self.centre_y.copy(), jac @ cov @ jac.T


class ChartLogProb(OffsetConditionals):
    """A tumble posterior (:class:`~jaxlc.inference.tumble_posterior.MarginalLogProb`)
    in the period chart: (W, 9) chart coordinates → (W,) ln density of y (−∞ where the
    inverse map fails); Δm's conditionals remembered at the chart points."""

    def __init__(self, lp, chart: PeriodChart):
        super().__init__(lp.offset_index)
        self.lp, self.chart = lp, chart

    def __call__(self, y: np.ndarray) -> np.ndarray:
        y = np.ascontiguousarray(y, np.float64)
        old, log_jac, ok = self.chart.from_chart(y)
        old[~ok] = self.chart.centre  # a valid point, so the batch keeps its shape
        ll, d, sd = self.lp.evaluate(old)
        self.remember(y, d, sd)
        return np.where(ok, ll + log_jac, -np.inf)


def in_period_chart(lp, p0, centre, cov, rate_ref_rad_s: float, log=None):
    """A mode's posterior and Laplace ball in the period chart, or unchanged (with a
    log line) where the chart does not hold (:class:`PeriodChart`)."""
    try:
        chart = PeriodChart(centre, rate_ref_rad_s)
    except ValueError as err:
        (log or (lambda msg: None))(f"  sampling in the plain coordinates: {err}")
        return lp, p0, centre, cov
    return ChartLogProb(lp, chart), *chart.ball(p0, cov)


def plain_run(run: dict, lp) -> dict:
    """A run in all MCMC coordinates (:func:`~jaxlc.inference.mcmc.full_coordinates`)
    back from the period chart, its ln posterior as a density of those coordinates, its
    τ keyed by the coordinates it was sampled in (``tau_names``)."""
    if not isinstance(lp, ChartLogProb):
        return run
    chain = run["chain"]
    keep = [i for i in range(chain.shape[-1]) if i != lp.offset_index]
    flat = chain.reshape(-1, chain.shape[-1]).copy()
    old, log_jac, _ = lp.chart.from_chart(flat[:, keep])
    flat[:, keep] = old
    names = list(CHART_NAMES)
    names.insert(lp.offset_index, "dmag")
    return {
        **run,
        "chain": flat.reshape(chain.shape),
        "log_prob": run["log_prob"] - log_jac.reshape(run["log_prob"].shape),
        "tau_names": tuple(names),
    }

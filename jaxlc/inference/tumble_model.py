"""The tumble fit's forward model: the renderer's model with a torque-free state as parameters.

LM coordinates θ (10; host float64, the device's float32 the same numbers):

* 0, 1: x with ln(S_x / S_z), ln(S_y / S_z) = B tanh(x / B) (B =
  :data:`LN_RATIO_BOUND`), the body's second moments of mass S_i = ∫ x_i² dm
  relative to S_z. The principal moments are I = (S_y + S_z, S_x + S_z,
  S_x + S_y): every θ is a body that exists (the triangle inequality holds by
  construction), the scale, which no light curve sees, is fixed, and the
  bound keeps a direction the light curve barely constrains (an axisymmetric
  body's) from running off to a flat or a needle (the search found
  ln S_y/S_z = −18.6 for a cylinder without it).
* 2–4: the body-frame angular velocity at the fit epoch in units of the
  model's ``rate_ref_rad_s`` (2π over the light curve's strongest period,
  so that these coordinates are of order one).
* 5–8: an unnormalised quaternion ``[w, x, y, z]`` body → inertial at the fit
  epoch (drawn from N(0, I) it is a uniform attitude).
* 9: the magnitude offset Δm.

MCMC coordinates (10): 0–4 as above, 5–7 a rotation vector δ (rad) of the
attitude relative to the sampled mode's, q = q_mode ⊗ exp(δ/2) (a chart
without the quaternion's scale and sign), 8 Δm and 9 ln(noise_mag).

Times are float32 seconds from the fit epoch, split into whole body periods
on the device (:meth:`jaxlc.body.tumble.Tumble.times` with ``seconds``): the
split depends on the parameters, so it cannot be made once on the host as a
render makes it. The attitude is then precise to ~6e-8 × t × |ω| rad (1e-5 rad
over a 20-minute pass at 0.1 rad/s); fit days-long spans in pieces.

Everything else — the object, its shadows, the exposures and their
sub-exposures — comes from :func:`jaxlc.inference.model.fit_preparation`, the
preparation of the spin fit and of :func:`jaxlc.render`.
"""

from __future__ import annotations

import math
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc.body.attitude import quaternion_to_matrix
from jaxlc.body.free_body import torque_free_motion
from jaxlc.body.tumble import Tumble
from jaxlc.inference.data import FitData
from jaxlc.inference.model import FitModel, fit_preparation, intensity_floor_m2_sr
from jaxlc.rendering.attitude_jacobian import attitude_intensity
from jaxlc.rendering.prepare import adapt, kernel_inputs
from jaxlc.rendering.render import evaluate_instants
from jaxlc.scene import Scene

N_TUMBLE_LM = 10
N_TUMBLE_MC = 10
TUMBLE_MC_NAMES = (
    "x_sx_over_sz",
    "x_sy_over_sz",
    "omega_x",
    "omega_y",
    "omega_z",
    "rotation_x_rad",
    "rotation_y_rad",
    "rotation_z_rad",
    "dmag",
    "ln_noise_mag",
)


#: Largest |ln(S_i / S_z)| of the fit's bodies (ratios 1/400 … 400).
LN_RATIO_BOUND = 6.0


def bounded_ratios(x):
    """LM/MCMC coordinates 0, 1 → ln(S_x/S_z), ln(S_y/S_z) (numpy or JAX)."""
    xp = jnp if isinstance(x, jax.Array) else np
    return LN_RATIO_BOUND * xp.tanh(x / LN_RATIO_BOUND)


def ratio_coordinates(ln_s) -> np.ndarray:
    """The inverse of :func:`bounded_ratios` (host; clipped inside the bound)."""
    r = np.clip(np.asarray(ln_s, np.float64) / LN_RATIO_BOUND, -0.999999, 0.999999)
    return LN_RATIO_BOUND * np.arctanh(r)


def moments_from_ratios(ln_s):
    """(…, 2) ln(S_x/S_z), ln(S_y/S_z) → (…, 3) principal moments (I_x, I_y, I_z)
    with S_z = 1 (numpy or JAX)."""
    xp = jnp if isinstance(ln_s, jax.Array) else np
    sx, sy = xp.exp(ln_s[..., 0]), xp.exp(ln_s[..., 1])
    return xp.stack([sy + 1.0, sx + 1.0, sx + sy], axis=-1)


def ratios_from_moments(inertia) -> np.ndarray:
    """The inverse of :func:`moments_from_ratios` (host; moments obeying the triangle
    inequality strictly)."""
    i = np.asarray(inertia, np.float64)
    s = 0.5 * (i.sum(axis=-1, keepdims=True) - 2.0 * i)  # S_x = (I_y + I_z − I_x) / 2 …
    return np.log(s[..., :2] / s[..., 2:3])


class TumbleModel(FitModel):
    """A tumble fit's forward model (a pytree; :class:`~jaxlc.inference.model.FitModel`'s
    fields, then ``rate_ref_rad_s``, the unit of the ω coordinates)."""

    rate_ref_rad_s: jax.Array

    dmag_index: ClassVar[int] = 9

    def attitude(self, theta) -> Tumble:
        """The tumble of device LM coordinates (10,)."""
        q = theta[5:9] / jnp.linalg.norm(theta[5:9])
        inertia = moments_from_ratios(bounded_ratios(theta[0:2]))
        return Tumble(inertia, theta[2:5] * self.rate_ref_rad_s, q)

    def intensity(self, theta_lm, chunk=None):
        return attitude_intensity(self.obj, self.inputs, self.attitude, theta_lm, chunk)

    def to_device(self, theta) -> jax.Array:
        return jnp.asarray(np.asarray(theta, np.float64), jnp.float32)

    def from_device(self, theta) -> np.ndarray:
        return np.asarray(theta, np.float64)


def state_of(theta_lm, rate_ref_rad_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(inertia (…, 3), ω (…, 3) rad/s, unit quaternion (…, 4)) of host LM coordinates."""
    t = np.asarray(theta_lm, np.float64)
    q = t[..., 5:9] / np.linalg.norm(t[..., 5:9], axis=-1, keepdims=True)
    return moments_from_ratios(bounded_ratios(t[..., 0:2])), t[..., 2:5] * rate_ref_rad_s, q


def theta_of(inertia, omega_rad_s, quaternion, rate_ref_rad_s: float, dmag=0.0) -> np.ndarray:
    """(…, 10) host LM coordinates of tumble states (the inverse of :func:`state_of`)."""
    inertia = np.asarray(inertia, np.float64)
    lead = inertia.shape[:-1]
    return np.concatenate(
        [
            ratio_coordinates(ratios_from_moments(inertia)),
            np.asarray(omega_rad_s, np.float64) / rate_ref_rad_s,
            np.asarray(quaternion, np.float64),
            np.broadcast_to(np.asarray(dmag, np.float64), lead)[..., None],
        ],
        axis=-1,
    )


def truth_theta(scene: Scene, data: FitData, rate_ref_rad_s: float) -> np.ndarray:
    """(10,) host LM coordinates of a tumbling scene's own state at the fit epoch (Δm = 0):
    the truth of a fit to a light curve rendered from ``scene``."""
    tumble = scene.attitude.tumble()
    if scene.attitude.epoch_utc is not None:
        tumble = tumble.at_offset((data.epoch_utc - scene.attitude.epoch_utc).total_seconds())
    return theta_of(
        np.asarray(tumble.inertia_kg_m2),
        np.asarray(tumble.omega_body_rad_s),
        np.asarray(tumble.quaternion),
        rate_ref_rad_s,
    )


def tumble_model(
    scene: Scene,
    data: FitData,
    theta_plan,
    rate_ref_rad_s: float,
    exact: bool = True,
    directions: int = 128,
    max_subsamples: int | None = None,
    adapted: bool = False,
    least_levels: bool = True,
) -> TumbleModel:
    """The tumble fit model of a scene over ``data``: exact (facets, shadows) or coarse.

    Args:
        scene: shape, materials and ``[render]`` options.
        data: the fitted samples.
        theta_plan: (10,) host LM coordinates of the state the render plan is made
            for (its largest rate sets the sub-exposures): the fastest the model
            will be asked about.
        rate_ref_rad_s: the unit of the ω coordinates.
        exact, directions, max_subsamples: as for
            :func:`~jaxlc.inference.model.spin_model` (False: the search model).
        adapted: where the render plan asks for adaptive sub-exposures, choose them
            for ``theta_plan``'s state as :func:`jaxlc.render` would, each exposure
            then at its least level within tolerance unless ``least_levels`` is False
            (the MCMC model about one mode); otherwise the plan's fixed count.
    """
    inertia, omega, q = state_of(theta_plan, rate_ref_rad_s)
    trial = scene.with_tumble(inertia, omega, q, epoch_utc=data.epoch_utc)
    prep = fit_preparation(trial, data, exact, directions, max_subsamples)
    if adapted and prep.adaptive:
        prep = adapt([prep], evaluate_instants, least_levels=least_levels)[0]
    inputs = kernel_inputs(prep.object.attitude, prep.exposures, prep.precision, {"seconds": True})
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return TumbleModel(
        obj=prep.object,
        inputs=inputs,
        const_mag=f32(data.const_mag),
        floor_m2_sr=f32(intensity_floor_m2_sr(scene)),
        limit_mag=f32(data.limit_mag),
        rate_ref_rad_s=f32(rate_ref_rad_s),
    )


# ---------------------------------------------------------------------------
# What a state means: periods, mode, L (host, float64, vectorised)

_motions64 = jax.jit(jax.vmap(torque_free_motion))


def motion_invariants(inertia, omega_rad_s) -> dict[str, np.ndarray]:
    """Periods and mode of (K, 3) states: ``body_period_s`` (T_ω, ∞ for a uniform
    rotation), ``precession_period_s`` (2π T_ω / Δψ), ``sam`` (bool) and
    ``excitation`` (0 a principal-axis spin … 1 the separatrix; see
    :meth:`jaxlc.body.tumble.Tumble.excitation`)."""
    inertia = np.atleast_2d(np.asarray(inertia, np.float64))
    omega = np.atleast_2d(np.asarray(omega_rad_s, np.float64))
    with jax.enable_x64(True):
        m = jax.tree_util.tree_map(np.asarray, _motions64(jnp.asarray(inertia), jnp.asarray(omega)))
    uniform = np.asarray(m.uniform, bool)
    period, step = np.asarray(m.period_s), np.asarray(m.step_rad)
    with np.errstate(divide="ignore", invalid="ignore"):
        precession = np.where(uniform, 2 * np.pi / m.rate_rad_s, 2 * np.pi * period / step)
    i1, i2, i3 = np.sort(inertia, axis=1).T
    e = np.sum(inertia * omega**2, axis=1) / np.sum((inertia * omega) ** 2, axis=1)  # 2E/L²
    sam = np.asarray(m.sam, bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        exc = np.where(sam, (e - 1 / i3) / (1 / i2 - 1 / i3), (1 / i1 - e) / (1 / i1 - 1 / i2))
    return {
        "body_period_s": np.where(uniform, np.inf, period),
        "precession_period_s": precession,
        "sam": sam,
        "excitation": np.clip(np.nan_to_num(exc, nan=0.0), 0.0, 1.0),
    }


def angular_momentum_radec_deg(inertia, omega_rad_s, quaternion) -> tuple[np.ndarray, np.ndarray]:
    """RA and Dec (deg) of the inertial angular momentum of (…) states."""
    ell_b = np.asarray(inertia, np.float64) * np.asarray(omega_rad_s, np.float64)
    with jax.enable_x64(True):
        rot = np.asarray(quaternion_to_matrix(jnp.asarray(np.asarray(quaternion, np.float64))))
    ell = np.einsum("...ij,...j->...i", rot, ell_b)
    ell = ell / np.linalg.norm(ell, axis=-1, keepdims=True)
    ra = np.degrees(np.mod(np.arctan2(ell[..., 1], ell[..., 0]), 2 * np.pi))
    return ra, np.degrees(np.arcsin(np.clip(ell[..., 2], -1.0, 1.0)))


# ---------------------------------------------------------------------------
# MCMC chart: a rotation vector about the mode's attitude


def quaternion_product(a, b):
    """Hamilton product a ⊗ b of (…, 4) quaternions (numpy or JAX)."""
    xp = jnp if isinstance(a, jax.Array) or isinstance(b, jax.Array) else np
    aw, ax, ay, az = (a[..., k] for k in range(4))
    bw, bx, by, bz = (b[..., k] for k in range(4))
    return xp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def rotation_quaternion(delta):
    """(…, 3) rotation vectors (rad) → (…, 4) unit quaternions exp(δ/2) (numpy or JAX;
    smooth through δ = 0)."""
    xp = jnp if isinstance(delta, jax.Array) else np
    angle2 = xp.sum(delta**2, axis=-1, keepdims=True)
    angle = xp.sqrt(angle2 + 1e-30)
    half = 0.5 * angle
    sinc = xp.where(angle2 < 1e-8, 0.5 - angle2 / 48.0, xp.sin(half) / angle)
    return xp.concatenate([xp.cos(half), delta * sinc], axis=-1)


def mc_to_lm(theta_mc, q_mode):
    """(…, 10) MCMC → LM coordinates about the mode's unit quaternion ``q_mode`` (4,)."""
    xp = jnp if isinstance(theta_mc, jax.Array) else np
    q = quaternion_product(q_mode, rotation_quaternion(theta_mc[..., 5:8]))
    return xp.concatenate([theta_mc[..., 0:5], q, theta_mc[..., 8:9]], axis=-1)


def lm_to_mc(theta_lm, noise_mag: float) -> tuple[np.ndarray, np.ndarray]:
    """(10,) LM coordinates of a mode → its (10,) MCMC coordinates (δ = 0) and q_mode."""
    t = np.asarray(theta_lm, np.float64)
    q = t[5:9] / np.linalg.norm(t[5:9])
    return np.concatenate([t[0:5], np.zeros(3), [t[9], math.log(noise_mag)]]), q

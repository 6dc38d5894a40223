"""The spin fit's forward model: the renderer's model with the spin as parameters.

Parameters (a flat vector θ, shapes in brackets):

* LM coordinates, ``θ_lm`` (6): pole as an unnormalised 3-vector u (its
  direction is the inertial spin pole; drawn from N(0, I) it is isotropic),
  ln(period_s), rotation phase φ (rad) at the fit epoch, and a magnitude
  offset Δm (the brightness scale: size × albedo errors).
* MCMC coordinates, ``θ_mc`` (6): (λ, sin β) of the pole (isotropic when
  uniform), ln(period_s), φ, Δm and ln(noise_mag), the noise added in
  quadrature to the data's own errors.

The model magnitude of sample i is
``m_i = c_i − 2.5 log10(⟨I/E⟩_i + I_floor) + Δm`` with
``c_i = −26.74 − 2.5 log10(E_i / (d_i² C_sun))`` from the geometry and ⟨I/E⟩_i
the exposure mean of :func:`jaxlc.rendering.kernel.exposure_intensity`: the
object and its exposures come from :func:`jaxlc.rendering.prepare.prepare`,
the same preparation :func:`jaxlc.render` uses, for the scene spinning about
its ``body_axis`` with a trial period (which sets the sub-exposures through
the render plan). Only the attitude is replaced per θ.

On the device the period coordinate is relative: ln(P / P_ref) with P_ref
the model's reference period (a float32 number, the one its float32 times are
split by), so that float32 resolves the period to far better than float32's
own 10⁻⁷ (a noise-free curve constrains it to ~10⁻⁸). The host keeps absolute
float64 coordinates and converts at the device boundary (:func:`to_device`,
:func:`from_device`).

Samples far fainter than the rest (an end-on rocket body can drop 20 mag in
the model, below any detection limit) would dominate a magnitude fit, so
model and data are both softly clipped at ``limit_mag``
(:func:`jaxlc.inference.data.soft_clip`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxlc.body.attitude import Spin, phase_at_offset_deg, pole_vector, reference_direction
from jaxlc.body.facet_merge import coarsen_facets
from jaxlc.errors import JaxlcError
from jaxlc.inference.data import FitData, soft_clip
from jaxlc.rendering.attitude_jacobian import attitude_intensity
from jaxlc.rendering.kernel import KernelInputs, SpaceObject
from jaxlc.rendering.prepare import Prepared, adapt, prepare
from jaxlc.rendering.render import evaluate_instants
from jaxlc.scene import Scene

N_LM = 6
N_MC = 6
MC_NAMES = ("pole_lambda_rad", "pole_sin_beta", "ln_period_s", "phase_rad", "dmag", "ln_noise_mag")
#: Intensity floor per m² of surface: 10⁻¹⁰ × the total area is 25 mag below a
#: fully lit face, far below the soft clip, so it changes no sample above the
#: limit by > 10⁻⁵ mag (a floor of 10⁻⁷ biased a CubeSat's faint plateau by 6 mmag
#: and its period by 2.5 σ in the calibration study).
FLOOR_PER_AREA = 1e-10


class FitModel(eqx.Module):
    """What every fit model holds: the renderer's object and exposures over the fitted
    samples, and how intensities become magnitudes (a pytree; subclasses add the
    attitude's parameterisation: :class:`SpinModel`, the tumble's).

    Attributes:
        obj: the traced object (its attitude is replaced per θ).
        inputs: the fitted samples' exposures.
        const_mag: (N,) magnitude of unit I/E per sample.
        floor_m2_sr: intensity floor that keeps unlit samples finite in magnitude.
        limit_mag: faint clipping level.
    """

    obj: SpaceObject
    inputs: KernelInputs
    const_mag: jax.Array
    floor_m2_sr: jax.Array
    limit_mag: jax.Array

    #: Index of the magnitude offset Δm in the LM coordinates.
    dmag_index: ClassVar[int] = 5

    @property
    def n(self) -> int:
        return self.inputs.n_rows

    @property
    def instants_per_exposure(self) -> float:
        """Sub-exposure instants per exposure, on average (padding left out)."""
        w = np.asarray(self.inputs.weight)
        return float(np.count_nonzero(w > 0)) / max(self.inputs.n_rows, 1)

    @property
    def subsamples(self) -> int:
        return self.inputs.subsamples

    def intensity(self, theta_lm, chunk=None):
        """(N,) exposure-mean I/E (m² sr⁻¹) at device LM coordinates ``theta_lm``."""
        raise NotImplementedError

    def magnitudes(self, theta_lm, chunk=None):
        """(N,) model magnitudes, softly clipped at the faint limit.

        ``chunk``: instants per block of the facet sum (static; default sized
        for one curve, see :func:`jaxlc.rendering.kernel.time_chunk`). Under
        ``vmap`` over W parameter vectors pass ``time_chunk(n_facets × W)``.
        """
        return soft_clip(self.unclipped_magnitudes(theta_lm, chunk), self.limit_mag)

    def unclipped_magnitudes(self, theta_lm, chunk=None):
        """(N,) model magnitudes before the faint clip (Δm enters them additively)."""
        i = self.intensity(theta_lm, chunk)
        return self.const_mag - 2.5 * jnp.log10(i + self.floor_m2_sr) + theta_lm[self.dmag_index]


def intensity_floor_m2_sr(scene: Scene) -> float:
    """The intensity floor of a scene's fit models (:data:`FLOOR_PER_AREA` × its area)."""
    return FLOOR_PER_AREA * float(scene.facets.areas_m2.sum())


class SpinModel(FitModel):
    """A spin fit's forward model over its samples (a pytree; :class:`FitModel`'s
    fields, then:)

    Attributes:
        period_ref_s: the reference period P_ref (s); the exposures' times are
            split into turns of it.
        body_axis, body_ref: (3,) spin axis and reference direction in the body frame.
        adapted: whether the exposures' instants were chosen at a spin
            (:func:`spin_model`'s ``theta``), not the plan's fixed count.

    Every model differentiates through body turns
    (:func:`~jaxlc.rendering.attitude_jacobian.attitude_intensity`): three tangents
    through the facet sum instead of six. The 1,024-start searches of a 10-minute
    pass ran 27 % (S4, S6) and 17 % (S5) faster than in plain forward mode (S4: 7.6
    vs 10.7 s; compiling 3.4 vs 3.1 s).
    """

    period_ref_s: jax.Array
    body_axis: jax.Array
    body_ref: jax.Array
    adapted: bool = eqx.field(static=True, default=False)

    def to_device(self, theta) -> jax.Array:
        """Host LM coordinates (…, 6) → device coordinates (:func:`to_device`)."""
        return to_device(self, theta)

    def from_device(self, theta) -> np.ndarray:
        """Device LM coordinates → host float64 (:func:`from_device`)."""
        return from_device(self, theta)

    def attitude(self, pole_vec, ln_period_ratio, phase) -> Spin:
        """The spin of a pole vector, ln(P / P_ref) and the phase at the fit epoch."""
        u = pole_vec / jnp.linalg.norm(pole_vec)
        ra = jnp.arctan2(u[1], u[0])
        dec = jnp.arctan2(u[2], jnp.hypot(u[0], u[1]))
        return Spin(
            body_axis=self.body_axis,
            body_ref=self.body_ref,
            pole_ra_rad=ra,
            pole_dec_rad=dec,
            period_s=self.period_ref_s,
            phase_rad=phase,
            period_offset_s=self.period_ref_s * jnp.expm1(ln_period_ratio),
        )

    def intensity(self, theta_lm, chunk=None):
        """(N,) exposure-mean I/E (m² sr⁻¹) for device LM coordinates ``theta_lm``
        (6,) (:func:`to_device`)."""
        spin = lambda t: self.attitude(t[:3], t[3], t[4])  # noqa: E731
        return attitude_intensity(self.obj, self.inputs, spin, theta_lm, chunk)


#: Normal bins of the search model's merged facets (:func:`~jaxlc.body.facet_merge.coarsen_facets`).
SEARCH_DIRECTIONS = 128


def spin_model(
    scene: Scene,
    data: FitData,
    period_s: float,
    exact: bool = True,
    directions: int = SEARCH_DIRECTIONS,
    max_subsamples: int | None = None,
    floor: bool = True,
    theta=None,
    tolerance_mag: float | None = None,
    least_levels: bool = True,
) -> SpinModel:
    """The fit model of a scene over ``data``: exact (its facets, its shadows) or coarse.

    Args:
        scene: shape, materials and ``[render]`` options; ``[attitude] body_axis``
            gives the spin axis in the body frame (a fixed-attitude scene spins
            about body z).
        data: the fitted samples and their geometry.
        period_s: the trial period: the exposures are sampled as the render
            plan would for this spin (the shortest period the model will see
            needs the most sub-exposures), and it is the reference P_ref
            (rounded to float32) of the device coordinates.
        exact: False for the search model: facets merged into ``directions``
            normal bins (:func:`~jaxlc.body.facet_merge.coarsen_facets`) and no shadows.
        max_subsamples: a cap on the sub-exposures per exposure (the search).
        floor: add the intensity floor (off: exact magnitudes, +inf where dark).
        theta: (6,) host LM coordinates of a spin: where the render plan asks for
            adaptive sub-exposures, they are chosen for this spin
            (:func:`jaxlc.rendering.prepare.adapt`, as :func:`jaxlc.render`
            chooses them for a scene's spin, then each exposure at its least level
            within tolerance: ``least_levels``) and kept for every θ the model is
            evaluated at (the MCMC around one mode). Without it the exposures
            get the plan's fixed count for the trial period (the search and
            the refinement).
        tolerance_mag: the adaptive sub-exposures' tolerance instead of the
            scene's ``blur_tolerance_mag`` (the fit ties it to the data's noise).
        least_levels: False: ``theta``'s instants exactly as render's (no least level).
    """
    period_ref = float(np.float32(period_s))  # exactly the device's reference
    trial = scene.with_spin(period_ref, epoch_utc=data.epoch_utc)
    prep = fit_preparation(trial, data, exact, directions, max_subsamples, tolerance_mag)
    b = np.asarray(trial.attitude.body_axis, np.float64)
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    model = SpinModel(
        obj=prep.object,
        inputs=prep.inputs,
        const_mag=f32(data.const_mag),
        floor_m2_sr=f32(intensity_floor_m2_sr(scene) if floor else 0.0),
        limit_mag=f32(data.limit_mag),
        period_ref_s=f32(period_ref),
        body_axis=f32(b),
        body_ref=f32(reference_direction(b)),
    )
    if theta is None or not prep.adaptive:
        return model
    t = to_device(model, theta)
    obj = eqx.tree_at(lambda o: o.attitude, prep.object, model.attitude(t[:3], t[3], t[4]))
    at_mode = dataclasses.replace(prep, object=obj)
    adapted = adapt([at_mode], evaluate_instants, least_levels=least_levels)[0]
    return dataclasses.replace(model, inputs=adapted.inputs, adapted=True)


def check_fittable(scene: Scene) -> None:
    """Refuse render options a fit cannot afford, naming the fix.

    ``shadow_exact = "glints"`` clips the brightest shadowed terms of an instant exactly
    where they are a visible share of it (a ``lax.cond``); the fit's solvers and samplers
    ``vmap`` their starts and walkers, where a cond takes both branches: every term of
    every instant is clipped at every trial spin. A 600-sample S6 curve (demo pass, 120 s
    spin) fitted in 43 s with the table; with glints the fit had not left its refinement
    after 30 min.
    """
    if scene.render.shadow_exact != "off":
        raise JaxlcError(
            f"{scene.source}: [render] shadow_exact = {scene.render.shadow_exact!r} is for "
            "single renders: a fit's batched solvers would clip every shadowed term exactly "
            "at every trial spin (a 600-sample S6 fit: 43 s with the table, unfinished after "
            "30 min with glints); fit with the shadow table: shadow_exact = 'off' in "
            "[render], or jaxlc fit --shadow-exact off"
        )


def fit_preparation(
    trial: Scene,
    data: FitData,
    exact: bool = True,
    directions: int = SEARCH_DIRECTIONS,
    max_subsamples: int | None = None,
    tolerance_mag: float | None = None,
) -> Prepared:
    """The renderer's preparation of a trial scene (its attitude at a trial state) over
    a fit's samples: what every fit model (spin or tumble) evaluates.

    ``exact`` False: the search model (facets merged into ``directions`` normal
    bins by :func:`~jaxlc.body.facet_merge.coarsen_facets`, no shadows); ``max_subsamples`` caps the
    sub-exposures; ``tolerance_mag`` replaces the scene's ``blur_tolerance_mag``.
    """
    options = trial.render
    facets = None
    if tolerance_mag is not None:
        options = dataclasses.replace(options, blur_tolerance_mag=float(tolerance_mag))
    if not exact:
        options = dataclasses.replace(options, shadows="off")
        facets = coarsen_facets(trial.body[1], directions)
    if max_subsamples is not None:
        options = dataclasses.replace(
            options, max_subsamples=min(options.max_subsamples, max_subsamples)
        )
        if options.subsamples is not None:
            options = dataclasses.replace(
                options, subsamples=min(options.subsamples, max_subsamples)
            )
    return prepare(
        trial, data.geometry, options, rows=data.rows, origin_utc=data.epoch_utc, facets=facets
    )


# ---------------------------------------------------------------------------
# Coordinates


def ln_period_ref(model: SpinModel) -> float:
    """ln P_ref (float64) of a model's device coordinates."""
    return math.log(float(model.period_ref_s))


def to_device(model: SpinModel, theta, index: int = 3) -> jax.Array:
    """Host coordinates (…, 6) float64 → the model's float32 device coordinates:
    ln P (at ``index``: 3 for LM, 2 for MCMC coordinates) made relative to P_ref."""
    t = np.array(theta, dtype=np.float64)
    t[..., index] -= ln_period_ref(model)
    return jnp.asarray(t, jnp.float32)


def from_device(model: SpinModel, theta, index: int = 3) -> np.ndarray:
    """The inverse of :func:`to_device` (float64 host coordinates)."""
    t = np.array(theta, dtype=np.float64)
    t[..., index] += ln_period_ref(model)
    return t


def lm_to_mc(theta_lm: np.ndarray, noise_mag) -> np.ndarray:
    """(..., 6) LM coordinates (+ noise) → (..., 6) MCMC coordinates."""
    t = np.asarray(theta_lm, np.float64)
    u = t[..., :3] / np.linalg.norm(t[..., :3], axis=-1, keepdims=True)
    lam = np.mod(np.arctan2(u[..., 1], u[..., 0]), 2 * np.pi)
    return np.stack(
        [
            lam,
            u[..., 2],
            t[..., 3],
            np.mod(t[..., 4], 2 * np.pi),
            t[..., 5],
            np.log(np.broadcast_to(noise_mag, lam.shape)),
        ],
        axis=-1,
    )


def mc_to_lm(theta_mc):
    """(..., 6) MCMC → LM coordinates (works on numpy and JAX arrays)."""
    xp = jnp if isinstance(theta_mc, jax.Array) else np
    lam, z = theta_mc[..., 0], xp.clip(theta_mc[..., 1], -1.0, 1.0)
    r = xp.sqrt(1 - z**2)
    return xp.stack(
        [r * xp.cos(lam), r * xp.sin(lam), z, theta_mc[..., 2], theta_mc[..., 3], theta_mc[..., 4]],
        axis=-1,
    )


def pole_radec_deg(theta_lm) -> tuple[np.ndarray, np.ndarray]:
    """Pole right ascension and declination (deg) of LM coordinates (..., 6)."""
    t = np.asarray(theta_lm, np.float64)
    u = t[..., :3] / np.linalg.norm(t[..., :3], axis=-1, keepdims=True)
    return (
        np.degrees(np.mod(np.arctan2(u[..., 1], u[..., 0]), 2 * np.pi)),
        np.degrees(np.arcsin(np.clip(u[..., 2], -1, 1))),
    )


def angle_between_deg(a, b) -> np.ndarray:
    """Angle (deg) between unit vectors (..., 3)."""
    a = np.asarray(a) / np.linalg.norm(a, axis=-1, keepdims=True)
    b = np.asarray(b) / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1, 1)))


def truth_theta(scene: Scene, data: FitData) -> np.ndarray:
    """(6,) LM host coordinates of a scene's own spin at the fit epoch (Δm = 0): the
    truth of a fit to a light curve rendered from ``scene``."""
    a = scene.attitude
    if a.epoch_utc is None:  # the phase is given at the geometry's first row
        offset = data.epoch_offset_s
    else:
        offset = (data.epoch_utc - a.epoch_utc).total_seconds()
    phase = math.radians(phase_at_offset_deg(a.phase_deg, a.period_s, offset))
    u = np.asarray(pole_vector(math.radians(a.pole_ra_deg), math.radians(a.pole_dec_deg)))
    return np.array([*u, math.log(a.period_s), phase, 0.0])

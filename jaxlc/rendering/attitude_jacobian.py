"""The kernel's derivative with respect to attitude parameters, through body rotations.

A fit differentiates the exposure-mean I/E of :func:`jaxlc.rendering.kernel.exposure_intensity`
with respect to P parameters θ of the attitude (a spin: pole, period, phase; a tumble:
nine). Forward mode pushes P tangents through the facet sum, which dominates the cost.
But θ reaches the facets only through each instant's rotation R_k(θ): a change dθ turns
the body by the small body-frame angle dω_k = vee(R_kᵀ ∂R_k/∂θ dθ), so

    ∂I_k/∂θ = g_k · Ω_k,   g_k = ∂I_k/∂ω (3,),   Ω_k = vee(R_kᵀ ∂R_k/∂θ) (3, P).

g needs three tangents through the facet sum whatever P is; Ω is per instant (no
facets) and cheap. :func:`attitude_intensity` carries this as the custom JVP of the
kernel entry, so ``jax.jacfwd`` / ``jax.linearize`` of a fit model push three tangents
through the facet sum instead of P (spin 6, tumble 10). Fused forward mode shares much
of its work between tangents, so the gain is less than the count: S4's exact spin
model (1,205 facets, shadows) 15–25 % faster per Jacobian, the spin searches' coarse
models 17–27 % (:class:`~jaxlc.inference.model.SpinModel`). :func:`body_turns` forms
Ω one tangent at a time without the (T, 3, 3, P) Jacobian of the rotations, which
XLA contracted slowly: S5's refinement Jacobian (6 starts × 38,400 instants, one core,
compiled as the fits compile it) fell from 799 to 145 ms with it and the tangent sum
written out (``experiments/bench_jacobians.py``).
The values are those of the plain chain rule up to float rounding
(``tests/test_attitude_jacobian.py``).
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxlc.body.attitude import AbstractAttitude
from jaxlc.rendering.kernel import (
    KernelInputs,
    SpaceObject,
    exposure_intensity,
    exposure_mean,
    light_curve_intensity,
)


class Turned(AbstractAttitude):
    """An attitude followed by a small body-frame turn ω: R(t) (I + [ω]×).

    Exact to first order in ω (the only order :func:`attitude_intensity` uses: its
    derivative at ω = 0 is R [e_j]×, the body turned about body axis j).
    """

    base: AbstractAttitude
    omega_rad: Float[Array, " 3"]

    def times(self, t_s, **exact):
        return self.base.times(t_s, **exact)

    def rotation(self, times):
        r = self.base.rotation(times)
        return r + _times_skew(r, self.omega_rad)


def _times_skew(r, w):
    """R [ω]× for (T, 3, 3) R: column j of [ω]× is ω × e_j."""
    wx, wy, wz = w[0], w[1], w[2]
    c0 = r[:, :, 1] * wz - r[:, :, 2] * wy
    c1 = r[:, :, 2] * wx - r[:, :, 0] * wz
    c2 = r[:, :, 0] * wy - r[:, :, 1] * wx
    return jnp.stack([c0, c1, c2], axis=2)


def body_turns(
    attitude_of: Callable[[Array], AbstractAttitude], theta: Array, times
) -> Float[Array, "T 3 P"]:
    """Ω_k = vee(R_kᵀ ∂R_k/∂θ) (T, 3, P): the body-frame turn per unit change of each
    coordinate of ``theta`` (P,) at each instant.

    One tangent at a time (vmapped), each reduced at once to the three entries of
    Rᵀ dR that vee reads, written out as sums of three products: forming the whole
    (T, 3, 3, P) Jacobian and contracting it cost S5's refinement model 10× its
    facet sum (a library reduction over a transposed copy)."""

    def rot(th):
        return attitude_of(th).rotation(times)

    def turn(v):
        r, dr = jax.jvp(rot, (theta,), (v,))  # (T, 3, 3) each; r unbatched under vmap
        entry = lambda i, j: sum(r[:, k, i] * dr[:, k, j] for k in range(3))  # noqa: E731
        return jnp.stack([entry(2, 1), entry(0, 2), entry(1, 0)], axis=1)  # (T, 3)

    return jax.vmap(turn, out_axes=2)(jnp.eye(theta.shape[0], dtype=theta.dtype))


def intensity_and_jacobian(
    obj: SpaceObject,
    inputs: KernelInputs,
    attitude_of: Callable[[Array], AbstractAttitude],
    theta: Array,
    chunk: int | None = None,
) -> tuple[Float[Array, " N"], Float[Array, "N P"]]:
    """(N,) exposure-mean I/E of ``obj`` with the attitude ``attitude_of(theta)`` and its
    (N, P) Jacobian with respect to ``theta`` (P,), through body turns (module docstring)."""
    attitude = attitude_of(theta)
    omega = body_turns(attitude_of, theta, inputs.times)

    def per_instant(w):
        turned = eqx.tree_at(lambda o: o.attitude, obj, Turned(attitude, w))
        i = light_curve_intensity(turned, inputs.times, inputs.sun_dir, inputs.obs_dir, chunk)
        return i, i

    g, i = jax.jacfwd(per_instant, has_aux=True)(jnp.zeros(3, inputs.sun_dir.dtype))
    di = sum(g[:, k, None] * omega[:, k, :] for k in range(3))  # (T, P); no reduce op
    return exposure_mean(i, inputs), exposure_mean(di, inputs)


def attitude_intensity(
    obj: SpaceObject,
    inputs: KernelInputs,
    attitude_of: Callable[[Array], AbstractAttitude],
    theta: Array,
    chunk: int | None = None,
) -> Float[Array, " N"]:
    """:func:`exposure_intensity` of ``obj`` with the attitude ``attitude_of(theta)``,
    differentiable in ``theta`` (P,) at the cost of three tangents (module docstring).

    Only ``theta`` is differentiated: ``obj``, ``inputs`` and what ``attitude_of``
    closes over are held fixed (a fit's model).
    """

    @jax.custom_jvp
    def intensity(th):
        at = eqx.tree_at(lambda o: o.attitude, obj, attitude_of(th))
        return exposure_intensity(at, inputs, chunk)

    @intensity.defjvp
    def _jvp(primals, tangents):
        (th,), (dth,) = primals, tangents
        value, jac = intensity_and_jacobian(obj, inputs, attitude_of, th, chunk)
        return value, jac @ dth

    return intensity(theta)

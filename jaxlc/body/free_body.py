"""The free rigid body: Euler's equations and the rotation about L, in closed form.

A body with principal moments of inertia (I_x, I_y, I_z) along its body axes
and body-frame angular velocity ω₀ at t = 0 moves with constant energy
E = ½ Σ I_i ω_i² and constant angular momentum L (inertial). Euler's equations
are solved by Jacobi elliptic functions (Landau & Lifshitz, *Mechanics* §37),
the rotation about L by an elliptic integral of the third kind
(:mod:`jaxlc.body.elliptic`); :func:`torque_free_motion` derives what a
state implies, :meth:`TorqueFreeMotion.state` evaluates it at an instant.

* Axes. With the moments sorted I₁ ≤ I₂ ≤ I₃ the body turns, on average, about
  the axis of largest moment (short-axis mode, SAM: L² > 2E I₂) or of smallest
  moment (long-axis mode, LAM: L² < 2E I₂). The model works in canonical axes
  (a, b, c), a proper rotation P of the body axes with c the axis ω circles
  (SAM: a, b, c = I₁, I₂, I₃; LAM: I₃, I₂, I₁; an oblate body I₁ = I₂ is SAM,
  a prolate one I₂ = I₃ LAM).
* ω in the body: ω_a = A_a cn u, ω_b = A_b sn u, ω_c = σ A_c dn u with
  u = ν t + u₀, parameter m = k² = I_a (I_b − I_a) A_a² / (I_c (I_c − I_b) A_c²)
  and σ = sign ω_c. ω (and L in the body) repeat every T_ω = 4 K(m) / |ν|.
  Amplitudes, m and 1 − m are written as sums of same-signed terms (no
  cancellation but the distance to the separatrix itself).
* Rotation about L. In a frame with L along z the body → L-frame rotation is
  R_z(ψ) · M(t) · P, where M(t) (the 3-1-3 Euler pair θ, φ: :func:`alignment`)
  is fixed by L in the body, and
  ψ̇ = L/I_a + L (1/I_a − 1/I_c) n sn²u / (1 − n sn²u)
  with n = −I_c (I_b − I_a) / (I_a (I_c − I_b)) ≤ 0,
  integrated with Π(n; am u | m) = u + (n/3) sn³u R_J(cn²u, dn²u, 1, 1 − n sn²u)
  on [−K, K] and Π's quasi-periodicity beyond. Over one period T_ω, ψ grows by
  Δψ (``step_rad``). With R_L fixed by the attitude at t = 0,
  R(t) = R_L · R_z(ψ(t)) · M(t) · P.
* Limits, exact: a spin about a principal axis (the unstable middle one, an
  equilibrium, included) and any spin of a body symmetric about it (ω fixed in
  the body: ν = 0, the sphere included) is a uniform rotation about ω
  (``uniform``); an axisymmetric body (I_a = I_b) has k = n = 0 (circular
  functions).
* Separatrix (L² = 2E I₂, m = 1, T_ω = ∞): m₁ = 1 − m is held at least
  :data:`SEPARATRIX_M1` × ε of the dtype (ε = 2.2e-16 float64, 1.2e-7 float32),
  i.e. the state is moved by about that relative energy: far below what its
  exponential divergence from the separatrix lets any finite-precision
  integration follow (the tests check states 1e-3 in relative energy from it
  against a 1e-12 integrator over 1e4 s).

Derivatives are finite everywhere and exact except at a uniform rotation,
where the closed form's phase is undefined and the uniform limit gives the
rigid rotation's derivatives, not those of the nutation a transverse change of
ω would excite.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from jaxlc.body.elliptic import carlson_rf_from_roots, carlson_rj_from_roots, jacobi_sn_cn_dn

#: The separatrix guard: m₁ = 1 − m ≥ SEPARATRIX_M1 × the dtype's ε (module docstring).
SEPARATRIX_M1 = 8.0


class TorqueFreeMotion(eqx.Module):
    """What a torque-free state implies (derived once per evaluation; a pytree).

    Attributes:
        frame: (3, 3) rows: the canonical axes a, b, c in the body frame.
        moments_kg_m2: (3,) I_a, I_b, I_c.
        omega_rad_s: (3,) ω at t = 0 in canonical axes.
        amplitude_rad_s: (3,) A_a, A_b, A_c.
        sign_c: σ = sign ω_c (±1).
        nu_rad_s: ν, the signed rate of the elliptic argument u.
        m, m1: parameter k² and 1 − k².
        quarter: K(m).
        rj_complete: R_J(0, m₁, 1, 1 − n).
        n: characteristic n ≤ 0.
        ratio: A_b / A_a = √(I_a (I_c − I_a) / (I_b (I_c − I_b))).
        momentum: |L| (kg m² rad/s).
        u0: u at t = 0.
        cn0, sn0: cn u₀, sn u₀.
        h0: H(u₀) (:meth:`h`).
        coefficient_rad: L (1/I_a − 1/I_c) n / ν (rad).
        sam: short-axis mode (else long-axis).
        separatrix_offset: L² − 2E I₂ (> 0 SAM, < 0 LAM).
        uniform: ω fixed in the body (uniform rotation about it).
        rate_rad_s: |ω|.
        axis: (3,) ω / |ω| in the body frame.
        period_s: the split period: T_ω, or 2π/|ω| for a uniform rotation.
        step_rad: ψ's growth over ``period_s`` (2π for a uniform rotation).
    """

    frame: Float[Array, "3 3"]
    moments_kg_m2: Float[Array, " 3"]
    omega_rad_s: Float[Array, " 3"]
    amplitude_rad_s: Float[Array, " 3"]
    sign_c: Float[Array, ""]
    nu_rad_s: Float[Array, ""]
    m: Float[Array, ""]
    m1: Float[Array, ""]
    quarter: Float[Array, ""]
    rj_complete: Float[Array, ""]
    n: Float[Array, ""]
    ratio: Float[Array, ""]
    momentum: Float[Array, ""]
    u0: Float[Array, ""]
    cn0: Float[Array, ""]
    sn0: Float[Array, ""]
    h0: Float[Array, ""]
    coefficient_rad: Float[Array, ""]
    sam: Bool[Array, ""]
    separatrix_offset: Float[Array, ""]
    uniform: Bool[Array, ""]
    rate_rad_s: Float[Array, ""]
    axis: Float[Array, " 3"]
    period_s: Float[Array, ""]
    step_rad: Float[Array, ""]

    def h(self, u, sn_cn_dn=None) -> Float[Array, "..."]:
        """H(u) with Π(n; am u | m) = u + n H(u), continued over half periods (u any
        real; ``sn_cn_dn``: the Jacobi functions at u when the caller has them)."""
        j = jnp.round(u / (2.0 * self.quarter))
        sn, cn, dn = jacobi_sn_cn_dn(u, self.m, self.m1) if sn_cn_dn is None else sn_cn_dn
        flip = 1.0 - 2.0 * jnp.mod(j, 2.0)  # (−1)^j: sn, cn at w = u − 2jK ∈ [−K, K]
        sn, cn = flip * sn, flip * cn
        p = 1.0 - self.n * sn * sn
        rj = carlson_rj_from_roots(cn, dn, jnp.ones_like(dn), p)  # cn ≥ 0 on [−K, K]
        return (2.0 * j * self.rj_complete + sn**3 * rj) / 3.0

    def initial_alignment(self) -> Float[Array, "3 3"]:
        """M(0) · P: the body → L-frame rotation at t = 0 (ψ = 0)."""
        moments, w = self.moments_kg_m2, self.omega_rad_s
        return alignment(moments, w, self.cn0, self.sn0, self.ratio) @ self.frame

    def state(
        self, r_s, extra_rad
    ) -> tuple[Float[Array, ""], Float[Array, "3 3"], Float[Array, " 3"]]:
        """The motion at one instant, as ψ, M(t) · P and ω: the body → L-frame rotation
        is R_z(ψ) · M(t) · P.

        Args:
            r_s: seconds from the time origin, less the whole periods ``period_s``.
            extra_rad: ψ accumulated over those whole periods.

        Returns:
            (ψ (rad), M(t) · P (3, 3), ω (3,) in the body frame, rad/s).
        """
        u = self.nu_rad_s * r_s + self.u0
        sn, cn, dn = jacobi_sn_cn_dn(u, self.m, self.m1)
        a = self.amplitude_rad_s
        w = jnp.stack([a[0] * cn, a[1] * sn, self.sign_c * a[2] * dn])
        align = alignment(self.moments_kg_m2, w, cn, sn, self.ratio)
        psi = (
            self.momentum / self.moments_kg_m2[0] * r_s
            + self.coefficient_rad * (self.h(u, (sn, cn, dn)) - self.h0)
            + extra_rad
        )
        return psi, matmul3(align, self.frame), jnp.sum(self.frame * w[:, None], axis=0)


def alignment(moments, w, cn, sn, ratio) -> Float[Array, "3 3"]:
    """M: canonical axes → a frame with L along z (3-1-3 Euler angles θ, φ).

    Rows: (cos φ, −sin φ, 0), L̂ × row 1, L̂, where (sin φ, cos φ) is the unit
    direction of L⊥ = (I_a ω_a, I_b ω_b), taken as (I_a cn, I_b (A_b/A_a) sn) so
    that it stays defined as A_a → 0.
    """
    ell = moments * w
    ell = ell / jnp.linalg.norm(ell)
    e = jnp.stack([moments[0] * cn, moments[1] * ratio * sn])
    e = e / jnp.linalg.norm(e)
    row1 = jnp.stack([e[1], -e[0], jnp.zeros_like(e[0])])
    return jnp.stack([row1, jnp.cross(ell, row1), ell])


def matmul3(a, b) -> Float[Array, "... 3 3"]:
    """a @ b for (..., 3, 3) matrices of equal rank, written out elementwise: under
    ``vmap`` a batched 3 × 3 ``dot_general`` is a slow library call per instant on
    the CPU, while this fuses."""
    return sum(a[..., :, k : k + 1] * b[..., k : k + 1, :] for k in range(3))


def turn_z(angle, n) -> Float[Array, "... 3 3"]:
    """R_z(angle) · n for (...,) angles (rad) and (..., 3, 3) matrices: rows mixed
    elementwise (no batched matrix product)."""
    c, s = jnp.cos(angle)[..., None], jnp.sin(angle)[..., None]
    n0, n1, n2 = n[..., 0, :], n[..., 1, :], n[..., 2, :]
    return jnp.stack([c * n0 - s * n1, s * n0 + c * n1, jnp.broadcast_to(n2, (c * n0).shape)], -2)


def frame_about(axis) -> Float[Array, "3 3"]:
    """A rotation B whose third column is the unit vector ``axis`` (3,): a rotation by
    an angle about ``axis`` is B · R_z(angle) · Bᵀ (whichever B)."""
    pick = jnp.abs(axis[0]) < 0.6  # a helper at least 53° from the axis
    helper = jnp.where(pick, jnp.eye(3, dtype=axis.dtype)[0], jnp.eye(3, dtype=axis.dtype)[1])
    b1 = helper - jnp.dot(helper, axis) * axis
    b1 = b1 / jnp.linalg.norm(b1)
    return jnp.stack([b1, jnp.cross(axis, b1), axis], axis=1)


def axis_angle_matrix(axis, angle) -> Float[Array, "3 3"]:
    """Rodrigues' rotation by ``angle`` (rad) about the unit vector ``axis`` (3,)."""
    k = jnp.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    k = k.astype(axis.dtype)
    return jnp.eye(3, dtype=axis.dtype) + jnp.sin(angle) * k + (1.0 - jnp.cos(angle)) * (k @ k)


def _safe_div(num, den, fallback=0.0):
    """num / den, ``fallback`` where den == 0 (finite derivatives either way)."""
    zero = den == 0
    return jnp.where(zero, fallback, num / jnp.where(zero, 1.0, den))


def _safe_sqrt(x):
    """√x with a zero (not infinite) derivative at x = 0."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def torque_free_motion(inertia_kg_m2, omega_body_rad_s) -> TorqueFreeMotion:
    """The motion a state implies (module docstring), traced: jittable, vmappable.

    Args:
        inertia_kg_m2: (3,) principal moments along body x, y, z (> 0; any scale).
        omega_body_rad_s: (3,) body-frame angular velocity at t = 0 (rad/s, ≠ 0).
    """
    inertia, omega = jnp.asarray(inertia_kg_m2), jnp.asarray(omega_body_rad_s)
    dtype = omega.dtype
    order = jnp.argsort(inertia)
    i_sorted, w_sorted = inertia[order], omega[order]
    offset = jnp.sum(i_sorted * w_sorted**2 * (i_sorted - i_sorted[1]))  # L² − 2E I₂
    oblate, prolate = i_sorted[0] == i_sorted[1], i_sorted[1] == i_sorted[2]
    sam = oblate | (~prolate & (offset >= 0))
    idx = jnp.where(sam, order, order[::-1])
    frame = jnp.eye(3, dtype=dtype)[idx]
    handed = jnp.dot(frame[0], jnp.cross(frame[1], frame[2]))
    frame = frame * jnp.stack([jnp.ones((), dtype), handed, jnp.ones((), dtype)])[:, None]
    ia, ib, ic = inertia[idx[0]], inertia[idx[1]], inertia[idx[2]]
    w = frame @ omega
    wa, wb, wc = w[0], w[1], w[2]
    dca, dcb, dba = ic - ia, ic - ib, ib - ia

    ra2 = _safe_div(ib * dcb, ia * dca, 1.0)  # (A_a/A_b)², > 0 (1 for a sphere)
    aa2 = wa * wa + ra2 * wb * wb
    ab2 = _safe_div(wa * wa, ra2) + wb * wb
    ac2 = wc * wc + _safe_div(ib * dba, ic * dca) * wb * wb
    amplitude = jnp.stack([_safe_sqrt(aa2), _safe_sqrt(ab2), _safe_sqrt(ac2)])
    lam2 = _safe_div(dcb * dca, ia * ib) * ac2
    sign_c = jnp.where(wc >= 0, 1.0, -1.0).astype(dtype)
    nu = sign_c * jnp.sign(dcb) * _safe_sqrt(lam2)

    eps = SEPARATRIX_M1 * jnp.finfo(dtype).eps
    m = jnp.clip(_safe_div(ia * dba * aa2, ic * dcb * ac2), 0.0, 1.0 - eps)
    to_b = ia * wa * wa * (ia - ib) + ic * wc * wc * (ic - ib)  # L² − 2E I_b
    to_a = ic * dca * ac2  # L² − 2E I_a
    m1 = jnp.clip(_safe_div(dca * to_b, dcb * to_a, 1.0), eps, 1.0)
    n = _safe_div(-ic * dba, ia * dcb)
    ratio = jnp.sqrt(1.0 / ra2)

    # u₀: (cn u₀, sn u₀) ∝ (ω_a / A_a, ω_b / A_b); u₀ = F(φ₀ | m), φ₀ ∈ (−π, π]
    norm = _safe_sqrt(aa2)
    c0 = _safe_div(wa, norm, 1.0)
    s0 = _safe_div(wb * jnp.sqrt(ra2), norm)
    one = jnp.ones_like(m1)
    quarter = carlson_rf_from_roots(jnp.zeros_like(m1), jnp.sqrt(m1), one)
    f = s0 * carlson_rf_from_roots(jnp.where(c0 >= 0, c0, -c0), jnp.sqrt(m1 + m * c0 * c0), one)
    half = jnp.where(s0 >= 0, 2.0, -2.0) * quarter
    u0 = jnp.where(c0 >= 0, f, half - f)
    rj_complete = carlson_rj_from_roots(jnp.zeros_like(m1), jnp.sqrt(m1), one, 1.0 - n)

    momentum = jnp.linalg.norm(inertia * omega)
    coefficient = momentum * (1.0 / ia - 1.0 / ic) * _safe_div(n, nu)
    rate = jnp.linalg.norm(omega)
    axis = omega / rate
    uniform = (lam2 == 0) | (jnp.sum(w != 0) <= 1)
    period = jnp.where(uniform, 2.0 * jnp.pi / rate, _safe_div(4.0 * quarter, jnp.abs(nu)))
    step = jnp.where(
        uniform,
        2.0 * jnp.pi,
        momentum / ia * period + coefficient * jnp.sign(nu) * 4.0 * rj_complete / 3.0,
    )
    motion = TorqueFreeMotion(
        frame=frame,
        moments_kg_m2=jnp.stack([ia, ib, ic]),
        omega_rad_s=w,
        amplitude_rad_s=amplitude,
        sign_c=sign_c,
        nu_rad_s=nu,
        m=m,
        m1=m1,
        quarter=quarter,
        rj_complete=rj_complete,
        n=n,
        ratio=ratio,
        momentum=momentum,
        u0=u0,
        cn0=c0,
        sn0=s0,
        h0=jnp.zeros_like(u0),
        coefficient_rad=coefficient,
        sam=sam,
        separatrix_offset=offset,
        uniform=uniform,
        rate_rad_s=rate,
        axis=axis,
        period_s=period,
        step_rad=step,
    )
    return eqx.tree_at(lambda mo: mo.h0, motion, motion.h(u0))


_motion64 = jax.jit(torque_free_motion)


def host_motion(inertia_kg_m2, omega_body_rad_s) -> TorqueFreeMotion:
    """:func:`torque_free_motion` in float64 on the host (numpy leaves)."""
    with jax.enable_x64(True):
        motion = _motion64(
            jnp.asarray(np.asarray(inertia_kg_m2, np.float64)),
            jnp.asarray(np.asarray(omega_body_rad_s, np.float64)),
        )
        return jax.tree_util.tree_map(np.asarray, motion)

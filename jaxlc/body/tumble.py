"""Torque-free tumbling: an attitude model from the free rigid body's closed form.

:class:`Tumble` holds the principal moments of inertia (body x, y, z), the
body-frame angular velocity and the attitude (body → inertial) at its time
origin; its rotations are those of :mod:`jaxlc.body.free_body` (Jacobi
elliptic functions for ω in the body, an elliptic integral of the third kind
for the rotation about the fixed angular momentum L).

Periods, in seconds (:meth:`Tumble.periods_s`): ``body_period_s`` = T_ω =
4K(m)/|ν|, the period of ω and of L in the body frame (the body's attitude
relative to L repeats with it up to a rotation about L; the nutation angle
between the c axis and L has half that period), and ``precession_period_s`` =
2π T_ω/Δψ, the mean period of the body's rotation about L. A uniform rotation
(a principal-axis spin) has ``body_period_s`` = ∞ and ``precession_period_s``
= 2π/|ω|.

Time precision: :meth:`Tumble.times` splits float64 seconds on the host into
t = n T_ω + r (|r| ≤ T_ω/2) and carries n Δψ mod 2π, both from float64
parameters, so that a float32 kernel evaluates one period's motion only:
1e-6 to 2.5e-6 rad over 1e4 s in the tests (≤ 5e-7 of it from rounding the
parameters to float32). Within 1e-3 in relative energy of the separatrix the
motion amplifies that rounding to ~2e-5 rad (the float64 motion of the
float32-rounded parameters is as far off): use float64 leaves there. The
derivatives of the n-period terms with respect to the parameters are added
back exactly ((x − stop_gradient(x)) terms, zero in value).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxlc.body.attitude import (
    AbstractAttitude,
    Spin,
    leaf_dtype,
    matrix_to_quaternion,
    quaternion_to_matrix,
)
from jaxlc.body.free_body import (
    TorqueFreeMotion,
    frame_about,
    host_motion,
    matmul3,
    torque_free_motion,
    turn_z,
)


class TumbleTimes(eqx.Module):
    """Times for :class:`Tumble`: t = periods · T_ω + remainder_s, with
    precession_rad = periods · Δψ mod 2π (each (T,), from float64 on the host)."""

    periods: Float[Array, " T"]
    remainder_s: Float[Array, " T"]
    precession_rad: Float[Array, " T"]

    @property
    def shape(self):
        return self.periods.shape


class Tumble(AbstractAttitude):
    """Torque-free rigid-body rotation (see the module docstring).

    Attributes:
        inertia_kg_m2: (3,) principal moments of inertia along body x, y, z
            (> 0, any common scale; I_i + I_j ≥ I_k).
        omega_body_rad_s: (3,) body-frame angular velocity at t = 0 (rad/s).
        quaternion: (4,) ``[w, x, y, z]`` body → inertial at t = 0.

    Example:
        >>> tumble = Tumble.from_state([1.0, 2.5, 3.0], [0.05, 0.2, 0.01], [1, 0, 0, 0])
        >>> r = tumble.rotation(tumble.times(np.linspace(0.0, 600.0, 601)))  # (601, 3, 3)
    """

    inertia_kg_m2: Float[Array, " 3"]
    omega_body_rad_s: Float[Array, " 3"]
    quaternion: Float[Array, " 4"]

    @classmethod
    def from_state(cls, inertia_kg_m2, omega_body_rad_s, quaternion, dtype=jnp.float32) -> Tumble:
        """Build from plain numbers (numpy leaves in ``dtype``; the quaternion normalised)."""
        q = np.asarray(quaternion, dtype=np.float64)
        f = lambda x: np.asarray(x, dtype=np.float64).astype(dtype)  # noqa: E731
        return cls(f(inertia_kg_m2), f(omega_body_rad_s), f(q / np.linalg.norm(q)))

    def motion(self) -> TorqueFreeMotion:
        """The derived motion (traced)."""
        return torque_free_motion(self.inertia_kg_m2, self.omega_body_rad_s)

    def times(
        self, t_s, inertia_kg_m2=None, omega_body_rad_s=None, seconds: bool = False
    ) -> TumbleTimes | np.ndarray:
        """Split float64 seconds into whole periods T_ω, a remainder and the
        precession those periods add (host side, float64).

        Args:
            t_s: (T,) float64 seconds from the time origin.
            inertia_kg_m2, omega_body_rad_s: the float64 values the model's
                leaves were rounded from (e.g. the scene's, at any epoch: T_ω and
                Δψ are invariants of the motion). Default: the model's own.
            seconds: return the plain seconds in the leaves' dtype instead, split
                on the device: for a model whose motion changes per evaluation
                (the tumble fit), where a split made on the host at one state
                would be wrong at another (float32: ~6e-8 × t × |ω| rad).
        """
        if seconds:
            return np.asarray(t_s, dtype=np.float64).astype(leaf_dtype(self))
        inertia = self.inertia_kg_m2 if inertia_kg_m2 is None else inertia_kg_m2
        omega = self.omega_body_rad_s if omega_body_rad_s is None else omega_body_rad_s
        motion = host_motion(inertia, omega)
        period, step = float(motion.period_s), float(motion.step_rad)
        t = np.asarray(t_s, dtype=np.float64)
        periods = np.round(t / period)  # remainders in [−T/2, T/2]: smaller angles in float32
        precession = np.mod(periods * math.fmod(step, 2 * math.pi), 2 * math.pi)
        dtype = leaf_dtype(self)
        return TumbleTimes(
            periods=periods.astype(dtype),
            remainder_s=(t - periods * period).astype(dtype),
            precession_rad=precession.astype(dtype),
        )

    def _split(self, motion: TorqueFreeMotion, times):
        """(T,) seconds into the period and (T,) ψ of the whole periods before."""
        period, step = motion.period_s, motion.step_rad
        if isinstance(times, TumbleTimes):
            n = times.periods
            # Zero in value; the exact derivatives of the n-period terms.
            dperiod = period - jax.lax.stop_gradient(period)
            dstep = step - jax.lax.stop_gradient(step)
            return times.remainder_s - n * dperiod, times.precession_rad + n * dstep
        t = jnp.asarray(times)
        n = jnp.round(t / period)
        return t - n * period, n * step

    def _evaluate(self, times):
        """(T, 3, 3) rotations and (T, 3) body-frame ω at ``times``.

        Both motions are R = G · R_z(ψ) · N: a tumble G = R_L, N = M(t) · P
        (:meth:`TorqueFreeMotion.state`); a uniform rotation by ψ about ω̂,
        G = q₀ · B, N = Bᵀ (B ẑ = ω̂). The choice is made on these factors, before
        the one product.
        """
        motion = self.motion()
        r, extra = self._split(motion, times)
        q0 = quaternion_to_matrix(self.quaternion)
        psi, n, omega = jax.vmap(motion.state)(r, extra)
        uniform = motion.uniform
        b = frame_about(motion.axis)
        g = jnp.where(uniform, q0 @ b, q0 @ motion.initial_alignment().T)
        psi = jnp.where(uniform, motion.rate_rad_s * r + extra, psi)
        n = jnp.where(uniform, b.T[None], n)
        omega = jnp.where(uniform, self.omega_body_rad_s[None], omega)
        return matmul3(g[None], turn_z(psi, n)), omega

    def rotation(self, times) -> Float[Array, "T 3 3"]:
        """(T, 3, 3) body → inertial matrices at ``times`` (:meth:`times`, or seconds)."""
        return self._evaluate(times)[0]

    def angular_velocity(self, times) -> Float[Array, "T 3"]:
        """(T, 3) body-frame angular velocity (rad/s) at ``times``."""
        return self._evaluate(times)[1]

    # Host-side descriptions (float64), for labels and plans.

    def mode(self) -> str:
        """``"SAM"`` (short-axis mode: L² > 2E I₂, or an oblate body), ``"LAM"``
        (long-axis mode: L² < 2E I₂, or a prolate body) or ``"separatrix"``."""
        motion = host_motion(self.inertia_kg_m2, self.omega_body_rad_s)
        i = np.sort(np.asarray(self.inertia_kg_m2, np.float64))
        if float(motion.separatrix_offset) == 0.0 and i[0] < i[1] < i[2]:
            return "separatrix"
        return "SAM" if bool(motion.sam) else "LAM"

    def excitation(self) -> float:
        """How far the motion is from a principal-axis spin, in energy: 0 at the
        mode's spin (about the largest moment in SAM, the smallest in LAM), 1 at the
        separatrix (:func:`tumble_from_invariants`); float64 on the host."""
        inertia = np.asarray(self.inertia_kg_m2, np.float64)
        omega = np.asarray(self.omega_body_rad_s, np.float64)
        i1, i2, i3 = np.sort(inertia)
        e = float(np.sum(inertia * omega**2) / np.sum((inertia * omega) ** 2))  # 2E / L²
        if self.mode() == "SAM":
            return _ratio(e - 1.0 / i3, 1.0 / i2 - 1.0 / i3)
        return _ratio(1.0 / i1 - e, 1.0 / i1 - 1.0 / i2)

    def periods_s(self) -> tuple[float, float]:
        """(body_period_s, precession_period_s): T_ω = 4K/|ν|, the period of ω in the
        body frame (∞ for a uniform rotation), and 2π T_ω/Δψ, the mean period of
        the rotation about L (module docstring)."""
        motion = host_motion(self.inertia_kg_m2, self.omega_body_rad_s)
        period, step = float(motion.period_s), float(motion.step_rad)
        body = math.inf if bool(motion.uniform) else period
        return body, 2.0 * math.pi * period / step

    def max_rate_rad_s(self) -> float:
        """The largest |ω| (rad/s) over the motion: |ω|² is linear in sn² over a period."""
        motion = host_motion(self.inertia_kg_m2, self.omega_body_rad_s)
        if bool(motion.uniform):
            return float(motion.rate_rad_s)
        a2 = np.asarray(motion.amplitude_rad_s, np.float64) ** 2
        return math.sqrt(max(a2[0] + a2[2], a2[1] + a2[2] * float(motion.m1)))

    def angular_momentum_radec_deg(self) -> tuple[float, float]:
        """Right ascension and declination (deg) of L in the inertial frame."""
        with jax.enable_x64(True):
            r = np.asarray(quaternion_to_matrix(jnp.asarray(self.quaternion, jnp.float64)))
        ell = r @ (
            np.asarray(self.inertia_kg_m2, np.float64)
            * np.asarray(self.omega_body_rad_s, np.float64)
        )
        ell = ell / np.linalg.norm(ell)
        ra = math.degrees(math.atan2(ell[1], ell[0])) % 360.0
        return ra, math.degrees(math.asin(max(-1.0, min(1.0, ell[2]))))

    def at_offset(self, offset_s: float) -> Tumble:
        """The same motion with its time origin ``offset_s`` seconds later
        (float64 on the host; float64 numpy leaves)."""
        with jax.enable_x64(True):
            model = Tumble.from_state(
                self.inertia_kg_m2, self.omega_body_rad_s, self.quaternion, np.float64
            )
            rot, omega = _evaluate64(model, model.times(np.array([float(offset_s)])))
        return Tumble.from_state(
            model.inertia_kg_m2, np.asarray(omega)[0], matrix_to_quaternion(rot[0]), np.float64
        )


_evaluate64 = jax.jit(Tumble._evaluate)
#: An attitude's rotations, compiled (host-side float64 set-up runs per dataset curve).
_rotation64 = jax.jit(lambda attitude, times: attitude.rotation(times))

#: The two tumbling modes: short-axis (about the largest moment) and long-axis.
TUMBLE_MODES = ("SAM", "LAM")


def _ratio(num: float, den: float) -> float:
    return min(max(num / den, 0.0), 1.0) if den > 0 else 0.0


def tumble_from_invariants(
    inertia_kg_m2,
    mode: str,
    excitation: float,
    precession_period_s: float,
    l_ra_deg: float,
    l_dec_deg: float,
    about_l_deg: float = 0.0,
    polhode_phase: float = 0.0,
    sense: int = 1,
) -> Tumble:
    """The tumble with given invariants, at a given point of its motion (host side,
    float64 leaves): how datasets draw tumbling bodies.

    With the moments sorted I₁ ≤ I₂ ≤ I₃ and E, L the energy and angular
    momentum, 2E/L² runs from 1/I₃ (a spin about the largest moment) through 1/I₂
    (the separatrix) to 1/I₁ (a spin about the smallest); ``excitation`` is the
    fraction of the mode's side of that range from its spin to the separatrix.

    Args:
        inertia_kg_m2: (3,) principal moments along body x, y, z (any scale).
        mode: ``"SAM"`` or ``"LAM"``.
        excitation: in [0, 1): 0 a principal-axis spin, → 1 the separatrix.
        precession_period_s: the mean period of the rotation about L
            (:meth:`Tumble.periods_s`), > 0 (s).
        l_ra_deg, l_dec_deg: the direction of L (deg).
        about_l_deg: the body's rotation about L at t = 0 (deg).
        polhode_phase: in [0, 1): where the body is on its polhode at t = 0, as a
            fraction of T_ω from the point where L has no component along I₂.
        sense: ±1: which of the mode's two polhodes (the sign of L along I₃ in
            SAM, along I₁ in LAM).

    Example:
        >>> t = tumble_from_invariants([1, 2.5, 3], "SAM", 0.4, 300.0, 30.0, 60.0)
        >>> t.mode(), t.periods_s()[1], t.angular_momentum_radec_deg()  # SAM, 300 s, (30, 60)
    """
    inertia = np.asarray(inertia_kg_m2, np.float64)
    if mode not in TUMBLE_MODES:
        raise ValueError(f"tumble_from_invariants: mode = {mode!r} must be 'SAM' or 'LAM'")
    if not 0.0 <= excitation < 1.0:
        raise ValueError(f"tumble_from_invariants: excitation = {excitation!r} is outside [0, 1)")
    order = np.argsort(inertia, kind="stable")
    i1, i2, i3 = inertia[order]
    if mode == "SAM":
        two_e = 1.0 / i3 + excitation * (1.0 / i2 - 1.0 / i3)
    else:
        two_e = 1.0 / i1 - excitation * (1.0 / i1 - 1.0 / i2)
    # unit L on the polhode where L₂ = 0: L₁²/I₁ + L₃²/I₃ = 2E, L₁² + L₃² = 1
    l1_sq = _ratio(two_e - 1.0 / i3, 1.0 / i1 - 1.0 / i3)
    l1, l3 = math.sqrt(l1_sq), math.sqrt(1.0 - l1_sq)
    sign = 1.0 if sense >= 0 else -1.0
    l1, l3 = (l1, sign * l3) if mode == "SAM" else (sign * l1, l3)
    omega = np.zeros(3)
    omega[order] = np.array([l1, 0.0, l3]) / np.array([i1, i2, i3])
    # every time of a torque-free motion scales as 1/|ω|
    start = Tumble.from_state(inertia, omega, [1.0, 0.0, 0.0, 0.0], np.float64)
    omega = omega * start.periods_s()[1] / float(precession_period_s)
    start = Tumble.from_state(inertia, omega, [1.0, 0.0, 0.0, 0.0], np.float64)
    if polhode_phase:
        start = start.at_offset(float(polhode_phase) * float(host_motion(inertia, omega).period_s))
    omega = np.asarray(start.omega_body_rad_s, np.float64)
    # orient: body L̂ onto the inertial direction, turned about it by about_l_deg
    with jax.enable_x64(True):
        ell = inertia * omega
        align = Spin.from_degrees(ell, l_ra_deg, l_dec_deg, 1.0, about_l_deg, np.float64)
        rotation = np.asarray(_rotation64(align, np.zeros(1)))[0]
    return Tumble.from_state(inertia, omega, matrix_to_quaternion(rotation), np.float64)

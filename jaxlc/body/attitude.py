"""Attitude: body → inertial rotations over time.

Every model is an ``equinox.Module`` with ``rotation(times) -> (T, 3, 3)``
matrices R such that ``x_inertial = R @ x_body``; times count seconds from the
model's time origin (the first row of the geometry table when built by
:func:`jaxlc.rendering.render.render`) and are prepared on the host by ``times(t_s)``.
New models subclass :class:`AbstractAttitude` and implement ``rotation`` (and
``times`` if float32 needs help with precision); torque-free tumbling is
:class:`jaxlc.body.tumble.Tumble`.

``Fixed(quaternion)``
    constant rotation, quaternion ``[w, x, y, z]`` (scalar first, body →
    inertial; the identity means body axes = inertial axes).
``Spin(body_axis, pole, period, phase)``
    uniform rotation about an inertial pole. Convention (like the IAU rotation
    models): at phase φ the body axis points at the pole p (RA α, Dec δ), and a
    body reference direction e (the body x, y or z axis least aligned with the
    body axis, made perpendicular to it) points at ``cos φ Q + sin φ (p × Q)``
    with Q = (−sin α, cos α, 0) the ascending node of the body's equator on
    the celestial equator. φ(t) = phase + 2π t / period, right-handed about p.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PyTree


class AbstractAttitude(eqx.Module):
    """Body → inertial rotation as a function of time.

    Times reach ``rotation`` in a form each model chooses: :meth:`times`
    converts float64 seconds on the host into it (a plain array by default,
    whole turns + remainder for :class:`Spin`), so that float32 kernels keep
    the precision of long light curves. ``rotation`` also accepts a plain
    array of seconds.
    """

    def times(self, t_s, **exact) -> PyTree:
        """Host-side conversion of float64 seconds (T,) into ``rotation``'s input
        (numpy arrays in the model's dtype; JAX moves them at the jit boundary).

        ``exact`` may carry float64 values of parameters the model holds in
        float32 (e.g. ``period_s``); models that need none ignore it.
        """
        return np.asarray(t_s, dtype=np.float64).astype(leaf_dtype(self))

    @abc.abstractmethod
    def rotation(self, times) -> Float[Array, "T 3 3"]:
        """(T, 3, 3) body→inertial matrices at ``times`` (from :meth:`times`, or seconds)."""


def leaf_dtype(module: eqx.Module) -> np.dtype:
    """The dtype of a model's first array leaf (float32 when it has none)."""
    leaves = [x for x in jax.tree_util.tree_leaves(module) if hasattr(x, "dtype")]
    return np.dtype(leaves[0].dtype) if leaves else np.dtype(np.float32)


def quaternion_to_matrix(q: Float[Array, "... 4"]) -> Float[Array, "... 3 3"]:
    """Rotation matrix of a scalar-first quaternion ``[w, x, y, z]`` (normalised here)."""
    q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return jnp.stack(
        [
            jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quaternion(r) -> np.ndarray:
    """Scalar-first unit quaternions ``[w, x, y, z]`` (w ≥ 0) of rotation matrices:
    (…, 3, 3) → (…, 4) (host side, float64; Shepperd's method: the largest of w, x, y,
    z is found first, so every branch divides by at least ½)."""
    r = np.asarray(r, dtype=np.float64)
    out = np.empty((*r.shape[:-2], 4))
    for idx in np.ndindex(*r.shape[:-2]):
        out[idx] = _one_quaternion(r[idx])
    return out


def _one_quaternion(r) -> np.ndarray:
    trace = np.trace(r)
    diag = np.diag(r)
    k = int(np.argmax([trace, *diag]))
    if k == 0:
        w = 0.5 * math.sqrt(max(1.0 + trace, 0.0))
        q = [
            w,
            (r[2, 1] - r[1, 2]) / (4 * w),
            (r[0, 2] - r[2, 0]) / (4 * w),
            (r[1, 0] - r[0, 1]) / (4 * w),
        ]
    else:
        i = k - 1
        j, l = (i + 1) % 3, (i + 2) % 3
        v = 0.5 * math.sqrt(max(1.0 + 2 * diag[i] - trace, 0.0))
        q = [0.0, 0.0, 0.0, 0.0]
        q[0] = (r[l, j] - r[j, l]) / (4 * v)
        q[1 + i] = v
        q[1 + j] = (r[j, i] + r[i, j]) / (4 * v)
        q[1 + l] = (r[l, i] + r[i, l]) / (4 * v)
    q = np.asarray(q)
    q = q / np.linalg.norm(q)
    return -q if q[0] < 0 else q


class Fixed(AbstractAttitude):
    """Constant attitude.

    Attributes:
        quaternion: (4,) ``[w, x, y, z]`` body→inertial, unit norm.
    """

    quaternion: Float[Array, " 4"]

    def rotation(self, times):
        r = quaternion_to_matrix(self.quaternion)
        return jnp.broadcast_to(r, (*jnp.shape(times), 3, 3))


def reference_direction(body_axis) -> np.ndarray:
    """The body reference direction e for a spin axis (host-side, float64).

    The body x, y or z axis least aligned with ``body_axis`` (first on ties),
    made perpendicular to it and normalised.
    """
    b = np.asarray(body_axis, dtype=np.float64)
    b = b / np.linalg.norm(b)
    e = np.zeros(3)
    e[int(np.argmin(np.abs(b)))] = 1.0
    e = e - (e @ b) * b
    return e / np.linalg.norm(e)


def pole_vector(ra_rad, dec_rad):
    """Unit vector (3,) of the direction with right ascension / declination (rad)."""
    return jnp.stack(
        [jnp.cos(dec_rad) * jnp.cos(ra_rad), jnp.cos(dec_rad) * jnp.sin(ra_rad), jnp.sin(dec_rad)],
        -1,
    )


class Spin(AbstractAttitude):
    """Uniform rotation about a fixed inertial pole (see the module docstring).

    Attributes:
        body_axis: (3,) unit spin axis in the body frame.
        body_ref: (3,) unit body reference direction ⊥ body_axis
            (:func:`reference_direction`).
        pole_ra_rad, pole_dec_rad: inertial direction of the spin pole.
        period_s: rotation period in seconds (> 0).
        phase_rad: rotation angle φ at t = 0.
        period_offset_s: added to ``period_s`` (default 0). A float32 model
            whose period is ``period_s`` = the :class:`SpinTimes` reference plus
            a small offset resolves period changes far below float32's
            resolution of the period itself (the spin fit of high-SNR data
            needs 10⁻⁸ relative).
    """

    body_axis: Float[Array, " 3"]
    body_ref: Float[Array, " 3"]
    pole_ra_rad: Float[Array, ""]
    pole_dec_rad: Float[Array, ""]
    period_s: Float[Array, ""]
    phase_rad: Float[Array, ""]
    period_offset_s: Float[Array, ""] = 0.0

    @classmethod
    def from_degrees(
        cls, body_axis, pole_ra_deg, pole_dec_deg, period_s, phase_deg=0.0, dtype=jnp.float32
    ) -> Spin:
        """Build from scene-file units (degrees), phase at the time origin (numpy
        leaves in ``dtype``)."""
        b = np.asarray(body_axis, dtype=np.float64)
        b = b / np.linalg.norm(b)
        f = lambda x: np.asarray(x, dtype=np.float64).astype(dtype)  # noqa: E731
        return cls(
            body_axis=f(b),
            body_ref=f(reference_direction(b)),
            pole_ra_rad=f(math.radians(pole_ra_deg)),
            pole_dec_rad=f(math.radians(pole_dec_deg)),
            period_s=f(period_s),
            phase_rad=f(math.radians(phase_deg)),
            period_offset_s=f(0.0),
        )

    def times(self, t_s, period_s: float | None = None) -> SpinTimes:
        """Split float64 seconds into whole turns and a remainder (host side).

        Args:
            t_s: (T,) float64 seconds from the time origin.
            period_s: the float64 period that ``self.period_s`` was rounded
                from (e.g. the scene's); the split then reproduces the float64
                angle to ~1e-7 rad in a float32 model. Default: ``self.period_s``.
        """
        t = np.asarray(t_s, dtype=np.float64)
        period = float(self.period_s) if period_s is None else float(period_s)
        turns = np.floor(t / period)
        dtype = leaf_dtype(self)
        return SpinTimes(
            turns=turns.astype(dtype),
            remainder_s=(t - turns * period).astype(dtype),
            period_ref_s=np.full(t.shape, period, dtype=dtype),
        )

    def angle_rad(self, times) -> Float[Array, " T"]:
        """Rotation angle φ(t) (rad, not wrapped)."""
        if isinstance(times, SpinTimes):
            # t = n P₀ + r, so φ = phase + 2π (r + n (P₀ − P)) / P  (mod 2π): exact in
            # value and in dφ/dP, and precise in float32 while P stays near P₀.
            # With P = period_s + period_offset_s: (P₀ − period_s) is exactly 0 when
            # period_s is the reference, and the offset keeps its full precision.
            dt = times.remainder_s + times.turns * (
                (times.period_ref_s - self.period_s) - self.period_offset_s
            )
        else:
            dt = times
        return self.phase_rad + (2.0 * jnp.pi / (self.period_s + self.period_offset_s)) * dt

    def rotation(self, times):
        ra, dec = self.pole_ra_rad, self.pole_dec_rad
        p = pole_vector(ra, dec)
        q = jnp.stack([-jnp.sin(ra), jnp.cos(ra), jnp.zeros_like(ra)])
        pxq = jnp.cross(p, q)
        phi = self.angle_rad(times)  # (T,)
        c, s = jnp.cos(phi)[:, None], jnp.sin(phi)[:, None]
        q_t = c * q[None, :] + s * pxq[None, :]  # image of body_ref
        pq_t = c * pxq[None, :] - s * q[None, :]  # image of body_axis × body_ref
        b, e = self.body_axis, self.body_ref
        be = jnp.cross(b, e)
        return (
            q_t[:, :, None] * e[None, None, :]
            + pq_t[:, :, None] * be[None, None, :]
            + p[None, :, None] * b[None, None, :]
        )


@functools.partial(
    jax.tree_util.register_dataclass,
    data_fields=["turns", "remainder_s", "period_ref_s"],
    meta_fields=[],
)
@dataclasses.dataclass(frozen=True)
class SpinTimes:
    """Times for :class:`Spin`: t = turns · period_ref_s + remainder_s (each (T,)).

    A dataclass registered as a pytree (one is made per kernel call on the host; an
    ``eqx.Module`` took ~10 µs to make)."""

    turns: Float[Array, " T"]
    remainder_s: Float[Array, " T"]
    period_ref_s: Float[Array, " T"]

    @property
    def shape(self):
        return self.turns.shape


def phase_at_offset_deg(phase_deg: float, period_s: float, offset_s: float) -> float:
    """Spin phase (deg, in [0, 360)) at ``offset_s`` seconds after the epoch where it
    is ``phase_deg``; float64 on the host so long offsets keep their precision."""
    turns = math.fmod(offset_s / period_s, 1.0)
    return math.fmod(phase_deg + 360.0 * turns, 360.0) % 360.0

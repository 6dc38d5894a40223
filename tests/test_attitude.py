"""Attitude models against independent rotation constructions."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import rotation_matrix_from_quaternion, unit

from jaxlc.body.attitude import (
    Fixed,
    Spin,
    matrix_to_quaternion,
    phase_at_offset_deg,
    quaternion_to_matrix,
    reference_direction,
)


def test_identity_quaternion_is_identity():
    r = np.asarray(Fixed(jnp.asarray([1.0, 0, 0, 0])).rotation(jnp.zeros(3)))
    np.testing.assert_allclose(r, np.broadcast_to(np.eye(3), (3, 3, 3)))


def test_quaternion_matches_rodrigues():
    rng = np.random.default_rng(0)
    with jax.enable_x64(True):
        for q in rng.normal(size=(50, 4)):
            got = np.asarray(quaternion_to_matrix(jnp.asarray(q)))
            np.testing.assert_allclose(got, rotation_matrix_from_quaternion(q), atol=1e-12)


def test_matrix_to_quaternion_round_trips():
    """Every branch of Shepperd's method (w, x, y or z largest), sign w ≥ 0."""
    rng = np.random.default_rng(1)
    qs = np.concatenate([rng.normal(size=(40, 4)), np.eye(4), -np.eye(4)])
    for q in qs / np.linalg.norm(qs, axis=1, keepdims=True):
        got = matrix_to_quaternion(rotation_matrix_from_quaternion(q))
        assert got[0] >= 0 and min(np.abs(got - q).max(), np.abs(got + q).max()) < 1e-14


def test_quaternion_convention_body_to_inertial():
    """90° about +z (w = cos 45°, z = sin 45°): body x → inertial y."""
    q = jnp.asarray([math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)])
    r = np.asarray(quaternion_to_matrix(q))
    np.testing.assert_allclose(r @ [1, 0, 0], [0, 1, 0], atol=1e-6)


@pytest.mark.parametrize("axis", [(1, 0, 0), (0, 0, 1), (0.3, -0.5, 0.8)])
def test_spin_axis_points_at_pole_and_phase_convention(axis):
    ra, dec = 30.0, 60.0
    with jax.enable_x64(True):
        spin = Spin.from_degrees(axis, ra, dec, period_s=82.6, phase_deg=0.0, dtype=jnp.float64)
        t = jnp.linspace(0, 200, 41)
        r = np.asarray(spin.rotation(t))
    pole = [
        math.cos(math.radians(dec)) * math.cos(math.radians(ra)),
        math.cos(math.radians(dec)) * math.sin(math.radians(ra)),
        math.sin(math.radians(dec)),
    ]
    b = unit(axis)
    # orthonormal, proper
    np.testing.assert_allclose(
        np.einsum("tij,tkj->tik", r, r), np.broadcast_to(np.eye(3), r.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    # body axis → pole at all times
    np.testing.assert_allclose(r @ b, np.broadcast_to(pole, (41, 3)), atol=1e-12)
    # at φ = 0 the reference direction points at the node Q = (−sin α, cos α, 0)
    e = reference_direction(b)
    q = [-math.sin(math.radians(ra)), math.cos(math.radians(ra)), 0.0]
    np.testing.assert_allclose(r[0] @ e, q, atol=1e-12)
    # right-handed rotation about the pole by 2π t / P
    angle = np.arctan2(np.cross(q, r[:, :, :] @ e) @ pole, (r @ e) @ q)
    expected = np.angle(np.exp(1j * 2 * np.pi * np.asarray(t) / 82.6))
    np.testing.assert_allclose(angle, expected, atol=1e-10)


def test_spin_times_split_is_exact_in_float64_and_precise_in_float32():
    """t = turns·P₀ + r gives the same angle as plain seconds; float32 keeps 2e-6 rad.

    The float32 model's period is 9.7 rounded to float32; the reference uses
    that same period in float64 arithmetic, so only arithmetic error is left.
    """
    t = np.linspace(0.0, 5000.0, 1001) + 0.123
    with jax.enable_x64(True):
        s64 = Spin.from_degrees((1, 0, 0), 10.0, 20.0, 9.7, 33.0, jnp.float64)
        plain = np.asarray(s64.angle_rad(jnp.asarray(t)))
        split = np.asarray(s64.angle_rad(s64.times(t)))
    np.testing.assert_allclose(np.angle(np.exp(1j * (split - plain))), 0, atol=1e-11)
    s32 = Spin.from_degrees((1, 0, 0), 10.0, 20.0, 9.7, 33.0, jnp.float32)
    period32 = float(s32.period_s)
    ref = float(s32.phase_rad) + 2 * np.pi * t / period32
    a32 = np.asarray(s32.angle_rad(s32.times(t)), np.float64)
    assert np.max(np.abs(np.angle(np.exp(1j * (a32 - ref))))) < 2e-6
    # the naive float32 angle loses ~1e-4 rad after 500 turns: why times() exists
    naive = np.asarray(s32.angle_rad(jnp.asarray(t, jnp.float32)), np.float64)
    assert np.max(np.abs(np.angle(np.exp(1j * (naive - ref))))) > 2e-5


def test_spin_times_gradient_wrt_period_is_exact():
    """dφ/dP = −2π t / P² through the split times representation."""
    t = np.array([1.0, 100.0, 1234.5])
    with jax.enable_x64(True):
        spin = Spin.from_degrees((1, 0, 0), 0.0, 0.0, 10.0, 0.0, jnp.float64)
        times = spin.times(t)

        def phi(p):
            import equinox as eqx

            return eqx.tree_at(lambda s: s.period_s, spin, p).angle_rad(times)

        d = np.asarray(jax.jacfwd(phi)(jnp.asarray(10.0)))
    np.testing.assert_allclose(d, -2 * np.pi * t / 100.0, rtol=1e-12)


def test_phase_transfer_between_epochs():
    assert phase_at_offset_deg(10.0, 82.6, 82.6 * 1000) == pytest.approx(10.0, abs=1e-6)
    assert phase_at_offset_deg(10.0, 80.0, 20.0) == pytest.approx(100.0)
    assert phase_at_offset_deg(10.0, 80.0, -20.0) == pytest.approx(280.0)

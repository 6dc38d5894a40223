"""Torque-free tumbling against an independent integrator, its limits and its scene files.

The reference integrates Euler's equations and the quaternion kinematics
q̇ = ½ q ⊗ (0, ω) with scipy's DOP853 (rtol = atol = 1e-12, float64): nothing
of the closed form (elliptic functions, canonical axes, the rotation about L)
is shared. Tolerances are angles between rotations (rad) over 1e4 s.
"""

from __future__ import annotations

import math
import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
import scipy.special as sp
from helpers import MESHES, SCENES, radec_unit, rotation_matrix_from_quaternion
from scipy.integrate import solve_ivp

import jaxlc
from jaxlc.body import elliptic
from jaxlc.body.attitude import Spin, matrix_to_quaternion
from jaxlc.body.tumble import Tumble, tumble_from_invariants
from jaxlc.errors import SceneError
from jaxlc.rendering.observation import geometry_arrays
from jaxlc.rendering.plan import make_plan

SPAN_S = 1e4
T_S = np.linspace(0.0, SPAN_S, 101)
Q0 = np.array([0.3, -0.2, 0.5, 0.6]) / np.linalg.norm([0.3, -0.2, 0.5, 0.6])


def rotation_angle_rad(a, b) -> np.ndarray:
    """Angle (rad) of the rotation between matrices a and b (..., 3, 3), precise near 0."""
    return 2.0 * np.arcsin(np.linalg.norm(np.asarray(a) - np.asarray(b), axis=(-2, -1)) / 8**0.5)


def integrate(inertia, omega, quaternion, t_s):
    """(T, 3, 3) body → inertial rotations and (T, 3) body ω by numerical integration."""
    i = np.asarray(inertia, np.float64)

    def rhs(_, y):
        w, (qw, qx, qy, qz) = y[:3], y[3:]
        dw = np.array(
            [
                (i[1] - i[2]) * w[1] * w[2] / i[0],
                (i[2] - i[0]) * w[2] * w[0] / i[1],
                (i[0] - i[1]) * w[0] * w[1] / i[2],
            ]
        )
        wx, wy, wz = w
        dq = 0.5 * np.array(
            [
                -qx * wx - qy * wy - qz * wz,
                qw * wx + qy * wz - qz * wy,
                qw * wy - qx * wz + qz * wx,
                qw * wz + qx * wy - qy * wx,
            ]
        )
        return np.concatenate([dw, dq])

    y0 = np.concatenate([np.asarray(omega, np.float64), np.asarray(quaternion, np.float64)])
    sol = solve_ivp(rhs, (0.0, t_s[-1]), y0, t_eval=t_s, rtol=1e-12, atol=1e-12, method="DOP853")
    assert sol.success
    r = np.stack([rotation_matrix_from_quaternion(q) for q in sol.y[3:].T])
    return r, sol.y[:3].T


#: One compilation per kind of times and dtype, shared by the tests (all T = 101).
_both = jax.jit(lambda model, times: (model.rotation(times), model.angular_velocity(times)))


def _rotation(model, times):
    return _both(model, times)[0]


def evaluate(inertia, omega, quaternion, t_s, dtype=np.float64):
    """The closed form's rotations and ω at t_s (host times from float64 parameters)."""
    with jax.enable_x64(dtype == np.float64):
        model = Tumble.from_state(inertia, omega, quaternion, dtype)
        r, w = _both(model, model.times(t_s, inertia, omega))
        return np.asarray(r, np.float64), np.asarray(w, np.float64)


def random_state(seed: int, mode: str):
    """Moments (triangle inequality), ω mostly along the largest (SAM) or smallest
    (LAM) moment, body axes shuffled."""
    rng = np.random.default_rng(seed)
    while True:
        i = np.sort(rng.uniform(1.0, 3.0, 3))
        if i[0] + i[1] >= i[2] and i[1] - i[0] > 0.1 and i[2] - i[1] > 0.1:
            break
    w = rng.normal(size=3) * 0.03
    w[2 if mode == "SAM" else 0] = rng.choice([-1, 1]) * rng.uniform(0.1, 0.2)
    perm = rng.permutation(3)
    return i[perm], w[perm]


def near_separatrix(offset: float):
    """A state with (L² − 2E I₂) / (2E I₂) = offset (I = 1, 2, 3)."""
    i = np.array([1.0, 2.0, 3.0])
    w1, w2 = 0.12, 0.1
    num = offset * i[1] * (i[0] * w1**2 + i[1] * w2**2) + i[0] * w1**2 * (i[1] - i[0])
    w3 = math.sqrt(num / (i[2] * (i[2] - i[1] - offset * i[1])))
    return i, np.array([w1, w2, w3])


#: name → (moments, ω); the name's first word is the mode.
CASES = {
    "SAM-1": random_state(1, "SAM"),
    "SAM-2": random_state(2, "SAM"),
    "LAM-3": random_state(3, "LAM"),
    "LAM-4": random_state(4, "LAM"),
    "SAM-separatrix+1e-3": near_separatrix(1e-3),
    "LAM-separatrix-1e-3": near_separatrix(-1e-3),
    "SAM-oblate": (np.array([2.0, 2.0, 3.0]), np.array([0.1, 0.05, 0.2])),
    "LAM-prolate": (np.array([3.0, 1.0, 3.0]), np.array([0.02, 0.15, -0.05])),
}


# ---------------------------------------------------------------------------
# The elliptic functions against scipy


@pytest.mark.parametrize("m1", [1.0, 0.5, 1e-3, 1e-8])
def test_jacobi_functions_match_scipy(m1):
    m = 1.0 - m1
    m1 = 1.0 - m  # the m1 scipy sees
    u = np.random.default_rng(0).uniform(-6, 6, 400) * sp.ellipkm1(m1)
    with jax.enable_x64(True):
        got = np.asarray(elliptic.jacobi_sn_cn_dn(u, m, m1))
        k = float(elliptic.ellipk(m, m1))
    ref = np.asarray(sp.ellipj(u, m)[:3])
    np.testing.assert_allclose(got[:2], ref[:2], rtol=0, atol=1e-13)
    # scipy's dn = cos φ₀ / cos(φ₁ − φ₀) is off by up to 5e-13 where dn ≈ √m₁ (it breaks
    # dn² = m₁ + m cn² by that much); ours is √(m₁ + m cn²)
    np.testing.assert_allclose(got[2], ref[2], rtol=0, atol=1e-12)
    np.testing.assert_allclose(k, sp.ellipkm1(m1), rtol=1e-14)


@pytest.mark.parametrize("m1", [1e-12, 1e-15])
def test_jacobi_functions_near_the_separatrix(m1):
    """scipy's ellipj is an approximation there; check F(am u | m) = u with scipy's R_F.

    dF/dφ = 1/dn reaches 1/√m₁ at u = ±K: the check is of the amplitude φ, (F − u) dn.
    """
    with jax.enable_x64(True):
        k = float(elliptic.ellipk(1.0 - m1, m1))
        u = np.linspace(-k, k, 201)
        sn, cn, dn = map(np.asarray, elliptic.jacobi_sn_cn_dn(u, 1.0 - m1, m1))
    np.testing.assert_allclose(k, sp.ellipkm1(m1), rtol=1e-14)
    np.testing.assert_allclose(sn**2 + cn**2, 1.0, atol=1e-15)
    assert np.max(np.abs(sn * sp.elliprf(cn**2, dn**2, 1.0) - u) * dn) < 3e-13


def test_carlson_integrals_match_scipy():
    rng = np.random.default_rng(1)
    x, y, z = rng.uniform(0, 3, (3, 2000))
    x[:200] = 0.0
    y[200:400] = 10 ** rng.uniform(-15, 0, 200)
    p = np.concatenate([rng.uniform(0.01, 3, 1000), rng.uniform(1, 100, 1000)])
    with jax.enable_x64(True):
        rf = np.asarray(elliptic.carlson_rf(x, y, z))
        rj = np.asarray(elliptic.carlson_rj(x, y, z, p))
        # from roots: a zero first argument keeps a finite derivative
        g = jax.grad(lambda s: elliptic.carlson_rj_from_roots(s, 0.5, 1.0, 2.0))(0.0)
    np.testing.assert_allclose(rf, sp.elliprf(x, y, z), rtol=2e-15)
    np.testing.assert_allclose(rj, sp.elliprj(x, y, z, p), rtol=5e-14)
    assert np.isfinite(g)


def test_float32_elliptic_functions_match_scipy_with_their_fewer_steps():
    """float32 runs 6 AGM steps and 10 duplication steps instead of 12: over m₁ down to
    the float32 separatrix guard (1e-6), |u| ≤ 6 K and p = 1 − n sn² up to 1e3, the
    results are scipy's to float32 rounding (sn, cn, dn: the argument's own rounding,
    ~1e-7 × u; R_F, R_J: a few ulp)."""
    rng = np.random.default_rng(2)
    m1 = np.concatenate([10 ** rng.uniform(-6, 0, 2000), [1.0, 1e-6]])
    m = 1.0 - m1
    u = (rng.uniform(-6, 6, m.size) * sp.ellipk(m)).astype(np.float32).astype(np.float64)
    n = -(10 ** rng.uniform(-3, 3, m.size))
    f32 = lambda *xs: [jnp.asarray(x, jnp.float32) for x in xs]  # noqa: E731
    got = np.asarray(elliptic.jacobi_sn_cn_dn(*f32(u, m, m1)), np.float64)
    ref = np.asarray(sp.ellipj(u, m)[:3])
    assert np.max(np.abs(got - ref) / (1.0 + np.abs(u))) < 1e-6  # measured 1.7e-7; 4 steps 2.7e-4
    sn, cn, dn = ref
    p = 1.0 - n * sn * sn
    rj = np.asarray(elliptic.carlson_rj_from_roots(*f32(np.abs(cn), dn, np.ones_like(dn), p)))
    ones = np.ones_like(m1)
    rf = np.asarray(elliptic.carlson_rf_from_roots(*f32(0 * ones, np.sqrt(m1), ones)))
    np.testing.assert_allclose(rj, sp.elliprj(cn**2, dn**2, 1.0, p), rtol=2e-6)  # 8 steps fail
    np.testing.assert_allclose(rf, sp.elliprf(0.0, m1, 1.0), rtol=2e-6)


# ---------------------------------------------------------------------------
# The motion against the integrator


@pytest.mark.parametrize("name", list(CASES))
def test_matches_the_integrator(name):
    inertia, omega = CASES[name]
    r, w = evaluate(inertia, omega, Q0, T_S)
    r_ref, w_ref = integrate(inertia, omega, Q0, T_S)
    assert Tumble.from_state(inertia, omega, Q0, np.float64).mode() == name[:3]
    assert rotation_angle_rad(r, r_ref).max() < 1e-6  # measured ≤ 5e-8 (the integrator's)
    np.testing.assert_allclose(w, w_ref, rtol=0, atol=1e-9)
    # energy, |L| and L in the inertial frame are constant
    energy = 0.5 * np.sum(inertia * w**2, axis=1)
    np.testing.assert_allclose(energy, energy[0], rtol=1e-12)
    ell = np.einsum("tij,tj->ti", r, inertia * w)
    np.testing.assert_allclose(ell, np.broadcast_to(ell[0], ell.shape), rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["SAM-1", "LAM-3", "SAM-oblate"])
def test_periods_are_those_of_the_motion(name):
    """ω repeats after body_period_s; over it the body turns by Δψ about L, and
    2π/Δψ body periods make the precession period."""
    inertia, omega = CASES[name]
    tumble = Tumble.from_state(inertia, omega, Q0, np.float64)
    body, precession = tumble.periods_s()
    r, w = integrate(inertia, omega, Q0, np.array([0.0, body]))
    np.testing.assert_allclose(w[1], w[0], rtol=0, atol=1e-10)
    turn = r[1] @ r[0].T  # a rotation about L by Δψ
    ell = r[0] @ (inertia * omega)
    ell /= np.linalg.norm(ell)
    angle = math.atan2(
        np.dot(ell, [turn[2, 1] - turn[1, 2], turn[0, 2] - turn[2, 0], turn[1, 0] - turn[0, 1]]),
        np.trace(turn) - 1.0,
    )
    dpsi = 2.0 * math.pi * body / precession
    assert abs(math.remainder(angle - dpsi, 2 * math.pi)) < 1e-9
    _, w_model = evaluate(inertia, omega, Q0, T_S / SPAN_S * body)  # one period, 101 instants
    rate = np.linalg.norm(w_model, axis=1).max()
    assert tumble.max_rate_rad_s() * (1 - 1e-2) < rate <= tumble.max_rate_rad_s() * (1 + 1e-12)
    ra, dec = tumble.angular_momentum_radec_deg()
    np.testing.assert_allclose(ell, radec_unit(ra, dec), atol=1e-12)


def test_axisymmetric_periods_are_the_textbook_ones():
    """Oblate top: ω circles the symmetry axis at ν = (I₃ − I₁) ω₃ / I₁ in the body,
    and the symmetry axis precesses about L at L / I₁."""
    inertia, omega = CASES["SAM-oblate"]
    body, precession = Tumble.from_state(inertia, omega, Q0, np.float64).periods_s()
    nu = (inertia[2] - inertia[0]) * omega[2] / inertia[0]
    assert body == pytest.approx(2 * math.pi / abs(nu), rel=1e-13)
    assert precession == pytest.approx(
        2 * math.pi * inertia[0] / np.linalg.norm(inertia * omega), rel=1e-13
    )


@pytest.mark.parametrize(
    ("axis", "inertia"),
    [
        ((1, 0, 0), (1.0, 2.5, 3.0)),  # smallest moment
        ((0, 1, 0), (1.0, 2.5, 3.0)),  # the middle one: an (unstable) equilibrium
        ((0, 0, 1), (1.0, 2.5, 3.0)),  # largest moment
        ((0.6, 0.8, 0), (2.0, 2.0, 3.0)),  # in the plane of an oblate body
        ((0.3, 0.4, 0.5), (2.0, 2.0, 2.0)),  # a sphere
    ],
)
def test_principal_axis_spin_is_the_spin_model(axis, inertia):
    with jax.enable_x64(True):
        spin = Spin.from_degrees(axis, 30.0, 60.0, 82.6, 10.0, jnp.float64)
        r_spin = np.asarray(spin.rotation(spin.times(T_S)))
        q = matrix_to_quaternion(r_spin[0])
    omega = 2 * math.pi / 82.6 * np.asarray(axis) / np.linalg.norm(axis)
    r, w = evaluate(inertia, omega, q, T_S)
    assert rotation_angle_rad(r, r_spin).max() < 1e-9  # measured 1e-13
    np.testing.assert_allclose(w, np.broadcast_to(omega, w.shape), atol=1e-15)
    tumble = Tumble.from_state(inertia, omega, q, np.float64)
    assert tumble.periods_s() == (math.inf, pytest.approx(82.6, rel=1e-13))
    assert tumble.max_rate_rad_s() == pytest.approx(np.linalg.norm(omega), rel=1e-14)


@pytest.mark.parametrize("axis", [(1, 0, 0), (0, 0, 1)])
def test_nearly_principal_spin_tends_to_the_spin_model(axis):
    """1e-13 rad/s off the axis takes the elliptic path (m ≈ 0): the limit is continuous."""
    with jax.enable_x64(True):
        spin = Spin.from_degrees(axis, 30.0, 60.0, 82.6, 10.0, jnp.float64)
        r_spin = np.asarray(spin.rotation(spin.times(T_S)))
    omega = 2 * math.pi / 82.6 * np.asarray(axis, np.float64) + 1e-13 * np.array([1, -0.7, 0.4])
    r, _ = evaluate((1.0, 2.5, 3.0), omega, matrix_to_quaternion(r_spin[0]), T_S)
    assert rotation_angle_rad(r, r_spin).max() < 1e-8  # measured 1e-9


@pytest.mark.parametrize(
    "axis", [(1, 0, 0), (-1, 0, 0), (0, 0, -1), (0.6, 0.8, 0), (0.59, -0.2, 0.78), (0.3, 0.4, 0.5)]
)
def test_uniform_factor_frame_is_a_rotation_about_the_axis(axis):
    """A uniform rotation is written B · R_z(ψ) · Bᵀ: B must be a proper rotation whose
    third column is the axis, on both sides of its helper's switch (|x| = 0.6)."""
    from jaxlc.body.free_body import frame_about

    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    with jax.enable_x64(True):
        b = np.asarray(frame_about(jnp.asarray(a)))
    np.testing.assert_allclose(b.T @ b, np.eye(3), atol=1e-14)
    assert np.linalg.det(b) == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(b[:, 2], a, atol=1e-15)


_directional = jax.jit(
    lambda state, tangent, t: jax.jvp(
        lambda i, w, q: jnp.sum(Tumble(i, w, q).rotation(t) * jnp.arange(9.0).reshape(1, 3, 3)),
        state,
        tangent,
    )
)


@pytest.mark.parametrize(
    ("axis", "inertia"),
    [((0, 0, 1), (1.0, 2.5, 3.0)), ((0.6, 0.8, 0), (2.0, 2.0, 3.0)), ((0.3, 0.4, 0.5), (2.0,) * 3)],
)
def test_uniform_rotation_derivatives_match_finite_differences(axis, inertia):
    """Along changes that keep the motion a uniform rotation (|ω| along its axis, the
    quaternion, and for a sphere any ω) the derivative of the rotations is the rigid
    rotation's: autodiff through B · R_z(ψ) · Bᵀ matches central differences."""
    w0 = 2 * math.pi / 82.6 * np.asarray(axis, np.float64) / np.linalg.norm(axis)
    state = (np.asarray(inertia, np.float64), w0, Q0)
    directions = [(1, w0 / np.linalg.norm(w0))] + [(2, e) for e in np.eye(4)]
    if len(set(inertia)) == 1:
        directions += [(1, e) for e in np.eye(3)]
    with jax.enable_x64(True):
        t = jnp.asarray(T_S[:40])
        zero = tuple(jnp.zeros_like(jnp.asarray(x)) for x in state)
        for k, d in directions:
            h = 1e-6 * np.max(np.abs(state[k]))
            tangent = list(zero)
            tangent[k] = jnp.asarray(d)
            got = _directional(tuple(map(jnp.asarray, state)), tuple(tangent), t)[1]
            plus, minus = list(state), list(state)
            plus[k], minus[k] = state[k] + h * d, state[k] - h * d
            fd = (
                _directional(tuple(map(jnp.asarray, plus)), zero, t)[0]
                - _directional(tuple(map(jnp.asarray, minus)), zero, t)[0]
            ) / (2 * h)
            assert float(got) == pytest.approx(float(fd), rel=1e-6, abs=1e-6), (k, d)


# ---------------------------------------------------------------------------
# Precision, derivatives, batching


@pytest.mark.parametrize("name", ["SAM-1", "LAM-3"])
def test_float32_with_host_times_keeps_long_curves_precise(name):
    inertia, omega = CASES[name]
    r64, _ = evaluate(inertia, omega, Q0, T_S)
    r32, _ = evaluate(inertia, omega, Q0, T_S, np.float32)
    assert rotation_angle_rad(r32, r64).max() < 1e-5  # measured ≤ 3e-6


def _loss(rotations):
    return np.sum(np.asarray(rotations) * np.arange(9.0).reshape(1, 3, 3))


_grad = jax.jit(
    jax.grad(
        lambda i, w, q, times: jnp.sum(
            Tumble(i, w, q).rotation(times) * jnp.arange(9.0).reshape(1, 3, 3)
        ),
        argnums=(0, 1, 2),
    )
)


def test_seconds_and_host_times_agree():
    inertia, omega = CASES["LAM-4"]
    with jax.enable_x64(True):
        model = Tumble.from_state(inertia, omega, Q0, np.float64)
        a = _rotation(model, model.times(T_S))
        b = _rotation(model, jnp.asarray(T_S))
    assert rotation_angle_rad(a, b).max() < 1e-12


@pytest.mark.parametrize(
    "state",
    [
        CASES["SAM-2"],
        CASES["LAM-3"],
        ((1.0, 2.5, 3.0), (0.0, 0.0, 0.2)),
        ((2.0, 2.0, 3.0), (0.1, 0.1, 0.0)),
    ],
    ids=["SAM", "LAM", "principal", "symmetric-plane"],
)
def test_gradients_are_finite_and_match_finite_differences(state):
    """d(rotation)/d(moments, ω, quaternion) with host times (whose whole periods
    come from the host) agree with central differences of plain seconds (float64,
    over 1e4 s)."""
    inertia, omega = (np.asarray(x, np.float64) for x in state)
    with jax.enable_x64(True):
        args = (jnp.asarray(inertia), jnp.asarray(omega), jnp.asarray(Q0))
        grads = _grad(*args, Tumble(*args).times(T_S))
        assert all(np.all(np.isfinite(g)) for g in grads)
        if np.count_nonzero(omega) < 3 or len(set(inertia)) < 3:
            return  # the uniform limit: finite, not the nutation's derivative (documented)
        for k, (arg, g) in enumerate(zip(args, grads, strict=True)):
            for j in range(len(arg)):
                h = 1e-6 * max(abs(float(arg[j])), 0.01)
                step = jnp.zeros_like(arg).at[j].set(h)
                plus, minus = list(args), list(args)
                plus[k], minus[k] = arg + step, arg - step
                fd = (
                    _loss(_rotation(Tumble(*plus), jnp.asarray(T_S)))
                    - _loss(_rotation(Tumble(*minus), jnp.asarray(T_S)))
                ) / (2 * h)
                assert float(g[j]) == pytest.approx(fd, rel=1e-5, abs=1e-3)


def test_vmap_over_tumbles_matches_one_at_a_time():
    states = [CASES["SAM-1"], CASES["LAM-3"], CASES["SAM-oblate"]]
    with jax.enable_x64(True):
        models = [Tumble.from_state(i, w, Q0, np.float64) for i, w in states]
        times = [m.times(T_S) for m in models]
        stack = lambda xs: jax.tree_util.tree_map(lambda *a: jnp.stack(a), *xs)  # noqa: E731
        batched = np.asarray(
            jax.jit(jax.vmap(lambda m, t: m.rotation(t)))(stack(models), stack(times))
        )
        for k, (m, t) in enumerate(zip(models, times, strict=True)):
            np.testing.assert_allclose(batched[k], np.asarray(_rotation(m, t)), atol=1e-12)


@pytest.mark.parametrize("mode", ["SAM", "LAM"])
def test_tumble_from_invariants_has_them(mode):
    """Mode, excitation (2E/L² from ω directly), precession period, L's direction
    (R I ω from the quaternion directly) and the polhode phase (the same motion
    started later) are what was asked for."""
    rng = np.random.default_rng(7 if mode == "SAM" else 8)
    for _ in range(6):
        inertia, _ = random_state(int(rng.integers(1000)), mode)
        x, period = rng.uniform(0.0, 0.95), 10 ** rng.uniform(0.5, 4.0)
        ra, dec, about, phase = rng.uniform(0, 360), rng.uniform(-89, 89), *rng.uniform(0, 1, 2)
        sense = int(rng.choice([-1, 1]))
        t = tumble_from_invariants(inertia, mode, x, period, ra, dec, 360 * about, phase, sense)
        w, q = np.asarray(t.omega_body_rad_s), np.asarray(t.quaternion)
        i1, i2, i3 = np.sort(inertia)
        e = np.sum(inertia * w**2) / np.sum((inertia * w) ** 2)  # 2E / L²
        sam = (e - 1 / i3) / (1 / i2 - 1 / i3)
        got = sam if mode == "SAM" else (1 / i1 - e) / (1 / i1 - 1 / i2)
        assert t.mode() == mode and got == pytest.approx(x, abs=1e-12)
        assert t.excitation() == pytest.approx(x, abs=1e-12)
        assert t.periods_s()[1] == pytest.approx(period, rel=1e-12)
        ell = rotation_matrix_from_quaternion(q) @ (inertia * w)
        np.testing.assert_allclose(ell / np.linalg.norm(ell), radec_unit(ra, dec), atol=1e-12)
        start = tumble_from_invariants(inertia, mode, x, period, ra, dec, 0.0, 0.0, sense)
        body = start.periods_s()[0]
        _, w_later = integrate(inertia, start.omega_body_rad_s, [1, 0, 0, 0], [0, phase * body])
        np.testing.assert_allclose(w, w_later[1], rtol=0, atol=1e-9 * np.abs(w).max())
    with pytest.raises(ValueError, match="excitation"):
        tumble_from_invariants([1, 2, 3], mode, 1.0, 10.0, 0.0, 0.0)


def test_moving_the_time_origin_is_exact():
    inertia, omega = CASES["SAM-2"]
    offset = 86400.0 * 3 + 0.123
    with jax.enable_x64(True):
        model = Tumble.from_state(inertia, omega, Q0, np.float64)
        moved = model.at_offset(offset)
        a = np.asarray(_rotation(moved, moved.times(T_S)))
        b = np.asarray(_rotation(model, model.times(T_S + offset)))
    assert rotation_angle_rad(a, b).max() < 1e-11
    assert moved.periods_s() == pytest.approx(model.periods_s(), rel=1e-12)


# ---------------------------------------------------------------------------
# Scene files and rendering

ISSUE_EXAMPLE = """
[attitude]
model = "tumble"
inertia_kg_m2 = [1.0, 2.5, 3.0]
omega_body_rad_s = [0.05, 0.20, 0.01]
quaternion = [1.0, 0.0, 0.0, 0.0]
epoch_utc = "2024-03-20T20:00:00Z"
"""

OBJECT = """
[object]
mesh = "@MESHES@/cubesat_3u.obj"
[[material]]
part = "*"
brdf = "lambert"
rd = 0.5
"""


def test_scene_accepts_the_issue_example(write_scene):
    scene = jaxlc.load_scene(write_scene(OBJECT + ISSUE_EXAMPLE))
    a = scene.attitude
    assert (a.model, a.inertia_kg_m2, a.omega_body_rad_s) == (
        "tumble",
        (1.0, 2.5, 3.0),
        (0.05, 0.2, 0.01),
    )
    assert a.epoch_utc.isoformat().startswith("2024-03-20T20:00:00")
    assert a.exact_parameters() == {
        "inertia_kg_m2": (1.0, 2.5, 3.0),
        "omega_body_rad_s": (0.05, 0.2, 0.01),
    }
    assert a.rate_rad_s() >= np.linalg.norm([0.05, 0.2, 0.01])
    assert "tumble (LAM)" in a.describe()
    # build() moves the epoch to the time origin in float64
    origin = a.epoch_utc + pd.Timedelta(seconds=5000.25)
    with jax.enable_x64(True):
        built = a.build(origin, np.float64)
        at_epoch = a.build(None, np.float64)
        r1 = np.asarray(_rotation(built, built.times(T_S)))
        r0 = np.asarray(_rotation(at_epoch, at_epoch.times(T_S + 5000.25)))
    assert rotation_angle_rad(r1, r0).max() < 1e-11
    with pytest.raises(SceneError, match="model = 'tumble' has no single spin axis"):
        scene.with_spin(10.0)


BAD = [
    ("[1.0, 2.5, 3.0]", "[1.0, 0.0, 3.0]", r"inertia_kg_m2 = \[1\., 0\., 3\.\] must all be > 0"),
    (
        "[1.0, 2.5, 3.0]",
        "[1.0, 1.0, 3.0]",
        r"inertia_kg_m2 = .* breaks the triangle inequality "
        r"I_x \+ I_y ≥ I_z \(1 \+ 1 < 3\)",
    ),
    ("[1.0, 2.5, 3.0]", "[1.0, 2.5]", "inertia_kg_m2 = .* must be a list of 3 finite numbers"),
    (
        "[0.05, 0.20, 0.01]",
        "[0.0, 0.0, 0.0]",
        r"omega_body_rad_s = .* has \|ω\| = 0 rad/s, "
        "outside .* model = 'fixed'",
    ),
    ("[0.05, 0.20, 0.01]", "[0.05, nan, 0.01]", "omega_body_rad_s = .* must be a list of 3 finite"),
    (
        "[1.0, 0.0, 0.0, 0.0]",
        "[1.0, 0.5, 0.0, 0.0]",
        r"quaternion = .* has norm 1\.11803; give "
        "a unit quaternion",
    ),
    ('"2024-03-20T20:00:00Z"', '"soon"', "epoch_utc = 'soon' is not an ISO 8601"),
]


@pytest.mark.parametrize(("old", "new", "message"), BAD, ids=[b[2][:24] for b in BAD])
def test_scene_refuses_bad_tumbles(write_scene, old, new, message):
    text = OBJECT + ISSUE_EXAMPLE.replace(old, new)
    with pytest.raises(SceneError, match=message):
        jaxlc.load_scene(write_scene(text))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("inertia_kg_m2 = [1.0, 2.5, 3.0]\n", ""), "missing required key 'inertia_kg_m2'"),
        (("quaternion =", "omega_rad_s = 1\nquaternion ="), "unknown key 'omega_rad_s'; did you"),
        (('model = "tumble"', 'model = "tumbling"'), "must be one of 'spin', 'fixed', 'tumble'"),
    ],
)
def test_scene_tumble_keys_are_strict(write_scene, edit, message):
    text = OBJECT + ISSUE_EXAMPLE.replace(*edit)
    with pytest.raises(SceneError, match=message):
        jaxlc.load_scene(write_scene(text))


def test_shipped_tumble_scene_explains_its_periods():
    scene = jaxlc.load_scene("falcon9_tumble")
    geo = jaxlc.synthetic_geometry(duration_s=10)
    plan = make_plan(scene, geometry_arrays(geo, scene.exposure_s), scene.render)
    text = plan.explain()
    body, precession = scene.attitude.tumble().periods_s()
    assert "attitude   tumble (SAM)" in text
    assert f"every {body:.6g} s" in text and f"every {precession:.6g} s" in text


def test_tumble_renders_with_shadows_and_blur():
    """The box-wing (non-convex: shadows; glossy panels: adaptive blur) tumbling."""
    text = (SCENES / "s6_boxwing.toml").read_text()
    head = text[: text.index("[attitude]")].replace('"../meshes/', f'"{MESHES}/')
    scene = jaxlc.scene_from_dict(
        tomllib.loads(
            head
            + ISSUE_EXAMPLE.replace("[0.05, 0.20, 0.01]", "[0.02, 0.08, 0.004]")
            + "[sensor]\nexposure_s = 2.0\n"
        )
    )
    lc = jaxlc.render(scene, jaxlc.synthetic_geometry(duration_s=20))
    flux = lc["flux_w_m2"].to_numpy()
    assert np.all(np.isfinite(flux) & (flux >= 0)) and np.ptp(flux) > 0
    plan = lc.attrs["plan"]
    assert "approximate" in plan and "adaptive per exposure" in plan and "tumble (" in plan


def test_tumble_light_curve_shows_its_two_frequencies(write_scene):
    """Fixed Sun and observer: the light curve's strongest periodogram peak is at a
    small combination i/P_ψ + j/T_ω of the two frequencies (and not at those of
    periods 30 % off). A precessing box: measured 4 (1/P_ψ − 1/T_ω), 0.2 bins off."""
    scene = jaxlc.load_scene(
        write_scene(
            OBJECT
            + ISSUE_EXAMPLE.replace("[1.0, 2.5, 3.0]", "[1.0, 1.0, 1.6]").replace(
                "[0.05, 0.20, 0.01]", "[0.02, 0.01, 0.1]"
            )
        )
    )
    step, n = 2.0, 2048
    geo = jaxlc.synthetic_geometry(
        duration_s=step * n, step_s=step, phase_start_deg=50, phase_end_deg=50, exposure_s=0.01
    )
    flux = jaxlc.render(scene, geo)["flux_w_m2"].to_numpy()[:n]
    power = np.abs(np.fft.rfft(flux - flux.mean())) ** 2
    freq = np.fft.rfftfreq(n, step)
    peak = freq[np.argmax(power[1:]) + 1]
    body, precession = scene.attitude.tumble().periods_s()

    def near(f1, f2):
        combos = [abs(i * f1 + j * f2) for i in range(-4, 5) for j in range(-4, 5) if i or j]
        return min(abs(peak - c) for c in combos) <= 1.0 / (n * step)

    assert near(1 / precession, 1 / body)
    assert not near(1.3 / precession, 1.3 / body)

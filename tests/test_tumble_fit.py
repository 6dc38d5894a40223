"""The tumble fit: its coordinates, its model (the renderer's), its seeds and a round trip."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from helpers import radec_unit

import jaxlc
from jaxlc.body.tumble import Tumble
from jaxlc.inference import tumble_model as tm
from jaxlc.inference import tumble_search as ts
from jaxlc.inference.data import fit_data

CYLINDER_TUMBLE = """
[object]
mesh = "{mesh}"

[[material]]
part = "*"
brdf = "ashikhmin-shirley"
rd = 0.6
rs = 0.1
nu = 20
nv = 20

[attitude]
model = "tumble"
inertia_kg_m2 = [9.5e4, 1.0e5, 2.0e4]
omega_body_rad_s = [0.02, 0.09, 0.03]
quaternion = [0.8, 0.2, 0.4, 0.4]
epoch_utc = "2019-07-07T12:00:00Z"

[sensor]
exposure_s = 1.0
"""


@pytest.fixture
def cylinder_tumble(write_scene, meshes_dir):
    return jaxlc.load_scene(
        write_scene(CYLINDER_TUMBLE.format(mesh=meshes_dir / "falcon9_cylinder.obj"))
    )


def test_second_moments_make_every_body_physical():
    rng = np.random.default_rng(0)
    ln_s = rng.uniform(-6, 6, size=(2000, 2))
    inertia = tm.moments_from_ratios(ln_s)
    i = np.sort(inertia, axis=1)
    assert np.all(i[:, 0] + i[:, 1] >= i[:, 2] * (1 - 1e-12))  # the triangle inequality
    np.testing.assert_allclose(tm.ratios_from_moments(inertia), ln_s, atol=1e-9)
    x = tm.ratio_coordinates(ln_s)
    np.testing.assert_allclose(tm.bounded_ratios(x), ln_s, atol=1e-9)
    assert np.all(np.abs(tm.bounded_ratios(np.array([-1e3, 1e3]))) <= tm.LN_RATIO_BOUND)
    # a real body's moments come back up to scale
    given = np.array([9.5e4, 1.0e5, 2.0e4])
    back = tm.moments_from_ratios(tm.ratios_from_moments(given))
    np.testing.assert_allclose(back / back[2], given / given[2], rtol=1e-12)


def test_invariants_are_the_tumbles_own():
    rng = np.random.default_rng(1)
    inertia = tm.moments_from_ratios(rng.uniform(-3, 3, size=(20, 2)))
    omega = rng.normal(size=(20, 3)) * 0.1
    q = rng.normal(size=(20, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    inv = tm.motion_invariants(inertia, omega)
    ra, dec = tm.angular_momentum_radec_deg(inertia, omega, q)
    for k in range(20):
        t = Tumble.from_state(inertia[k], omega[k], q[k], np.float64)
        body, precession = t.periods_s()
        assert inv["body_period_s"][k] == pytest.approx(body, rel=1e-10)
        assert inv["precession_period_s"][k] == pytest.approx(precession, rel=1e-10)
        assert ("SAM" if inv["sam"][k] else "LAM") == t.mode()
        assert inv["excitation"][k] == pytest.approx(t.excitation(), abs=1e-10)
        assert (ra[k], dec[k]) == pytest.approx(t.angular_momentum_radec_deg(), abs=1e-8)


def test_mcmc_chart_is_the_attitude_about_the_mode():
    rng = np.random.default_rng(2)
    theta = np.concatenate([rng.normal(size=5), rng.normal(size=4), [0.3]])
    centre, q_mode = tm.lm_to_mc(theta, 0.05)
    back = tm.mc_to_lm(centre, q_mode)
    np.testing.assert_allclose(back[5:9], theta[5:9] / np.linalg.norm(theta[5:9]), atol=1e-12)
    np.testing.assert_allclose(back[[0, 1, 2, 3, 4, 9]], theta[[0, 1, 2, 3, 4, 9]])
    assert centre[9] == pytest.approx(math.log(0.05))
    # a rotation vector δ turns the attitude by |δ| about δ̂, applied in the body frame
    delta = np.array([0.0, 0.0, 0.3])
    q = tm.mc_to_lm(np.concatenate([centre[:5], delta, centre[8:]]), np.array([1.0, 0, 0, 0]))
    np.testing.assert_allclose(q[5:9], [math.cos(0.15), 0, 0, math.sin(0.15)], atol=1e-12)


@pytest.mark.parametrize(
    ("inertia", "omega", "mode"),
    [
        ([9.5e4, 1.0e5, 2.0e4], [0.02, 0.09, 0.03], "SAM"),  # the round trip's cylinder
        ([1.0, 2.5, 3.0], [0.2, 0.05, 0.01], "LAM"),  # a triaxial body
    ],
)
def test_period_chart_inverts_with_the_jacobian_of_its_inverse(inertia, omega, mode):
    """The chart with both periods as coordinates: its period coordinates are the
    tumble's own periods, the inverse map (Newton) returns the MCMC coordinates to
    1e-9, and its ln |∂old/∂y| equals central differences of that inverse; periods no
    body of those moments can have get −∞ density."""
    from jaxlc.inference.tumble_chart import ChartLogProb, PeriodChart

    rate_ref = 0.05
    theta = tm.theta_of(inertia, omega, [0.8, 0.2, 0.4, 0.4], rate_ref)
    centre = np.delete(tm.lm_to_mc(theta, 0.02)[0], 8)
    chart = PeriodChart(centre, rate_ref)
    tumble = Tumble.from_state(inertia, omega, [1, 0, 0, 0], np.float64)
    assert tumble.mode() == mode
    body, precession = tumble.periods_s()
    rng = np.random.default_rng(3)
    spread = np.array([0.05, 0.05, 0.02, 0.02, 0.02, 0.1, 0.1, 0.1, 0.5])
    old = centre + rng.normal(size=(6, 9)) * spread
    y = chart.to_chart(old)
    lm = tm.mc_to_lm(np.insert(old, 8, 0.0, axis=1), np.array([1.0, 0.0, 0.0, 0.0]))
    inv = tm.motion_invariants(*tm.state_of(lm, rate_ref)[:2])
    np.testing.assert_allclose(y[:, 2], np.log(inv["precession_period_s"] / precession), atol=1e-10)
    np.testing.assert_allclose(y[:, 3], np.log(inv["body_period_s"] / body), atol=1e-10)
    back, log_jac, ok = chart.from_chart(y)
    assert ok.all()
    np.testing.assert_allclose(back, old, atol=1e-9)
    for k in range(3):
        h = 1e-6 * np.maximum(np.abs(y[k]), 1e-2)
        cols = []
        for j in range(9):
            dy = np.zeros(9)
            dy[j] = h[j]
            plus, minus = chart.from_chart(np.stack([y[k] + dy, y[k] - dy]))[0]
            cols.append((plus - minus) / (2 * h[j]))
        numeric = math.log(abs(np.linalg.det(np.stack(cols, axis=1))))
        assert log_jac[k] == pytest.approx(numeric, abs=1e-5)

    class Flat:  # a posterior of constant density and Δm conditional (0, 1)
        offset_index = 8

        def evaluate(self, x):
            return np.zeros(len(x)), np.zeros(len(x)), np.ones(len(x))

    lp = ChartLogProb(Flat(), chart)
    unreachable = y[:2].copy()
    unreachable[1, 3] = unreachable[1, 2] + 30.0  # T_ω e^30 × P_ψ
    got = lp(unreachable)
    assert got[0] == pytest.approx(log_jac[0], abs=1e-9)
    assert got[1] == -np.inf


def test_local_noise_is_the_white_noise_of_a_smooth_curve_with_glints():
    """The yardstick of ``poor_fit`` without errors: 0.03 mag of noise on a 37 s
    two-harmonic curve sampled at 1 Hz comes back within 10 %, and within 20 % with 2 %
    of the samples in 1-mag glints; a noise-free curve gives (nearly) zero."""
    from jaxlc.inference.data import local_noise_mag

    rng = np.random.default_rng(4)
    t = np.arange(0.0, 600.0, 1.0)
    mag = 8.0 + 0.4 * np.sin(2 * np.pi * t / 37.0) + 0.15 * np.cos(4 * np.pi * t / 37.0)
    noisy = mag + 0.03 * rng.standard_normal(t.size)
    assert local_noise_mag(noisy) == pytest.approx(0.03, rel=0.1)
    glints = noisy - np.where(rng.random(t.size) < 0.02, 1.0, 0.0)
    assert local_noise_mag(glints) == pytest.approx(0.03, rel=0.2)
    assert local_noise_mag(mag) < 0.003
    assert math.isnan(local_noise_mag(mag[:9]))


def test_the_fit_model_is_the_renderer(cylinder_tumble):
    """The tumble model at a scene's own state gives ``jaxlc.render``'s magnitudes (the
    same preparation and kernel; the times split on the device instead of the host);
    with each exposure at its least level (the MCMC's model), within the blur tolerance."""
    scene = cylinder_tumble
    geo = jaxlc.synthetic_geometry(duration_s=600, phase_start_deg=30, phase_end_deg=90)
    lc = jaxlc.render(scene, geo)
    data = fit_data(lc, geo, default_exposure_s=scene.exposure_s)
    rate = 0.1
    theta = tm.truth_theta(scene, data, rate)
    for least, atol in ((False, 2e-4), (True, 2 * scene.render.blur_tolerance_mag)):
        model = tm.tumble_model(scene, data, theta, rate, adapted=True, least_levels=least)
        m = np.asarray(model.magnitudes(model.to_device(theta)), np.float64)
        np.testing.assert_allclose(m, data.mag, atol=atol)


def test_mirror_twins_give_the_same_light_curve(cylinder_tumble):
    """With the Sun and the observer in one plane (the equator), a body mirror-symmetric
    about its x = 0 and y = 0 planes (the cylinder) has the same light curve in a state
    and in its mirror twins about those axes, and the twin's L is −(L − 2(L·n)n)."""
    scene = cylinder_tumble
    geo = jaxlc.synthetic_geometry(duration_s=300, phase_start_deg=30, phase_end_deg=90)
    data = fit_data(jaxlc.render(scene, geo), geo, default_exposure_s=scene.exposure_s)
    rate = 0.1
    theta = tm.truth_theta(scene, data, rate)
    twins = ts.mirror_twins(theta[None], data, rate)  # b = x, y, z
    model = tm.tumble_model(scene, data, theta, rate)
    m = np.asarray(model.magnitudes(model.to_device(theta)), np.float64)
    for k in (0, 1):
        mk = np.asarray(model.magnitudes(model.to_device(twins[k])), np.float64)
        np.testing.assert_allclose(mk, m, atol=5e-4)
    ell = radec_unit(*tm.angular_momentum_radec_deg(*tm.state_of(theta, rate)))
    n = np.array([0.0, 0.0, 1.0])  # the synthetic geometry's Sun–observer plane
    for twin in twins:
        got = radec_unit(*tm.angular_momentum_radec_deg(*tm.state_of(twin, rate)))
        np.testing.assert_allclose(got, -(ell - 2 * (ell @ n) * n), atol=1e-9)
    inv = tm.motion_invariants(*tm.state_of(np.vstack([theta, twins]), rate)[:2])
    np.testing.assert_allclose(inv["body_period_s"], inv["body_period_s"][0], rtol=1e-9)


def test_frequency_hypotheses_contain_the_motion():
    """The shipped tumbler's two reported periods are 1/P_ψ − 1/T_ω and T_ω/3."""
    f_psi, f_omega = 1 / 47.98, 1 / 166.06
    hyp = ts.frequency_hypotheses(f_psi - f_omega, 3 * f_omega)
    assert any(
        abs(math.log(a / f_psi)) < 1e-9 and abs(math.log(b / f_omega)) < 1e-9 for a, b in hyp
    )
    assert all(a > 0 and b > 0 for a, b in hyp)
    one = ts.frequency_hypotheses(0.02)
    assert all(h[0] == 0.02 and math.isnan(h[1]) for h in one)
    assert (2, -2) in [h[2:] for h in one]  # a tumbling cylinder's only period


def test_one_period_starts_make_it_their_combination():
    rng = np.random.default_rng(4)
    hyp = ts.frequency_hypotheses(1 / 33.7)
    starts = ts.tumble_starts(hyp, 64, rng, 0.1)
    inertia, omega, _q = tm.state_of(starts, 0.1)
    inv = tm.motion_invariants(inertia, omega)
    f_psi, f_omega = 1 / inv["precession_period_s"], 1 / inv["body_period_s"]
    combos = [h[2] * f_psi + h[3] * f_omega for h in hyp]
    assert np.min(np.abs(np.array(combos) * 33.7 - 1), axis=0).max() < 1e-6


def test_starts_have_the_hypothesis_periods():
    rng = np.random.default_rng(3)
    hyp = [(1 / 48.0, 1 / 166.0, 0.0), (1 / 30.0, 1 / 70.0, 0.0)]
    starts = ts.tumble_starts(hyp, 40, rng, 0.1)
    inertia, omega, _q = tm.state_of(starts, 0.1)
    inv = tm.motion_invariants(inertia, omega)
    for k, (f_psi, f_omega, _) in enumerate(hyp * 20):
        assert inv["body_period_s"][k] == pytest.approx(1 / f_omega, rel=1e-9)
        assert inv["precession_period_s"][k] == pytest.approx(
            1 / f_psi, rel=math.expm1(ts.RATIO_TOLERANCE) + 1e-9
        )


def test_render_then_fit_a_tumbler_back(cylinder_tumble, tmp_path):
    """A tumbling cylinder rendered over 10 minutes of a real pass with 0.02 mag noise,
    fitted from the command line with its two periods given 1 % off: the fit reports
    both periods (within 0.5 %, the truth inside the 90 % intervals), the mode, residuals
    the data's errors explain, and the true L among its modes."""
    from typer.testing import CliRunner

    from jaxlc.cli import app
    from jaxlc.geometry.observe import geometry_table
    from jaxlc.geometry.sites import get_site
    from jaxlc.geometry.tle import read_tles

    scene = cylinder_tumble
    tles = read_tles(Path(__file__).parents[1] / "data" / "tle" / "falcon9_rb.tle")
    tle = next(t for t in tles if t.norad_id == 45921)  # the demo pass's first 10 minutes
    start = pd.Timestamp("2020-08-10T18:00:00Z")
    geo = geometry_table(tle, get_site("mt-stromlo"), start, 600.0, 1.0, 1.0)
    lc = jaxlc.render(scene, geo)
    rng = np.random.default_rng(1)
    lc["mag"] = lc["mag"] + 0.02 * rng.standard_normal(len(lc))
    lc["mag_err"] = 0.02
    geo.to_csv(tmp_path / "geo.csv", index=False)
    lc.to_csv(tmp_path / "lc.csv", index=False)
    body, precession = scene.attitude.tumble().periods_s()
    out = tmp_path / "fit"
    args = [
        "fit",
        str(scene.source),
        str(tmp_path / "lc.csv"),
        "--geometry",
        str(tmp_path / "geo.csv"),
        "-o",
        str(out),
        "--starts",
        "512",
        "--max-steps",
        "300",
        "--period-s",
        f"{precession * 1.01:.6g}",
        "--body-period-s",
        f"{body * 0.99:.6g}",
    ]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["attitude"] == "tumble"
    assert summary["tumble_mode"] == "SAM"
    iv = summary["intervals"]
    for key, truth in (("precession_period_s", precession), ("body_period_s", body)):
        assert summary[key] == pytest.approx(truth, rel=5e-3), key
        assert iv[key]["p05"] <= truth <= iv[key]["p95"], key
    assert summary["reduced_chi2"] < 1.3  # the data's own errors explain the residuals
    assert not summary["poor_fit"] and summary["data_noise_mag"] == 0.02
    assert summary["scatter_mag"] == pytest.approx(0.02, rel=0.1)
    # The period chart mixes: τ ≈ 7–13 steps, so 300 steps hold > 15 τ (the plain
    # coordinates' τ ≈ 100–190 steps gave 2–3 τ).
    assert summary["diagnostics"]["chain_length_tau"] > 15
    # L: the best mode's is the truth's or its mirror image through the Sun–observer
    # plane (−(L − 2 (L·n) n), L a pseudovector): a mirror-symmetric body's light curve
    # is the same for both, and that plane turns by 0.2° over these 10 minutes.
    ell = radec_unit(*scene.attitude.tumble().angular_momentum_radec_deg())
    g = geo[geo["visible"]].iloc[len(geo) // 4]
    rso = g[["rso_x_m", "rso_y_m", "rso_z_m"]].to_numpy(float)
    sun = g[["sun_x_m", "sun_y_m", "sun_z_m"]].to_numpy(float) - rso
    obs = g[["obs_x_m", "obs_y_m", "obs_z_m"]].to_numpy(float) - rso
    n = np.cross(sun, obs)
    n /= np.linalg.norm(n)
    mirror = -(ell - 2 * (ell @ n) * n)
    found = radec_unit(summary["l_ra_deg"], summary["l_dec_deg"])
    angle = lambda a, b: math.degrees(math.acos(max(-1.0, min(1.0, float(a @ b)))))  # noqa: E731
    assert min(angle(found, ell), angle(found, mirror)) < 3.0
    samples = pd.read_parquet(out / "samples.parquet")
    assert {"precession_period_s", "body_period_s", "l_ra_deg", "weight"} <= set(samples)
    assert (out / "fit.png").exists() and (out / "corner.png").exists()

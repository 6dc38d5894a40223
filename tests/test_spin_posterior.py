"""The spin posterior with Δm integrated out, against brute-force integration of the
six-coordinate likelihood over a Δm grid (the slow twin)."""

import dataclasses
import math

import jax
import numpy as np
import pytest
from scipy.integrate import trapezoid

import jaxlc
from jaxlc.inference.data import fit_data, soft_clip
from jaxlc.inference.model import lm_to_mc, mc_to_lm, spin_model, to_device, truth_theta
from jaxlc.inference.offset_marginal import with_offset
from jaxlc.inference.spin_posterior import DMAG_MC, MarginalLogProb
from jaxlc.xla import filter_jit


@pytest.fixture(scope="module")
def cubesat():
    scene = jaxlc.load_scene("s5_cubesat")
    geo = jaxlc.synthetic_geometry(
        duration_s=240, step_s=1.0, phase_start_deg=30, phase_end_deg=80, tilt_deg=40
    )
    lc = jaxlc.render(scene, geo)
    lc["mag"] = lc["mag"] + 0.05 * np.random.default_rng(3).standard_normal(len(lc))
    data = fit_data(lc, geo)
    truth = truth_theta(scene, data)
    return scene, data, truth


@filter_jit
def _magnitudes(model, thetas_lm):
    return jax.vmap(model.magnitudes)(thetas_lm)


def joint_log_likelihood(model, data, x6):
    """(K,) ln L of (K, 6) points, written out from the model's magnitudes."""
    m = np.asarray(_magnitudes(model, mc_to_lm(to_device(model, x6, index=2))), float)
    var = data.mag_err**2 + np.exp(2 * x6[:, 5:6])
    r = m - soft_clip(data.mag, data.limit_mag)
    return -0.5 * np.sum(r**2 / var + np.log(2 * np.pi * var), axis=1)


def brute_force(model, data, x5, centre, half_width=1.0, n=801):
    """ln ∫ L dΔm, and Δm's conditional mean and sd, on a grid about ``centre``."""
    grid = np.linspace(centre - half_width, centre + half_width, n)
    ll = joint_log_likelihood(model, data, np.insert(np.tile(x5, (n, 1)), DMAG_MC, grid, axis=1))
    p = np.exp(ll - ll.max())
    mean = trapezoid(p * grid, grid) / trapezoid(p, grid)
    sd = np.sqrt(trapezoid(p * (grid - mean) ** 2, grid) / trapezoid(p, grid))
    log_z = ll.max() + np.log(trapezoid(p, grid))
    return log_z, mean, sd


@pytest.mark.parametrize("clip_above_median_mag", [None, 0.3])
def test_marginal_over_dmag_matches_brute_force_integration(cubesat, clip_above_median_mag):
    """Exact without the faint clip (the model is linear in Δm), and with a clip level
    0.3 mag above the median (a third of the samples softly clipped: the
    quadrature's case); the joint ln posterior of the Δm draws is exact without
    the clip, a Gaussian's approximation with it."""
    scene, data, truth = cubesat
    if clip_above_median_mag is not None:
        limit = float(np.median(data.mag)) + clip_above_median_mag
        data = dataclasses.replace(data, limit_mag=limit)
    model = spin_model(scene, data, scene.attitude.period_s, theta=truth)
    x6 = lm_to_mc(truth, 0.05)
    # the truth and a point 0.02 rad and 0.5 % in period away
    x5 = np.delete(x6, DMAG_MC)
    points = np.stack([x5, x5 + np.array([0.02, -0.01, 0.005, 0, 0])])
    lp = MarginalLogProb(model, data, float(truth[3]))
    got = lp(points)
    clipped = clip_above_median_mag is not None
    for x5, g in zip(points, got, strict=True):
        d, sd = lp.conditional[np.ascontiguousarray(x5).tobytes()]
        log_z, mean, sd_ref = brute_force(model, data, x5, d, half_width=12 * sd)
        assert g == pytest.approx(log_z, abs=0.01)  # float32 sums of ~10³
        assert d == pytest.approx(mean, abs=0.05 * sd_ref)
        assert sd == pytest.approx(sd_ref, rel=0.03)

    # with_offset: the joint ln posterior it reports is the six-coordinate one
    chain5, lp5 = points[None], got[None]
    chain6, lp6 = with_offset(chain5, lp5, lp, np.random.default_rng(0))
    assert chain6.shape == (1, 2, 6)
    np.testing.assert_allclose(np.delete(chain6[0], DMAG_MC, axis=1), points)
    np.testing.assert_allclose(
        lp6[0], joint_log_likelihood(model, data, chain6[0]), atol=0.3 if clipped else 2e-3
    )


def test_marginal_refuses_points_outside_the_prior(cubesat):
    """A period beyond the prior's factor 3, or a noise above 2 mag: −inf, not a number."""
    scene, data, truth = cubesat
    model = spin_model(scene, data, scene.attitude.period_s, theta=truth)
    x5 = np.delete(lm_to_mc(truth, 0.05), DMAG_MC)
    lp = MarginalLogProb(model, data, float(truth[3]))
    far = x5 + np.array([[0, 0, np.log(4.0), 0, 0], [0, 0, 0, 0, 4.0], [0, 0, 0, 0, 0]])
    got = lp(far)
    assert np.isneginf(got[:2]).all() and np.isfinite(got[2])


@pytest.mark.parametrize(
    "noise_mag, err_mag", [(0.05, 0.0), (0.05, 0.01), (0.003, 0.05), (0.0, 0.0)]
)
def test_noise_coordinate_moments_match_quadrature(noise_mag, err_mag):
    """The ln σ ball the samplers start from (``noise_moments``) against scipy's adaptive
    quadrature of the same one-dimensional posterior: noise dominating the errors
    (the Laplace value 1/(2N) holds), errors dominating (a plateau from the prior's
    floor, ~100× broader than 1/(2N)), and a noise-free curve (against the floor)."""
    from scipy.integrate import quad

    from jaxlc.inference.laplace import NOISE_BOUNDS_MAG, noise_moments

    n, k = 1200, 5
    rng = np.random.default_rng(7)
    r = rng.standard_normal(n) * math.hypot(noise_mag, err_mag)
    err2 = np.full(n, err_mag**2)
    mean, var = noise_moments(r, err2, k)

    r2 = np.sum(r**2) * n / (n - k)

    def ll(s):
        v = err_mag**2 + math.exp(2 * s)
        return -0.5 * (r2 / v + n * math.log(v))

    lo, hi = (math.log(b) for b in NOISE_BOUNDS_MAG)
    scan = np.linspace(lo, hi, 20001)
    values = [ll(s) for s in scan]
    top, peak = max(values), scan[int(np.argmax(values))]
    # break points where the mass is: near the peak and (geometrically) near the floor
    near = peak + np.linspace(-20, 20, 81) / math.sqrt(n)
    floor = lo + np.geomspace(1e-6, hi - lo, 60)
    points = np.unique(np.clip(np.r_[near, floor], lo + 1e-9, hi - 1e-9))

    def moment(j):
        return quad(lambda s: s**j * math.exp(ll(s) - top), lo, hi, points=points, limit=800)[0]

    z = moment(0)
    ref_mean = moment(1) / z
    ref_var = moment(2) / z - ref_mean**2
    assert mean == pytest.approx(ref_mean, abs=0.02 * math.sqrt(ref_var))
    assert var == pytest.approx(ref_var, rel=0.02)
    if err_mag == 0 and noise_mag > 0:  # the Laplace value
        assert var == pytest.approx(1 / (2 * n), rel=0.1)
    if err_mag > noise_mag > 0:
        assert var > 50 / (2 * n)

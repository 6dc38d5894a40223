"""Per-exposure start of the adaptive quadrature: where a glint or a facet's turn-on can be.

The claims of :mod:`jaxlc.rendering.glints` are checked on densely followed paths
(scipy rotations, 2,001 instants per exposure), and the render that uses them
against 256 sub-exposures.
"""

from __future__ import annotations

import re

import numpy as np
from helpers import SCENES
from scipy.spatial.transform import Rotation

import jaxlc
from jaxlc.rendering.adaptive import first_level_for
from jaxlc.rendering.glints import CLEARANCE_SIGMAS, exposure_start_scales, turning
from jaxlc.rendering.options import RenderOptions
from jaxlc.rendering.patterson import level_count


def _paths(axis, n: int, points: int, rate_rad_s: float, exposure_s: float = 1.0):
    """A map of (n, 3) inertial vectors (one per exposure, held through it) to their
    (n, points, 3) unit body-frame paths under a spin about ``axis`` over n consecutive
    exposures, and the angle turned between samples."""
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    frac = np.linspace(0.0, 1.0, points)
    t = (np.arange(n)[:, None] + frac[None, :]) * exposure_s
    rot = Rotation.from_rotvec((rate_rad_s * t).reshape(-1, 1) * axis)

    def body(v):
        v = v / np.linalg.norm(v, axis=-1, keepdims=True)
        return rot.inv().apply(np.repeat(v, points, axis=0)).reshape(n, points, 3)

    return body, rate_rad_s * exposure_s / (points - 1)


def test_cleared_exposures_stay_clear_of_every_lobe_on_the_dense_path():
    rng = np.random.default_rng(3)
    n, rate, sigma = 400, 0.4, 0.03
    normals = rng.normal(size=(6, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    h_inertial = rng.normal(size=(n, 3))  # one half-vector per exposure, held through it
    axis = rng.normal(size=3)
    body, step = _paths(axis, n, 9, rate)
    scale = exposure_start_scales(body(h_inertial), np.full(n, step), [(sigma, sigma, normals)])
    dense = _paths(axis, n, 2001, rate)[0](h_inertial)
    nearest = np.arccos(np.clip(np.max(dense @ normals.T, axis=(1, 2)), -1, 1))
    clear = scale > sigma
    assert 0.2 < clear.mean() < 0.95  # both kinds occur
    assert np.all(nearest[clear] >= CLEARANCE_SIGMAS * sigma)
    # the lobe (n·h)^n with n = 1/σ² is then below 1e-7 of its peak everywhere on the path
    assert np.all(np.max(dense @ normals.T, axis=(1, 2))[clear] ** (1 / sigma**2) < 1e-7)


def test_every_terminator_crossing_on_the_dense_path_is_flagged():
    rng = np.random.default_rng(5)
    n, rate = 300, 0.3
    normals = rng.normal(size=(8, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    sun, obs, axis = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=3)
    body, step = _paths(axis, n, 5, rate)
    flagged = turning(body(sun), body(obs), np.full(n, step), normals)
    dense_body, _ = _paths(axis, n, 2001, rate)
    crosses = np.zeros(n, bool)
    for v in (sun, obs):
        c = dense_body(v) @ normals.T
        crosses |= np.any(np.diff(np.sign(c), axis=1) != 0, axis=(1, 2))
    assert crosses.any() and (~crosses).any()
    assert np.all(flagged[crosses])


def test_cubesat_exposures_start_at_their_own_level_and_match_256_subexposures():
    """S5 (lobe 1.8°) spinning in 12 s: the whole curve used to start where its sharpest
    lobe needs (every exposure ≥ that level's instants); exposures that no face can glint
    in now start lower, and the render stays within 10 mmag of a dense one."""
    scene = jaxlc.load_scene(SCENES / "s5_cubesat.toml").with_spin(12.0, 40.0, 25.0, 0.0)
    geo = jaxlc.synthetic_geometry(
        duration_s=300, phase_start_deg=20, phase_end_deg=120, exposure_s=1.0
    )
    prep = jaxlc.prepare(scene, geo)
    blur = prep.plan.blur
    curve_start = level_count(first_level_for(blur.sweep_rad, blur.start_scale))
    auto = jaxlc.render(scene, geo)
    dense = jaxlc.render(scene, geo, options=RenderOptions(subsamples=256))
    ok = np.isfinite(dense["mag"]) & (dense["mag"] < np.nanmedian(dense["mag"]) + 5)
    assert ok.mean() > 0.8
    assert np.abs(auto["mag"][ok] - dense["mag"][ok]).max() <= 0.01
    instants = float(re.search(r"([\d.]+) instants per exposure", auto.attrs["plan"]).group(1))
    assert curve_start >= 15 and instants < 0.8 * curve_start, (instants, curve_start)

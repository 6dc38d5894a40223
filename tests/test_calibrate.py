"""The Blender/Cycles reference (calibrate): calibration both ways, analytic sphere,
shadows and blur against the JAX model, worker failure paths. Small images."""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np
import pytest
from helpers import (
    REPO,
    SCENES,
    lambert_sphere_intensity,
    pass_geometry,
    rotation_matrix_from_quaternion,
)

import jaxlc
from calibrate.environment import find_blender_environment
from calibrate.job import BlenderOptions, anisotropy, roughness, write_job
from calibrate.render import blender_render
from calibrate.runner import BlenderError, run_worker
from jaxlc.body.brdf import ASGlossy
from jaxlc.rendering.options import RenderOptions
from jaxlc.scene import MaterialSpec

needs_blender = pytest.mark.skipif(
    not find_blender_environment().available,
    reason=f"Blender environment: {find_blender_environment().describe()}",
)
SMALL = dict(resolution=64, samples=16)
PLAIN = RenderOptions(shadows="off", blur="off")


_geometry = pass_geometry


# ---------------------------------------------------------------------------
# Pure-Python pieces (no Blender)


def test_roughness_and_anisotropy_mapping():
    assert roughness(0.0) == pytest.approx(1.0)
    n = 300.0
    r = roughness(n)
    assert 2.0 / r**4 - 2.0 == pytest.approx(n)  # α = r², n = 2/α² − 2 (PHYSICS.md §5)
    r_iso, a_iso = anisotropy(n, n)
    assert a_iso == pytest.approx(0.0, abs=1e-12) and r_iso == pytest.approx(r)
    rr, a = anisotropy(30.0, 90.0)
    aspect = math.sqrt(1 - 0.9 * a)
    ax, ay = rr**2 / aspect, rr**2 * aspect  # Cycles: along its tangent (w) and across (u)
    assert 2 / ax**2 - 2 == pytest.approx(90.0) and 2 / ay**2 - 2 == pytest.approx(30.0)
    # Cycles' |anisotropy| ≤ 0.99 allows exponent ratios up to ~3.6: beyond, it is clipped
    assert anisotropy(30.0, 120.0)[1] == pytest.approx(-0.99)


# ---------------------------------------------------------------------------
# Calibration of pixel sums: the plate both ways


@needs_blender
def test_plate_calibration_both_ways_agree_with_facet_model():
    """(a) the seed's perspective camera with its 10 km plate reference and (b) the
    orthographic far-field camera agree with each other and with the facet model
    to ≤ 0.01 mag, at 500–2,000 km and phase angles 10–120°."""
    scene = jaxlc.load_scene(SCENES / "s1_plate.toml")
    geo = _geometry()
    ff = jaxlc.render(scene, geo, precision="float64", options=PLAIN)
    ortho = blender_render(scene, geo, BlenderOptions(camera="ortho", **SMALL))
    seed = blender_render(scene, geo, BlenderOptions(camera="seed", **SMALL))
    ok = np.isfinite(ff["mag"])
    assert ok.sum() >= 5
    assert np.abs(ortho["mag"] - ff["mag"])[ok].max() <= 0.01
    assert np.abs(seed["mag"] - ff["mag"])[ok].max() <= 0.01
    assert np.abs(seed["mag"] - ortho["mag"])[ok].max() <= 0.01
    assert "m_ff -5.497" in seed.attrs["seed_calibration"]  # the 1 m² plate at 10 km
    assert list(ortho.columns[:8]) == list(jaxlc.io.tables.LIGHTCURVE_COLUMNS)


@needs_blender
def test_lambert_sphere_against_analytic_phase_law():
    """Cycles renders the 5,120-facet icosphere of S2 like the analytic Lambert sphere
    (the flat-faceted mesh itself is ≤ 0.006 mag off the law)."""
    scene = jaxlc.load_scene(SCENES / "s2_sphere.toml")
    geo = _geometry(n=8, phase_start_deg=0, phase_end_deg=150, sun_dec_deg=0, tilt_deg=0)
    lc = blender_render(scene, geo, BlenderOptions(resolution=96, samples=16))
    table = jaxlc.io.tables.validate_geometry(geo)
    from jaxlc.rendering.observation import geometry_arrays

    g = geometry_arrays(table)
    law = lambert_sphere_intensity(np.radians(g.phase_angle_deg), 1.0, 0.5)
    analytic = jaxlc.rendering.photometry.magnitude(
        jaxlc.rendering.photometry.flux_w_m2(law, g.irradiance_w_m2, g.range_m)
    )
    assert np.abs(lc["mag"] - analytic).max() <= 0.015


# ---------------------------------------------------------------------------
# Against the JAX model


@needs_blender
def test_shadowed_box_wing_against_jax_model():
    from calibrate.crosscheck import same_material

    scene = same_material(jaxlc.load_scene(SCENES / "s6_boxwing.toml"))
    geo = _geometry(n=6)
    jax_lc = jaxlc.render(scene, geo, options=RenderOptions(blur="off"))
    cyc = blender_render(scene, geo, BlenderOptions(**SMALL))
    ok = np.isfinite(jax_lc["mag"]) & np.isfinite(cyc["mag"])
    rms = float(np.sqrt(np.mean((cyc["mag"] - jax_lc["mag"])[ok] ** 2)))
    assert rms <= 0.05, rms
    unshadowed = jaxlc.render(scene, geo, options=PLAIN)
    assert np.abs(unshadowed["mag"] - cyc["mag"])[ok].max() > 0.05  # Cycles does see the shadows


def _sharp_and_blurred_match_jax(scene, geo) -> None:
    """Cycles against the JAX model, sharp (≤ 0.01 mag) and motion-blurred (≤ 0.02 mag),
    where the blur itself matters (> 0.02 mag)."""
    sharp_jax = jaxlc.render(scene, geo, precision="float64", options=RenderOptions(blur="off"))
    sharp = blender_render(scene, geo, BlenderOptions(**SMALL))
    assert np.abs(sharp["mag"] - sharp_jax["mag"]).max() <= 0.01
    blur_jax = jaxlc.render(scene, geo, precision="float64")
    blur = blender_render(scene, geo, BlenderOptions(motion_blur=True, **SMALL))
    assert np.abs(blur["mag"] - blur_jax["mag"]).max() <= 0.02
    assert np.abs(blur_jax["mag"] - sharp_jax["mag"]).max() > 0.02  # the blur matters here


@needs_blender
def test_motion_blur_keyframes_follow_the_spin():
    """The CubeSat (as-glossy) spinning in 10 s over 1 s exposures: Cycles' motion blur
    of the keyframed spin against the JAX sub-exposures; sharp renders agree too."""
    scene = jaxlc.load_scene(SCENES / "s5_cubesat.toml")
    scene = dataclasses.replace(
        scene, materials=(MaterialSpec("*", ASGlossy(0.15, 0.4, 1000.0, 1000.0)),)
    )
    geo = _geometry(
        n=5, duration_s=20, step_s=4, phase_start_deg=30, phase_end_deg=60, exposure_s=1.0
    )
    _sharp_and_blurred_match_jax(scene, geo)


@needs_blender
def test_tumbling_body_keyframed_from_the_same_attitude():
    """The CubeSat (as-glossy) tumbling torque-free (LAM, 2.4°/s … 8°/s): the job's
    per-frame keyframes come from the tumble, so Cycles' motion-blurred frames match
    the JAX sub-exposures; the sharp renders match the tumble's rotation at each
    exposure's midpoint (and not the tumble's at its start)."""
    scene = jaxlc.load_scene(SCENES / "s5_cubesat.toml")
    tumble = jaxlc.scene_from_dict(
        {
            "object": {"mesh": str(scene.mesh_path)},
            "material": [{"part": "*", "brdf": "lambert", "rd": 0.5}],
            "attitude": {
                "model": "tumble",
                "inertia_kg_m2": [0.3, 1.0, 1.05],
                "omega_body_rad_s": [0.12, 0.04, 0.05],
                "quaternion": [0.9, 0.1, 0.3, 0.3],
            },
        }
    )
    scene = dataclasses.replace(
        scene,
        attitude=tumble.attitude,
        materials=(MaterialSpec("*", ASGlossy(0.15, 0.4, 1000.0, 1000.0)),),
    )
    geo = _geometry(n=5, duration_s=25, step_s=5, phase_start_deg=30, phase_end_deg=60)
    geo["exposure_s"] = 2.0
    _sharp_and_blurred_match_jax(scene, geo)
    # the sharp frames are the tumble's attitude at mid-exposure, as prepared
    prepared = jaxlc.prepare(scene, geo, precision="float64", subsamples=1)
    with jax.enable_x64(True):
        want = scene.attitude.build(None, np.float64).rotation(
            np.asarray(geo["t_s"] + 0.5 * geo["exposure_s"])
        )
    got = jaxlc.rotation_matrices(prepared)
    np.testing.assert_allclose(got, np.asarray(want), atol=1e-12)
    q = np.array([0.9, 0.1, 0.3, 0.3]) / np.linalg.norm([0.9, 0.1, 0.3, 0.3])
    assert np.abs(got[0] - rotation_matrix_from_quaternion(q)).max() > 1e-3


# ---------------------------------------------------------------------------
# Failure paths


def _tiny_job(tmp_path, **extra):
    frames = {
        "quaternions": np.array([[[1.0, 0, 0, 0]]]),
        "sun_dir": np.array([[0, 0, 1.0]]),
        "obs_dir": np.array([[0, 0, 1.0]]),
        "irradiance_w_m2": np.array([1062.0]),
        "camera_distance": np.array([3.0]),
    }
    parts = [
        (
            "plate",
            np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0.0]]),
            np.array([[0, 1, 2]]),
        )
    ]
    settings = BlenderOptions(resolution=16, samples=1).job_settings() | {"motion_steps": 1}
    return write_job(
        tmp_path / "job",
        parts,
        [{"part": "plate", "diffuse": 1.0, "glossy": 0.0}],
        {"mode": "ortho", "ortho_scale": 2.0},
        settings,
        frames,
        extra,
    )


def test_missing_environment_says_make_setup(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXLC_BLENDER_VENV", str(tmp_path / "nowhere"))
    with pytest.raises(BlenderError, match="run `make setup`"):
        run_worker(_tiny_job(tmp_path), timeout_s=30)


@needs_blender
def test_worker_crash_reports_stderr(tmp_path):
    with pytest.raises(BlenderError, match=r"exit status 3.*crash requested by the job"):
        run_worker(_tiny_job(tmp_path, crash_for_test=True), timeout_s=60)


@needs_blender
def test_worker_hang_times_out(tmp_path):
    with pytest.raises(BlenderError, match="did not finish within 4 s"):
        run_worker(_tiny_job(tmp_path, hang_for_test=True), timeout_s=4)


@needs_blender
def test_worker_bad_job(tmp_path):
    job = _tiny_job(tmp_path)
    (job / "job.json").write_text("{not json")
    with pytest.raises(BlenderError, match="cannot read the job"):
        run_worker(job, timeout_s=60)


@needs_blender
def test_keep_images(tmp_path):
    keep = tmp_path / "images"
    lc = blender_render(
        SCENES / "s1_plate.toml", _geometry(n=2), BlenderOptions(keep_images=keep, **SMALL)
    )
    assert len(list(keep.glob("*.exr"))) == int(lc["visible"].sum()) > 0


@needs_blender
def test_cli_calibrate_render(tmp_path):
    from test_cli import run_cli

    geo = tmp_path / "g.csv"
    jaxlc.write_table(_geometry(n=3), geo)
    out = tmp_path / "lc.csv"
    r = run_cli(
        "calibrate",
        "render",
        SCENES / "s1_plate.toml",
        geo,
        "-o",
        out,
        "--resolution",
        "32",
        "--samples",
        "8",
        cwd=tmp_path,
    )
    assert r.returncode == 0, r.stderr
    lc = jaxlc.read_lightcurve(out)
    assert lc.attrs["renderer"].startswith("blender") and len(lc) == 3
    bad = run_cli(
        "calibrate",
        "render",
        SCENES / "s1_plate.toml",
        geo,
        "-o",
        out,
        "--camera",
        "fisheye",
        cwd=tmp_path,
    )
    assert bad.returncode == 1 and "camera = 'fisheye'" in bad.stderr


def test_worker_reads_the_job_version_the_main_side_writes():
    """The worker (bpy + numpy only, no jaxlc) states its own format version: the
    same number :mod:`calibrate.job` writes."""
    import re

    from calibrate.job import JOB_VERSION

    src = (REPO / "calibrate" / "worker.py").read_text()
    assert re.search(r"^JOB_VERSION = (\d+)$", src, flags=re.M).group(1) == str(JOB_VERSION)


@needs_blender
def test_worker_refuses_another_version_and_misshapen_arrays(tmp_path):
    import json

    job = _tiny_job(tmp_path / "a")
    spec = json.loads((job / "job.json").read_text())
    (job / "job.json").write_text(json.dumps({**spec, "version": 1}))
    with pytest.raises(BlenderError, match="job format version 1, this worker reads version 2"):
        run_worker(job, timeout_s=60)
    job = _tiny_job(tmp_path / "b")
    arrays = dict(np.load(job / "arrays.npz"))
    np.savez(job / "arrays.npz", **{**arrays, "sun_dir": arrays["sun_dir"][:, :2]})
    with pytest.raises(BlenderError, match=r"job array 'sun_dir' is shape \(1, 2\)"):
        run_worker(job, timeout_s=60)

"""Exact BRDFs with Cycles' visibility (calibrate.visibility): any material, direct light,
against analytic facet values, the analytic Lambert sphere and the exact shadow twin."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from helpers import SCENES, ashikhmin_shirley_rho, lambert_sphere_intensity, pass_geometry

import jaxlc
from calibrate.environment import find_blender_environment
from calibrate.job import BlenderOptions
from calibrate.visibility import (
    body_directions,
    coincident_twins,
    cycles_visibility,
    exact_direct_render,
)
from jaxlc import AshikhminShirley, RenderOptions
from jaxlc.body.shadow_exact import ExactShadows
from jaxlc.rendering import photometry
from jaxlc.rendering.observation import geometry_arrays
from jaxlc.scene import MaterialSpec

needs_blender = pytest.mark.skipif(
    not find_blender_environment().available,
    reason=f"Blender environment: {find_blender_environment().describe()}",
)
AS = AshikhminShirley(rd=0.5, rs=0.3, nu=200.0, nv=200.0)


def _geometry(n=6, **kw):
    args = dict(phase_start_deg=5, phase_end_deg=140, range_start_m=1e6, range_end_m=1e6)
    return pass_geometry(n, **(args | kw))


def _mag(intensity, g):
    return photometry.magnitude(photometry.flux_w_m2(intensity, g.irradiance_w_m2, g.range_m))


def test_coincident_twins_pair_a_two_sided_plate():
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2], [1, 2, 3]])
    assert coincident_twins(faces).tolist() == [2, 3, 0, 1, -1]


@needs_blender
def test_as_plate_matches_the_analytic_brdf():
    """A two-sided 1 m² plate (facing +z) in the AS material: Cycles' visibility and
    the facet BRDF give I/E = ρ_AS(n, s, v) μ0 μ A of the facet facing both (an
    independent float64 BRDF) to ≤ 0.01 mag, from either side, through the
    orthographic camera and the seed's perspective one."""
    scene = dataclasses.replace(
        jaxlc.load_scene(SCENES / "s1_plate.toml"), materials=(MaterialSpec("*", AS),)
    )
    geo = _geometry(phase_end_deg=120)
    lc = exact_direct_render(scene, geo, BlenderOptions(resolution=256), all_facets=True)
    g = geometry_arrays(jaxlc.io.tables.validate_geometry(geo))
    expected = []
    for s, v in zip(g.sun_dir, g.obs_dir, strict=True):
        n = np.array([0.0, 0.0, 1.0 if s[2] > 0 else -1.0])
        u = np.array([1.0, 0.0, 0.0])
        ok = np.dot(n, s) > 0 and np.dot(n, v) > 0
        rho = ashikhmin_shirley_rho(n, u, np.cross(n, u), s, v, 0.5, 0.3, 200.0, 200.0)
        expected.append(rho * np.dot(n, s) * np.dot(n, v) if ok else 0.0)
    expected = np.array(expected)
    lit = expected > 0
    assert lit.sum() >= 4
    np.testing.assert_allclose(lc["mag"][lit], _mag(expected, g)[lit], atol=0.01)
    seed = exact_direct_render(
        scene, geo, BlenderOptions(camera="seed", resolution=256), all_facets=True
    )
    np.testing.assert_allclose(seed["mag"][lit], _mag(expected, g)[lit], atol=0.01)


@needs_blender
def test_spheres_through_the_visibility_path():
    """The S2 icosphere: in Lambert against the analytic sphere law (the mesh itself
    is ≤ 0.006 mag off it) and in AS against the facet model, ≤ 0.01 mag, over
    phase 0–150°."""
    scene = jaxlc.load_scene(SCENES / "s2_sphere.toml")
    geo = _geometry(n=8, phase_start_deg=0, phase_end_deg=150, sun_dec_deg=0, tilt_deg=0)
    g = geometry_arrays(jaxlc.io.tables.validate_geometry(geo))
    law = lambert_sphere_intensity(np.radians(g.phase_angle_deg), 1.0, 0.5)
    lc = exact_direct_render(scene, geo, all_facets=True)  # 512 px; 256: 0.009 mag at 150°
    assert np.abs(lc["mag"] - _mag(law, g)).max() <= 0.01
    glossy = dataclasses.replace(scene, materials=(MaterialSpec("*", AS),))
    lc = exact_direct_render(glossy, geo, all_facets=True)
    facet = jaxlc.render(glossy, geo, precision="float64")
    assert np.abs(lc["mag"] - facet["mag"]).max() <= 0.01


@needs_blender
def test_shadowed_facets_agree_with_the_exact_twin():
    """S6 box-wing frames where the panels shadow the bus: Cycles' lit-and-seen
    fraction of every facet facing both that it sees with ≥ 300 pixels equals the exact polygon
    clipping's to ≤ 0.03, and some facets are partly shadowed."""
    scene = jaxlc.load_scene(SCENES / "s6_boxwing.toml")
    geo = _geometry(n=4, phase_start_deg=40, phase_end_deg=120)
    prepared, vis = cycles_visibility(scene, geo, BlenderOptions(resolution=512), all_facets=True)
    mesh, facets = prepared.scene.body
    exact = ExactShadows(mesh, facets)
    sun_b, obs_b = body_directions(prepared)
    got, want = [], []
    for i in range(len(vis.rows)):
        truth = exact.fractions(sun_b[i], obs_b[i])
        mu, mu0 = obs_b[i] @ facets.normals.T, sun_b[i] @ facets.normals.T
        big = (mu > 0.1) & (mu0 > 0.1) & (vis.seen_pixels[i] >= 300)
        got += list(vis.lit_seen[i][big])
        want += list(truth[big])
    want = np.array(want)
    assert len(want) >= 4
    np.testing.assert_allclose(got, want, atol=0.03)
    assert np.any((want > 0.1) & (want < 0.9))  # a partly shadowed facet among them


@needs_blender
def test_as_falcon9_matches_the_jax_shadow_model():
    """S4 in its own AS materials (which Cycles' BSDFs cannot render): the visibility
    path and the JAX model with its shadow table agree like the matched-material
    crosscheck does (RMS ≤ 0.05 mag over a pass)."""
    scene = jaxlc.load_scene(SCENES / "s4_falcon9.toml")
    geo = _geometry(n=8, phase_end_deg=150)
    lc = exact_direct_render(scene, geo, BlenderOptions(resolution=256))
    jax_lc = jaxlc.render(scene, geo, precision="float64", options=RenderOptions(blur="off"))
    d = (lc["mag"] - jax_lc["mag"]).to_numpy()
    d = d[np.isfinite(d)]
    assert len(d) >= 6 and math.sqrt(np.mean(d**2)) <= 0.05


@needs_blender
def test_crosscheck_as_command_writes_the_binned_table(tmp_path):
    """`jaxlc calibrate crosscheck --material as` on the antenna-box shape: the
    table has the three comparisons, "all" and the phase bins (no accuracy is
    asserted: that is the facet model's shadowing, which the table measures)."""
    import subprocess
    import sys

    from helpers import REPO

    out = tmp_path / "cc"
    r = subprocess.run(
        [sys.executable, "-m", "jaxlc.cli", "calibrate", "crosscheck", "--material", "as",
         "--scenes", "S7", "--frames", "6", "--resolution", "64", "--samples", "16",
         "--visibility-resolution", "256", "--out", str(out)],
        capture_output=True, text=True, cwd=REPO, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    table = jaxlc.read_table(out / "as_crosscheck.csv")
    assert set(table["comparison"]) == {"as direct", "bounces 1", "bounces 4"}
    assert "all" in set(table["phase_bin"]) and "0–30" in set(table["phase_bin"])
    row = table[(table.comparison == "as direct") & (table.phase_bin == "all")].iloc[0]
    assert row.frames >= 5 and np.isfinite(row.rms_mag) and row.meets_target in (True, False)
    assert (out / "as_crosscheck.png").exists() and "as direct" in r.stdout

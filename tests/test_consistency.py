"""One forward model: render, the dataset path and the spin fit's model agree.

Every path that makes a light curve calls one preparation
(:func:`jaxlc.prepare`) and one kernel entry (:func:`jaxlc.exposure_intensity`).
These tests hold them together where they used to drift apart: for S4 (shadows),
S5 (sharp glints, many sub-exposures) and S6 (shadows, anisotropic gloss), each
spinning, with 1 s exposures, motion blur and shadows on,

* a curve generated into a dataset (the dataset path) and stored,
* the same curve re-rendered with :func:`jaxlc.render` from its labels, and
* the spin fit's forward model at the curve's true spin (from its labels)

agree within 10⁻⁴ mag (float32) on every visible row. And a render → fit round
trip with default options recovers the truth of S5 and S6 from the command
line and from a dataset.

The geometry is a real pass (Falcon 9 R/B 45921 over Mt Stromlo, the demo's):
with synthetic geometry the Sun and the observer stay in one plane, and a
mirror-symmetric body (every shipped one) then has a second pole, the first's
mirror image in that plane, with exactly the same light curve; the fit reports
both modes with equal weight, and no test of "the" pole can pass.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from helpers import REPO
from test_cli import run_cli

import jaxlc
import jaxlc.dataset as dataset
from jaxlc.errors import JaxlcError
from jaxlc.inference.data import fit_data
from jaxlc.inference.model import angle_between_deg, spin_model, to_device, truth_theta

pytest.importorskip("zarr")

TLE = REPO / "data" / "tle" / "falcon9_rb.tle"
PASS = ["--tle", TLE, "--norad", "45921", "--site", "mt-stromlo", "--step-s", "1"]
CONFIG = f"""
[dataset]
count = 9
samples = 600
cadence_s = 1.0
exposure_s = 1.0
shard_size = 9
seed = 5

[[class]]
name = "S4"
scene = "s4_falcon9"
period_s = [20.0, 60.0]

[[class]]
name = "S5"
scene = "s5_cubesat"
period_s = [8.0, 12.0]

[[class]]
name = "S6"
scene = "s6_boxwing"
period_s = [40.0, 80.0]

[geometry]
source = "passes"
tle = "{TLE}"
norad = [45921]
sites = ["mt-stromlo"]
start_utc = "2020-08-10T00:00:00Z"
days = 1
"""


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("consistency") / "bulk.toml"
    path.write_text(CONFIG)
    return dataset.generate(path, path.with_suffix(".zarr"), workers=0, progress=False)


def _first_of_each_class(ds):
    labels = ds.labels
    return {c: int(labels.index[labels["class"] == c][0]) for c in ("S4", "S5", "S6")}


@pytest.mark.parametrize("name", ["S4", "S5", "S6"])
def test_render_dataset_and_fit_model_agree(store, name):
    i = _first_of_each_class(store)[name]
    scene = jaxlc.scene_from_dict(store.scene(i))
    geo = store.geometry(i)
    assert scene.attitude.model == "spin" and (geo["exposure_s"] == 1.0).all()

    rendered = jaxlc.render(scene, geo)  # the front door, float32
    plan = rendered.attrs["plan"]
    assert plan.split(" | ")[3].startswith("adaptive per exposure")  # blurred where needed
    if name != "S5":
        assert "approximate" in plan  # S4 and S6 are rendered with self-shadowing
    mag = rendered["mag"].to_numpy()
    visible = rendered["visible"].to_numpy()
    assert visible.sum() > 500

    stored = store["mag"][i].astype(np.float64)  # the dataset path
    np.testing.assert_array_equal(np.isfinite(stored), np.isfinite(mag))
    np.testing.assert_array_equal(np.isposinf(stored), np.isposinf(mag))
    lit = np.isfinite(mag)
    assert np.max(np.abs(stored[lit] - mag[lit])) < 1e-4

    # The fit's forward model at the true spin, over the rows a fit uses (visible,
    # finite magnitude), its magnitudes unclipped and without the intensity floor.
    data = fit_data(rendered, geo, default_exposure_s=scene.exposure_s)
    # Its sub-exposures are chosen at the spin it is evaluated around (as the
    # MCMC's model is at each mode), here the truth: the instants a render picks;
    # with each exposure then at its least level (the MCMC's model), within twice
    # the blur tolerance of the render (each within it of the exact integral).
    truth = truth_theta(scene, data)
    assert data.n == lit.sum()
    for least, atol in ((False, 1e-4), (True, 2 * scene.render.blur_tolerance_mag)):
        model = spin_model(
            scene, data, scene.attitude.period_s, floor=False, theta=truth, least_levels=least
        )
        assert model.adapted  # per-exposure counts, chosen at the truth
        intensity = np.asarray(model.intensity(to_device(model, truth)))
        fit_mag = data.const_mag - 2.5 * np.log10(intensity)
        assert np.max(np.abs(fit_mag - mag[data.rows])) < atol


def _pole_error_deg(result, attitude) -> float:
    def unit(ra, dec):
        ra, dec = math.radians(ra), math.radians(dec)
        return [math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra), math.sin(dec)]

    return float(
        angle_between_deg(
            unit(result["pole_ra_deg"], result["pole_dec_deg"]),
            unit(attitude.pole_ra_deg, attitude.pole_dec_deg),
        )
    )


@pytest.mark.slow
@pytest.mark.parametrize("name", ["s5_cubesat", "s6_boxwing"])
def test_render_then_fit_from_the_command_line(tmp_path, name):
    """The README's pipeline, default options throughout: a pass from a TLE, a shipped
    scene rendered over it, fitted; the period within 0.1 % and the pole within 5°
    of the scene's. S6 is sampled by emcee (``--sampler emcee``), S5 by the default."""
    geo, lc, out = tmp_path / "geo.csv", tmp_path / "lc.csv", tmp_path / "fit"
    duration = "1200" if name == "s6_boxwing" else "600"  # S6 spins in 300 s
    sampler = ["--sampler", "emcee"] if name == "s6_boxwing" else []
    window = ["--start", "2020-08-10T18:00:00Z", "--duration-s", duration, "--exposure-s", "1"]
    for cmd in (
        ("geometry", "pass", *PASS, *window, "-o", geo),
        ("render", name, geo, "-o", lc),
        ("fit", name, lc, "--geometry", geo, "-o", out, *sampler),
    ):
        r = run_cli(*cmd, cwd=tmp_path)
        assert r.returncode == 0, r.stderr
    summary = json.loads((out / "summary.json").read_text())
    truth = jaxlc.load_scene(name).attitude
    assert summary["period_s"] == pytest.approx(truth.period_s, rel=1e-3)
    assert _pole_error_deg(summary, truth) < 5.0
    assert summary["model"]["subsamples"] > 1  # the fit modelled the exposures
    if sampler:
        assert summary["diagnostics"]["method"] == "emcee"
        assert summary["diagnostics"]["chain_length_tau"] >= 50


@pytest.mark.slow
@pytest.mark.parametrize("name", ["S5", "S6"])
def test_dataset_curve_then_fit(store, name):
    """A stored dataset curve (noise-free), fitted with default options, gives back
    the spin in its labels."""
    i = _first_of_each_class(store)[name]
    scene = jaxlc.scene_from_dict(store.scene(i))
    geo = store.geometry(i)
    lc = geo[["utc", "t_s"]].copy()
    lc["mag"] = store["mag"][i].astype(np.float64)
    lc["visible"] = store["visible"][i]
    r = jaxlc.fit_spin(scene, lc, geo)
    assert r["period_s"] == pytest.approx(scene.attitude.period_s, rel=1e-3)
    assert _pole_error_deg(r, scene.attitude) < 5.0


GLINTS = """
[dataset]
count = 1
samples = 240
cadence_s = 1.0
exposure_s = 1.0
shard_size = 1
seed = 11

[[class]]
name = "S6"
scene = "s6_boxwing"
period_s = [40.0, 80.0]
[class.render]
shadow_exact = "glints"

[geometry]
source = "synthetic"
phase_start_deg = [20.0, 60.0]
phase_end_deg = [90.0, 140.0]
range_start_m = 1.0e6
range_end_m = 1.5e6
"""


def test_exact_glints_are_one_forward_model_too(tmp_path):
    """With ``shadow_exact = "glints"`` the dataset path, :func:`jaxlc.render` (its scene
    from the store) and the spin fit's model at the truth agree within 10⁻⁴ mag: each
    instant decides its exact terms on its own, so how the instants are cut into blocks
    does not matter. The option changes the curve (the table alone differs), so the
    agreement is of the new path."""
    path = tmp_path / "glints.toml"
    path.write_text(GLINTS)
    ds = dataset.generate(path, tmp_path / "glints.zarr", workers=0, progress=False)
    changed = 0.0
    for i in range(len(ds)):
        scene = jaxlc.scene_from_dict(ds.scene(i))
        assert scene.render.shadow_exact == "glints"
        geo = ds.geometry(i)
        mag = jaxlc.render(scene, geo)["mag"].to_numpy()
        stored = ds["mag"][i].astype(np.float64)
        lit = np.isfinite(mag)
        np.testing.assert_array_equal(np.isfinite(stored), lit)
        assert np.max(np.abs(stored[lit] - mag[lit])) < 1e-4
        table = dataclasses.replace(scene.render, shadow_exact="off")
        plain = jaxlc.render(scene, geo, options=table)["mag"].to_numpy()
        changed = max(changed, float(np.max(np.abs(plain[lit] - mag[lit]))))
        # the spin fit's forward model at the truth (rows not dark: I/E ≥ 1e-6 of the
        # brightest; a 1e-16 row is float32 noise in any path)
        rendered = jaxlc.render(scene, geo)
        data = fit_data(rendered, geo, default_exposure_s=scene.exposure_s)
        truth = truth_theta(scene, data)
        model = spin_model(
            scene, data, scene.attitude.period_s, floor=False, theta=truth, least_levels=False
        )
        assert model.obj.exact is not None
        intensity = np.asarray(model.intensity(to_device(model, truth)))
        bright = intensity > 1e-6 * intensity.max()
        fit_mag = data.const_mag - 2.5 * np.log10(intensity[bright])
        assert np.max(np.abs(fit_mag - mag[data.rows][bright])) < 1e-4
    assert changed > 1e-3
    # a whole fit would clip every term at every trial spin (its solvers vmap): refused,
    # with the fix, before any work
    with pytest.raises(JaxlcError, match="shadow_exact = 'glints' is for single renders"):
        jaxlc.fit_spin(scene, rendered, geo)

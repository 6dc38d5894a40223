"""The closed-form bound on a spinning body's lobes per exposure, against the kernel's own
lobes at dense instants, and the adaptive quadrature that starts from it."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from helpers import SCENES

import jaxlc
from jaxlc.body.facet_model import facet_intensity
from jaxlc.rendering import prepare as prepare_module
from jaxlc.rendering.exposures import exposure_instants
from jaxlc.rendering.glint_bound import lobe_bound
from jaxlc.rendering.options import RenderOptions


def _cubesat(period_s: float, duration_s: float = 300.0):
    scene = jaxlc.load_scene(SCENES / "s5_cubesat.toml")
    scene = dataclasses.replace(
        scene, attitude=dataclasses.replace(scene.attitude, period_s=period_s)
    )
    geo = jaxlc.synthetic_geometry(
        duration_s=duration_s, phase_start_deg=10, phase_end_deg=150, exposure_s=1.0
    )
    return scene, geo


@pytest.mark.parametrize("period_s", [7.0, -13.0, 40.0])
def test_bound_holds_the_lobes_at_256_instants_of_every_exposure(period_s):
    """Spins of either sense: the bound is never below the largest specular sum at 256
    instants of an exposure, and where there is a lobe it is within a few times of it
    (the bound takes min(μ0, μ) as 1), not a vacuous one."""
    scene, geo = _cubesat(period_s)
    with jax.enable_x64(True):
        prep = jaxlc.prepare(scene, geo, RenderOptions(blur="off"), precision="float64")
        obj, g, rows = prep.object, prep.geometry, prep.exposures.rows
        bound = lobe_bound(obj.model, obj.attitude, g, rows, prep.t0_s)
        dense = exposure_instants(g, rows, 256, t0_s=prep.t0_s)
        r = np.asarray(obj.attitude.rotation(dense.t_s))  # body → inertial
        s_b = np.einsum("tji,tj->ti", r, dense.sun_dir)
        v_b = np.einsum("tji,tj->ti", r, dense.obs_dir)
        lobes = dataclasses.replace(obj.model, use_lambert=False, use_as_diffuse=False)
        most = np.asarray(facet_intensity(lobes, s_b, v_b)).reshape(len(rows), 256).max(axis=1)
    assert np.all(bound >= most * (1 + 1e-9))
    glints = most > 1e-6 * most.max()
    assert 0.05 < glints.mean() < 0.95  # exposures with and without a lobe
    assert np.median(bound[glints] / most[glints]) < 3.0
    assert np.all(bound[most < 1e-30] < 1e-6 * most.max())  # no lobe: ~nothing bounded


def test_no_bound_without_a_spin_or_with_traced_coefficients():
    scene, geo = _cubesat(10.0)
    prep = jaxlc.prepare(scene, geo)
    obj, g, rows = prep.object, prep.geometry, prep.exposures.rows
    assert lobe_bound(obj.model, obj.attitude, g, rows) is not None
    traced = jax.tree_util.tree_map(jax.numpy.asarray, obj.model)
    assert lobe_bound(traced, obj.attitude, g, rows) is None
    tumble = jaxlc.prepare(SCENES / "falcon9_tumble.toml", geo)
    assert lobe_bound(tumble.object.model, tumble.object.attitude, g, rows) is None


def test_glint_free_exposures_start_coarser_and_stay_within_tolerance(monkeypatch):
    """A 10 s CubeSat spin: with the bound, exposures no lobe reaches start from the
    diffuse terms' levels — fewer instants — and the curve stays within 2 mmag of 256
    sub-exposures, as it does when every exposure starts at the lobe's level."""
    scene, geo = _cubesat(10.0, duration_s=400.0)
    dense = jaxlc.render(scene, geo, options=RenderOptions(subsamples=256))
    auto = jaxlc.render(scene, geo)
    monkeypatch.setattr(prepare_module, "lobe_bound", lambda *a, **k: None)
    lobe_start = jaxlc.render(scene, geo)
    ok = np.isfinite(dense["mag"]) & (dense["mag"] < np.nanmedian(dense["mag"]) + 5)
    for lc in (auto, lobe_start):
        assert np.abs(lc["mag"][ok] - dense["mag"][ok]).max() < 0.002
    instants = [float(lc.attrs["plan"].split(" instants per exposure")[0].split()[-1])
                for lc in (auto, lobe_start)]  # fmt: skip
    assert instants[0] < 0.7 * instants[1], instants
    assert "started from the diffuse scale" in auto.attrs["plan"]  # the plan says so
    assert "started from the diffuse scale" not in lobe_start.attrs["plan"]

"""Motion blur: adaptive sub-exposures against a dense reference; skips exact."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import SCENES

import jaxlc
from jaxlc.rendering.blur import choose_subsamples, direction_rate_rad_s
from jaxlc.rendering.exposures import exposure_instants, quadrature_nodes
from jaxlc.rendering.options import RenderOptions


def _compare(a, b):
    """Max |Δm| over exposures within 5 mag of the pass's median brightness, and the
    largest flux difference elsewhere relative to the median flux."""
    ok = np.isfinite(b["mag"]) & (b["mag"] < np.nanmedian(b["mag"]) + 5)
    dm = np.abs(a["mag"][ok] - b["mag"][ok]).max()
    median_flux = np.nanmedian(b["flux_w_m2"])
    df = (
        np.abs(a["flux_w_m2"][~ok] - b["flux_w_m2"][~ok]).max() / median_flux
        if (~ok).any()
        else 0.0
    )
    return dm, df, ok.mean()


def test_cubesat_adaptive_blur_against_256_subexposures():
    """The seed's blur object: 3U CubeSat, 10 s spin, 1 s exposures; max |Δm| ≤ 0.01."""
    scene = jaxlc.load_scene(SCENES / "s5_cubesat.toml")
    assert scene.attitude.period_s == 10.0
    geo = jaxlc.synthetic_geometry(
        duration_s=400, phase_start_deg=10, phase_end_deg=140, exposure_s=1.0
    )
    auto = jaxlc.render(scene, geo)
    dense = jaxlc.render(scene, geo, options=RenderOptions(subsamples=256))
    sharp = jaxlc.render(scene, geo, options=RenderOptions(blur="off"))
    dm, df, kept = _compare(auto, dense)
    assert kept > 0.85
    assert dm <= 0.01 and df <= 0.01, (dm, df)
    assert _compare(sharp, dense)[0] > 1.0  # blur matters here: without it, > 1 mag off
    n = int(auto.attrs["plan"].split("|")[3].split()[0])
    assert 16 <= n <= 64


@pytest.mark.parametrize("name", ["s4_falcon9", "s6_boxwing"])
def test_adaptive_blur_of_the_other_spinners(name):
    scene = jaxlc.load_scene(SCENES / f"{name}.toml")
    geo = jaxlc.synthetic_geometry(
        duration_s=200, phase_start_deg=10, phase_end_deg=140, exposure_s=1.0
    )
    auto = jaxlc.render(scene, geo)
    dense = jaxlc.render(scene, geo, options=RenderOptions(subsamples=128))
    dm, df, _ = _compare(auto, dense)
    assert dm <= 0.01 and df <= 0.01, (dm, df)


def test_slow_spin_needs_one_subexposure_and_equals_no_blur(write_scene):
    """S3's cylinder tumbling once an hour, over a slow pass: blur skipped, exactly."""
    text = (SCENES / "s3_cylinder.toml").read_text().replace('"../meshes/', '"@MESHES@/')
    scene = jaxlc.load_scene(write_scene(text.replace("period_s = 82.6", "period_s = 3600.0")))
    geo = jaxlc.synthetic_geometry(duration_s=1000, phase_start_deg=40, phase_end_deg=50)
    auto = jaxlc.render(scene, geo)
    assert "1 per exposure" in auto.attrs["plan"]
    off = jaxlc.render(scene, geo, options=RenderOptions(blur="off"))
    assert np.array_equal(auto["flux_w_m2"].to_numpy(), off["flux_w_m2"].to_numpy())


def test_subsamples_proportional_to_the_sweep():
    """Blur cost follows the motion: twice the exposure, about twice the sub-exposures."""
    scale = 1.0 / np.sqrt(1000.0)
    a = choose_subsamples(1.0, 0.2 * np.pi, scale, "lobe", max_subsamples=4096)
    b = choose_subsamples(2.0, 0.2 * np.pi, scale, "lobe", max_subsamples=4096)
    assert abs(b.subsamples - 2 * a.subsamples) <= 1
    assert choose_subsamples(1.0, 1e-4, scale, "lobe").subsamples == 1
    capped = choose_subsamples(100.0, 1.0, scale, "lobe", max_subsamples=64)
    assert capped.subsamples == 64 and capped.capped


def test_subexposure_midpoints_respect_readout_gaps():
    """Exposures of 0.4 s every 1 s: sub-exposures stay inside [t, t + 0.4]."""
    geo = jaxlc.geometry_from_positions(
        [0.0, 1.0], np.zeros((2, 3)), [[1e11, 0, 0]] * 2, [[0, 1e6, 0]] * 2, exposure_s=0.4
    )
    e = exposure_instants(geo, [0, 1], 4)
    np.testing.assert_allclose(e.t_s, [0.05, 0.15, 0.25, 0.35, 1.05, 1.15, 1.25, 1.35])
    np.testing.assert_array_equal(e.row, [0, 0, 0, 0, 1, 1, 1, 1])
    np.testing.assert_allclose(e.weight, 0.25)


@pytest.mark.parametrize("n", [1, 2, 5, 16])
def test_quadratures_integrate_linear_functions_exactly(n):
    """Midpoints and end points with trapezoid weights: weights sum to 1 and the
    mean of a linear function over the exposure is exact."""
    for rule in ("midpoint", "endpoints"):
        frac, w = quadrature_nodes(n, rule)
        assert w.sum() == pytest.approx(1.0) and np.all((frac >= 0) & (frac <= 1))
        assert np.sum(w * (3.0 * frac + 1.0)) == pytest.approx(2.5)
    assert list(quadrature_nodes(3, "endpoints")[0]) == [0.0, 0.5, 1.0]


def test_direction_rate():
    t = np.arange(5.0)
    ang = np.radians(2.0) * t
    d = np.stack([np.cos(ang), np.sin(ang), 0 * ang], 1)
    assert direction_rate_rad_s(d, t) == pytest.approx(np.radians(2.0))


def test_fixed_attitude_static_geometry_no_blur():
    scene = jaxlc.load_scene(SCENES / "s1_plate.toml")
    geo = jaxlc.synthetic_geometry(duration_s=10, phase_start_deg=30, phase_end_deg=30)
    assert "1 per exposure" in jaxlc.render(scene, geo).attrs["plan"]

"""End-to-end rendering: photometry, invariances, precision, batching, gradients."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from helpers import SCENES, lambert_sphere_intensity, random_unit_vectors, unit

import jaxlc
from jaxlc.body.attitude import Fixed, quaternion_to_matrix
from jaxlc.body.shadow import ShadowSettings
from jaxlc.rendering import photometry
from jaxlc.rendering.kernel import light_curve_intensity, stack_objects
from jaxlc.rendering.observation import geometry_arrays
from jaxlc.rendering.options import RenderOptions
from jaxlc.rendering.prepare import space_object

PLATE_FACING_X = """
[object]
mesh = "@MESHES@/plate.obj"
[[material]]
brdf = "lambert"
rd = 0.8
[attitude]
model = "fixed"
quaternion = [0.7071067811865476, 0.0, 0.7071067811865476, 0.0]   # body +z -> inertial +x
"""


def test_plate_end_to_end_photometry(write_scene):
    """Plate facing the Sun: m = −26.74 − 2.5 log10(E (ρ/π) A cos α / d² / C)."""
    geo = jaxlc.synthetic_geometry(
        duration_s=100, phase_start_deg=0, phase_end_deg=80, range_start_m=1e4, range_end_m=3e4
    )
    for precision in ("float32", "float64"):
        lc = jaxlc.render(write_scene(PLATE_FACING_X), geo, precision=precision)
        alpha = np.radians(lc["phase_angle_deg"].to_numpy())
        d = lc["range_m"].to_numpy()
        flux = photometry.C_SUN_VIS_W_M2 * 0.8 / math.pi * 1.0 * np.cos(alpha) / d**2
        mag = -26.74 - 2.5 * np.log10(flux / 1062.0)
        tol = 1e-10 if precision == "float64" else 1e-5
        np.testing.assert_allclose(lc["flux_w_m2"], flux, rtol=tol * 10)
        np.testing.assert_allclose(lc["mag"], mag, atol=tol)
    # geometry columns are exact and the table keeps every row
    np.testing.assert_allclose(lc["phase_angle_deg"], np.linspace(0, 80, 100), atol=1e-9)
    assert list(lc.columns) == list(jaxlc.io.tables.LIGHTCURVE_COLUMNS)
    assert lc.attrs["frame"] == "synthetic"


def test_seed_plate_reference_magnitude(write_scene):
    """The seed's calibration plate: 1 m² white Lambert plate at 10 km, facing Sun
    and observer (α = 0): m = −26.74 − 2.5 log10(1/(π·10⁸)) = −5.497 mag (m_ff)."""
    geo = jaxlc.synthetic_geometry(
        duration_s=1, phase_start_deg=0, phase_end_deg=0, range_start_m=1e4
    )
    text = PLATE_FACING_X.replace("rd = 0.8", "rd = 1.0")
    lc = jaxlc.render(write_scene(text), geo, precision="float64")
    assert lc["mag"].iloc[0] == pytest.approx(-26.74 + 2.5 * math.log10(math.pi * 1e8), abs=1e-9)
    assert lc["mag"].iloc[0] == pytest.approx(-5.4971, abs=1e-4)


def test_invisible_rows_kept_as_nan_and_zero_flux_is_inf(write_scene):
    geo = jaxlc.synthetic_geometry(duration_s=10, phase_start_deg=10, phase_end_deg=10)
    geo.loc[[2, 5], "visible"] = False
    geo.loc[7, "shadow_nu"] = 0.0  # umbra: not renderable either
    geo.loc[8, "shadow_nu"] = 0.5  # penumbra: half the light, +0.753 mag
    lc = jaxlc.render(write_scene(PLATE_FACING_X), geo, precision="float64")
    assert len(lc) == 10
    assert lc["mag"][[2, 5, 7]].isna().all() and lc["flux_w_m2"][[2, 5, 7]].isna().all()
    assert not lc["visible"][[2, 5, 7]].any()
    assert lc["mag"][8] - lc["mag"][9] == pytest.approx(2.5 * math.log10(2), abs=1e-9)
    # observer behind the plate (α = 170°): nothing lit is seen, zero flux, mag = +inf
    behind = jaxlc.synthetic_geometry(duration_s=3, phase_start_deg=170, phase_end_deg=170)
    lc = jaxlc.render(write_scene(PLATE_FACING_X), behind)
    assert lc["visible"].all() and (lc["flux_w_m2"] == 0).all() and np.isposinf(lc["mag"]).all()


def test_sun_distance_scales_irradiance(write_scene):
    geo = jaxlc.synthetic_geometry(duration_s=2, phase_start_deg=30, phase_end_deg=30)
    far = geo.copy()
    for c in "xyz":
        far[f"sun_{c}_m"] *= 1.04  # the farthest a Sun may be (0.95–1.05 AU)
    a = jaxlc.render(write_scene(PLATE_FACING_X), geo, precision="float64")
    b = jaxlc.render(write_scene(PLATE_FACING_X), far, precision="float64")
    np.testing.assert_allclose(b["mag"] - a["mag"], 2.5 * math.log10(1.04**2), atol=1e-9)


def test_sphere_brightness_independent_of_attitude():
    """Icosphere L4: any attitude within 0.01 mag of the analytic law, and rotating
    the object is exactly the same as rotating Sun and observer the other way."""
    scene = jaxlc.load_scene(SCENES / "s2_sphere.toml")
    rng = np.random.default_rng(11)
    alpha = np.radians(np.linspace(0, 150, 16))
    s = np.tile([1.0, 0.0, 0.0], (16, 1))
    v = np.stack([np.cos(alpha), np.sin(alpha), np.zeros(16)], 1)
    ref = lambert_sphere_intensity(alpha, 1.0, 0.5)
    with jax.enable_x64(True):
        base = space_object(scene, None, jnp.float64)
        for q in rng.normal(size=(8, 4)):
            obj = eqx.tree_at(lambda o: o.attitude, base, Fixed(jnp.asarray(unit(q))))
            got = np.asarray(
                light_curve_intensity(obj, jnp.zeros(16), jnp.asarray(s), jnp.asarray(v))
            )
            assert np.max(np.abs(2.5 * np.log10(ref / got))) < 0.01
            r = np.asarray(quaternion_to_matrix(jnp.asarray(q)))
            same = np.asarray(
                light_curve_intensity(base, jnp.zeros(16), jnp.asarray(s @ r), jnp.asarray(v @ r))
            )
            np.testing.assert_allclose(got, same, rtol=1e-12)


@pytest.mark.parametrize("scene_name", ["s4_falcon9", "s5_cubesat"])
def test_spin_light_curve_is_periodic(scene_name):
    """Fixed Sun and observer: the light curve repeats after one spin period."""
    scene = jaxlc.load_scene(SCENES / f"{scene_name}.toml")
    period = scene.attitude.period_s
    t = np.linspace(0, period, 97)
    s = np.tile(unit([1.0, 0.2, 0.1]), (97, 1))
    v = np.tile(unit([0.3, 1.0, -0.2]), (97, 1))
    with jax.enable_x64(True):
        obj = space_object(scene, None, jnp.float64)
        a = np.asarray(
            light_curve_intensity(obj, obj.attitude.times(t), jnp.asarray(s), jnp.asarray(v))
        )
        b = np.asarray(
            light_curve_intensity(
                obj, obj.attitude.times(t + 7 * period), jnp.asarray(s), jnp.asarray(v)
            )
        )
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12 * a.max())
    assert a.max() > 1.5 * a.min()  # and it does vary


@pytest.mark.parametrize("shadows", [False, True])
def test_chunking_changes_nothing(shadows):
    """The kernel's blocks of instants (balanced, padded or not, one block or many)
    give the per-instant I/E of one block holding everything (S6 with and without
    its shadow table; 1,000 instants, a count no block size divides)."""
    scene = jaxlc.load_scene(SCENES / "s6_boxwing.toml")
    rng = np.random.default_rng(3)
    n = 1000
    t = np.sort(rng.uniform(0, 600, n))
    s, v = unit(rng.normal(size=(n, 3))), unit(rng.normal(size=(n, 3)))
    with jax.enable_x64(True):
        obj = space_object(scene, None, jnp.float64, ShadowSettings() if shadows else None)
        assert (obj.shadow is not None) == shadows
        args = (obj, obj.attitude.times(t), jnp.asarray(s), jnp.asarray(v))
        whole = np.asarray(light_curve_intensity(*args, chunk=n))
        for chunk in (7, 64, 96, 128, 333, 999):
            got = np.asarray(light_curve_intensity(*args, chunk=chunk))
            np.testing.assert_allclose(got, whole, rtol=1e-12, atol=1e-15 * whole.max())
    assert np.count_nonzero(whole) > n // 4  # lit and seen often enough to compare


def test_epoch_phase_transfer(write_scene, scenes_dir):
    """Shifting the attitude epoch by whole periods changes nothing; by half a
    period it equals a 180° phase offset."""
    text = (scenes_dir / "s5_cubesat.toml").read_text().replace('"../meshes/', '"@MESHES@/')
    geo = jaxlc.synthetic_geometry(duration_s=60, phase_start_deg=40, phase_end_deg=60)
    base = jaxlc.render(write_scene(text), geo, precision="float64")
    shifted = text.replace("2019-07-07T12:00:00Z", "2019-07-07T11:50:00Z")  # 60 periods of 10 s
    same = jaxlc.render(write_scene(shifted), geo, precision="float64")
    np.testing.assert_allclose(base["mag"], same["mag"], atol=1e-7)
    half = text.replace("2019-07-07T12:00:00Z", "2019-07-07T12:00:05Z").replace(
        "phase_deg = 0.0", "phase_deg = 180.0"
    )
    np.testing.assert_allclose(
        base["mag"], jaxlc.render(write_scene(half), geo, precision="float64")["mag"], atol=1e-7
    )


def test_attitude_at_mid_exposure(scenes_dir):
    """Without blur, exposure e at t renders the attitude at t + e/2."""
    geo = jaxlc.synthetic_geometry(
        duration_s=30, phase_start_deg=50, phase_end_deg=50, exposure_s=1.0
    )
    geo0 = geo.copy()
    geo0["exposure_s"] = 0.0
    geo0["t_s"] += 0.5
    geo0["utc"] = jaxlc.io.utc.format_utc(
        pd.to_datetime(geo["utc"], utc=True) + pd.Timedelta(0.5, "s")
    )
    scene = jaxlc.load_scene(scenes_dir / "s5_cubesat.toml")
    one = RenderOptions(blur="off")  # a single sub-exposure
    a = jaxlc.render(scene, geo, precision="float64", options=one)
    b = jaxlc.render(scene, geo0, precision="float64", options=one)
    np.testing.assert_allclose(a["mag"], b["mag"], atol=1e-9)


@pytest.mark.parametrize("range_m", [71.0, 1e3, 1e7, 4e8, 1e20])
def test_tiny_and_huge_ranges(write_scene, range_m):
    """Magnitudes follow 5 log10(d) from the far field's edge (100 radii) to 10²⁰ m in
    both precisions."""
    geo = jaxlc.synthetic_geometry(
        duration_s=1, phase_start_deg=20, phase_end_deg=20, range_start_m=range_m
    )
    for precision in ("float32", "float64"):
        lc = jaxlc.render(write_scene(PLATE_FACING_X), geo, precision=precision)
        flux = 1062.0 * 0.8 / math.pi * math.cos(math.radians(20)) / range_m**2
        assert lc["mag"].iloc[0] == pytest.approx(
            -26.74 - 2.5 * math.log10(flux / 1062.0), abs=1e-5
        )


def test_float32_matches_float64_over_random_sweep():
    """10⁵ random geometries (Sun, observer, time in a 30-min pass) per scene S2–S6:
    float32 within 10⁻³ mag of float64 for every sample brighter than 1/100 of the
    median sample; everywhere within 2·10⁻⁵ of the peak in absolute intensity
    (the only larger relative errors are facets within ~10⁻⁴ of grazing)."""
    n = 100_000
    rng = np.random.default_rng(2024)
    s, v = random_unit_vectors(rng, n), random_unit_vectors(rng, n)
    t = rng.uniform(0, 1800, n)
    for name in ("s2_sphere", "s3_cylinder", "s4_falcon9", "s5_cubesat", "s6_boxwing"):
        scene = jaxlc.load_scene(SCENES / f"{name}.toml")
        exact = scene.attitude.exact_parameters()
        o32 = space_object(scene, None, jnp.float32)
        i32 = np.asarray(
            light_curve_intensity(
                o32,
                o32.attitude.times(t, **exact),
                jnp.asarray(s, jnp.float32),
                jnp.asarray(v, jnp.float32),
            ),
            np.float64,
        )
        with jax.enable_x64(True):
            o64 = space_object(scene, None, jnp.float64)
            i64 = np.asarray(
                light_curve_intensity(
                    o64, o64.attitude.times(t, **exact), jnp.asarray(s), jnp.asarray(v)
                )
            )
        bright = i64 >= 1e-2 * np.median(i64[i64 > 0])
        dm = np.abs(2.5 * np.log10(i32[bright] / i64[bright]))
        assert bright.mean() > 0.8, name
        assert dm.max() <= 1e-3, (name, dm.max())
        assert np.median(dm) <= 1e-5, name
        assert np.max(np.abs(i32 - i64)) <= 2e-5 * i64.max(), name
        assert np.all(np.isfinite(i32)) and np.all(i32 >= 0)


PLAIN = RenderOptions(shadows="off", blur="off")  # the instantaneous, unshadowed facet model


def test_vmap_over_objects_equals_single_renders():
    scenes = [
        jaxlc.load_scene(SCENES / f"{n}.toml") for n in ("s3_cylinder", "s5_cubesat", "s4_falcon9")
    ]
    geo = jaxlc.synthetic_geometry(duration_s=300, phase_start_deg=20, phase_end_deg=100)
    geo_arrays = geometry_arrays(jaxlc.io.tables.validate_geometry(geo))
    with jax.enable_x64(True):
        objs = [space_object(sc, geo_arrays.origin_utc, jnp.float64) for sc in scenes]
        times = [o.attitude.times(geo_arrays.t_mid_s) for o in objs]
        s, v = jnp.asarray(geo_arrays.sun_dir), jnp.asarray(geo_arrays.obs_dir)
        single = [
            np.asarray(light_curve_intensity(o, tm, s, v))
            for o, tm in zip(objs, times, strict=True)
        ]
        stacked = stack_objects(objs)
        stacked_times = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *times)
        batched = np.asarray(
            jax.vmap(light_curve_intensity, in_axes=(0, 0, None, None))(
                stacked, stacked_times, s, v
            )
        )
    for k in range(3):
        np.testing.assert_allclose(batched[k], single[k], rtol=1e-12)
        ref = jaxlc.render(scenes[k], geo, precision="float64", options=PLAIN)
        flux = photometry.flux_w_m2(batched[k], geo_arrays.irradiance_w_m2, geo_arrays.range_m)
        np.testing.assert_allclose(photometry.magnitude(flux), ref["mag"], atol=1e-9)


def test_stack_objects_rejects_mixed_attitudes():
    a = space_object(jaxlc.load_scene(SCENES / "s2_sphere.toml"), None)
    b = space_object(jaxlc.load_scene(SCENES / "s5_cubesat.toml"), None)
    with pytest.raises(jaxlc.JaxlcError, match="attitudes must share one type"):
        stack_objects([a, b])


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_gradients_finite_wrt_period_phase_pole_albedo(dtype):
    """jax.grad of the magnitudes of a pass, including α → 0°/180° and grazing
    samples, is finite for period, phase, pole RA/Dec and albedos."""
    scene = jaxlc.load_scene(SCENES / "s4_falcon9.toml")
    geo = jaxlc.synthetic_geometry(duration_s=120, phase_start_deg=0, phase_end_deg=180)
    g = geometry_arrays(jaxlc.io.tables.validate_geometry(geo))
    with jax.enable_x64(dtype == jnp.float64):
        obj = space_object(scene, None, dtype)
        times = obj.attitude.times(g.t_mid_s)
        args = [jnp.asarray(x, dtype) for x in (g.sun_dir, g.obs_dir, g.irradiance_w_m2, g.range_m)]

        def loss(period, phase, ra, dec, rd):
            att = eqx.tree_at(
                lambda a: (a.period_s, a.phase_rad, a.pole_ra_rad, a.pole_dec_rad),
                obj.attitude,
                (period, phase, ra, dec),
            )
            mats = scene.materials_for(scene.facets.part_names)
            mats = [eqx.tree_at(lambda m: m.rd, m, rd) for m in mats]
            model = jaxlc.facet_model(scene.facets, mats, dtype)
            i = light_curve_intensity(jaxlc.SpaceObject(model, att), times, *args[:2])
            e, d = args[2:]
            lit = i > 0  # α = 180°: nothing lit is seen, +inf mag: left out ("double where")
            safe = jnp.where(lit, i, 1.0)
            m = -26.74 - 2.5 * (jnp.log10(safe) + jnp.log10(e / 1062.0) - 2.0 * jnp.log10(d))
            return jnp.sum(jnp.where(lit, m, 0.0))

        a = obj.attitude
        grads = jax.grad(loss, argnums=(0, 1, 2, 3, 4))(
            a.period_s, a.phase_rad, a.pole_ra_rad, a.pole_dec_rad, jnp.asarray(0.5, dtype)
        )
    for name, gr in zip(("period", "phase", "ra", "dec", "rd"), grads, strict=True):
        assert np.isfinite(float(gr)), name
        assert float(gr) != 0.0, name


def test_gradient_wrt_period_matches_finite_difference():
    scene = jaxlc.load_scene(SCENES / "s5_cubesat.toml")
    geo = jaxlc.synthetic_geometry(duration_s=200, phase_start_deg=30, phase_end_deg=70)
    g = geometry_arrays(jaxlc.io.tables.validate_geometry(geo))
    with jax.enable_x64(True):
        obj = space_object(scene, None, jnp.float64)
        times = obj.attitude.times(g.t_mid_s)
        s, v = jnp.asarray(g.sun_dir), jnp.asarray(g.obs_dir)

        def total(p):
            o = eqx.tree_at(lambda x: x.attitude.period_s, obj, p)
            return jnp.sum(light_curve_intensity(o, times, s, v))

        p0 = obj.attitude.period_s
        grad = float(jax.grad(total)(p0))
        h = 1e-6
        fd = (float(total(p0 + h)) - float(total(p0 - h))) / (2 * h)
    assert grad == pytest.approx(fd, rel=1e-5)


def test_bucketed_padding_changes_nothing(scenes_dir):
    """Rendering 37 visible rows (padded to 64) equals rendering them in a longer table."""
    scene = jaxlc.load_scene(scenes_dir / "s6_boxwing.toml")
    geo = jaxlc.synthetic_geometry(duration_s=100, phase_start_deg=10, phase_end_deg=140)
    part = geo.copy()
    part.loc[37:, "visible"] = False
    a = jaxlc.render(scene, geo, precision="float64")
    b = jaxlc.render(scene, part, precision="float64")
    np.testing.assert_allclose(a["mag"][:37], b["mag"][:37], atol=1e-12)
    assert b["mag"][37:].isna().all()


def test_bad_precision():
    with pytest.raises(jaxlc.JaxlcError, match="precision = 'float16'"):
        jaxlc.render(
            SCENES / "s1_plate.toml", jaxlc.synthetic_geometry(duration_s=1), precision="float16"
        )


@pytest.mark.parametrize("range_m", [1e-3, 1.0, 70.0])
def test_observer_inside_the_far_field_is_refused(write_scene, range_m):
    """Parallel rays need a distant observer: a 1×1 m plate (radius 0.71 m) within 100 radii."""
    geo = jaxlc.synthetic_geometry(duration_s=1, range_start_m=range_m)
    with pytest.raises(jaxlc.errors.JaxlcError, match="parallel rays"):
        jaxlc.render(write_scene(PLATE_FACING_X), geo)


def test_empty_table_renders_empty():
    geo = jaxlc.synthetic_geometry(duration_s=5).iloc[:0]
    lc = jaxlc.render(SCENES / "s5_cubesat.toml", geo)
    assert len(lc) == 0 and list(lc.columns) == list(jaxlc.io.tables.LIGHTCURVE_COLUMNS)

"""BRDFs and the fused facet sum against analytic laws and an independent float64 twin."""

from __future__ import annotations

import math
import zlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import (
    MESHES,
    as_glossy_rho,
    ashikhmin_shirley_rho,
    facet_sum_reference,
    lambert_plate_intensity,
    lambert_sphere_intensity,
    random_unit_vectors,
    unit,
)
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxlc
from jaxlc.body.brdf import ASGlossy, AshikhminShirley, Lambert
from jaxlc.body.facet_model import facet_intensity, facet_model
from jaxlc.body.mesh import facets_from_mesh, load_mesh


def _intensity64(model_fn, s, v):
    with jax.enable_x64(True):
        model = model_fn(jnp.float64)
        return np.asarray(facet_intensity(model, jnp.asarray(s), jnp.asarray(v)))


@pytest.fixture(scope="module")
def plate_facets():
    return facets_from_mesh(load_mesh(MESHES / "plate.obj"))


def test_lambert_plate_many_angles(plate_facets):
    """Lambert plate, 2,000 random geometries (both sides of the plate): exact formula."""
    rng = np.random.default_rng(0)
    s = random_unit_vectors(rng, 2000)
    v = random_unit_vectors(rng, 2000)
    got = _intensity64(lambda dt: facet_model(plate_facets, [Lambert(rd=0.8)], dt), s, v)
    # The zero-thickness plate has a front (+z) and a back (−z) face.
    ref = [
        lambert_plate_intensity([0, 0, 1], a, b, 1.0, 0.8)
        + lambert_plate_intensity([0, 0, -1], a, b, 1.0, 0.8)
        for a, b in zip(s, v, strict=True)
    ]
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-15)
    # float32: the same to float rounding
    model32 = facet_model(plate_facets, [Lambert(rd=0.8)], jnp.float32)
    got32 = np.asarray(
        facet_intensity(model32, jnp.asarray(s, jnp.float32), jnp.asarray(v, jnp.float32))
    )
    np.testing.assert_allclose(got32, ref, rtol=2e-5, atol=2e-7)


@pytest.mark.parametrize(
    ("level", "tolerance_mag"),
    [(2, 0.10), (3, 0.025), (4, 0.01)],  # 320, 1,280, 5,120 facets (issue 2)
)
def test_lambert_sphere_phase_law_converges(level, tolerance_mag):
    """Inscribed icosphere vs ρR²(2/3π)[sin α + (π−α)cos α], α ≤ 150°."""
    f = facets_from_mesh(load_mesh(MESHES / f"sphere_L{level}.obj"))
    alpha = np.radians(np.linspace(0, 150, 31))
    s = np.tile([1.0, 0.0, 0.0], (len(alpha), 1))
    v = np.stack([np.cos(alpha), np.sin(alpha), np.zeros_like(alpha)], 1)
    got = _intensity64(lambda dt: facet_model(f, [Lambert(rd=0.5)], dt), s, v)
    ref = lambert_sphere_intensity(alpha, 1.0, 0.5)
    dm = 2.5 * np.log10(ref / got)
    assert np.max(np.abs(dm)) <= tolerance_mag
    # the inscribed polyhedron is always a little too faint (smaller cross-section)
    assert np.all(dm > 0)


def test_sphere_error_shrinks_fourfold_per_level():
    """Error ∝ facet size²: each subdivision level divides it by about 4."""
    alpha = np.radians([30.0, 90.0])
    s = np.tile([1.0, 0.0, 0.0], (2, 1))
    v = np.stack([np.cos(alpha), np.sin(alpha), np.zeros(2)], 1)
    ref = lambert_sphere_intensity(alpha, 1.0, 1.0)
    errs = []
    for level in (2, 3, 4, 5):
        f = facets_from_mesh(load_mesh(MESHES / f"sphere_L{level}.obj"))
        got = _intensity64(lambda dt, f=f: facet_model(f, [Lambert(rd=1.0)], dt), s, v)
        errs.append(np.max(np.abs(np.log(ref / got))))
    ratios = np.array(errs[:-1]) / np.array(errs[1:])
    assert np.all((ratios > 3.0) & (ratios < 5.0)), ratios


def _random_facets(rng, n):
    normals = random_unit_vectors(rng, n)
    areas = rng.uniform(0.1, 2.0, n)
    return normals, areas


def _model_from_arrays(normals, areas, brdf, dtype):
    """A FacetModel for free-floating facets (one part), via the public builder."""
    from jaxlc.body.mesh import Facets

    f = Facets(
        normals=normals,
        areas_m2=areas,
        centroids_m=np.zeros_like(normals),
        part=np.zeros(len(areas), np.int32),
        can_shadow=np.zeros(len(areas), bool),
        triangle_facet=np.arange(len(areas)),
        part_names=("body",),
        n_triangles=len(areas),
        n_masked=0,
    )
    return facet_model(f, [brdf], dtype)


@pytest.mark.parametrize("kind", ["ashikhmin-shirley", "as-glossy"])
@pytest.mark.parametrize(("nu", "nv"), [(10.0, 10.0), (300.0, 300.0), (5.0, 2000.0), (1e4, 50.0)])
def test_as_facet_sum_matches_float64_reference(kind, nu, nv):
    """Fused kernel vs the direct formulas, 100 facets × 120 random geometries."""
    rng = np.random.default_rng(zlib.crc32(repr((kind, nu, nv)).encode()))
    normals, areas = _random_facets(rng, 100)
    s = random_unit_vectors(rng, 120)
    v = random_unit_vectors(rng, 120)
    # near-specular geometries (mirror of s in facet k's plane) exercise the sharp lobes
    k = slice(0, 60)
    mirror = 2 * np.einsum("ij,ij->i", s[k], normals[k])[:, None] * normals[k] - s[k]
    v[k] = unit(mirror + 0.01 * rng.normal(size=(60, 3)))
    rd, rs = 0.4, 0.3
    cls = AshikhminShirley if kind == "ashikhmin-shirley" else ASGlossy
    rho_fn = ashikhmin_shirley_rho if kind == "ashikhmin-shirley" else as_glossy_rho
    brdf = cls(rd=rd, rs=rs, nu=nu, nv=nv)
    got = _intensity64(lambda dt: _model_from_arrays(normals, areas, brdf, dt), s, v)
    with jax.enable_x64(True):
        model = _model_from_arrays(normals, areas, brdf, jnp.float64)
    u, w = np.asarray(model.tangent_u), np.asarray(model.tangent_w)
    params = [(rd, rs, nu, nv)] * len(areas)
    ref = np.array(
        [
            facet_sum_reference(normals, u, w, areas, a, b, rho_fn, params)
            for a, b in zip(s, v, strict=True)
        ]
    )
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    rd=st.floats(0, 1),
    rs=st.floats(0, 1),
    log_nu=st.floats(0, 5),
    log_nv=st.floats(0, 5),
    seed=st.integers(0, 2**31),
)
def test_as_single_facet_property(rd, rs, log_nu, log_nv, seed):
    """One facet, any material, random directions: kernel = direct formula."""
    rng = np.random.default_rng(seed)
    normals, areas = _random_facets(rng, 1)
    s = random_unit_vectors(rng, 16)
    v = random_unit_vectors(rng, 16)
    nu, nv = 10.0**log_nu, 10.0**log_nv
    brdf = AshikhminShirley(rd=rd, rs=rs, nu=nu, nv=nv)
    got = _intensity64(lambda dt: _model_from_arrays(normals, areas, brdf, dt), s, v)
    with jax.enable_x64(True):
        model = _model_from_arrays(normals, areas, brdf, jnp.float64)
    u, w = np.asarray(model.tangent_u), np.asarray(model.tangent_w)
    ref = [
        facet_sum_reference(normals, u, w, areas, a, b, ashikhmin_shirley_rho, [(rd, rs, nu, nv)])
        for a, b in zip(s, v, strict=True)
    ]
    np.testing.assert_allclose(got, ref, rtol=1e-8, atol=1e-13)


def test_as_diffuse_normalisation():
    """28/23π: at normal incidence and view ρ_d is 1.142× the Lambert value (PHYSICS §1).

    With s = v = n the Schlick term (1 − h·s)⁵ is 0, so rs = 0 switches the lobe off.
    """
    n = s = v = np.array([[0.0, 0.0, 1.0]])
    a = _intensity64(
        lambda dt: _model_from_arrays(n, np.ones(1), AshikhminShirley(0.5, 0.0, 100.0, 100.0), dt),
        s,
        v,
    )
    lam = _intensity64(lambda dt: _model_from_arrays(n, np.ones(1), Lambert(0.5), dt), s, v)
    assert a[0] / lam[0] == pytest.approx(28 / 23 * (1 - 0.5**5) ** 2, rel=1e-12)
    assert a[0] / lam[0] == pytest.approx(1.142, abs=1e-3)


def test_mixed_materials_per_part(scenes_dir):
    """Falcon 9 stage: per-part materials sum like separate single-material renders."""
    scene = jaxlc.load_scene(scenes_dir / "s4_falcon9.toml")
    f = scene.facets
    materials = scene.materials_for(f.part_names)
    rng = np.random.default_rng(3)
    s = random_unit_vectors(rng, 50)
    v = random_unit_vectors(rng, 50)
    whole = _intensity64(lambda dt: facet_model(f, materials, dt), s, v)
    parts = 0.0
    for i in range(len(f.part_names)):
        # zero albedos on every other part
        only = [m if j == i else Lambert(rd=0.0) for j, m in enumerate(materials)]
        parts = parts + _intensity64(lambda dt, only=only: facet_model(f, only, dt), s, v)
    np.testing.assert_allclose(whole, parts, rtol=1e-12)


# ---------------------------------------------------------------------------
# Numerical stress: no NaN/inf in values or gradients


def _stress_geometries():
    """(s, v) pairs at the edges: grazing, α → 0° and 180°, exact specular."""
    n = np.array([0.0, 0.0, 1.0])
    out = []
    for eps in (0.0, 1e-30, 1e-12, 1e-7, 1e-4):
        g = unit([1.0, 0.0, eps])  # grazing incidence
        out.append((g, unit([0.2, 0.1, 1.0])))
        out.append((unit([0.2, 0.1, 1.0]), g))  # grazing view
        out.append((g, unit([-1.0, 0.0, eps])))  # both grazing, α ≈ 180°
    for d in (0.0, 1e-9, 1e-6, 1e-3):
        s = unit([0.3, 0.0, 1.0])
        out.append((s, unit(s + np.array([0.0, d, 0.0]))))  # α → 0
        out.append((s, unit(-s + np.array([0.0, d, 0.0]))))  # α → 180°
        out.append((s, unit([-0.3, d, 1.0])))  # exact and near specular
    out.append((n, n))  # normal incidence and view
    out.append((n, -n))
    return np.array([a for a, _ in out]), np.array([b for _, b in out])


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize("exponent", [1.0, 10.0, 1e3, 1e4, 1e5])
def test_stress_values_and_gradients_finite(dtype, exponent):
    s, v = _stress_geometries()
    normals = np.array([[0.0, 0.0, 1.0], unit([0.1, 0.2, 1.0]), unit([1.0, 0.0, 0.0])])
    areas = np.ones(3)

    def total(rd, rs, nu, s_, v_):
        brdf = AshikhminShirley(rd=rd, rs=rs, nu=nu, nv=nu * 2)
        model = _model_from_arrays(normals, areas, brdf, dtype)
        return jnp.sum(facet_intensity(model, s_, v_))

    with jax.enable_x64(dtype == jnp.float64):
        args = [jnp.asarray(x, dtype) for x in (0.5, 0.3, exponent)]
        sv = jnp.asarray(s, dtype), jnp.asarray(v, dtype)
        values = facet_intensity(
            _model_from_arrays(
                normals, areas, AshikhminShirley(0.5, 0.3, exponent, 2 * exponent), dtype
            ),
            *sv,
        )
        grads = jax.grad(total, argnums=(0, 1, 2, 3, 4))(*args, *sv)
    assert np.all(np.isfinite(np.asarray(values))) and np.all(np.asarray(values) >= 0)
    for g in grads:
        assert np.all(np.isfinite(np.asarray(g)))


def test_huge_exponent_no_overflow_float32():
    """n = 10⁵ exactly on the specular direction: lobe = √((n+1)²)/8π · F/(hs·max), finite."""
    normals = np.array([[0.0, 0.0, 1.0]])
    s = unit([[0.3, 0.0, 1.0]])
    v = unit([[-0.3, 0.0, 1.0]])
    model = _model_from_arrays(
        normals, np.ones(1), AshikhminShirley(0.0, 1.0, 1e5, 1e5), jnp.float32
    )
    got = float(facet_intensity(model, jnp.asarray(s, jnp.float32), jnp.asarray(v, jnp.float32))[0])
    ns = s[0, 2]
    expected = (1e5 + 1) / (8 * math.pi) / (ns * ns) * ns * ns  # F = 1, hs = ns, n·h = 1
    assert got == pytest.approx(expected, rel=1e-5)


def test_lobe_logarithm_against_numpy():
    """The kernel's float32 ln(1 − δ) against numpy's float64 log1p: relative error
    < 5·10⁻⁷ from δ = 10⁻¹⁴ (where ln(1 − δ) = −δ) to the lit-facet bound 0.999999,
    including the bit-level branch points (δ = 1 − √½ and powers of two)."""
    from jaxlc.body.facet_model import log1m

    d = np.concatenate(
        [
            np.logspace(-14, np.log10(0.999999), 200_001),
            np.linspace(0.0, 0.999999, 200_001),
            [1 - 2**-0.5, 0.5, 0.75, 1 - 2**-10, 2**-20],
        ]
    ).astype(np.float32)
    got = np.asarray(jax.jit(log1m)(jnp.asarray(d)), np.float64)
    ref = np.log1p(-d.astype(np.float64))
    nz = ref != 0
    assert np.all(got[~nz] == 0)
    assert np.max(np.abs(got[nz] / ref[nz] - 1)) < 5e-7
    # gradients of the lobe flow through it (reverse mode, float32)
    g = jax.grad(lambda x: jnp.sum(log1m(x)))(jnp.asarray([1e-6, 0.3, 0.9], jnp.float32))
    np.testing.assert_allclose(np.asarray(g), -1 / (1 - np.array([1e-6, 0.3, 0.9])), rtol=1e-5)


def _albedo(plate_facets, brdf, incidence_deg, n_theta=160, n_phi=320):
    """Directional-hemispherical reflectance ∫ ρ (n·v) dω of the plate's front face (its
    I/E over (A n·s) with A = 1 m²), by the midpoint rule over the upper hemisphere."""
    th = (np.arange(n_theta) + 0.5) * (math.pi / 2) / n_theta
    ph = (np.arange(n_phi) + 0.5) * 2 * math.pi / n_phi
    T, P = np.meshgrid(th, ph, indexing="ij")
    v = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    a = math.radians(incidence_deg)
    s = np.broadcast_to([math.sin(a), 0.0, math.cos(a)], v.shape)
    got = _intensity64(lambda dt: facet_model(plate_facets, [brdf], dt), s, v)
    d_omega = (np.sin(T) * (math.pi / 2 / n_theta) * (2 * math.pi / n_phi)).reshape(-1)
    return float(np.sum(got / math.cos(a) * d_omega))


@pytest.mark.parametrize("nu", [0.0, 1.0, 10.0, 300.0])
def test_allowed_materials_reflect_at_most_what_they_receive(plate_facets, nu):
    """Energy: every parameter set a scene may give reflects ≤ the incident light
    (AS: rd, rs ∈ [0, 1], any exponent; as-glossy: rd + rs ≤ 1), while as-glossy with
    rd = rs = 1, which scenes refuse, reflects more."""
    for incidence in (0.0, 45.0, 75.0):
        for rd, rs in ((1.0, 0.0), (1.0, 0.5), (1.0, 1.0)):
            albedo = _albedo(plate_facets, AshikhminShirley(rd=rd, rs=rs, nu=nu, nv=nu), incidence)
            assert albedo <= 1.005, (rd, rs, nu, incidence, albedo)
        for rd, rs in ((1.0, 0.0), (0.5, 0.5), (0.0, 1.0)):
            albedo = _albedo(plate_facets, ASGlossy(rd=rd, rs=rs, nu=nu, nv=nu), incidence)
            assert albedo <= 1.005, (rd, rs, nu, incidence, albedo)
    # Lambert rd/π integrates to rd exactly: the quadrature is right
    assert _albedo(plate_facets, Lambert(rd=1.0), 30.0) == pytest.approx(1.0, abs=2e-4)
    assert _albedo(plate_facets, ASGlossy(rd=1.0, rs=1.0, nu=nu, nv=nu), 0.0) > 1.1

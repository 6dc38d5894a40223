"""Exact lit-and-seen areas in JAX (polygon clipping) against hand geometry and the slow
shapely twin, in float64 and float32, and the kernel's exact glints (``shadow_exact``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import SCENES, random_unit_vectors, roof_over_floor, unit

import jaxlc
from jaxlc.body.clip_polygons import clip_data
from jaxlc.body.facet_model import facet_contributions, facet_model
from jaxlc.body.mesh import facets_from_mesh
from jaxlc.body.shadow import ShadowSettings, shadow_data
from jaxlc.body.shadow_clip import exact_fractions
from jaxlc.body.shadow_exact import ExactShadows, exact_intensity
from jaxlc.body.shadow_lookup import lit_seen_fraction, shadow_table
from jaxlc.io.toml import Section
from jaxlc.rendering.kernel import body_intensity
from jaxlc.rendering.options import RenderOptions, render_options_from_table
from jaxlc.rendering.prepare import space_object


def _fractions(mesh, facets, s, v, dtype):
    """(T, K) exact fractions of every facet that can be shadowed, and their ids."""
    data, owner = clip_data(mesh, facets, np.flatnonzero(facets.can_shadow), dtype=dtype)
    ids, column = np.unique(owner, return_inverse=True)
    f = jax.jit(lambda d, a, b: exact_fractions(d, column, facets.areas_m2[ids], a, b))
    return np.asarray(f(data, jnp.asarray(s, dtype), jnp.asarray(v, dtype)), np.float64), ids


@pytest.mark.parametrize(
    ("dx", "dy"), [(0.3, 0.01), (0.25, -0.4), (0.8, 0.6), (1.5, 0.02), (-0.1, 0.7)]
)
def test_roof_shadow_is_the_analytic_area(dx, dy):
    """A 1 × 1 roof 1 m above a 2 × 2 floor, seen from near the zenith (offset (ox, oy)),
    the Sun tilted: lit and seen = 4 − (hidden + shadow − their overlap), each a unit
    square shifted by the direction's slope and cut to the floor."""
    mesh = roof_over_floor()
    facets = facets_from_mesh(mesh)
    ox, oy = 0.05, -0.03
    s, v = unit([dx, dy, 1.0]), unit([ox, oy, 1.0])

    def on_floor(d):  # length of [d − ½, d + ½] ∩ [−1, 1]
        return max(0.0, min(1.0, d + 0.5) - max(-1.0, d - 0.5))

    def overlap(a, b):
        return max(0.0, 1 - abs(a - b))

    hidden, shadow = on_floor(ox) * on_floor(oy), on_floor(dx) * on_floor(dy)
    # the two unit squares' overlap, itself cut to the floor
    lo = [max(-1.0, max(a, b) - 0.5) for a, b in ((ox, dx), (oy, dy))]
    hi = [min(1.0, min(a, b) + 0.5) for a, b in ((ox, dx), (oy, dy))]
    both = max(0.0, hi[0] - lo[0]) * max(0.0, hi[1] - lo[1])
    assert both <= overlap(ox, dx) * overlap(oy, dy) + 1e-12
    expected = (4 - (hidden + shadow - both)) / 4
    floor_up = int(np.flatnonzero((facets.part == 0) & (facets.normals[:, 2] > 0))[0])
    with jax.enable_x64(True):
        got, ids = _fractions(mesh, facets, s[None], v[None], jnp.float64)
    assert got[0, list(ids).index(floor_up)] == pytest.approx(expected, abs=1e-12)
    got32, _ = _fractions(mesh, facets, s[None], v[None], jnp.float32)
    assert got32[0, list(ids).index(floor_up)] == pytest.approx(expected, abs=2e-6)
    # the twin agrees
    assert ExactShadows(mesh, facets).fractions(s, v)[floor_up] == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize("name", ["s6_boxwing", "s7_antenna_box", "s8_boom_panel"])
def test_clipping_matches_the_exact_twin(name):
    """Every facet that can be shadowed (its convex pieces: two coplanar wings are one
    facet) is handled, and its fraction equals the shapely twin's over 200 random pairs
    of directions: to 1e-5 in float64 (the twin's 0.1 µm grid), and in float32 to 1e-4
    where both directions are ≥ 6° above the facet (nearer grazing the projection's
    coordinates grow as 1/cos; the term is ∝ cos there: |Δ| cos ≤ 1e-4)."""
    scene = jaxlc.load_scene(SCENES / f"{name}.toml")
    facets = scene.facets
    twin = ExactShadows(scene.mesh, facets)
    rng = np.random.default_rng(7)
    s, v = random_unit_vectors(rng, 200), random_unit_vectors(rng, 200)
    with jax.enable_x64(True):
        exact64, ids = _fractions(scene.mesh, facets, s, v, jnp.float64)
    assert list(ids) == list(np.flatnonzero(facets.can_shadow))
    exact32, _ = _fractions(scene.mesh, facets, s, v, jnp.float32)
    ref = np.stack([twin.fractions(a, b)[ids] for a, b in zip(s, v, strict=True)])
    cos = np.minimum(s @ facets.normals[ids].T, v @ facets.normals[ids].T)
    lit = cos > 0
    assert np.sum(lit & (ref > 1e-3) & (ref < 1 - 1e-3)) > 50  # partial shadows were tested
    assert np.abs(exact64 - ref)[lit].max() < 1e-5
    assert np.abs(exact32 - ref)[cos > 0.1].max() < 1e-4
    assert (np.abs(exact32 - ref) * np.clip(cos, 0, 1))[lit].max() < 1e-4


def test_facets_beyond_the_polygon_budget_keep_the_table():
    """A facet with more occluding polygons than allowed is left out (its table stays)."""
    scene = jaxlc.load_scene(SCENES / "s6_boxwing.toml")
    facets = scene.facets
    cand = np.flatnonzero(facets.can_shadow)
    data, owner = clip_data(scene.mesh, facets, cand, max_polygons=10)
    counted, _ = clip_data(scene.mesh, facets, cand)
    assert data is None or len(np.unique(owner)) < len(cand)
    assert counted is not None


@pytest.mark.parametrize("name", ["s6_boxwing", "s7_antenna_box", "s8_boom_panel"])
def test_exact_glints_bound_the_shadow_error_of_every_sample(name):
    """With ``shadow_exact = "glints"`` the kernel's I/E is within 0.5 % of the exact twin's
    at every lit and seen sample of 300 random geometries (phase ≤ 160°); with the table
    alone some samples are over 1 % off (S6: 4 %), so the test tells them apart."""
    scene = jaxlc.load_scene(SCENES / f"{name}.toml")
    rng = np.random.default_rng(3)
    s, v = random_unit_vectors(rng, 300), random_unit_vectors(rng, 300)
    keep = np.sum(s * v, axis=1) > np.cos(np.radians(160.0))
    s, v = s[keep], v[keep]
    with jax.enable_x64(True):
        model = facet_model(scene.facets, scene.materials_for(scene.facets.part_names), jnp.float64)
    ref = exact_intensity(model, ExactShadows(scene.mesh, scene.facets), s, v)
    lit = ref > 1e-6 * ref.max()
    rel = {}
    for glints in (False, True):
        obj = space_object(scene, None, jnp.float32, shadow=ShadowSettings(), exact_glints=glints)
        got = jax.jit(body_intensity)(obj, jnp.asarray(s, jnp.float32), jnp.asarray(v, jnp.float32))
        rel[glints] = np.abs(np.asarray(got, np.float64) - ref)[lit] / ref[lit]
    assert rel[False].max() > 0.01
    assert rel[True].max() < 0.005


def test_exact_glints_option_reads_and_refuses():
    """The ``[render]`` key round-trips, reaches the plan, and a wrong value is named."""
    opts = RenderOptions(shadow_exact="glints")
    assert render_options_from_table(Section(opts.as_table(), "[render]")) == opts
    with pytest.raises(jaxlc.JaxlcError, match="shadow_exact"):
        RenderOptions(shadow_exact="exact")
    with pytest.raises(jaxlc.JaxlcError, match="shadow_exact"):
        render_options_from_table(Section({"shadow_exact": "yes"}, "[render]"))
    scene = jaxlc.load_scene(SCENES / "s6_boxwing.toml")
    geo = jaxlc.synthetic_geometry(duration_s=20.0)
    plan = jaxlc.prepare(scene, geo, options=opts).plan
    assert plan.exact_glints and "clipped exactly" in plan.explain()
    assert not jaxlc.prepare(scene, geo).plan.exact_glints


#: Sun and observer (S4's body frame) where S4's nozzle glints through a partial shadow:
#: the worst samples of four curves of ``experiments/shadow_curves.py`` (their table
#: errors are 2.6–5.7 % of the curve's median flux).
S4_GLINTS = [
    ([0.0287, 0.3476, 0.9372], [-0.6981, -0.0645, -0.7131]),
    ([-0.7281, -0.5816, -0.3627], [0.3114, -0.4427, 0.8409]),
    ([0.2807, -0.8674, 0.4108], [-0.9116, -0.0193, 0.4106]),
    ([0.3844, -0.657, 0.6486], [-0.7618, 0.4502, -0.4659]),
]


@pytest.fixture(scope="module")
def s4_twin():
    """S4, the four geometries and the shapely twin's fractions there (~6 s)."""
    scene = jaxlc.load_scene(SCENES / "s4_falcon9.toml")
    s = np.array([unit(a) for a, _ in S4_GLINTS])
    v = np.array([unit(b) for _, b in S4_GLINTS])
    twin = ExactShadows(scene.mesh, scene.facets)
    return scene, s, v, np.stack([twin.fractions(a, b) for a, b in zip(s, v, strict=True)])


def test_cast_rays_count_fractions_the_clipping_cannot_take(s4_twin):
    """S4's nozzle facets have too many occluders to clip; their rays, cast in the kernel
    (512 sub-points), give every partly shadowed facet's fraction within 0.02 of the
    shapely twin (48 facets: 0.012 at most, 0.003 on average), where the table is
    more than 0.1 off."""
    from jaxlc.body.shadow_rays import ray_data, ray_fraction

    scene, s, v, ref = s4_twin
    mesh, facets = scene.body
    cand = np.flatnonzero(facets.can_shadow)
    clip, owner = clip_data(mesh, facets, cand)
    assert clip is None or len(np.unique(owner)) < len(cand) // 2  # the clipping refuses most
    cos = np.minimum(s @ facets.normals.T, v @ facets.normals.T)
    partial = (cos > 0) & (ref > 0.02) & (ref < 0.98)
    sample, facet = np.nonzero(partial)
    assert len(facet) > 20
    ids, k = np.unique(facet, return_inverse=True)
    data = ray_data(mesh, facets, ids)
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    each = jax.jit(lambda d, *x: jax.lax.map(lambda y: ray_fraction(d, *y), x))
    got = each(data, jnp.asarray(k, jnp.int32), f32(s[sample]), f32(v[sample]))
    err = np.abs(np.asarray(got, np.float64) - ref[sample, facet])
    assert err.max() < 0.02
    assert err.mean() < 0.004
    data = shadow_data(mesh, facets, ShadowSettings())  # the table, for comparison
    table = np.asarray(lit_seen_fraction(shadow_table(data), f32(s), f32(v)), np.float64)
    row = np.full(facets.n_facets, -1)
    row[data.facet_ids] = np.arange(len(data.facet_ids))
    row = row[facet]
    assert (row >= 0).all()
    assert np.abs(table[sample, row] - ref[sample, facet]).max() > 0.1


def test_exact_glints_take_s4s_nozzle_glints(s4_twin):
    """With ``shadow_exact = "glints"`` S4's I/E at its nozzle glints is within 0.4 % of
    the exact twin's; with the table alone each of them is over 0.5 % off."""
    scene, s, v, fractions = s4_twin
    with jax.enable_x64(True):
        model = facet_model(scene.facets, scene.materials_for(scene.facets.part_names), jnp.float64)
        terms = np.asarray(facet_contributions(model, jnp.asarray(s), jnp.asarray(v)))
    ref = np.sum(terms * fractions, axis=1)  # as exact_intensity sums them
    rel = {}
    for glints in (False, True):
        obj = space_object(scene, None, jnp.float32, shadow=ShadowSettings(), exact_glints=glints)
        got = jax.jit(body_intensity)(obj, jnp.asarray(s, jnp.float32), jnp.asarray(v, jnp.float32))
        rel[glints] = np.abs(np.asarray(got, np.float64) - ref) / ref
    assert rel[False].min() > 0.005
    assert rel[True].max() < 0.004


def test_ray_kits_stay_within_their_point_budget():
    """A large mesh's kit gets fewer rays per facet, never more than the budget's points
    (down to the minimum), so asking for exact glints cannot exhaust memory."""
    from jaxlc.body.shadow_rays import (
        MIN_RAY_POINTS,
        RAY_POINT_BUDGET,
        RAY_POINTS,
        ray_points,
    )

    assert ray_points(1_104) == RAY_POINTS  # S4's nozzle and engine
    for n in (10_000, 20_000, 65_536):
        k = ray_points(n)
        assert MIN_RAY_POINTS <= k < RAY_POINTS and k * n <= RAY_POINT_BUDGET
        assert 2 * k * n > RAY_POINT_BUDGET  # no fewer than the budget allows
    assert ray_points(10**7) == MIN_RAY_POINTS

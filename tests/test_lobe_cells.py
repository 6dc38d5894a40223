"""Specular candidate cells: every lobe above the floor is listed, and the sum over the
listed facets is the full facet sum (float64 loops, the shadow table's own fractions)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import (
    MESHES,
    SCENES,
    ashikhmin_shirley_rho,
    facet_sum_reference,
    random_unit_vectors,
    unit,
)

import jaxlc
from jaxlc.body import lobe_cells, shadow_lookup
from jaxlc.body.brdf import AshikhminShirley
from jaxlc.body.facet_model import facet_model
from jaxlc.body.mesh import load_body
from jaxlc.body.octahedral import nearest_node
from jaxlc.rendering.kernel import SpaceObject, body_intensity
from jaxlc.rendering.options import RenderOptions
from jaxlc.rendering.prepare import space_object

S4_MESH = MESHES / "falcon9_upper_stage.obj"
#: Per part (nozzle, engine, nose, body): (rd, rs, nu, nv); the nozzle's lobe anisotropic.
MATERIALS = [
    (0.1, 0.5, 300.0, 150.0),
    (0.2, 0.3, 100.0, 100.0),
    (0.6, 0.1, 20.0, 20.0),
    (0.6, 0.1, 20.0, 20.0),
]


def s4_model(dtype=jnp.float64):
    _, facets = load_body(S4_MESH)
    materials = [AshikhminShirley(rd=a, rs=b, nu=c, nv=d) for a, b, c, d in MATERIALS]
    return facets, materials, facet_model(facets, materials, dtype=dtype)


def glint_directions(normals, rng, n):
    """Sun and observer directions that put the half vector within a few degrees of
    facet normals (glints), and random ones."""
    s = random_unit_vectors(rng, n)
    v = random_unit_vectors(rng, n)
    for k in range(0, n, 2):  # every other pair: v mirrors s about a perturbed normal
        m = unit(normals[rng.integers(len(normals))] + 0.03 * rng.normal(size=3))
        s[k] = unit(m + 0.8 * unit(np.cross(m, rng.normal(size=3))))
        v[k] = 2 * np.dot(s[k], m) * m - s[k]
    return s, v


@pytest.mark.parametrize(
    ("dtype", "floor"),
    [(jnp.float64, lobe_cells.LOBE_FLOOR), (jnp.float32, lobe_cells.LOBE_FLOOR_FLOAT32)],
)
def test_cells_list_every_lobe_above_the_floor(dtype, floor):
    facets, _, model = s4_model(dtype)
    cells = lobe_cells.cells_for(model)
    assert cells is not None and cells.facets.shape[1] <= lobe_cells.MAX_SHARE * model.n_facets
    exponent = np.minimum(model.nu, model.nv)  # the anisotropic lobe is at most (n·h)^min
    rng = np.random.default_rng(4)
    h = np.concatenate([random_unit_vectors(rng, 3000), unit(facets.normals + 0.02)])
    cos = h @ facets.normals.T  # (H, F)
    lobe = np.where(cos > 0, np.maximum(cos, 0.0) ** exponent[None, :], 0.0)
    listed = np.zeros_like(lobe, dtype=bool)
    rows = np.asarray(cells.facets)[nearest_node(h, cells.grid)]
    for i, row in enumerate(rows):
        listed[i, row[row >= 0]] = True
    assert not np.any((lobe > floor) & ~listed)


def test_float32_candidate_sum_is_the_full_float32_sum():
    """The float32 floor leaves out only what float32 cannot hold: at glints and random
    directions the candidate sum is the full sum of the same float32 model to rounding."""
    facets, _, model = s4_model(jnp.float32)
    cells = lobe_cells.cells_for(model)
    assert (
        cells is not None
        and cells.facets.shape[1] < lobe_cells.cells_for(s4_model()[2]).facets.shape[1]
    )
    rng = np.random.default_rng(11)
    s, v = (jnp.asarray(x, jnp.float32) for x in glint_directions(facets.normals, rng, 48))
    got = np.asarray(body_intensity(SpaceObject(model, None, lobes=cells), s, v), np.float64)
    full = np.asarray(body_intensity(SpaceObject(model, None), s, v), np.float64)
    np.testing.assert_allclose(got, full, rtol=5e-7)  # 1.2e-7 found; 1.7e-6 at a 1e-4 floor


def test_candidate_sum_is_the_full_facet_sum():
    """Diffuse of every facet plus the listed lobes against the float64 loops of
    PHYSICS.md's AS BRDF, at glints and at random directions (nozzle lobe anisotropic)."""
    facets, _, model = s4_model()
    rng = np.random.default_rng(7)
    s, v = glint_directions(facets.normals, rng, 24)
    with jax.enable_x64(True):
        obj = SpaceObject(model, None, lobes=lobe_cells.cells_for(model))
        got = np.asarray(body_intensity(obj, jnp.asarray(s), jnp.asarray(v)))
    u, w = np.asarray(model.tangent_u), np.asarray(model.tangent_w)
    params = [MATERIALS[p] for p in facets.part]
    for k in range(len(s)):
        ref = facet_sum_reference(
            facets.normals, u, w, facets.areas_m2, s[k], v[k], ashikhmin_shirley_rho, params
        )
        assert got[k] == pytest.approx(ref, rel=1e-9, abs=1e-12 * facets.areas_m2.sum())


@pytest.mark.parametrize("selected", [16, 0])
def test_shadowed_weights_are_the_tables_fractions(monkeypatch, selected):
    """weights_at (one gather, a select per large facet — or, past SELECTED_FACETS, a
    gather of their fractions) reads each facet's lit-and-seen fraction, 1 past the table."""
    monkeypatch.setattr(shadow_lookup, "SELECTED_FACETS", selected)
    scene = jaxlc.load_scene(SCENES / "s4_falcon9.toml")
    obj = space_object(scene, None, shadow=RenderOptions().shadow)
    table = obj.shadow
    rng = np.random.default_rng(3)
    s = jnp.asarray(random_unit_vectors(rng, 40), jnp.float32)
    v = jnp.asarray(random_unit_vectors(rng, 40), jnp.float32)
    columns = shadow_lookup.lit_seen_columns(table, s, v)
    frac = np.asarray(shadow_lookup.column_fractions(table, columns))
    full = np.concatenate([frac, np.ones((40, obj.n_facets - frac.shape[1]))], axis=1)
    idx = rng.integers(0, obj.n_facets, size=(40, 64)).astype(np.int32)
    idx[:, :8] = np.arange(frac.shape[1] - 4, frac.shape[1] + 4)  # the large facets, the rest
    got = np.asarray(shadow_lookup.weights_at(table, columns, jnp.asarray(idx)))
    np.testing.assert_allclose(got, np.take_along_axis(full, idx, axis=1), rtol=1e-6)


def test_shadowed_kernel_with_cells_is_the_full_sum():
    scene = jaxlc.load_scene(SCENES / "s4_falcon9.toml")
    rng = np.random.default_rng(5)
    with jax.enable_x64(True):
        obj = space_object(scene, None, "float64", shadow=RenderOptions().shadow)
        assert obj.lobes is not None
        full = SpaceObject(obj.model, obj.attitude, obj.shadow, obj.exact)
        s, v = glint_directions(np.asarray(obj.model.normals), rng, 60)
        s, v = jnp.asarray(s), jnp.asarray(v)
        a, b = (np.asarray(body_intensity(o, s, v)) for o in (obj, full))
    assert np.all(b > 0)
    np.testing.assert_allclose(a, b, rtol=1e-9)


def test_small_or_traced_models_keep_the_plain_sum():
    _, facets = load_body(MESHES / "cubesat_3u.obj")
    small = facet_model(facets, [AshikhminShirley(rd=0.3, rs=0.5, nu=1000.0, nv=1000.0)])
    assert lobe_cells.cells_for(small) is None
    _, _, model = s4_model()
    assert lobe_cells.cells_for(model) is not None
    as_jax = jax.tree_util.tree_map(jnp.asarray, model)
    assert lobe_cells.cells_for(as_jax) is None

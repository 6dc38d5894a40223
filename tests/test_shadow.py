"""Self-shadowing: the approximation against its exact twin, the twin against geometry,
and every skip against the full computation."""

from __future__ import annotations

import hashlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import DATA, REPO, SCENES, random_unit_vectors, unit

import jaxlc
from jaxlc.body.mesh import TriangleMesh, facets_from_mesh
from jaxlc.body.octahedral import (
    grid_corners,
    nearest_node,
    octahedral_directions,
    octahedral_encode,
)
from jaxlc.body.raycast import sub_points
from jaxlc.body.shadow import ShadowSettings, shadow_data, shadow_table
from jaxlc.body.shadow_exact import ExactShadows
from jaxlc.rendering.kernel import body_intensity
from jaxlc.rendering.options import RenderOptions
from jaxlc.rendering.prepare import space_object

REGENERATE = "regenerate with: python experiments/make_shadow_reference.py"


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXLC_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def _sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ---------------------------------------------------------------------------
# Accuracy against the exact twin (committed reference, 1,000 geometries each)


@pytest.mark.parametrize("name", ["s4_falcon9", "s6_boxwing"])
def test_approximation_meets_accuracy_targets(name):
    """Median |Δm| ≤ 0.01 and 95th percentile ≤ 0.05 over 1,000 random geometries
    against exact polygon clipping (issue 4); the unshadowed model is far off."""
    ref = jaxlc.read_table(DATA / f"shadow_reference_{name.split('_')[0]}.csv")
    scene = jaxlc.load_scene(SCENES / f"{name}.toml")
    assert ref.attrs["scene_sha256"] == _sha(SCENES / f"{name}.toml"), REGENERATE
    assert ref.attrs["mesh_sha256"] == _sha(scene.mesh_path), REGENERATE
    assert len(ref) >= 1000
    s = ref[["sun_x", "sun_y", "sun_z"]].to_numpy()
    v = ref[["obs_x", "obs_y", "obs_z"]].to_numpy()
    obj = space_object(scene, None, jnp.float32, shadow=ShadowSettings())
    approx = np.asarray(
        body_intensity(obj, jnp.asarray(s, jnp.float32), jnp.asarray(v, jnp.float32)), np.float64
    )
    exact = ref["i_exact_m2_sr"].to_numpy()
    lit = exact > 0
    assert np.all(approx[~lit] <= 1e-6 * exact.max())  # dark stays dark
    dm = np.abs(2.5 * np.log10(approx[lit] / exact[lit]))
    assert np.median(dm) <= 0.01, np.median(dm)
    assert np.percentile(dm, 95) <= 0.05, np.percentile(dm, 95)
    plain = np.abs(2.5 * np.log10(ref["i_unshadowed_m2_sr"].to_numpy()[lit] / exact[lit]))
    assert np.percentile(plain, 95) > 0.3  # shadows matter in these scenes


def test_reference_data_is_reproduced_by_the_twin():
    """The committed numbers are what the exact twin computes today (a few rows)."""
    from jaxlc.body.facet_model import facet_model
    from jaxlc.body.shadow_exact import exact_intensity

    for name, rows in (("s6_boxwing", 25), ("s4_falcon9", 2)):
        ref = jaxlc.read_table(DATA / f"shadow_reference_{name.split('_')[0]}.csv").iloc[:rows]
        scene = jaxlc.load_scene(SCENES / f"{name}.toml")
        twin = ExactShadows(scene.mesh, scene.facets)
        s = ref[["sun_x", "sun_y", "sun_z"]].to_numpy()
        v = ref[["obs_x", "obs_y", "obs_z"]].to_numpy()
        with jax.enable_x64(True):
            model = facet_model(
                scene.facets, scene.materials_for(scene.facets.part_names), jnp.float64
            )
        got = exact_intensity(model, twin, s, v)
        np.testing.assert_allclose(got, ref["i_exact_m2_sr"], rtol=1e-9, atol=1e-15)


# ---------------------------------------------------------------------------
# The twin against hand geometry: a 1 × 1 m roof 1 m above a 2 × 2 m floor


def _roof_over_floor() -> TriangleMesh:
    floor = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    roof = np.array([[-0.5, -0.5, 1], [0.5, -0.5, 1], [0.5, 0.5, 1], [-0.5, 0.5, 1]], float)
    v = np.concatenate([floor, roof])
    up = [[0, 1, 2], [0, 2, 3]]
    down = [[0, 2, 1], [0, 3, 2]]
    faces = np.array(up + down + [[a + 4, b + 4, c + 4] for a, b, c in up + down])
    part = np.array([0, 0, 0, 0, 1, 1, 1, 1], np.int32)
    return TriangleMesh(v, faces, part, ("floor", "roof"), "roof-over-floor")


@pytest.mark.parametrize(
    ("dx", "dy"), [(0.0, 0.0), (0.3, 0.0), (0.25, -0.4), (0.8, 0.6), (1.5, 0.0)]
)
def test_exact_twin_roof_shadow(dx, dy):
    """Floor seen from the zenith, Sun tilted: the roof hides the 1 × 1 square under it
    and shadows that square shifted by (dx, dy), cut to the floor: lit and seen =
    4 − (1 + shadow on floor − overlap of the two squares)."""
    mesh = _roof_over_floor()
    facets = facets_from_mesh(mesh)
    floor_up = int(np.flatnonzero((facets.part == 0) & (facets.normals[:, 2] > 0))[0])
    s, v = unit([dx, dy, 1.0]), np.array([0.0, 0.0, 1.0])

    def on_floor(d):  # length of [d − ½, d + ½] ∩ [−1, 1]
        return max(0.0, min(1.0, d + 0.5) - max(-1.0, d - 0.5))

    shadow = on_floor(dx) * on_floor(dy)
    overlap = max(0.0, 1 - abs(dx)) * max(0.0, 1 - abs(dy))
    expected = (4 - (1 + shadow - overlap)) / 4
    got = ExactShadows(mesh, facets).fractions(s, v)[floor_up]
    assert got == pytest.approx(expected, abs=1e-9)
    # the approximation represents the partial shadow too
    fine = ShadowSettings(grid=64, spacing=0.005, max_subpoints=1024)
    data = shadow_data(mesh, facets, fine, use_cache=False)
    from jaxlc.body.shadow import lit_seen_fraction

    row = int(np.flatnonzero(data.facet_ids == floor_up)[0])
    approx = lit_seen_fraction(
        shadow_table(data), jnp.asarray([s], jnp.float32), jnp.asarray([v], jnp.float32)
    )
    assert float(approx[0, row]) == pytest.approx(expected, abs=0.03)


# ---------------------------------------------------------------------------
# Every skip is exact where it claims to be


def test_convex_scene_has_no_shadow_work_and_identical_output():
    scene = jaxlc.load_scene(SCENES / "s3_cylinder.toml")
    obj = space_object(scene, None, shadow=ShadowSettings())
    assert obj.shadow is None and obj.free == 0
    geo = jaxlc.synthetic_geometry(duration_s=200, phase_start_deg=10, phase_end_deg=150)
    a = jaxlc.render(scene, geo, options=RenderOptions(shadows="auto"))
    b = jaxlc.render(scene, geo, options=RenderOptions(shadows="off"))
    assert np.array_equal(a["flux_w_m2"].to_numpy(), b["flux_w_m2"].to_numpy())


def test_facets_that_cannot_be_shadowed_carry_no_data_and_recombine_exactly():
    """S4: free facets first, shadowable ones after; with every bit set (nothing
    blocked) the weighted sum equals the unshadowed one."""
    scene = jaxlc.load_scene(SCENES / "s4_falcon9.toml")
    f = scene.facets
    with jax.enable_x64(True):
        obj = space_object(scene, None, jnp.float64, shadow=ShadowSettings(grid=8))
        assert obj.free == int((~f.can_shadow).sum()) and obj.model.n_facets == f.n_facets
        assert int(f.can_shadow.sum()) == obj.shadow.subpoints.shape[0]
        import equinox as eqx

        # every sub-point sees everything
        data = shadow_data(jaxlc.load_mesh(scene.mesh_path), f, ShadowSettings(grid=8))
        real = np.full_like(data.bits, 0xFFFFFFFF)
        unblocked = eqx.tree_at(lambda o: o.shadow.bits, obj, jnp.asarray(real))
        plain = space_object(scene, None, jnp.float64, shadow=None)
        rng = np.random.default_rng(0)
        s, v = (
            jnp.asarray(random_unit_vectors(rng, 300)),
            jnp.asarray(random_unit_vectors(rng, 300)),
        )
        np.testing.assert_allclose(
            body_intensity(unblocked, s, v), body_intensity(plain, s, v), rtol=1e-12
        )


def test_shadows_off_option_is_the_plain_model():
    scene = jaxlc.load_scene(SCENES / "s6_boxwing.toml")
    geo = jaxlc.synthetic_geometry(duration_s=60, phase_start_deg=20, phase_end_deg=140)
    off = jaxlc.render(scene, geo, options=RenderOptions(shadows="off", blur="off"))
    on = jaxlc.render(scene, geo, options=RenderOptions(blur="off"))
    assert "off (requested; 12 facets could be shadowed)" in off.attrs["plan"]
    assert "approximate" in on.attrs["plan"]
    assert np.all(on["flux_w_m2"] <= off["flux_w_m2"] * (1 + 1e-6))  # shadows only remove light
    assert np.any(on["flux_w_m2"] < 0.9 * off["flux_w_m2"])


# ---------------------------------------------------------------------------
# Building blocks


def test_octahedral_grid_round_trip_and_weights():
    n = 16
    dirs = octahedral_directions(n)
    assert dirs.shape == (n * n, 3)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0)
    np.testing.assert_array_equal(
        nearest_node(dirs, n), np.arange(n * n)
    )  # nodes map to themselves
    rng = np.random.default_rng(1)
    d = random_unit_vectors(rng, 2000)
    idx, w = grid_corners(jnp.asarray(d), n, "bilinear")
    np.testing.assert_allclose(np.asarray(w).sum(1), 1.0, atol=1e-6)
    # the weighted corners point close to the direction (within a grid cell, ~2π/n)
    blend = unit(np.einsum("tc,tcj->tj", np.asarray(w), dirs[np.asarray(idx)]))
    assert np.degrees(np.arccos(np.clip(np.sum(blend * d, 1), -1, 1))).max() < 360 / n
    u, vv = octahedral_encode(d)
    assert np.all(np.abs(u) <= 1) and np.all(np.abs(vv) <= 1)


def test_sub_points_lie_on_their_facets():
    scene = jaxlc.load_scene(SCENES / "s6_boxwing.toml")
    mesh, f = jaxlc.load_mesh(scene.mesh_path), scene.facets
    ids = np.flatnonzero(f.can_shadow)
    counts = 32 * ShadowSettings().words_per_facet(f.areas_m2[ids], 11.9)
    pts = sub_points(mesh, f, ids, counts)
    for fid, p, k in zip(ids, pts, counts, strict=True):
        assert len(p) == k
        np.testing.assert_allclose((p - f.centroids_m[fid]) @ f.normals[fid], 0.0, atol=1e-9)
    assert counts.max() > 32 and counts.min() == 32  # big panels get more points


def test_cache_reuse_and_invalidation(cache):
    scene = jaxlc.load_scene(SCENES / "s6_boxwing.toml")
    mesh, f = jaxlc.load_mesh(scene.mesh_path), scene.facets
    first = shadow_data(mesh, f, ShadowSettings(grid=16))
    assert not first.from_cache and first.path.is_file() and first.path.parent.parent == cache
    again = shadow_data(mesh, f, ShadowSettings(grid=16))
    assert again.from_cache and np.array_equal(again.bits, first.bits)
    other = shadow_data(mesh, f, ShadowSettings(grid=12))
    assert not other.from_cache and other.path != first.path
    scaled = jaxlc.load_mesh(scene.mesh_path, scale=2.0)
    assert shadow_data(scaled, facets_from_mesh(scaled), ShadowSettings(grid=16)).path != first.path
    first.path.write_bytes(b"not a numpy file")  # damaged entry: traced again
    fixed = shadow_data(mesh, f, ShadowSettings(grid=16))
    assert not fixed.from_cache and np.array_equal(fixed.bits, first.bits)


def test_bad_settings():
    with pytest.raises(jaxlc.JaxlcError, match="shadow grid = 2"):
        ShadowSettings(grid=2)
    with pytest.raises(jaxlc.JaxlcError, match="max_subpoints = 40"):
        ShadowSettings(max_subpoints=40)
    with pytest.raises(jaxlc.JaxlcError, match="interpolation = 'cubic'"):
        ShadowSettings(interpolation="cubic")


def test_explain_cli(tmp_path):
    from test_cli import run_cli

    geo = tmp_path / "g.csv"
    jaxlc.write_table(jaxlc.synthetic_geometry(duration_s=20), geo)
    table = jaxlc.read_geometry(geo)
    table.loc[5:9, "visible"] = False
    jaxlc.write_table(table, geo)
    r = run_cli(
        "render", SCENES / "s6_boxwing.toml", geo, "-o", tmp_path / "lc.csv", "--explain", cwd=REPO
    )
    assert r.returncode == 0, r.stderr
    for word in (
        "mesh",
        "18 facets",
        "convex     no",
        "shadows    approximate, 12 of 18",
        "blur",
        "15 of 20 rendered (5 invisible, skipped)",
    ):
        assert word in r.stderr, word

"""Self-shadowing: the approximation against its exact twin, the twin against geometry,
and every skip against the full computation."""

from __future__ import annotations

import dataclasses
import hashlib
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import DATA, MESHES, REPO, SCENES, random_unit_vectors, roof_over_floor, unit

import jaxlc
from jaxlc.body import raycast
from jaxlc.body import shadow as shadow_module
from jaxlc.body.mesh import facets_from_mesh
from jaxlc.body.occlusion import Occluders, hits, occluded, plane_basis
from jaxlc.body.octahedral import (
    grid_corners,
    nearest_node,
    octahedral_directions,
    octahedral_encode,
)
from jaxlc.body.raycast import sub_points, word_layout
from jaxlc.body.shadow import ShadowSettings, reduced_resolution, shadow_data
from jaxlc.body.shadow_exact import ExactShadows
from jaxlc.body.shadow_lookup import lit_seen_fraction, shadow_table
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
# Accuracy against the exact twin (committed reference, 2,000 geometries each)


@pytest.mark.parametrize(
    ("name", "p99_max", "plain_p95_min"),
    [
        ("s4_falcon9", 0.05, 0.3),
        ("s6_boxwing", 0.05, 0.3),
        # the two non-convex shapes of issue 16: an antenna block 4 cm above a face,
        # a panel on a 1.5 m boom
        ("s7_antenna_box", 0.05, 0.1),
        ("s8_boom_panel", 0.05, 0.05),
    ],
)
@pytest.mark.parametrize("interpolation", ["bilinear", "triangle"])
def test_approximation_meets_accuracy_targets(name, p99_max, plain_p95_min, interpolation):
    """Median |Δm| ≤ 0.01 and 95th percentile ≤ 0.05 over 2,000 random geometries
    against exact polygon clipping (issue 4); the 99th percentile at phase ≤ 160° within
    issue 16's 0.05 (at the default 64 × 64 grid; S4 and S6 are at 0.06 on a 32 × 32
    one); the unshadowed model is far off."""
    ref = jaxlc.read_table(DATA / f"shadow_reference_{name.split('_')[0]}.csv")
    scene = jaxlc.load_scene(SCENES / f"{name}.toml")
    assert ref.attrs["scene_sha256"] == _sha(SCENES / f"{name}.toml"), REGENERATE
    assert ref.attrs["mesh_sha256"] == _sha(scene.mesh_path), REGENERATE
    assert len(ref) >= 2000
    s = ref[["sun_x", "sun_y", "sun_z"]].to_numpy()
    v = ref[["obs_x", "obs_y", "obs_z"]].to_numpy()
    obj = space_object(scene, None, jnp.float32, shadow=ShadowSettings(interpolation=interpolation))
    assert obj.shadow.interpolation == interpolation
    approx = np.asarray(
        body_intensity(obj, jnp.asarray(s, jnp.float32), jnp.asarray(v, jnp.float32)), np.float64
    )
    exact = ref["i_exact_m2_sr"].to_numpy()
    lit = exact > 1e-12 * exact.max()  # below: the clipping's round-off (1e-18 slivers)
    assert np.all(approx[~lit] <= 1e-6 * exact.max())  # dark stays dark
    dm = np.abs(2.5 * np.log10(approx[lit] / exact[lit]))
    assert np.median(dm) <= 0.01, np.median(dm)
    assert np.percentile(dm, 95) <= 0.05, np.percentile(dm, 95)
    phase = np.degrees(np.arccos(np.clip(np.sum(s * v, axis=1), -1, 1)))
    near = lit & (phase <= 160)
    tail = np.abs(2.5 * np.log10(approx[near] / exact[near]))
    assert np.percentile(tail, 99) <= p99_max, np.percentile(tail, 99)
    plain = np.abs(2.5 * np.log10(ref["i_unshadowed_m2_sr"].to_numpy()[lit] / exact[lit]))
    assert np.percentile(plain, 95) > plain_p95_min  # shadows matter in these scenes


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


@pytest.mark.parametrize(
    ("dx", "dy"), [(0.0, 0.0), (0.3, 0.0), (0.25, -0.4), (0.8, 0.6), (1.5, 0.0)]
)
def test_exact_twin_roof_shadow(dx, dy):
    """Floor seen from the zenith, Sun tilted: the roof hides the 1 × 1 square under it
    and shadows that square shifted by (dx, dy), cut to the floor: lit and seen =
    4 − (1 + shadow on floor − overlap of the two squares)."""
    mesh = roof_over_floor()
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

    row = int(np.flatnonzero(data.facet_ids == floor_up)[0])
    approx = lit_seen_fraction(
        shadow_table(data), jnp.asarray([s], jnp.float32), jnp.asarray([v], jnp.float32)
    )
    assert float(approx[0, row]) == pytest.approx(expected, abs=0.03)


@pytest.mark.parametrize(
    ("facet", "sun", "obs"),
    [
        (54, [-0.9437231, -0.08384194, -0.31993318], [-0.69151085, -0.59428952, -0.41064912]),
        (1099, [-0.31181086, -0.94918386, 0.04270813], [0.98922139, -0.1437014, 0.02812369]),
    ],
)
def test_exact_twin_where_neighbours_touch_the_plane_at_one_vertex(facet, sun, obs):
    """S4's nozzle: a neighbour sharing one vertex with a facet (on its plane) and
    rising in front of it. The twin once cut such a triangle at that vertex twice, and
    the "quadrilateral" (v, b, c, v) that repeats it became, in GEOS, a blocked set
    covering whole facets: these two, fully and 87 % visible, came out at 0. The twin
    equals a ray cast of 4,000 points spread over the facet (every triangle an occluder)
    within its sampling error."""
    scene = jaxlc.load_scene(SCENES / "s4_falcon9.toml")
    mesh, facets = scene.body
    s, v = unit(sun), unit(obs)
    got = ExactShadows(mesh, facets).fractions(s, v)[facet]
    points = sub_points(mesh, facets, [facet], [4000]) + 1e-6 * facets.normals[facet]
    tris = mesh.vertices_m[mesh.faces]
    seen = ~occluded(points, tris, s, 1e-7) & ~occluded(points, tris, v, 1e-7)
    assert seen.mean() > 0.5  # the case: mostly lit and seen
    assert got == pytest.approx(seen.mean(), abs=0.02)  # binomial σ ≤ 0.008


# ---------------------------------------------------------------------------
# Every skip is exact where it claims to be


def test_convex_scene_has_no_shadow_work_and_identical_output():
    scene = jaxlc.load_scene(SCENES / "s3_cylinder.toml")
    obj = space_object(scene, None, shadow=ShadowSettings())
    assert obj.shadow is None
    geo = jaxlc.synthetic_geometry(duration_s=200, phase_start_deg=10, phase_end_deg=150)
    a = jaxlc.render(scene, geo, options=RenderOptions(shadows="auto"))
    b = jaxlc.render(scene, geo, options=RenderOptions(shadows="off"))
    assert np.array_equal(a["flux_w_m2"].to_numpy(), b["flux_w_m2"].to_numpy())


def test_facets_that_cannot_be_shadowed_carry_no_data_and_recombine_exactly():
    """S4: shadowable facets first (the table's order), the others after; with every bit
    set (nothing blocked) the weighted sum equals the unshadowed one."""
    scene = jaxlc.load_scene(SCENES / "s4_falcon9.toml")
    f = scene.facets
    with jax.enable_x64(True):
        obj = space_object(scene, None, jnp.float64, shadow=ShadowSettings(grid=8))
        assert obj.model.n_facets == f.n_facets
        shadowed = sum(n for n, _ in obj.shadow.groups)
        assert shadowed == int(f.can_shadow.sum())
        # the table's facets lead, the others follow (S4 has facets of both kinds)
        np.testing.assert_array_equal(
            np.asarray(obj.model.normals[shadowed:]), f.normals[~f.can_shadow]
        )
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


@pytest.mark.parametrize("interpolation", ["bilinear", "triangle"])
def test_octahedral_grid_round_trip_and_weights(interpolation):
    n = 16
    dirs = octahedral_directions(n)
    assert dirs.shape == (n * n, 3)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0)
    np.testing.assert_array_equal(
        nearest_node(dirs, n), np.arange(n * n)
    )  # nodes map to themselves
    rng = np.random.default_rng(1)
    d = random_unit_vectors(rng, 2000)
    idx, w = grid_corners(jnp.asarray(d), n, interpolation)
    assert idx.shape == (len(d), {"bilinear": 4, "triangle": 3}[interpolation])
    np.testing.assert_allclose(np.asarray(w).sum(1), 1.0, atol=1e-6)
    assert np.asarray(w).min() >= -1e-6  # an interpolation, not an extrapolation
    # Both are exact for a linear function of the grid coordinates (i, j) inside the grid.
    u, vv = octahedral_encode(d)
    a, b = (u + 1.0) * (0.5 * n) - 0.5, (vv + 1.0) * (0.5 * n) - 0.5
    inside = (a >= 0) & (a <= n - 1) & (b >= 0) & (b <= n - 1)
    i_node, j_node = np.divmod(np.asarray(idx), n)
    for coord, node in ((a, i_node), (b, j_node)):
        lin = np.sum(np.asarray(w, np.float64) * node, axis=1)
        np.testing.assert_allclose(lin[inside], coord[inside], atol=1e-4)
    # the weighted corners point close to the direction (within a grid cell, ~2π/n)
    blend = unit(np.einsum("tc,tcj->tj", np.asarray(w), dirs[np.asarray(idx)]))
    assert np.degrees(np.arccos(np.clip(np.sum(blend * d, 1), -1, 1))).max() < 360 / n
    u, vv = octahedral_encode(d)
    assert np.all(np.abs(u) <= 1) and np.all(np.abs(vv) <= 1)


@pytest.mark.parametrize("interpolation", ["bilinear", "triangle"])
def test_octahedral_interpolation_is_continuous_across_the_seams(interpolation):
    """The square's edges are seams of the sphere (the lower hemisphere folds onto the
    corners): a smooth function interpolated from the nodes must not jump there. Pairs
    of directions 2e-5 rad apart straddle the four seams (z < 0, x = 0 or y = 0) and the
    −z pole; clamping the cell at the square's edge made them differ by a cell's change."""
    n = 16
    nodes = octahedral_directions(n)
    f_nodes = nodes @ unit(np.array([0.3, -0.5, -0.8]))  # a smooth function on the sphere
    rng = np.random.default_rng(4)
    z = -rng.uniform(0.02, 0.999, 400)
    r = np.sqrt(1 - z**2)
    eps = 1e-5
    pairs = []
    for axis in (0, 1):  # seams x = 0 (y ≠ 0) and y = 0 (x ≠ 0)
        other = r * rng.choice([-1.0, 1.0], len(z))
        for sign in (-1.0, 1.0):
            d = np.zeros((len(z), 3))
            d[:, axis], d[:, 1 - axis], d[:, 2] = sign * eps, other, z
            pairs.append(unit(d))
    a, b = pairs[0::2], pairs[1::2]  # the same points, either side of each seam
    pole = unit(np.column_stack([rng.normal(size=(400, 2)) * eps, -np.ones(400)]))
    a.append(pole)
    b.append(unit(pole * [-1.0, -1.0, 1.0]))

    def interpolated(d):
        idx, w = grid_corners(jnp.asarray(d), n, interpolation)
        return np.sum(np.asarray(w, np.float64) * f_nodes[np.asarray(idx)], axis=1)

    for x, y in zip(a, b, strict=True):
        jump = np.abs(interpolated(x) - interpolated(y))
        assert jump.max() < 1e-3, jump.max()  # a cell's change of f is ~0.2


def test_sub_points_lie_on_their_facets():
    scene = jaxlc.load_scene(SCENES / "s6_boxwing.toml")
    mesh, f = jaxlc.load_mesh(scene.mesh_path), scene.facets
    ids = np.flatnonzero(f.can_shadow)
    counts = 32 * ShadowSettings().words_per_facet(f.areas_m2[ids], 11.9)
    pts = np.split(sub_points(mesh, f, ids, counts), np.cumsum(counts)[:-1])
    for fid, p, k in zip(ids, pts, counts, strict=True):
        assert len(p) == k
        np.testing.assert_allclose((p - f.centroids_m[fid]) @ f.normals[fid], 0.0, atol=1e-9)
    assert counts.max() > 32 and counts.min() == 32  # big panels get more points


def _halton(i, base):
    """Van der Corput: the digits of i in ``base`` mirrored about the point."""
    out = np.zeros(len(i))
    for n, k in enumerate(i):
        f = 1.0
        while k > 0:
            f /= base
            out[n] += f * (k % base)
            k //= base
    return out


def _sub_points_loop(mesh, facets, facet_ids, counts):
    """The slow twin of sub_points: facet by facet (ties of the remainders to the
    earlier triangle)."""
    tri = mesh.vertices_m[mesh.faces]
    out = []
    for f, k in zip(facet_ids, counts, strict=True):
        t = tri[facets.triangle_facet == f]
        area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
        share = k * area / area.sum()
        count = np.floor(share).astype(int)
        count[np.argsort(-(share - count), kind="stable")[: k - count.sum()]] += 1
        first = 1  # the Halton index runs on over the facet's triangles
        for tt, c in zip(t, count, strict=True):
            i = np.arange(first, first + c)
            first += c
            r1, r2 = _halton(i, 2), _halton(i, 3)
            fold = r1 + r2 > 1
            r1, r2 = np.where(fold, 1 - r1, r1), np.where(fold, 1 - r2, r2)
            out.append(tt[0] + r1[:, None] * (tt[1] - tt[0]) + r2[:, None] * (tt[2] - tt[0]))
    return np.concatenate(out)


@pytest.mark.parametrize("name", ["s6_boxwing", "s4_falcon9"])
def test_sub_points_equal_the_facet_by_facet_loop(name):
    scene = jaxlc.load_scene(SCENES / f"{name}.toml")
    mesh, f = scene.body
    ids = np.flatnonzero(f.can_shadow)
    rng = np.random.default_rng(5)
    for counts in (
        32 * ShadowSettings().words_per_facet(f.areas_m2[ids], 11.9),
        rng.choice([1, 2, 4, 8, 16, 32, 96], size=len(ids)),
    ):
        np.testing.assert_array_equal(
            sub_points(mesh, f, ids, counts), _sub_points_loop(mesh, f, ids, counts)
        )


def _all_pairs_occluded(points, occluders, d, eps):
    """The slow twin of the binned cast: every (point, triangle) pair, same projection."""
    basis = plane_basis(d).astype(np.float32)
    keep = (
        np.flatnonzero(occluders.normals @ basis[2] < 0)
        if occluders.cull_back
        else np.arange(len(occluders.normals))
    )
    a, b, h = zip(*[basis @ c[:, keep] for c in occluders.corners], strict=True)
    pa, pb, ph = basis @ points
    p, t = np.repeat(np.arange(len(pa)), len(keep)), np.tile(np.arange(len(keep)), len(pa))
    hit = hits(pa[p], pb[p], ph[p] + np.float32(eps), a, b, h, t)
    return np.bincount(p[hit], minlength=len(pa)) > 0


@pytest.mark.parametrize(
    ("name", "cull_back"), [("boxwing", False), ("falcon9_upper_stage", True), ("soup", False)]
)
def test_binned_occlusion_equals_all_pairs(name, cull_back):
    """Sub-points of shadowable facets (random points for the soup) against every
    triangle, along 12 directions: the binned cast finds exactly the same hits."""
    rng = np.random.default_rng(11)
    if name == "soup":  # 300 random triangles of very different sizes, crossing each other
        centre = rng.uniform(-1, 1, (300, 1, 3))
        tris = centre + rng.normal(size=(300, 3, 3)) * rng.choice([0.02, 0.2, 1.0], (300, 1, 1))
        points = rng.uniform(-1.2, 1.2, (4000, 3))
    else:
        mesh = jaxlc.load_mesh(MESHES / f"{name}.obj")
        f = facets_from_mesh(mesh)
        ids = np.flatnonzero(f.can_shadow)
        counts = 32 * ShadowSettings().words_per_facet(f.areas_m2[ids], 11.9)
        owner = np.repeat(ids, counts)
        points = sub_points(mesh, f, ids, counts) + 1e-4 * f.normals[owner]
        points = points[rng.permutation(len(points))[:3000]]
        tris = mesh.vertices_m[mesh.faces]
    occluders = Occluders(tris, cull_back)
    points_t = np.ascontiguousarray(points.T, dtype=np.float32)
    blocked = 0
    for d in random_unit_vectors(rng, 12):
        fast = occluders.occluded(points_t, d, 1e-5)
        np.testing.assert_array_equal(fast, _all_pairs_occluded(points_t, occluders, d, 1e-5))
        blocked += fast.sum()
    assert 0.05 < blocked / (12 * len(points)) < 0.95  # both outcomes are exercised


@pytest.mark.parametrize("shared", [True, False])
@pytest.mark.parametrize("interpolation", ["bilinear", "triangle"])
def test_fraction_equals_unpacked_bits(monkeypatch, interpolation, shared):
    """The kernel's fractions equal counting the unpacked bits facet by facet, for a
    mesh over the budget (1–16 sub-points per facet, several facets to a word) and
    for one within it (32, 128 and 512: a facet over several words, which the
    device copy reorders word by word)."""
    if shared:
        monkeypatch.setattr(shadow_module, "SUBPOINT_BUDGET", 12)  # 192 at an 8 × 8 grid
    scene = jaxlc.load_scene(SCENES / "s6_boxwing.toml")
    mesh, f = scene.body
    data = shadow_data(
        mesh, f, ShadowSettings(grid=8, interpolation=interpolation), use_cache=False
    )
    if shared:
        assert data.subpoints <= 192 and data.counts.min() < 32 and len(data.groups) > 1
    else:
        assert data.counts.min() == 32 and data.counts.max() > 64 and len(data.groups) > 2
    rng = np.random.default_rng(2)
    s, v = random_unit_vectors(rng, 64), random_unit_vectors(rng, 64)
    table = shadow_table(dataclasses.replace(data, key=""), jnp.float32)
    fast = np.asarray(
        lit_seen_fraction(table, jnp.asarray(s, jnp.float32), jnp.asarray(v, jnp.float32))
    )

    start, _ = word_layout(data.counts)
    bits = np.unpackbits(data.bits.view(np.uint8), axis=1, bitorder="little").astype(bool)
    slow = np.zeros_like(fast)
    idx_s, w_s = (np.asarray(x) for x in grid_corners(jnp.asarray(s), 8, interpolation))
    idx_v, w_v = (np.asarray(x) for x in grid_corners(jnp.asarray(v), 8, interpolation))
    for i, (first, k) in enumerate(zip(start, data.counts, strict=True)):
        own = bits[:, first : first + k]  # (D, k) this facet's sub-points
        both = own[idx_s][:, :, None, :] & own[idx_v][:, None, :, :]  # (T, C, C, k)
        slow[:, i] = np.einsum("ta,tb,tab->t", w_s, w_v, both.sum(-1)) / k
    np.testing.assert_allclose(fast, slow, atol=2e-6)


def test_budgets_reduce_the_resolution_and_the_plan_says_so(monkeypatch):
    monkeypatch.setattr(shadow_module, "SUBPOINT_BUDGET", 200)
    monkeypatch.setattr(shadow_module, "TRACE_BUDGET", 400 * 16**2)
    scene = jaxlc.load_scene(SCENES / "s6_boxwing.toml")
    mesh, f = scene.body
    asked = ShadowSettings(grid=32)
    note = reduced_resolution(mesh, f, asked)
    data = shadow_data(mesh, f, asked, use_cache=False)
    assert data.subpoints <= 200 and data.settings.grid < 32
    assert data.settings.grid**2 * (data.subpoints + 2 * 52) <= 400 * 16**2
    assert note.startswith(f"; REDUCED for a mesh this large: {data.settings.grid}×")
    geo = jaxlc.synthetic_geometry(duration_s=20)
    lc = jaxlc.render(scene, geo, options=RenderOptions(blur="off"))
    assert "REDUCED" in lc.attrs["plan"] and np.all(np.isfinite(lc["flux_w_m2"]))
    # A grid finer than 32 × 32 gives way first, to the finest grid whose bits fit (the
    # same number of bits at any grid): every sub-point is kept.
    monkeypatch.undo()
    full = shadow_data(mesh, f, ShadowSettings(grid=8), use_cache=False).subpoints
    monkeypatch.setattr(shadow_module, "SUBPOINT_BUDGET", 2 * full)
    monkeypatch.setattr(shadow_module, "TRACE_BUDGET", 1 << 40)
    fine = shadow_data(mesh, f, ShadowSettings(grid=64), use_cache=False)
    assert fine.subpoints == full and fine.settings.grid == math.isqrt(2 * 32**2)  # 45
    monkeypatch.undo()
    assert reduced_resolution(mesh, f, asked) == ""  # the shipped meshes are far below both


def test_mirroring_near_the_horizon_only_renders_alike(monkeypatch):
    """Bits below a facet's horizon are filled only within reach of an interpolation
    from above it; filling them all (as before) gives the same lit-and-seen fractions
    wherever the facet is lit and seen."""
    scene = jaxlc.load_scene(SCENES / "s6_boxwing.toml")
    mesh, f = scene.body
    near = shadow_data(mesh, f, ShadowSettings(grid=12), use_cache=False)
    monkeypatch.setattr(raycast, "node_spacing_rad", lambda grid: np.pi)
    every = shadow_data(mesh, f, ShadowSettings(grid=12), use_cache=False)
    assert not np.array_equal(near.bits, every.bits)
    rng = np.random.default_rng(4)
    s, v = random_unit_vectors(rng, 2000), random_unit_vectors(rng, 2000)
    fr = [
        np.asarray(
            lit_seen_fraction(
                shadow_table(dataclasses.replace(d, key="")), jnp.asarray(s), jnp.asarray(v)
            )
        )
        for d in (near, every)
    ]
    n = f.normals[near.facet_ids]
    both = (s @ n.T > 0) & (v @ n.T > 0)
    np.testing.assert_array_equal(fr[0][both], fr[1][both])


def test_interpolation_is_each_call_s_own_with_a_table_in_memory():
    """One table (the bits depend on the grid only) serves every interpolation: a second
    setting in the same process is not the first one's (it was, for the memory copy)."""
    scene = jaxlc.load_scene(SCENES / "s6_boxwing.toml")
    mesh, f = scene.body
    rng = np.random.default_rng(3)
    s, v = (jnp.asarray(random_unit_vectors(rng, 200), jnp.float32) for _ in range(2))
    fractions = {}
    for interpolation in ("bilinear", "nearest", "triangle", "bilinear"):
        data = shadow_data(mesh, f, ShadowSettings(grid=16, interpolation=interpolation))
        table = shadow_table(data)
        assert data.settings.interpolation == table.interpolation == interpolation
        got = np.asarray(lit_seen_fraction(table, s, v))
        fractions.setdefault(interpolation, got)
        np.testing.assert_array_equal(got, fractions[interpolation])
    assert not np.array_equal(fractions["bilinear"], fractions["nearest"])
    assert not np.array_equal(fractions["bilinear"], fractions["triangle"])


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


def test_grazing_sun_on_the_base_of_s4_matches_the_exact_twin():
    """S4's base annulus (normal −z, so grid nodes lie in its plane) seen along its
    normal, lit from 0.5° to 20° above it: the lit-and-seen fraction stays within
    0.025 of polygon clipping. Zero bits at the in-plane nodes gave 0.06 for 0.21 at
    grazing, and Halton points restarted in every sliver of the fan 0.18."""
    from jaxlc.body.facet_model import tangent_frame

    scene = jaxlc.load_scene(SCENES / "s4_falcon9.toml")
    mesh, facets = scene.body
    data = shadow_data(mesh, facets, ShadowSettings())
    f = int(np.argmax(np.where(facets.normals[:, 2] < -0.99, facets.areas_m2, 0.0)))
    k = int(np.flatnonzero(data.facet_ids == f)[0])
    n = facets.normals[f]
    u, w = (x[f] for x in tangent_frame(facets.normals))
    exact = ExactShadows(mesh, facets)
    for el in np.radians([0.5, 1.0, 2.0, 4.0, 10.0, 20.0]):
        d = np.cos(el) * (np.cos(0.7) * u + np.sin(0.7) * w) + np.sin(el) * n
        got = lit_seen_fraction(
            shadow_table(data), jnp.asarray(d[None], jnp.float32), jnp.asarray(n[None], jnp.float32)
        )
        assert abs(float(got[0, k]) - exact.fractions(d, n)[f]) <= 0.025, np.degrees(el)

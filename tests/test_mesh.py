"""Meshes → facets: formats, parts, degenerate faces, merging, convexity."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from helpers import MESHES, random_unit_vectors

from jaxlc.body import mesh as mesh_module
from jaxlc.body.brdf import AshikhminShirley, Lambert
from jaxlc.body.facet_model import facet_intensity, facet_model, tangent_frame
from jaxlc.body.hull import support_heights
from jaxlc.body.mesh import (
    MAX_TRIANGLES,
    SHADOW_TOLERANCE,
    MeshWarning,
    TriangleMesh,
    facets_from_mesh,
    load_mesh,
)
from jaxlc.body.planes import COPLANAR_TOLERANCE, coplanar_groups
from jaxlc.errors import MeshError

SHIPPED = {
    "plate.obj": (("plate",), True),
    "sphere_L3.obj": (("body",), True),
    "falcon9_cylinder.obj": (("body",), True),
    "falcon9_upper_stage.obj": (("nozzle", "engine", "nose", "body"), False),
    "cubesat_3u.obj": (("body",), True),
    "boxwing.obj": (("panels", "boom", "bus"), False),
}


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_meshes_parts_and_convexity(name):
    parts, convex = SHIPPED[name]
    f = facets_from_mesh(load_mesh(MESHES / name))
    assert f.part_names == parts
    assert f.convex is convex
    assert f.n_masked == 0
    # areas add up to trimesh's own surface area
    mesh = trimesh.load(MESHES / name, force="mesh", process=False)
    assert f.areas_m2.sum() == pytest.approx(mesh.area, rel=1e-9)


def test_dimensions_in_metres():
    """S3 has the Falcon 9 second stage's 3.66 m diameter; S5 is 0.1 × 0.1 × 0.34 m."""
    v = load_mesh(MESHES / "falcon9_cylinder.obj").vertices_m
    assert np.ptp(v[:, 0]) == pytest.approx(3.66, abs=1e-6)
    v = load_mesh(MESHES / "cubesat_3u.obj").vertices_m
    np.testing.assert_allclose(np.ptp(v, axis=0), [0.1, 0.1, 0.34], atol=1e-9)


def test_falcon9_nozzle_inside_faces_the_axis():
    """The bell is a thin shell: half its facets face out, half face the axis."""
    f = facets_from_mesh(load_mesh(MESHES / "falcon9_upper_stage.obj"))
    sel = f.part == f.part_names.index("nozzle")
    radial = np.einsum("ij,ij->i", f.normals[sel, :2], f.centroids_m[sel, :2])
    assert np.sum(radial > 1e-9) == np.sum(radial < -1e-9) > 100


@pytest.mark.parametrize("ext", ["obj", "stl", "ply", "glb"])
def test_any_trimesh_format(tmp_path, ext):
    """The same shape read from OBJ, STL, PLY and GLB gives the same facets."""
    box = trimesh.creation.box((1.0, 2.0, 3.0))
    path = tmp_path / f"box.{ext}"
    box.export(path)
    f = facets_from_mesh(load_mesh(path))
    assert f.n_facets == 6
    assert f.convex
    np.testing.assert_allclose(np.sort(f.areas_m2), [2, 2, 3, 3, 6, 6], rtol=1e-6)


def test_glb_keeps_part_names(tmp_path):
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box((1, 1, 1)), geom_name="bus", node_name="bus")
    scene.add_geometry(
        trimesh.creation.box((0.1, 3, 1)),
        geom_name="panel",
        node_name="panel",
        transform=trimesh.transformations.translation_matrix([0, 2.5, 0]),
    )
    path = tmp_path / "sat.glb"
    scene.export(path)
    m = load_mesh(path)
    assert set(m.part_names) == {"bus", "panel"}
    # the node transform was applied
    panel = m.vertices_m[np.unique(m.faces[m.face_part == m.part_names.index("panel")])]
    assert panel[:, 1].min() == pytest.approx(1.0)


def test_scale_factor():
    m = load_mesh(MESHES / "cubesat_3u.obj", scale=1000.0)
    assert np.ptp(m.vertices_m[:, 2]) == pytest.approx(340.0)


def _two_triangles_plus(extra_vertices, extra_faces):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], *extra_vertices], float)
    f = np.array([[0, 1, 2], *extra_faces])
    return TriangleMesh(v, f, np.zeros(len(f), np.int32), ("body",), "test")


def test_degenerate_faces_masked_with_warning():
    mesh = _two_triangles_plus(
        [[2, 0, 0], [np.nan, 0, 0]],
        [[0, 1, 3], [1, 1, 2], [0, 4, 2]],  # collinear, repeated vertex, NaN vertex
    )
    with pytest.warns(MeshWarning, match="masked out 3 of 4 triangles"):
        f = facets_from_mesh(mesh)
    assert f.n_facets == 1 and f.n_masked == 3
    np.testing.assert_array_equal(f.triangle_facet, [0, -1, -1, -1])
    assert np.all(np.isfinite(f.normals))


def test_all_degenerate_is_an_error():
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    mesh = TriangleMesh(v, np.array([[0, 1, 2]]), np.zeros(1, np.int32), ("body",), "flat.obj")
    with pytest.raises(MeshError, match="all 1 triangles are degenerate"):
        facets_from_mesh(mesh)


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(MeshError, match="does not exist"):
        load_mesh(tmp_path / "nope.obj")
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"not a glb file at all")
    with pytest.raises(MeshError, match="cannot read mesh"):
        load_mesh(bad)
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing\n")
    with pytest.raises(MeshError):
        load_mesh(empty)


@pytest.mark.parametrize("name", ["falcon9_upper_stage.obj", "boxwing.obj", "falcon9_cylinder.obj"])
def test_merged_facets_equal_raw_triangles(name):
    """Merging coplanar triangles leaves the unshadowed facet sum unchanged."""
    mesh = load_mesh(MESHES / name)
    merged = facets_from_mesh(mesh, merge=True)
    raw = facets_from_mesh(mesh, merge=False)
    assert merged.n_facets < raw.n_facets == mesh.n_triangles
    rng = np.random.default_rng(7)
    s = jnp.asarray(random_unit_vectors(rng, 500))
    v = jnp.asarray(random_unit_vectors(rng, 500))
    brdf = AshikhminShirley(rd=0.5, rs=0.2, nu=50.0, nv=400.0, tangent=(0.0, 0.0, 1.0))
    with jax.enable_x64(True):
        outs = []
        for f in (merged, raw):
            model = facet_model(f, [brdf] * len(f.part_names), jnp.float64)
            outs.append(np.asarray(facet_intensity(model, s, v)))
    np.testing.assert_allclose(outs[0], outs[1], rtol=1e-9)


def test_merging_keeps_parts_apart():
    """Coplanar triangles of different parts stay separate facets."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    one = facets_from_mesh(TriangleMesh(v, f, np.array([0, 0], np.int32), ("a",)))
    two = facets_from_mesh(TriangleMesh(v, f, np.array([0, 1], np.int32), ("a", "b")))
    assert one.n_facets == 1 and two.n_facets == 2
    assert one.areas_m2[0] == pytest.approx(1.0)
    np.testing.assert_allclose(one.centroids_m[0], [0.5, 0.5, 0.0])


def test_can_shadow_flags():
    """Box-wing: the panels' faces and the bus's ±y faces can be shadowed; the
    bus's ±x, ±z faces cannot (nothing lies in front of them)."""
    f = facets_from_mesh(load_mesh(MESHES / "boxwing.obj"))
    bus = f.part == f.part_names.index("bus")
    for normal, expected in [((1, 0, 0), False), ((0, 0, 1), False), ((0, 1, 0), True)]:
        sel = bus & np.all(np.isclose(f.normals, normal), axis=1)
        assert sel.sum() == 1 and f.can_shadow[sel][0] == expected
    panels = f.part == f.part_names.index("panels")
    big = panels & (f.areas_m2 > 1.0)
    assert np.all(f.can_shadow[big])


def test_tangent_frame_orthonormal():
    rng = np.random.default_rng(0)
    n = random_unit_vectors(rng, 1000)
    n[0] = [0, 0, 1]  # parallel to the reference axis: falls back to x
    u, w = tangent_frame(n, (0.0, 0.0, 1.0))
    np.testing.assert_allclose(np.einsum("ij,ij->i", u, n), 0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), 1, atol=1e-12)
    np.testing.assert_allclose(np.cross(n, u), w, atol=1e-12)
    np.testing.assert_allclose(u[0], [1, 0, 0])


def test_lambert_facet_model_total_area():
    """Σ kl = (ρ/π) × total area: area folded into the coefficients once."""
    f = facets_from_mesh(load_mesh(MESHES / "falcon9_upper_stage.obj"))
    model = facet_model(f, [Lambert(rd=0.7)] * 4, jnp.float32)
    assert float(jnp.sum(model.kl)) == pytest.approx(0.7 / np.pi * f.areas_m2.sum(), rel=1e-5)


# ---------------------------------------------------------------------------
# Hostile files and size limits


def test_binary_obj_is_refused_as_not_text(tmp_path):
    """Random bytes named .obj: one line naming the file, what it is not and what is read."""
    bad = tmp_path / "noise.obj"
    bad.write_bytes(np.random.default_rng(0).integers(0, 256, 20_000, dtype=np.uint8).tobytes())
    with pytest.raises(MeshError) as err:
        load_mesh(bad)
    msg = str(err.value)
    assert "noise.obj" in msg and "not a text OBJ mesh" in msg and "STL, PLY, GLB" in msg
    assert "\n" not in msg and "charset" not in msg


def test_missing_optional_module_is_named_with_the_install_hint(tmp_path, monkeypatch):
    path = tmp_path / "box.obj"
    trimesh.creation.box((1, 1, 1)).export(path)

    def load(*args, **kwargs):
        raise ModuleNotFoundError("No module named 'charset_normalizer'", name="charset_normalizer")

    monkeypatch.setattr(trimesh, "load", load)
    with pytest.raises(
        MeshError,
        match=r"missing dependency.*'charset_normalizer'.*"
        r"pip install charset-normalizer",
    ):
        load_mesh(path)


def test_face_limit(tmp_path):
    """Above the limit: a MeshError naming the file, the count and the limit, for an OBJ
    before it is parsed and for any other format after; at the limit, fine."""
    box = trimesh.creation.box((1, 1, 1))  # 12 triangles
    obj, stl = tmp_path / "box.obj", tmp_path / "box.stl"
    box.export(obj)
    box.export(stl)
    with pytest.raises(
        MeshError, match=r"box\.obj' has at least 12 faces, more than the limit of 11"
    ):
        load_mesh(obj, max_triangles=11)
    with pytest.raises(MeshError, match=r"box\.stl' has 12 triangles, more than the limit of 11"):
        load_mesh(stl, max_triangles=11)
    assert load_mesh(stl, max_triangles=12).n_triangles == 12
    assert f"{MAX_TRIANGLES:,}" in mesh_module.__doc__  # documented


# ---------------------------------------------------------------------------
# Fast set-up against its slow twins


def _all_pairs_groups(normals, centroids, part, diag):
    """Coplanar groups by linking every pair of keys within the tolerance (the old way)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    key = np.column_stack([normals, np.einsum("ij,ij->i", normals, centroids) / diag, part * 10.0])
    pairs = cKDTree(key).query_pairs(r=COPLANAR_TOLERANCE, output_type="ndarray")
    n = len(normals)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def _triangle_keys(mesh):
    tri = mesh.vertices_m[mesh.faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    diag = float(np.linalg.norm(np.ptp(mesh.vertices_m, axis=0)))
    return cross / np.linalg.norm(cross, axis=1, keepdims=True), tri.mean(1), diag


def _noisy_subdivided_falcon(digits=8, times=2):
    """The S4 mesh subdivided and its coordinates rounded, as exporters do: many
    triangles per plane, their normals scattered within the merging tolerance
    (8 digits: 35,200 distinct planes merge into S4's 1,205) or across it (6)."""
    mesh = load_mesh(MESHES / "falcon9_upper_stage.obj")
    v, f, part = mesh.vertices_m, mesh.faces, mesh.face_part
    for _ in range(times):
        v, f = trimesh.remesh.subdivide(v, f)
        part = np.repeat(part, 4)  # face i becomes faces 4i … 4i + 3
    return TriangleMesh(np.round(v, digits), f, part, mesh.part_names, "noisy")


@pytest.mark.parametrize("name", [*sorted(SHIPPED), "noisy-6", "noisy-8"])
def test_coplanar_groups_equal_all_pairs(name):
    if name.startswith("noisy"):
        mesh = _noisy_subdivided_falcon(digits=int(name[-1]))
    else:
        mesh = load_mesh(MESHES / name)
    normals, centroids, diag = _triangle_keys(mesh)
    fast = coplanar_groups(normals, centroids, mesh.face_part, diag)
    slow = _all_pairs_groups(normals, centroids, mesh.face_part, diag)
    # the same partition, numbered by first triangle
    _, first = np.unique(slow, return_index=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    np.testing.assert_array_equal(fast, rank[slow])


@pytest.mark.parametrize("name", [*sorted(SHIPPED), "cloud", "flat", "noisy"])
def test_support_heights_equal_brute_force(name):
    rng = np.random.default_rng(3)
    if name == "cloud":
        points = rng.normal(size=(3000, 3)) * [1.0, 2.0, 0.5]
    elif name == "flat":  # a plate: Qhull needs its joggle
        points = np.column_stack([rng.normal(size=(2000, 2)), np.zeros(2000)])
    elif name == "noisy":
        points = _noisy_subdivided_falcon().vertices_m
    else:
        points = load_mesh(MESHES / name).vertices_m
    d = random_unit_vectors(rng, 3000)
    np.testing.assert_allclose(
        support_heights(points, d), (points @ d.T).max(axis=0), rtol=0, atol=1e-12
    )


def test_can_shadow_equals_brute_force_on_a_noisy_mesh():
    mesh = _noisy_subdivided_falcon(digits=6, times=1)
    f = facets_from_mesh(mesh)
    diag = float(np.linalg.norm(np.ptp(mesh.vertices_m, axis=0)))
    height = (mesh.vertices_m @ f.normals.T).max(0) - np.einsum(
        "ij,ij->i", f.normals, f.centroids_m
    )
    np.testing.assert_array_equal(f.can_shadow, height > SHADOW_TOLERANCE * diag)
    assert 0 < f.can_shadow.sum() < f.n_facets

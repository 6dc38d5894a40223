"""Self-shadowing precomputation: sub-points on facets and rays cast on the direction grid.

Each facet that can be shadowed gets K = 32·W sub-points, spread over its
triangles in proportion to area (stratified by a Halton sequence,
deterministic). For every direction d of the octahedral grid
(:mod:`jaxlc.body.octahedral`) and every sub-point x, one bit says whether the
ray x + t d escapes the mesh. Rays are cast once, in JAX, with 2-D edge
functions and interpolated depth after projecting along d; only facets with
n·d > 0 are traced, and for a watertight mesh only triangles with n_T·d < 0 (a
ray leaving the surface can only hit the solid through a triangle facing it).
The bits are packed into uint32 words (:func:`pack_bits`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc.body.mesh import Facets, TriangleMesh
from jaxlc.body.octahedral import nearest_node, octahedral_directions
from jaxlc.xla import compiler_options


def sub_points(
    mesh: TriangleMesh, facets: Facets, facet_ids: np.ndarray, counts: np.ndarray
) -> list[np.ndarray]:
    """Per facet, ``counts[i]`` points (k, 3) spread over its triangles by area.

    Each triangle gets its share (largest remainder); inside a triangle the
    points follow a 2-D Halton sequence folded into the triangle, so the
    placement is stratified and reproducible.
    """
    tri = mesh.vertices_m[mesh.faces]
    out = []
    for f, k in zip(facet_ids, counts, strict=True):
        t = tri[facets.triangle_facet == f]
        area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
        share = k * area / area.sum()
        count = np.floor(share).astype(int)
        rest = np.argsort(-(share - count))[: k - count.sum()]
        count[rest] += 1
        pts = []
        for tt, c in zip(t, count, strict=True):
            if c:
                r1, r2 = _halton(c, 2), _halton(c, 3)
                fold = r1 + r2 > 1  # fold the unit square onto the triangle
                r1, r2 = np.where(fold, 1 - r1, r1), np.where(fold, 1 - r2, r2)
                pts.append(tt[0] + r1[:, None] * (tt[1] - tt[0]) + r2[:, None] * (tt[2] - tt[0]))
        out.append(np.concatenate(pts))
    return out


def _halton(n: int, base: int) -> np.ndarray:
    i = np.arange(1, n + 1)
    f, r = np.ones(n), np.zeros(n)
    while np.any(i > 0):
        f = f / base
        r = r + f * (i % base)
        i = i // base
    return r


# ---------------------------------------------------------------------------
# Precomputation: ray casting on the grid


def _occluded(points, tris, d, eps):
    """(P,) True where the ray points + t·d (t > 0) hits one of tris (M, 3, 3)."""
    helper = jnp.where(jnp.abs(d[0]) < 0.9, jnp.array([1.0, 0.0, 0.0]), jnp.array([0.0, 1.0, 0.0]))
    e1 = jnp.cross(d, helper.astype(d.dtype))
    e1 = e1 / jnp.linalg.norm(e1)
    e2 = jnp.cross(d, e1)
    pa, pb, ph = points @ e1, points @ e2, points @ d
    ta, tb, th = tris @ e1, tris @ e2, tris @ d  # (M, 3)

    def edge(i, j):  # edge function of the edge i → j at every point, (P, M)
        return (tb[:, j] - tb[:, i])[None, :] * (pa[:, None] - ta[:, i][None, :]) - (
            ta[:, j] - ta[:, i]
        )[None, :] * (pb[:, None] - tb[:, i][None, :])

    w0, w1, w2 = edge(1, 2), edge(2, 0), edge(0, 1)  # barycentric weights × 2·area
    total = w0 + w1 + w2
    inside = ((w0 >= 0) & (w1 >= 0) & (w2 >= 0)) | ((w0 <= 0) & (w1 <= 0) & (w2 <= 0))
    inside = inside & (jnp.abs(total) > 1e-30)
    depth = (w0 * th[None, :, 0] + w1 * th[None, :, 1] + w2 * th[None, :, 2]) / jnp.where(
        inside, total, 1.0
    )
    return jnp.any(inside & (depth > ph[:, None] + eps), axis=1)


@jax.jit
def _occluded_batch(points, tris, dirs, eps):
    """(B, P) occlusion for a batch of directions with their own points and triangles."""
    return jax.lax.map(lambda a: _occluded(a[0], a[1], a[2], eps), (points, tris, dirs))


def _is_watertight(mesh: TriangleMesh) -> bool:
    import trimesh

    tm = trimesh.Trimesh(mesh.vertices_m, mesh.faces, process=False)
    tm.merge_vertices(digits_vertex=6)
    return bool(tm.is_watertight)


def trace_visibility(
    mesh: TriangleMesh,
    facets: Facets,
    facet_ids: np.ndarray,
    words: np.ndarray,
    grid: int,
    progress=None,
) -> np.ndarray:
    """Packed visibility (D, Σ words) uint32 of the sub-points of ``facet_ids``.

    Facet ``facet_ids[i]`` owns ``words[i]`` consecutive words (32 sub-points
    each). Directions below a facet's plane take the bits of their mirror image
    above it, so that interpolating near grazing does not mix in zeros (those
    directions never light or show the facet, so nothing else changes).
    """
    dirs = octahedral_directions(grid)
    n_dir = len(dirs)
    valid = facets.triangle_facet >= 0
    tri = mesh.vertices_m[mesh.faces][valid]
    tri_normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    tri_normal /= np.linalg.norm(tri_normal, axis=1, keepdims=True)
    diag = float(np.linalg.norm(np.ptp(mesh.vertices_m, axis=0)))
    normals = facets.normals[facet_ids]
    counts = 32 * np.asarray(words)
    owner = np.repeat(np.arange(len(facet_ids)), counts)  # facet row of each sub-point
    pts = np.concatenate(sub_points(mesh, facets, facet_ids, counts))
    pts = pts + 1e-5 * diag * normals[owner]  # lift off the surface
    cull_back = _is_watertight(mesh)

    facing = dirs @ normals.T > 1e-9  # (D, F_s): directions above each facet
    p_pad = max(32, int((facing @ counts).max()))
    tri_ok = (dirs @ tri_normal.T < 0) if cull_back else np.ones((n_dir, len(tri)), bool)
    m_pad = max(1, int(tri_ok.sum(1).max()))

    packed = np.zeros((n_dir, int(np.sum(words))), np.uint32)
    batch = 16
    kernel = jax.jit(_occluded_batch.__wrapped__, compiler_options=compiler_options())
    eps = np.float32(1e-6 * diag)
    for start in range(0, n_dir, batch):
        ids = list(range(start, min(start + batch, n_dir)))
        p_blk = np.zeros((batch, p_pad, 3), np.float32)
        t_blk = np.zeros((batch, m_pad, 3, 3), np.float32)  # zero triangles: never hit
        d_blk = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (batch, 1))
        chosen = []
        for b, j in enumerate(ids):
            sel = np.flatnonzero(facing[j][owner])
            t = tri[tri_ok[j]]
            p_blk[b, : len(sel)] = pts[sel]
            t_blk[b, : len(t)] = t
            d_blk[b] = dirs[j]
            chosen.append(sel)
        occ = np.asarray(kernel(jnp.asarray(p_blk), jnp.asarray(t_blk), jnp.asarray(d_blk), eps))
        for b, (j, sel) in enumerate(zip(ids, chosen, strict=True)):
            seen = np.zeros(len(pts), bool)
            seen[sel] = ~occ[b, : len(sel)]
            packed[j] = pack_bits(seen.reshape(-1, 32)).ravel()
        if progress is not None:
            progress(ids[-1] + 1, n_dir)

    # Below each facet's horizon: the bits of the mirror direction above it.
    first_word = np.concatenate([[0], np.cumsum(words)[:-1]])
    for row, nrm in enumerate(normals):
        below = ~facing[:, row]
        if not below.any():
            continue
        d = dirs[below]
        mirror = nearest_node(d - 2.0 * (d @ nrm)[:, None] * nrm, grid)
        cols = slice(first_word[row], first_word[row] + words[row])
        packed[below, cols] = packed[mirror, cols]
    return packed


def pack_bits(visible: np.ndarray) -> np.ndarray:
    """(…, 32) bool → (…, 1) uint32; element b is bit b."""
    bits = visible.astype(np.uint64) << np.arange(32, dtype=np.uint64)
    return bits.sum(-1, keepdims=True).astype(np.uint32)

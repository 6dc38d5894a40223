"""Self-shadowing precomputation: sub-points on facets and rays cast on the direction grid.

Each facet that can be shadowed gets k sub-points (k = 1, 2, 4, 8, 16 or a
multiple of 32), spread over its triangles in proportion to area (stratified by
a Halton sequence, deterministic). For every direction d of the octahedral grid
(:mod:`jaxlc.body.octahedral`) and every sub-point x, one bit says whether the
ray x + t d escapes the mesh. Only sub-points of facets with n·d > 0 are
traced, and for a watertight mesh only triangles with n_T·d < 0 (a ray leaving
the surface can only hit the solid through a triangle facing it).

Rays are cast on the host, one direction at a time, by
:class:`jaxlc.body.occlusion.Occluders` (binned: O((P + M) log M) a direction,
not P × M). The bits are packed into uint32 words (:func:`pack_bits`) in the
layout of :func:`word_layout`.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from jaxlc.body.mesh import Facets, TriangleMesh
from jaxlc.body.occlusion import Occluders
from jaxlc.body.octahedral import nearest_node, node_spacing_rad, octahedral_directions

#: Threads casting directions at once.
THREADS = max(1, min(4, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 2))
#: A grid node in a facet's plane is traced along the node's direction raised off
#: the plane by this angle (rad; 0.75°, 1/20 of the 32-grid's node spacing): the
#: limit from above.
IN_PLANE_LIFT_RAD = 0.013
#: Sub-points sit this far (× the mesh's bounding-box diagonal) above their facet.
SURFACE_LIFT = 1e-5
#: A triangle blocks a ray only this far (× the diagonal) beyond the ray's start.
DEPTH_MARGIN = 1e-6
#: Most (direction, facet) pairs of one block of the horizon fix-up.
MIRROR_BLOCK = 1 << 22


def sub_points(
    mesh: TriangleMesh, facets: Facets, facet_ids: np.ndarray, counts: np.ndarray
) -> np.ndarray:
    """(Σ counts, 3) points (m): ``counts[i]`` on facet ``facet_ids[i]``, facet by facet.

    Each triangle of a facet gets its share of the facet's points by area
    (largest remainder; ties to the earlier triangle); inside a triangle the
    points follow a 2-D Halton sequence folded into the triangle, so the
    placement is stratified and reproducible; the sequence runs on from one
    triangle of a facet to the next (indices 1 … k over the facet). All facets
    at once: O(M log M).
    """
    counts = np.asarray(counts, dtype=np.int64)
    rank = np.full(facets.n_facets + 1, -1, dtype=np.int64)
    rank[np.asarray(facet_ids)] = np.arange(len(facet_ids))
    tri_rank = rank[facets.triangle_facet]  # −1: masked out (index −1) or not wanted
    tri_ids = np.flatnonzero(tri_rank >= 0)
    tri_ids = tri_ids[np.argsort(tri_rank[tri_ids], kind="stable")]  # by facet, then index
    owner = tri_rank[tri_ids]
    t = mesh.vertices_m[mesh.faces[tri_ids]]
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    first = np.searchsorted(owner, np.arange(len(facet_ids)))
    share = counts[owner] * area / np.add.reduceat(area, first)[owner]
    count = np.floor(share).astype(np.int64)
    missing = counts - np.bincount(owner, weights=count, minlength=len(facet_ids)).astype(int)
    by_rest = np.lexsort((np.arange(len(owner)), count - share, owner))
    place = np.arange(len(owner)) - first[owner[by_rest]]  # rank of the remainder in its facet
    count[by_rest[place < missing[owner[by_rest]]]] += 1

    tri_of = np.repeat(np.arange(len(owner)), count)
    # Halton indices run on across a facet's triangles (1 … k per facet): restarting
    # them in every triangle put the same few points in each sliver of a fan and
    # biased the fractions of narrow lit or seen regions (a 10 % error on S4's base).
    k = np.arange(len(tri_of)) - np.repeat(np.cumsum(counts) - counts, counts) + 1
    r1, r2 = _halton(k, 2), _halton(k, 3)
    fold = r1 + r2 > 1  # fold the unit square onto the triangle
    r1, r2 = np.where(fold, 1 - r1, r1), np.where(fold, 1 - r2, r2)
    tt = t[tri_of]
    return tt[:, 0] + r1[:, None] * (tt[:, 1] - tt[:, 0]) + r2[:, None] * (tt[:, 2] - tt[:, 0])


def _halton(index: np.ndarray, base: int) -> np.ndarray:
    """Element ``index`` (1, 2, …) of the van der Corput sequence in ``base``."""
    i = np.array(index, dtype=np.int64)
    f, r = np.ones(len(i)), np.zeros(len(i))
    while np.any(i > 0):
        f = f / base
        r = r + f * (i % base)
        i = i // base
    return r


def word_layout(counts: np.ndarray) -> tuple[np.ndarray, int]:
    """Where each facet's bits go: (first bit (F,), number of uint32 words).

    ``counts`` (sub-points per facet) must be sorted. Facets with equal counts
    form a run that starts at a word; a run of k < 32 packs 32/k facets into a
    word (its last word padded with zero bits), k ≥ 32 gives each facet k/32
    words of its own.
    """
    counts = np.asarray(counts, dtype=np.int64)
    if np.any(np.diff(counts) < 0):
        raise ValueError("word_layout: counts must be sorted")
    first = np.flatnonzero(np.diff(counts, prepend=-1))
    size = np.diff(np.append(first, len(counts)))
    words = -(-size * counts[first] // 32)
    run_start = 32 * (np.cumsum(words) - words)
    run = np.repeat(np.arange(len(first)), size)
    start = run_start[run] + (np.arange(len(counts)) - first[run]) * counts
    return start, int(words.sum())


# ---------------------------------------------------------------------------
# Precomputation: ray casting on the grid


def is_watertight(mesh: TriangleMesh) -> bool:
    """Whether the mesh is closed (vertices merged to 1 µm): a ray leaving its surface can
    then only be blocked by a triangle facing against it."""
    import trimesh

    tm = trimesh.Trimesh(mesh.vertices_m, mesh.faces, process=False)
    tm.merge_vertices(digits_vertex=6)
    return bool(tm.is_watertight)


def mesh_occluders(mesh: TriangleMesh, facets: Facets) -> Occluders:
    """The mesh's triangles (masked ones left out) as ray blockers, back faces culled
    where the mesh is watertight: what the table's trace and the ray kit
    (:mod:`jaxlc.body.shadow_rays`) both cast against."""
    tris = mesh.vertices_m[mesh.faces[facets.triangle_facet >= 0]]
    return Occluders(tris, cull_back=is_watertight(mesh))


def lifted_sub_points(
    mesh: TriangleMesh, facets: Facets, facet_ids: np.ndarray, counts: np.ndarray
) -> np.ndarray:
    """:func:`sub_points`, each lifted :data:`SURFACE_LIFT` × the mesh's diagonal along its
    facet's normal: where the rays of the table and of the ray kit start (Σ counts, 3)."""
    counts = np.asarray(counts, dtype=np.int64)
    owner = np.repeat(np.arange(len(facet_ids)), counts)
    pts = sub_points(mesh, facets, facet_ids, counts)
    return pts + SURFACE_LIFT * mesh.diagonal_m * facets.normals[np.asarray(facet_ids)][owner]


def trace_visibility(
    mesh: TriangleMesh,
    facets: Facets,
    facet_ids: np.ndarray,
    counts: np.ndarray,
    grid: int,
    progress=None,
) -> np.ndarray:
    """Packed visibility (D, words) uint32 of the sub-points of ``facet_ids``.

    Facet ``facet_ids[i]`` has ``counts[i]`` sub-points (sorted counts; bits
    placed by :func:`word_layout`). Directions are cast in parallel threads
    (numpy releases the GIL). Directions just below a facet's plane take the
    bits of their mirror image above it (:func:`_mirror_below_horizon`).
    """
    dirs = octahedral_directions(grid)
    blockers = mesh_occluders(mesh, facets)
    diag = mesh.diagonal_m
    normals = facets.normals[facet_ids]
    counts = np.asarray(counts, dtype=np.int64)
    start, n_words = word_layout(counts)
    owner = np.repeat(np.arange(len(facet_ids)), counts)  # facet row of each sub-point
    bit = np.arange(len(owner)) + np.repeat(start - (np.cumsum(counts) - counts), counts)
    pts = lifted_sub_points(mesh, facets, facet_ids, counts)
    pts_t = np.ascontiguousarray(pts.T, dtype=np.float32)
    del pts

    lift = np.tan(IN_PLANE_LIFT_RAD)

    def row(d):
        cos = normals @ d
        facing = (cos > 1e-9)[owner]  # sub-points above their facet's horizon
        seen = np.zeros(32 * n_words, dtype=bool)
        seen[bit[facing]] = ~blockers.occluded(pts_t, d, DEPTH_MARGIN * diag, facing)[facing]
        # A node in a facet's plane takes the limit from above: the ray lifted
        # slightly off the plane (else its zeros darken every grazing look-up).
        in_plane = np.flatnonzero(np.abs(cos) <= 1e-9)
        planes = np.unique(np.round(normals[in_plane], 9), axis=0, return_inverse=True)[1]
        for g in np.unique(planes):
            members = in_plane[planes.ravel() == g]
            want = np.isin(owner, members)
            up = d + lift * normals[members[0]]
            up /= np.linalg.norm(up)
            seen[bit[want]] = ~blockers.occluded(pts_t, up, DEPTH_MARGIN * diag, want)[want]
        return pack_bits(seen.reshape(-1, 32)).ravel()

    packed = np.zeros((len(dirs), n_words), np.uint32)
    with ThreadPoolExecutor(max_workers=THREADS) as pool:
        for j, bits in enumerate(pool.map(row, dirs)):
            packed[j] = bits
            if progress is not None and (j % 16 == 15 or j == len(dirs) - 1):
                progress(j + 1, len(dirs))
    _mirror_below_horizon(packed, normals, start, counts, grid)
    return packed


def _mirror_below_horizon(packed, normals, start, counts, grid) -> None:
    """In place: each facet's bits at directions just below its plane are those of
    the mirror direction above it, so that interpolating near grazing does not
    mix in zeros. Only directions that a look-up above the plane can reach
    (within twice the grid's node spacing) are filled: further below, the
    facet's terms vanish whatever its bits (it is unlit or unseen).
    """
    dirs = octahedral_directions(grid)
    band = -np.sin(min(2.0 * node_spacing_rad(grid), 0.5 * np.pi))
    step = max(1, MIRROR_BLOCK // len(dirs))
    for s in range(0, len(normals), step):
        cos = dirs @ normals[s : s + step].T  # (D, facets of the block)
        j, f = np.nonzero((cos < -1e-9) & (cos > band))
        f = f + s
        d = dirs[j]
        mirror = nearest_node(d - 2.0 * np.sum(d * normals[f], 1)[:, None] * normals[f], grid)
        k, first = counts[f], start[f]
        narrow = k < 32  # bits of a shared word
        word = first[narrow] // 32
        mask = (((1 << k[narrow]) - 1) << (first[narrow] % 32)).astype(np.uint32)
        bits = packed[mirror[narrow], word] & mask  # read every source before writing
        n_w = k[~narrow] // 32  # whole words of their own
        rep = np.repeat(np.arange(len(n_w)), n_w)
        w = (
            np.repeat(first[~narrow] // 32, n_w)
            + np.arange(len(rep))
            - np.repeat(np.cumsum(n_w) - n_w, n_w)
        )
        words = packed[mirror[~narrow][rep], w]
        np.bitwise_or.at(packed, (j[narrow], word), bits)
        packed[j[~narrow][rep], w] = words


def pack_bits(visible: np.ndarray) -> np.ndarray:
    """(…, 32) bool → (…, 1) uint32; element b is bit b."""
    bits = visible.astype(np.uint64) << np.arange(32, dtype=np.uint64)
    return bits.sum(-1, keepdims=True).astype(np.uint32)

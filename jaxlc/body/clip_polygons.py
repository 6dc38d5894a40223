"""The static half of exact shadows: each facet's occluding polygons, once per mesh.

For a facet that can be shadowed, the polygons that can block it are the mesh's
triangles with a vertex in front of its plane, cut at the plane (as the slow twin,
:mod:`jaxlc.body.shadow_exact`, cuts them), two coplanar triangles of one facet
that make a convex quadrilateral merged into one polygon. Their points are kept
relative to the facet's centroid in its frame (r·u, r·w, r·n), so that the
projection along a direction d is two multiply-adds per point; their edges are
listed once with the polygons beside them, which is how the traced half
(:func:`jaxlc.body.shadow_clip.blocked_area`) tells U's boundary from its inside
(an edge between two coplanar polygons on either side is inside U in every
projection and is left out).

A facet is split into its convex pieces (the connected sets of its triangles; two
coplanar wings are one facet of two rectangles); a facet with a piece that is not
convex, or with more than ``max_polygons`` occluders, keeps the table.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxlc.body.facet_model import tangent_frame
from jaxlc.body.mesh import Facets, TriangleMesh
from jaxlc.body.shadow_clip import ClipData

#: A vertex at most this far (m) in front of a facet's plane counts as on it (as the twin's).
FRONT_M = 1e-12
#: Vertices closer than this (m) are one vertex (welded: shared edges must be found).
WELD_M = 1e-9
#: Polygons at most adjacent to one edge (more: the facet keeps the table).
MAX_ADJACENT = 4


def clip_data(
    mesh: TriangleMesh, facets: Facets, facet_ids, max_polygons: int = 64, dtype=np.float32
) -> tuple[ClipData | None, np.ndarray]:
    """The occluders of the pieces of the facets that can have exact shadows.

    Args:
        mesh: the triangles (their facet is ``facets.triangle_facet``).
        facets: the facets of the mesh.
        facet_ids: candidate facets (those that can be shadowed).
        max_polygons: a facet with more occluding polygons keeps the table.
        dtype: float dtype of the arrays.

    Returns:
        (data, (C,) the facet of each of its C pieces), or (None, empty) when no
        candidate is supported.
    """
    verts = np.asarray(mesh.vertices_m, np.float64)
    _, first, weld = np.unique(
        np.round(verts / WELD_M).astype(np.int64), axis=0, return_index=True, return_inverse=True
    )
    faces = weld.reshape(-1)[np.asarray(mesh.faces)]
    verts = verts[first]
    tri_facet = np.asarray(facets.triangle_facet)
    us, ws = tangent_frame(facets.normals)
    found, owner = [], []
    for f in np.asarray(facet_ids, np.int64):
        n, c, u, w = facets.normals[f], facets.centroids_m[f], us[f], ws[f]
        h = (verts - c) @ n
        cand = np.flatnonzero(
            (tri_facet >= 0) & (tri_facet != f) & (h[faces] > FRONT_M).any(axis=1)
        )
        if len(cand) > 2 * max_polygons:  # too many even merged in pairs (S4: all facets)
            continue
        outlines = _piece_outlines(verts, faces[tri_facet == f], c, u, w)
        if outlines is None:
            continue
        occ = _occluders(verts, faces, tri_facet, cand, h, (n, c, u, w))
        if occ is None or len(occ["polygon"]) > max_polygons:
            continue
        for outline, area in outlines:
            found.append(dict(occ, outline=outline, area_m2=area))
            owner.append(int(f))
    if not found:
        return None, np.zeros(0, np.int64)
    return _pad(found, dtype), np.asarray(owner, np.int64)


def _occluders(verts, faces, tri_facet, cand, h, frame) -> dict | None:
    """A facet's occluding polygons, their points and edges (float64), or None if an
    edge has more than :data:`MAX_ADJACENT` polygons.

    Args:
        cand: the triangles with a vertex in front of the facet's plane.
        h: (V,) each vertex's height above the plane (m).
        frame: the facet's normal, centroid and tangents (n, c, u, w).
    """
    n, c, u, w = frame
    polygons, coords = [], {}  # polygons: lists of point keys ("v", i) or ("e", i, j)
    for t in cand:
        poly = _front_part(faces[t], h, verts, coords)
        if poly is not None:
            polygons.append(
                (poly, int(tri_facet[t]), len(poly) == 3 and (h[faces[t]] > FRONT_M).all())
            )
    polygons = _split_t_junctions(_merge_quads(polygons, coords), coords)
    keys = sorted({k for p in polygons for k in p}, key=repr)
    index = {k: i for i, k in enumerate(keys)}
    r = np.array([coords[k] for k in keys]).reshape(-1, 3) - c
    points = np.stack([r @ u, r @ w, r @ n], axis=-1)
    on_plane = np.abs(points[:, 2]) <= FRONT_M
    points[on_plane, 2] = 0.0  # on the plane: projects onto itself
    n_s = max(len(p) for p in polygons)
    polygon = np.array([[index[k] for k in p] + [index[p[-1]]] * (n_s - len(p)) for p in polygons])
    polygon = polygon.reshape(len(polygons), n_s).astype(np.int64)
    edges: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for j, p in enumerate(polygons):
        idx = [index[k] for k in p]
        for i in range(len(idx)):
            a, b = idx[i], idx[(i + 1) % len(idx)]
            edges.setdefault((min(a, b), max(a, b)), []).append((j, 1 if a < b else -1))
    if any(len(v) > MAX_ADJACENT for v in edges.values()):
        return None
    # an edge between two coplanar polygons on either side of it is inside U in every
    # projection: it never counts (17 % of S6's edges; the traced half's cost is ∝ edges)
    normal = [_newell(np.array([coords[k] for k in p])) for p in polygons]
    edges = {
        e: users
        for e, users in edges.items()
        if not (
            len(users) == 2
            and users[0][1] == -users[1][1]
            and normal[users[0][0]] @ normal[users[1][0]] > 1 - 1e-9
        )
    }
    edge = np.array(list(edges), np.int64).reshape(-1, 2)
    adjacent = np.zeros((len(edge), MAX_ADJACENT), np.int64)
    winding = np.zeros((len(edge), MAX_ADJACENT))
    own = np.zeros((len(edge), len(polygons)), bool)
    for e, users in enumerate(edges.values()):
        for k, (j, sign) in enumerate(users):
            adjacent[e, k], winding[e, k], own[e, j] = j, sign, True
    return dict(
        normal=n, tangent_u=u, tangent_w=w, points=points, polygon=polygon, edge=edge,
        adjacent=adjacent, winding=winding, own=own,
        edge_flat=on_plane[edge[:, 0]] & on_plane[edge[:, 1]],
    )  # fmt: skip


def _front_part(tri, h, verts, coords) -> list | None:
    """The keys of the part of a triangle in front of the plane (its points into
    ``coords``), or None when less than a triangle remains."""
    front = h[tri] > FRONT_M
    poly = []
    for i in range(3):
        a, b = tri[i], tri[(i + 1) % 3]
        if front[i]:
            poly.append(("v", a))
            coords[("v", a)] = verts[a]
        if front[i] != front[(i + 1) % 3]:  # the side crosses the plane: cut it
            lo, hi = (a, b) if a < b else (b, a)
            if abs(h[lo]) <= FRONT_M:
                key = ("v", lo)
            elif abs(h[hi]) <= FRONT_M:
                key = ("v", hi)
            else:
                key = ("e", lo, hi)
            t = h[lo] / (h[lo] - h[hi])
            coords.setdefault(key, verts[lo] + t * (verts[hi] - verts[lo]))
            poly.append(key)
    poly = [k for i, k in enumerate(poly) if k != poly[i - 1]]  # a cut at a vertex on the plane
    return poly if len(set(poly)) >= 3 else None


def _merge_quads(polygons, coords) -> list[list]:
    """Whole triangles of one facet that share an edge and make a convex quadrilateral,
    merged (fewer polygons and no diagonal edge: the traced half's cost is their product)."""
    out, used = [], set()
    by_edge = {}
    for j, (p, _, whole) in enumerate(polygons):
        if whole:
            for i in range(3):
                by_edge.setdefault(frozenset((p[i], p[(i + 1) % 3])), []).append((j, i))
    for j, (p, facet, whole) in enumerate(polygons):
        if j in used:
            continue
        merged = None
        if whole:
            for i in range(3):
                for k, i2 in by_edge.get(frozenset((p[i], p[(i + 1) % 3])), []):
                    q, facet2, _ = polygons[k]
                    if k == j or k in used or facet2 != facet:
                        continue
                    quad = [p[(i + 2) % 3], p[i], q[(i2 + 2) % 3], p[(i + 1) % 3]]
                    if _convex(np.array([coords[x] for x in quad])):
                        merged, partner = quad, k
                        break
                if merged:
                    break
        if merged:
            used.update((j, partner))
            out.append(merged)
        else:
            used.add(j)
            out.append(p)
    return out


def _split_t_junctions(polygons: list[list], coords) -> list[list]:
    """Each polygon with the points of others that lie inside its sides inserted (a part
    attached mid-edge, a T-junction): an edge shared in part is then shared whole, and
    its polygons tell U's boundary from its inside (:mod:`jaxlc.body.shadow_clip`)."""
    keys = list({k for p in polygons for k in p})
    xyz = np.array([coords[k] for k in keys]).reshape(-1, 3)
    out = []
    for p in polygons:
        new = []
        for i, a in enumerate(p):
            b = p[(i + 1) % len(p)]
            new.append(a)
            pa, pb = coords[a], coords[b]
            side = pb - pa
            t = (xyz - pa) @ side / max(side @ side, 1e-300)
            off = np.linalg.norm(xyz - pa - t[:, None] * side, axis=1)
            inner = np.flatnonzero((off <= WELD_M) & (t > 1e-9) & (t < 1 - 1e-9))
            new += [keys[j] for j in inner[np.argsort(t[inner])] if keys[j] not in (a, b)]
        out.append(new)
    return out


def _newell(poly: np.ndarray) -> np.ndarray:
    """Unit normal (3,) of a planar polygon (K, 3) in its winding (Newell's method)."""
    n = np.cross(poly, np.roll(poly, -1, axis=0)).sum(axis=0)
    return n / max(float(np.linalg.norm(n)), 1e-300)


def _convex(quad: np.ndarray) -> bool:
    """Whether a planar quadrilateral (4, 3) is strictly convex."""
    side = np.roll(quad, -1, axis=0) - quad
    turn = np.cross(side, np.roll(side, -1, axis=0))
    normal = turn.sum(axis=0)
    return bool(np.all(turn @ normal > 1e-12 * np.dot(normal, normal)))


def _piece_outlines(verts, tris, c, u, w) -> list | None:
    """[(outline (H, 2) counter-clockwise in (u, w) about c, area m²)] of each connected
    set of the facet's triangles, or None if one of them is not convex."""
    from scipy.spatial import ConvexHull

    pieces = _connected(tris)
    out = []
    for piece in pieces:
        r = verts[np.unique(tris[piece])] - c
        q = np.stack([r @ u, r @ w], axis=-1)
        t = np.stack(
            [np.stack([(verts[x] - c) @ u, (verts[x] - c) @ w], -1) for x in tris[piece].T], 1
        )
        e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
        area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
        try:
            hull = ConvexHull(q)
        except Exception:
            return None
        if abs(hull.volume - area) > 1e-9 * area + 1e-15:
            return None
        out.append((q[hull.vertices], area))  # scipy's 2-D hulls run counter-clockwise
    return out


def _along(d: dict) -> np.ndarray:
    """(3, H, E) lo, hi and sign of the part of each outline side that each edge in the
    plane runs along (see :class:`~jaxlc.body.shadow_clip.ClipData`)."""
    o0 = d["outline"]
    o1 = np.roll(o0, -1, axis=0)
    out = np.zeros((3, len(o0), len(d["edge"])))
    q = d["points"][:, :2]
    tol = 1e-9 * np.sqrt(d["area_m2"])
    for e in np.flatnonzero(d["edge_flat"]):
        p0, p1 = q[d["edge"][e, 0]], q[d["edge"][e, 1]]
        for h in range(len(o0)):
            side = o1[h] - o0[h]
            length = np.linalg.norm(side)
            off = [
                abs(side[0] * (p - o0[h])[1] - side[1] * (p - o0[h])[0]) / length for p in (p0, p1)
            ]
            if max(off) > tol:
                continue
            t = [np.dot(p - o0[h], side) / length**2 for p in (p0, p1)]
            lo, hi = max(0.0, min(t)), min(1.0, max(t))
            if hi > lo:
                out[:, h, e] = lo, hi, 1.0 if t[1] > t[0] else -1.0
    return out


def _connected(tris: np.ndarray) -> list[np.ndarray]:
    """The connected sets (sharing a vertex) of triangles (M, 3), as index arrays."""
    label = np.arange(len(tris))
    changed = True
    while changed:  # propagate the least label through shared vertices (small meshes)
        changed = False
        for v in np.unique(tris):
            rows = np.flatnonzero((tris == v).any(axis=1))
            low = label[rows].min()
            if np.any(label[rows] != low):
                label[np.isin(label, label[rows])] = low
                changed = True
    return [np.flatnonzero(label == k) for k in np.unique(label)]


def _pad(found: list[dict], dtype) -> ClipData:
    """Stack the pieces' occluder lists, padding to the largest of each."""
    n_q = max(1, max(len(d["points"]) for d in found))
    n_p = max(1, max(len(d["polygon"]) for d in found))
    n_s = max(d["polygon"].shape[1] for d in found)
    for d in found:  # one side count: repeat each polygon's last point
        extra = n_s - d["polygon"].shape[1]
        d["polygon"] = np.concatenate([d["polygon"], np.repeat(d["polygon"][:, -1:], extra, 1)], 1)
        d["side_ok"] = d["polygon"] != np.roll(d["polygon"], -1, axis=1)
    n_e = max(1, max(len(d["edge"]) for d in found))
    n_h = max(len(d["outline"]) for d in found)

    def pad(x, n, fill=0):
        x = np.asarray(x)
        return np.concatenate([x, np.full((n - len(x), *x.shape[1:]), fill, x.dtype)])

    # the outline padded with its first vertex: sides past the last have no length
    outline = np.stack(
        [
            np.concatenate([o, np.repeat(o[:1], n_h - len(o), 0)])
            for o in (d["outline"] for d in found)
        ]
    )
    outline_ok = np.arange(n_h)[None, :] < np.array([len(d["outline"]) for d in found])[:, None]
    along = np.zeros((3, len(found), n_h, n_e))
    for k, d in enumerate(found):
        along[:, k, : len(d["outline"]), : len(d["edge"])] = _along(d)
    own = np.zeros((len(found), n_e, n_p), bool)
    for o, d in zip(own, found, strict=True):
        o[: d["own"].shape[0], : d["own"].shape[1]] = d["own"]
    stack = lambda k, n, fill=0: np.stack([pad(d[k], n, fill) for d in found])  # noqa: E731
    fl = lambda x: jnp.asarray(np.asarray(x, np.float64), dtype)  # noqa: E731
    return ClipData(
        normal=fl([d["normal"] for d in found]),
        tangent_u=fl([d["tangent_u"] for d in found]),
        tangent_w=fl([d["tangent_w"] for d in found]),
        area_m2=fl([d["area_m2"] for d in found]),
        points=fl(stack("points", n_q, 0.0)),
        polygon=jnp.asarray(stack("polygon", n_p), jnp.int32),
        side_ok=jnp.asarray(stack("side_ok", n_p, False)),
        polygon_ok=jnp.asarray(np.stack([np.arange(n_p) < len(d["polygon"]) for d in found])),
        edge=jnp.asarray(stack("edge", n_e), jnp.int32),
        adjacent=jnp.asarray(stack("adjacent", n_e), jnp.int32),
        winding=fl(stack("winding", n_e, 0.0)),
        own=jnp.asarray(own),
        edge_flat=jnp.asarray(stack("edge_flat", n_e, False)),
        outline=fl(outline),
        outline_ok=jnp.asarray(outline_ok),
        along_lo=fl(along[0]),
        along_hi=fl(along[1]),
        along_sign=fl(along[2]),
    )

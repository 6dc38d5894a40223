"""The support function of a point set: its highest point along many directions.

:func:`support_heights` gives h(d) = max_i d·x_i for F directions over V
points without forming the (F × V) products (for a convex mesh every vertex
is extreme and that product alone is F·V/2, 8·10¹¹ for 1.3 M faces). Only
convex-hull vertices can attain the maximum (scipy's Qhull), and on a convex
polytope a linear function has no local maximum but the global one, so a
greedy walk along hull edges ends at h(d) (the argument of the simplex
method). Each walk starts at the best corner of the hull face whose normal is
nearest to d, which for a finely tessellated hull is already the answer; all
walks advance together. Cost O((V + F) log V) in practice, memory O(V + F).

Used by :func:`jaxlc.body.mesh.facets_from_mesh` to decide which facets can be
shadowed (some vertex in front of the facet's plane).
"""

from __future__ import annotations

import numpy as np

#: Directions per block of the direct (directions × points) maximum, the
#: fallback for point sets too small or too degenerate for a hull.
BLOCK_ELEMENTS = 1 << 22


def support_heights(points: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """h(d) = max over points of d·x, for each direction.

    Args:
        points: (V, 3) finite points (m).
        directions: (F, 3) directions (unit or not; h scales with |d|).

    Returns:
        (F,) float64 support heights (m × |d|). Equal to
        ``(points @ directions.T).max(axis=0)`` up to round-off.

    Example:
        >>> support_heights(np.eye(3), np.array([[1.0, 1.0, 0.0]]))
        array([1.])
    """
    points = np.asarray(points, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    hull = _hull(points)
    if hull is None:
        return _direct_heights(points, directions)
    verts, faces, face_normals = hull
    pts = points[verts]
    indptr, neighbours = _vertex_neighbours(faces, len(verts))
    start = _start_vertices(pts, faces, face_normals, directions)
    return _walk(pts, indptr, neighbours, directions, start)


def _direct_heights(points, directions) -> np.ndarray:
    """The (directions × points) maximum, in blocks of bounded memory."""
    out = np.empty(len(directions))
    step = max(1, BLOCK_ELEMENTS // max(len(points), 1))
    for s in range(0, len(directions), step):
        out[s : s + step] = (points @ directions[s : s + step].T).max(axis=0)
    return out


def _hull(points):
    """(hull vertex ids (H,), faces (S, 3) in 0…H−1, outward face normals (S, 3)), or None.

    Flat point sets (a plate) are hulled with Qhull's joggle (``QJ``): the
    joggled hull's vertices and edges are used with the exact coordinates, off
    by ~10⁻¹¹ of the object's size at most.
    """
    from scipy.spatial import ConvexHull, QhullError

    if len(points) < 4:
        return None
    for options in (None, "QJ"):
        try:
            hull = ConvexHull(points, qhull_options=options)
            break
        except (QhullError, ValueError):
            continue
    else:
        return None
    verts = hull.vertices
    compact = np.full(len(points), -1, dtype=np.int64)
    compact[verts] = np.arange(len(verts))
    return verts, compact[hull.simplices], hull.equations[:, :3]


def _vertex_neighbours(faces: np.ndarray, n: int):
    """CSR adjacency (indptr (n + 1,), neighbours) of the hull's vertex graph."""
    a = faces.ravel()
    b = np.roll(faces, -1, axis=1).ravel()
    code = np.sort(np.concatenate([a * n + b, b * n + a]))  # by source; repeats are harmless
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(code // n, minlength=n), out=indptr[1:])
    return indptr, code % n


def _start_vertices(pts, faces, face_normals, directions) -> np.ndarray:
    """(F,) the best corner of the hull face whose normal is nearest each direction."""
    from scipy.spatial import cKDTree

    unit = directions / np.maximum(np.linalg.norm(directions, axis=1, keepdims=True), 1e-300)
    _, face = cKDTree(face_normals).query(unit)
    corners = faces[face]  # (F, 3)
    value = np.einsum("fj,fkj->fk", directions, pts[corners])
    return corners[np.arange(len(face)), np.argmax(value, axis=1)]


def _walk(pts, indptr, neighbours, directions, start) -> np.ndarray:
    """Greedy ascent of d·x along hull edges from ``start``, all directions at once."""
    cur = start.copy()
    val = np.einsum("fj,fj->f", directions, pts[cur])
    active = np.arange(len(cur))
    while active.size:
        c = cur[active]
        deg = indptr[c + 1] - indptr[c]
        owner = np.repeat(np.arange(active.size), deg)
        first = np.concatenate([[0], np.cumsum(deg)[:-1]])
        nb = neighbours[indptr[c][owner] + np.arange(owner.size) - first[owner]]
        nb_val = np.einsum("kj,kj->k", directions[active][owner], pts[nb])
        best = np.maximum.reduceat(nb_val, first)
        up = best > val[active]
        if not np.any(up):
            break
        # the first neighbour attaining the best value of each walk that moves
        hit = nb_val == best[owner]
        pos = np.where(hit, np.arange(owner.size), owner.size)
        arg = np.minimum.reduceat(pos, first)
        moved = active[up]
        cur[moved] = nb[arg[up]]
        val[moved] = best[up]
        active = moved
    return val

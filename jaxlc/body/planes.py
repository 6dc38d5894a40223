"""Coplanar triangles: which triangles of a mesh lie in one plane (and one part).

Merging them into one facet is exact for the unshadowed facet sum (it is
linear in area for a given normal and material) and shrinks subdivided or
CAD meshes many-fold (:func:`jaxlc.body.mesh.facets_from_mesh`).
"""

from __future__ import annotations

import numpy as np

#: Normals and plane offsets closer than this (relative) are the same plane.
COPLANAR_TOLERANCE = 1e-6


def coplanar_groups(
    normals: np.ndarray, centroids_m: np.ndarray, part: np.ndarray, diag_m: float
) -> np.ndarray:
    """Label triangles that share a part and a plane, numbered by their first triangle.

    Planes are keys (unit normal, offset / diag); keys closer than
    COPLANAR_TOLERANCE are linked. Keys in one cell of side COPLANAR_TOLERANCE / 2
    are within it and linked at once; the cells' first keys are then linked
    by a k-d tree's pairs within it. O(F log F) however many triangles share a
    plane (linking every pair would make 5·10⁹ pairs of one plane of 10⁵
    triangles). The groups refine those of linking every pair within the
    tolerance and equal them on the shipped meshes (tests/test_mesh.py).

    Args:
        normals: (M, 3) unit normals of the triangles.
        centroids_m: (M, 3) their centroids (m).
        part: (M,) integer part of each triangle (parts never share a group).
        diag_m: the mesh's size (m), the unit of the plane offsets.

    Returns:
        (M,) int64 group of each triangle, 0, 1, … in order of first appearance.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    key = np.column_stack([normals, np.einsum("ij,ij->i", normals, centroids_m) / diag_m])
    cell = np.column_stack([np.floor(key / (0.5 * COPLANAR_TOLERANCE)).astype(np.int64), part])
    order = np.lexsort(cell.T[::-1])
    new = np.ones(len(order), dtype=bool)
    new[1:] = np.any(cell[order[1:]] != cell[order[:-1]], axis=1)
    cell_of = np.empty(len(order), dtype=np.int64)
    cell_of[order] = np.cumsum(new) - 1
    first = order[new]  # one triangle of each cell
    # Parts are kept apart by a large coordinate jump in a 5th dimension.
    rep = np.column_stack([key[first], part[first] * 10.0])
    pairs = cKDTree(rep).query_pairs(r=COPLANAR_TOLERANCE, output_type="ndarray")
    n = len(first)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    labels = labels[cell_of]
    first_of_label = np.full(labels.max() + 1, len(labels), dtype=np.int64)
    np.minimum.at(first_of_label, labels, np.arange(len(labels)))
    rank = np.empty(len(first_of_label), dtype=np.int64)
    rank[np.argsort(first_of_label)] = np.arange(len(first_of_label))
    return rank[labels]

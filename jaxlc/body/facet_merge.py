"""Facets merged by normal: the spin search's coarse body.

:func:`coarsen_facets` merges each part's facets whose normals fall into one of a
few nearly uniform direction bins (:func:`fibonacci_sphere`), so a search model
sums over ~100 facets where the mesh has thousands.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxlc.body.mesh import Facets


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) nearly uniform unit vectors."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    r = np.sqrt(1 - z**2)
    phi = np.pi * (1 + 5**0.5) * k
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def coarsen_facets(facets: Facets, directions: int = 64) -> Facets:
    """Merge the facets of each part whose normals fall in one of ``directions`` bins.

    A merged facet keeps the summed area, the area-weighted mean normal and
    centroid, and its triangles (so the shadow table of a merged facet is the
    area-weighted mean over all of them). Exact for facets with identical
    normals; otherwise an approximation whose error grows with the bin size
    relative to the sharpest lobe.
    """
    if facets.n_facets <= directions:
        return facets
    grid = fibonacci_sphere(directions)
    bin_id = np.argmax(facets.normals @ grid.T, axis=1)
    key = facets.part.astype(np.int64) * directions + bin_id
    uniq, inv = np.unique(key, return_inverse=True)
    a = facets.areas_m2
    n_sum = np.zeros((len(uniq), 3))
    np.add.at(n_sum, inv, facets.normals * a[:, None])
    area = np.bincount(inv, weights=a)
    c_sum = np.zeros((len(uniq), 3))
    np.add.at(c_sum, inv, facets.centroids_m * a[:, None])
    norm = np.linalg.norm(n_sum, axis=1, keepdims=True)
    normals = np.where(norm > 0, n_sum / np.maximum(norm, 1e-300), grid[uniq % directions])
    can_shadow = np.bincount(inv, weights=facets.can_shadow.astype(float)) > 0
    tri = facets.triangle_facet
    return dataclasses.replace(
        facets,
        normals=normals,
        areas_m2=area,
        centroids_m=c_sum / area[:, None],
        part=(uniq // directions).astype(facets.part.dtype),
        can_shadow=can_shadow,
        triangle_facet=np.where(tri >= 0, inv[np.maximum(tri, 0)], -1),
    )

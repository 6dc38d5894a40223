"""The exact twin of :mod:`jaxlc.body.shadow`: lit-and-seen areas by polygon clipping.

For a facet f and a direction d (towards the Sun or the observer), a point x of
the facet is blocked when the ray x + t d hits another triangle. The blocked
set is the union, over every triangle, of its part in front of the facet's
plane projected onto that plane along d. The lit-and-seen area is the facet's
polygon minus the blocked sets of both directions. Polygon operations use
shapely (GEOS) on a 0.1 µm precision grid; everything else is float64 numpy.
Slow (seconds per sample for meshes of thousands of triangles) and meant for
tests, benchmarks and reference data, not for rendering.
"""

from __future__ import annotations

import numpy as np

from jaxlc.body.facet_model import tangent_frame
from jaxlc.body.mesh import Facets, TriangleMesh

#: Precision grid of the polygon operations (m).
GRID_M = 1e-7
_FRONT = 1e-12
#: A vertex this close to a facet's plane (m) counts as on it.
_ON_PLANE = 1e-9


class ExactShadows:
    """Exact lit-and-seen fractions of the facets of one mesh.

    Example:
        >>> ex = ExactShadows(mesh, facets)
        >>> frac = ex.fractions(sun_b, obs_b)   # (F,), 1 where nothing can shadow
    """

    def __init__(self, mesh: TriangleMesh, facets: Facets):
        import shapely

        self.facets = facets
        valid = facets.triangle_facet >= 0
        self.tris = mesh.vertices_m[mesh.faces][valid]
        self.tri_facet = facets.triangle_facet[valid]
        self.u, self.w = tangent_frame(facets.normals)
        self.polygons = {}
        for f in np.flatnonzero(facets.can_shadow):
            t = self.tris[self.tri_facet == f] - facets.centroids_m[f]
            q = np.stack([t @ self.u[f], t @ self.w[f]], -1)
            self.polygons[f] = shapely.union_all(shapely.polygons(q), grid_size=GRID_M)

    def fractions(self, sun_b: np.ndarray, obs_b: np.ndarray) -> np.ndarray:
        """(F,) lit-and-seen area fractions for one sample (body-frame unit vectors).

        Facets that cannot be shadowed, or that are not both lit and seen, get 1
        (their contribution is then complete or zero anyway).
        """
        import shapely

        out = np.ones(self.facets.n_facets)
        n = self.facets.normals
        for f, poly in self.polygons.items():
            if n[f] @ sun_b <= 0 or n[f] @ obs_b <= 0:
                continue
            visible = poly
            for d in (sun_b, obs_b):
                blocked = self._blocked(f, np.asarray(d, np.float64), poly.bounds)
                if blocked is not None:
                    visible = shapely.difference(visible, blocked, grid_size=GRID_M)
            out[f] = visible.area / poly.area
        return out

    def _blocked(self, f: int, d: np.ndarray, box):
        """The part of facet f's plane (2-D facet coordinates) whose ray along d is blocked."""
        import shapely

        n, c = self.facets.normals[f], self.facets.centroids_m[f]
        rel = self.tris - c
        h = rel @ n  # heights above the facet's plane
        cand = (h > _FRONT).any(1) & (self.tri_facet != f)
        rel, h = rel[cand], h[cand]
        nd = n @ d
        # Wholly in front: every vertex in front or on the plane. A vertex on the plane
        # taken as a crossing's odd one cuts the triangle at that vertex twice, and the
        # "quadrilateral" (v, b, c, v) repeats it: an invalid ring, which GEOS turned
        # into a blocked set covering whole facets (S4's nozzle: fully visible facets,
        # by ray casting, at 0).
        full = (h > -_ON_PLANE).all(1)
        pieces = [rel[full]]
        # Triangles crossing the plane: keep their part in front. Rotate each so
        # that its odd vertex (alone on its side) comes first.
        t, hh = rel[~full], h[~full]
        front = hh > _FRONT
        odd = np.where(front.sum(1) == 1, np.argmax(front, 1), np.argmax(~front, 1))
        order = (odd[:, None] + np.arange(3)) % 3
        t = np.take_along_axis(t, order[:, :, None], 1)
        hh = np.take_along_axis(hh, order, 1)
        a, b, cc = t[:, 0], t[:, 1], t[:, 2]
        with np.errstate(invalid="ignore", divide="ignore"):
            pab = a + (hh[:, 0] / (hh[:, 0] - hh[:, 1]))[:, None] * (b - a)
            pac = a + (hh[:, 0] / (hh[:, 0] - hh[:, 2]))[:, None] * (cc - a)
        alone_in_front = hh[:, 0] > _FRONT
        pieces.append(np.stack([a, pab, pac], 1)[alone_in_front])  # a triangle remains
        pieces.append(np.stack([pab, b, cc, pac], 1)[~alone_in_front])  # a quadrilateral
        shapes = []
        for p in pieces:
            if not len(p):
                continue
            proj = p - ((p @ n) / nd)[..., None] * d  # along d onto the plane
            q = np.stack([proj @ self.u[f], proj @ self.w[f]], -1)
            lo, hi = q.min(1), q.max(1)
            near = (
                (hi[:, 0] > box[0])
                & (lo[:, 0] < box[2])
                & (hi[:, 1] > box[1])
                & (lo[:, 1] < box[3])
            )
            q = q[near]
            x, y = q[..., 0], q[..., 1]
            area2 = np.abs(np.sum(x * np.roll(y, -1, 1) - y * np.roll(x, -1, 1), axis=1))
            shapes.extend(shapely.polygons(q[area2 > 1e-14]))
        if not shapes:
            return None
        # Projections of triangles (and of triangles cut by a plane) are convex and
        # valid; cutting them to the facet's box on the precision grid keeps GEOS robust.
        arr = shapely.intersection(
            np.array(shapes, dtype=object), shapely.box(*box), grid_size=GRID_M
        )
        arr = arr[shapely.area(arr) > 0]
        if not len(arr):
            return None
        return _polygonal(shapely.union_all(arr, grid_size=GRID_M))


def _polygonal(geometry):
    """The polygonal part of a geometry (drops points and lines), or None."""
    import shapely

    parts = [p for p in shapely.get_parts(geometry) if p.geom_type == "Polygon" and p.area > 0]
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)


def exact_intensity(model, exact: ExactShadows, sun_b: np.ndarray, obs_b: np.ndarray) -> np.ndarray:
    """I/E (m² sr⁻¹) of a float64 :class:`~jaxlc.body.brdf.FacetModel` with exact shadows.

    Args:
        model: the object's facets and materials (all facets, float64).
        exact: the twin of the same facets.
        sun_b, obs_b: (T, 3) body-frame unit vectors.
    """
    import jax
    import jax.numpy as jnp

    from jaxlc.body.facet_model import facet_contributions

    with jax.enable_x64(True):
        terms = np.asarray(facet_contributions(model, jnp.asarray(sun_b), jnp.asarray(obs_b)))
    frac = np.stack([exact.fractions(s, v) for s, v in zip(sun_b, obs_b, strict=True)])
    return np.sum(terms * frac, axis=1)

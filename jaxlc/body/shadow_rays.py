"""Lit-and-seen fractions by rays cast in the kernel: facets the clipping cannot take.

Exact clipping (:mod:`jaxlc.body.shadow_clip`) needs a facet's occluders listed
once, at most a few dozen polygons; a facet inside a concave part sees hundreds
(every facet of S4's nozzle bell: the glints of the bell's inner wall, partly
shadowed by its rim, are where S4's table is 2–6 % of a curve's median off,
``experiments/shadow_curves.py``). Here such a facet's fraction is counted on
:data:`RAY_POINTS` sub-points: each casts a ray towards the Sun and one towards
the observer against every triangle of the mesh, as the table's trace casts them
(:func:`jaxlc.body.raycast.trace_visibility`: the same sub-points, lift off the
surface and depth margin, :func:`jaxlc.body.occlusion.hits`), but for the
instant's own directions, not those of grid nodes. The table's 32 sub-points and
3° grid make its fraction 3–15 % off near a shadow edge; 512 points are within
1.2 % of the exact twin (0.3 % on average) on the 48 partly shadowed facets of four
S4 glints (``tests/test_shadow_clip.py``; 1,024 points: 0.3 % at most on the 15
whose table errs most, 512: 0.7 %).

Brute force over (points × triangles), one facet and one instant at a time (S4:
512 × 2,784 pairs a direction, a few ms on a CPU core): only for the few
terms :mod:`jaxlc.rendering.exact_glints` picks.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxlc.body.mesh import Facets, TriangleMesh
from jaxlc.body.occlusion import hits, plane_basis
from jaxlc.body.raycast import DEPTH_MARGIN, lifted_sub_points, mesh_occluders

#: Sub-points per facet whose rays are cast (fewer on a large mesh: :func:`ray_points`).
RAY_POINTS = 512
#: Most sub-points of one kit (48 MB of float32 points), and the fewest a facet gets.
RAY_POINT_BUDGET = 1 << 22
MIN_RAY_POINTS = 64


def ray_points(n_facets: int) -> int:
    """Sub-points per facet of a kit of ``n_facets`` facets: :data:`RAY_POINTS`, halved
    while the kit would exceed :data:`RAY_POINT_BUDGET` (not below :data:`MIN_RAY_POINTS`)."""
    k = RAY_POINTS
    while k > MIN_RAY_POINTS and k * n_facets > RAY_POINT_BUDGET:
        k //= 2
    return k


class RayData(eqx.Module):
    """The facets whose fractions are counted by casting rays (traced).

    Attributes:
        points: (K, P, 3) each facet's sub-points, lifted off its surface (m).
        corners: (3, M, 3) the mesh's triangles, corner by corner (m).
        tri_normal: (M, 3) their unit normals.
        depth_margin_m: how far beyond a point a triangle must lie to block it.
        cull_back: only triangles facing against a ray block it (a watertight mesh).
    """

    points: Float[Array, "K P 3"]
    corners: Float[Array, "3 M 3"]
    tri_normal: Float[Array, "M 3"]
    depth_margin_m: Float[Array, ""]
    cull_back: bool = eqx.field(static=True)


def ray_data(
    mesh: TriangleMesh, facets: Facets, facet_ids: np.ndarray, dtype=np.float32
) -> RayData:
    """The ray kit of facets ``facet_ids`` (host, once per mesh): their
    :func:`ray_points` sub-points each, placed and lifted as the shadow table's are."""
    ids = np.asarray(facet_ids, np.int64)
    blockers = mesh_occluders(mesh, facets)  # as the table's trace
    k = ray_points(len(ids))
    pts = lifted_sub_points(mesh, facets, ids, np.full(len(ids), k)).reshape(len(ids), k, 3)
    return RayData(
        points=jnp.asarray(pts, dtype),
        corners=jnp.asarray(np.moveaxis(blockers.triangles, 1, 0), dtype),
        tri_normal=jnp.asarray(blockers.normals, dtype),
        depth_margin_m=jnp.asarray(DEPTH_MARGIN * mesh.diagonal_m, dtype),
        cull_back=blockers.cull_back,
    )


def ray_fraction(
    data: RayData, k, sun_b: Float[Array, " 3"], obs_b: Float[Array, " 3"]
) -> Float[Array, ""]:
    """Share of facet ``k``'s sub-points whose rays to the Sun and to the observer
    (body-frame unit vectors) both escape the mesh (traced; one facet, one instant)."""
    points = data.points[k]

    def escapes(d):  # (P,) the ray from each point along d meets no triangle
        basis = plane_basis(d, xp=jnp)
        p = points @ basis.T  # (P, 3): plane coordinates and depth
        c = (data.corners @ basis.T)[:, None]  # (3 corners, 1, M, 3): against every point
        blocked = hits(
            p[:, 0, None],
            p[:, 1, None],
            p[:, 2, None] + data.depth_margin_m,
            c[..., 0],
            c[..., 1],
            c[..., 2],
            xp=jnp,
        )  # (P, M)
        if data.cull_back:
            blocked = blocked & (data.tri_normal @ d < 0)[None, :]
        return ~jnp.any(blocked, axis=1)

    both = escapes(sun_b) & escapes(obs_b)
    return jnp.mean(both.astype(sun_b.dtype))

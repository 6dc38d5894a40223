"""Exact lit-and-seen areas in the kernel: facets clipped by the projected occluders.

The shadow table (:mod:`jaxlc.body.shadow`) samples each facet at sub-points and
interpolates between grid directions; its error in a facet's lit fraction is
~1 %, which a glint of that facet (tens of times the curve's median flux)
turns into errors of 10–150 % of the median (``experiments/shadow_curves.py``,
S6). Here the fraction is exact, as the slow twin (:mod:`jaxlc.body.shadow_exact`)
makes it, but in JAX with fixed shapes so that it runs inside the kernel.

For a facet F (a convex polygon) and a direction d, the blocked set is the union
U of the occluding polygons — the mesh's triangles in front of F's plane, cut at
the plane — projected along d onto it. With Sun and observer, U is the union of
both projections, and the lit-and-seen area is |F| − |F ∩ U|. By Green's theorem
|F ∩ U| = ½ ∮ (x dy − y dx) over the boundary of F ∩ U, which is made of

* the parts of U's boundary inside F, oriented with U on their left, and
* the parts of F's outline inside U, counter-clockwise.

Along a straight piece p(t) = p0 + t (p1 − p0) the integrand is the constant
p0 × p1, so each edge contributes p0 × p1 times the length (in t) of its part
that counts. U's boundary lies on the occluders' edges: a projected edge
counts where no projected polygon holds it strictly inside and where its
adjacent polygons all lie on one side of it (a fold or an open rim: the
silhouette; an edge between two polygons on either side is inside U). Each
polygon is convex, so the part of a segment strictly inside it is one
interval (Cyrus–Beck), and the union of those intervals is measured after a
sort. No approximation is made; float32 round-off gives ~1e-6 of the area.

The static half (:func:`jaxlc.body.clip_polygons.clip_data`, numpy) lists each
facet piece's occluding polygons, their points and shared edges once per mesh;
:func:`blocked_area` is the traced half for one piece and one pair of directions.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int


class ClipData(eqx.Module):
    """The occluders of the facets with exact shadows, padded to common sizes (traced).

    Attributes (C facets, Q points, P polygons, E edges, H outline vertices):
        normal, tangent_u, tangent_w: (C, 3) each facet's frame.
        area_m2: (C,) facet areas.
        points: (C, Q, 3) occluder points relative to the facet's centroid, as
            (r·u, r·w, r·n) (m); r·n > 0 in front of the plane.
        polygon: (C, P, S) point indices of each occluding polygon (a triangle
            repeats its last point), in the mesh's winding; the points of other
            polygons inside its sides inserted (T-junctions).
        side_ok: (C, P, S) whether side i (point i → i + 1) has length.
        polygon_ok: (C, P) real polygons (not padding).
        edge: (C, E, 2) the points of each distinct edge.
        adjacent: (C, E, A) polygons that have the edge (padding: 0, with ``winding`` 0).
        winding: (C, E, A) +1 where that polygon runs along the edge from edge[0] to
            edge[1], −1 where back, 0 for padding.
        own: (C, E, P) the polygons beside each edge (they do not clip it).
        edge_flat: (C, E) edges in the facet's plane (both points on it: a part that
            touches the facet), which project onto themselves for both directions.
        outline: (C, H, 2) the facet's outline, counter-clockwise in (u, w) (m).
        outline_ok: (C, H) whether outline side i has length.
        along_lo, along_hi: (C, H, E) the part [lo, hi] of outline side h (its parameter,
            0 … 1) along which edge e runs (an edge in the plane: a part attached at the
            facet's edge); lo = hi = 0 where none.
        along_sign: (C, H, E) +1 where that edge runs the side's way, −1 the other way.
    """

    normal: Float[Array, "C 3"]
    tangent_u: Float[Array, "C 3"]
    tangent_w: Float[Array, "C 3"]
    area_m2: Float[Array, " C"]
    points: Float[Array, "C Q 3"]
    polygon: Int[Array, "C P S"]
    side_ok: Bool[Array, "C P S"]
    polygon_ok: Bool[Array, "C P"]
    edge: Int[Array, "C E 2"]
    adjacent: Int[Array, "C E A"]
    winding: Float[Array, "C E A"]
    own: Bool[Array, "C E P"]
    edge_flat: Bool[Array, "C E"]
    outline: Float[Array, "C H 2"]
    outline_ok: Bool[Array, "C H"]
    along_lo: Float[Array, "C H E"]
    along_hi: Float[Array, "C H E"]
    along_sign: Float[Array, "C H E"]


# ---------------------------------------------------------------------------
# The traced half


def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _inside(p0, p1, a, b, sign, ok):
    """(M, J) intervals [lo, hi] ⊂ [0, 1] of t where p0 + t (p1 − p0) lies strictly inside
    each of J convex polygons: sides a → b (J, S, 2), ``sign`` (J,) their orientation (+1:
    counter-clockwise), ``ok`` (J, S) sides with length. A point on a side is outside: an
    edge a polygon shares is told apart by adjacency, not by round-off. Empty intervals
    come back as lo = hi = 0."""
    side = b - a
    rel = p0[:, None, None, :] - a[None]
    n_ = sign[None, :, None] * _cross(side[None], rel)  # (M, J, S)
    d_ = sign[None, :, None] * _cross(side[None], (p1 - p0)[:, None, None, :])
    cut = -n_ / jnp.where(d_ == 0, 1.0, d_)
    lower = jnp.where(ok[None] & (d_ > 0), cut, -jnp.inf)
    upper = jnp.where(ok[None] & (d_ < 0), cut, jnp.inf)
    never = jnp.any(ok[None] & (d_ == 0) & (n_ <= 0), axis=-1)
    lo = jnp.maximum(jnp.max(lower, axis=-1), 0.0)
    hi = jnp.minimum(jnp.min(upper, axis=-1), 1.0)
    empty = never | (lo >= hi) | ~jnp.any(ok, axis=-1)[None]  # no sides: no polygon
    return jnp.where(empty, 0.0, lo), jnp.where(empty, 0.0, hi)


def _union_length(lo, hi, start, stop):
    """(M,) length of ∪_j [lo_j, hi_j] ∩ [start, stop] for (M, J) intervals."""
    lo = jnp.clip(lo, start[:, None], stop[:, None])
    hi = jnp.clip(hi, start[:, None], stop[:, None])
    # one sort of both (13 % faster than an argsort and two gathers; S6)
    lo, hi = jax.lax.sort((lo, hi), dimension=lo.ndim - 1, num_keys=1)
    reach = jax.lax.cummax(hi, axis=hi.ndim - 1)
    before = jnp.concatenate([start[:, None], reach[:, :-1]], axis=-1)
    return jnp.sum(jnp.maximum(hi - jnp.maximum(lo, before), 0.0), axis=-1)


def blocked_area(
    data: ClipData, sun_b: Float[Array, " 3"], obs_b: Float[Array, " 3"]
) -> Float[Array, ""]:
    """Exact area (m²) of one facet piece (``data``: one piece's slice of a
    :class:`ClipData`) that is in shadow or hidden, for body-frame unit vectors
    towards the Sun and the observer.

    0 where the piece faces away from either (its term is zero then anyway).
    ``jax.vmap`` it over pieces and directions.
    """
    dirs = jnp.stack([sun_b, obs_b])  # (2, 3)
    dn = dirs @ data.normal
    # grazing directions: the projection is taken at ≥ 1e-3 (the facet's term is ∝ n·d)
    slope = (
        jnp.stack([dirs @ data.tangent_u, dirs @ data.tangent_w], -1)
        / jnp.maximum(dn, 1e-3)[:, None]
    )
    pts = data.points[None, :, :2] - data.points[None, :, 2:] * slope[:, None, :]  # (2, Q, 2)
    # the projected polygons (2 × P, S sides) and their orientation
    corner = pts[:, data.polygon]  # (2, P, S, 2)
    nxt = jnp.roll(corner, -1, axis=2)
    area2 = jnp.sum(_cross(corner, nxt), axis=-1)  # (2, P), twice the signed area
    # a polygon seen edge-on keeps an orientation (either): then exactly one of the edges
    # it shares with polygons on either side is a fold (as a clipper it holds nothing)
    sign = jnp.where(data.polygon_ok, jnp.where(area2 >= 0, 1.0, -1.0), 0.0)
    n_p = data.polygon.shape[0]
    a = corner.reshape(2 * n_p, -1, 2)
    b = nxt.reshape(2 * n_p, -1, 2)
    sides_ok = jnp.broadcast_to(data.side_ok, (2, *data.side_ok.shape)) & (sign[..., None] != 0)
    sides_ok = sides_ok.reshape(2 * n_p, -1)
    # the projected edges on U's boundary: σ = +1 (U on the left), −1 (right) or 0 (inside U)
    left = sign[:, data.adjacent] * data.winding[None]  # (2, E, A)
    # an edge in the facet's plane projects onto itself in both sets: one edge, counted
    # once (from the Sun's set) with the polygons of both sets beside it
    flat = data.edge_flat[:, None]
    both = jnp.concatenate([left[0], left[1]], axis=-1)  # (E, 2A)
    alone = jnp.concatenate([left, jnp.zeros_like(left)], axis=-1)  # (2, E, 2A)
    left = jnp.stack([jnp.where(flat, both, alone[0]), jnp.where(flat, 0.0, alone[1])])
    left_any, right_any = jnp.any(left > 0, -1), jnp.any(left < 0, -1)
    sigma = jnp.where(left_any & ~right_any, 1.0, jnp.where(right_any & ~left_any, -1.0, 0.0))
    n_e = data.edge.shape[0]
    p0 = pts[:, data.edge[:, 0]].reshape(2 * n_e, 2)
    p1 = pts[:, data.edge[:, 1]].reshape(2 * n_e, 2)
    # an edge is on the boundary of its own polygons: they do not clip it
    pair = jnp.eye(2, dtype=bool)[:, None, :, None] | data.edge_flat[None, :, None, None]
    same = pair & data.own[None, :, None, :]  # (2, E, 2, P)
    lo, hi = _inside(p0, p1, a, b, sign.reshape(-1), sides_ok)
    clipping = ~same.reshape(2 * n_e, 2 * n_p)
    lo, hi = jnp.where(clipping, lo, 0.0), jnp.where(clipping, hi, 0.0)
    # ... within the facet's outline (counter-clockwise; an edge along the outline — a
    # part attached at the facet's edge — is not inside: it is counted as the outline's)
    o0 = data.outline
    o1 = jnp.roll(o0, -1, axis=0)
    t0, t1 = _inside(p0, p1, o0[None], o1[None], jnp.ones(1, pts.dtype), data.outline_ok[None])
    t0, t1 = t0[:, 0], t1[:, 0]
    kept = jnp.maximum(t1 - t0, 0.0) - _union_length(lo, hi, t0, t1)
    boundary = jnp.sum(sigma.reshape(-1) * _cross(p0, p1) * kept)
    # the outline's sides inside U; where an edge in the plane runs along one, that part
    # is U's boundary, and the side bounds F ∩ U where U lies on the facet's side of it
    lo_o, hi_o = _inside(o0, o1, a, b, sign.reshape(-1), sides_ok)
    facing = jnp.where(data.along_sign > 0, left_any[0][None], right_any[0][None])  # (H, E)
    lo_o = jnp.concatenate([lo_o, jnp.where(facing, data.along_lo, 0.0)], axis=-1)
    hi_o = jnp.concatenate([hi_o, jnp.where(facing, data.along_hi, 0.0)], axis=-1)
    n_h = o0.shape[0]
    covered = _union_length(lo_o, hi_o, jnp.zeros(n_h, pts.dtype), jnp.ones(n_h, pts.dtype))
    rim = jnp.sum(jnp.where(data.outline_ok, _cross(o0, o1) * covered, 0.0))
    blocked = jnp.clip(0.5 * (boundary + rim), 0.0, data.area_m2)
    return jnp.where(jnp.all(dn > 0), blocked, 0.0)


def exact_fractions(
    data: ClipData,
    piece_facet,
    facet_area_m2,
    sun_b: Float[Array, "T 3"],
    obs_b: Float[Array, "T 3"],
) -> Float[Array, "T K"]:
    """Exact lit-and-seen fractions (T, K) of the K facets whose C pieces ``data`` holds.

    Args:
        data: the pieces' occluders (:func:`jaxlc.body.clip_polygons.clip_data`).
        piece_facet: (C,) static column (0 … K − 1) of each piece's facet.
        facet_area_m2: (K,) the facets' areas.
        sun_b, obs_b: (T, 3) body-frame unit vectors.
    """
    per_pair = jax.vmap(jax.vmap(blocked_area, in_axes=(0, None, None)), in_axes=(None, 0, 0))
    blocked = per_pair(data, sun_b, obs_b)  # (T, C)
    k = len(facet_area_m2)
    onto = jax.nn.one_hot(jnp.asarray(piece_facet), k, dtype=blocked.dtype)  # (C, K)
    return 1.0 - (blocked @ onto) / jnp.asarray(facet_area_m2, blocked.dtype)[None, :]

"""Exact shadows where the table's error shows: the brightest shadowable facet-instants.

The shadow table's lit fraction is ~1 % off near shadow edges, which matters only
where a facet's term is large against the curve: a glint of a partly shadowed
panel is tens to hundreds of times the curve's median flux, so 1 % of it is
10–150 % of the median (``experiments/shadow_curves.py``). Exact clipping
(:mod:`jaxlc.body.shadow_clip`) costs ~0.2–0.5 ms per facet piece and instant on
the CPU, too much for every instant; here it replaces the table's fraction only for
the brightest terms of an instant that are each a good share of the whole
(:data:`EXACT_SHARE`): where the table's error can be a visible part of the
curve. The rest keep the table. On S6, S7 and S8 (40 spinning curves each,
50 samples, ``experiments/shadow_curves.py``) the curves whose every error is
within 2 % of their median flux go from 13, 33 and 21 to all 40, at 87, 22 and
22 ms per 50-sample curve on a CPU core (S6's panels carry most instants);
over 1,756 random geometries each (``experiments/shadow_tail.py``) the largest
error is 1.0 %, 0.01 % and 0.08 % of the median I/E instead of 20×, 6 % and 81 %
(max |Δm| 0.005, 0.000, 0.001 mag).

A facet with more occluders than the clipping takes (every facet of S4's nozzle
bell, whose inner wall glints through the rim's shadow) has its fraction counted on
rays instead (:mod:`jaxlc.body.shadow_rays`: 512 sub-points, within 1.2 % of the
twin where the table is 3–15 % off): S4's curves whose every error is within 2 % of
their median flux go from 16 to all 20 (30 samples each; worst 5.7 % → 1.5 %), at ~110 ms
per 30-sample curve on a CPU core.

:func:`exact_kit` (host, once per object) gathers what that needs;
:func:`glint_correction` (traced) returns the change of I/E per instant.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from jaxlc.body.clip_polygons import clip_data
from jaxlc.body.facet_model import FacetModel, facet_contributions
from jaxlc.body.mesh import Facets, TriangleMesh
from jaxlc.body.shadow import KEEP_TABLES, ShadowData
from jaxlc.body.shadow_clip import ClipData, blocked_area
from jaxlc.body.shadow_rays import RayData, ray_data, ray_fraction
from jaxlc.memo import remember

#: Kits made in this process, by (table cache key, dtype).
_KITS: dict[tuple[str, str], "ExactKit"] = {}

#: A table fraction within this of 0 or 1 counts as not partly shadowed.
PARTIAL = 1e-6
#: A chosen term is clipped exactly when it is at least this share of the instant's
#: I/E. At instants hundreds of times a curve's median, a term of 0.1 % of the instant
#: with the table's ~3 % error is still a few per cent of the median (S8, S7: 0.02 left
#: 1 and 3 of 40 curves over 2 %, 0.005 left 1; this leaves none, at 1.5× the cost).
EXACT_SHARE = 0.0005
#: The brightest shadowable terms of an instant that may be clipped exactly.
TERMS_PER_INSTANT = 2
#: Weight of a term the table calls unshadowed (or dark) in the choice of the terms made
#: exact: a shadow can still clip it between grid directions, but less often.
UNSHADOWED_WEIGHT = 0.02


class ExactKit(eqx.Module):
    """The facets with exact shadows of one object (traced): K clipped ones, then R whose
    rays are cast (:mod:`jaxlc.body.shadow_rays`: the clipping takes only a few dozen
    occluders).

    Attributes:
        clip: the C pieces' occluders of the clipped facets (None: none is clipped).
        rows: (K + R,) their rows in the object's model (and shadow table).
        pieces: (K, N) the pieces of each clipped facet (padding repeats one, with
            ``piece_ok`` False).
        piece_ok: (K, N) real entries of ``pieces``.
        area_m2: (K,) clipped facets' areas (of the mesh file: the fractions do not
            depend on scale).
        rays: the sub-points of the R others (None: every facet is clipped).
    """

    clip: ClipData | None
    rows: Int[Array, " KR"]
    pieces: Int[Array, "K N"]
    piece_ok: Array
    area_m2: Float[Array, " K"]
    rays: RayData | None = None


def kit_for(data: ShadowData, mesh: TriangleMesh, facets: Facets, dtype=np.float32):
    """:func:`exact_kit` of an object with shadow table ``data``, made once per table and
    dtype in this process (every curve of a dataset class shares it)."""
    memo = (data.key, str(np.dtype(dtype))) if data.key else None
    if memo in _KITS:
        return _KITS[memo]
    kit = exact_kit(mesh, facets, data.facet_ids, dtype)
    if memo is not None:
        remember(_KITS, memo, kit, KEEP_TABLES)
    return kit


def exact_kit(
    mesh: TriangleMesh, facets: Facets, facet_ids: np.ndarray, dtype=np.float32
) -> ExactKit:
    """The exact-shadow kit of an object whose shadow table covers ``facet_ids`` (its
    model's first rows, in that order): clipping where it takes the facet, rays else."""
    clip, owner = clip_data(mesh, facets, facet_ids, dtype=dtype)
    supported = np.unique(owner)
    cast = np.setdiff1d(np.asarray(facet_ids), supported)
    row_of = {int(f): j for j, f in enumerate(facet_ids)}
    rows = np.array([row_of[int(f)] for f in (*supported, *cast)], np.int64)
    width = max((int(np.sum(owner == f)) for f in supported), default=1)
    pieces = np.zeros((len(supported), width), np.int32)
    ok = np.zeros((len(supported), width), bool)
    for k, f in enumerate(supported):
        mine = np.flatnonzero(owner == f)
        pieces[k, : len(mine)], pieces[k, len(mine) :] = mine, mine[0]
        ok[k, : len(mine)] = True
    return ExactKit(
        clip=clip,
        rows=jnp.asarray(rows, jnp.int32),
        pieces=jnp.asarray(pieces),
        piece_ok=jnp.asarray(ok),
        area_m2=jnp.asarray(facets.areas_m2[supported], dtype),
        rays=ray_data(mesh, facets, cast, dtype) if len(cast) else None,
    )


def glint_correction(
    model: FacetModel,
    kit: ExactKit,
    sun_b: Float[Array, "T 3"],
    obs_b: Float[Array, "T 3"],
    table: Float[Array, "T S"],
    total: Float[Array, " T"],
) -> Float[Array, " T"]:
    """Change of I/E (m² sr⁻¹) per instant when the :data:`TERMS_PER_INSTANT` brightest
    terms of the kit's facets (those the table calls partly shadowed first) take their
    exact lit-and-seen fraction instead of the table's, each where it is at least
    :data:`EXACT_SHARE` of the instant's I/E (``total``, with the table's fractions).

    Each instant is decided on its own (a ``lax.cond`` per instant: clipping costs only
    where it is taken, and no result depends on how the instants are cut into blocks).

    Args:
        model: the object's facets (the shadow table's first).
        kit: :func:`exact_kit` of the same object.
        sun_b, obs_b: (T, 3) body-frame unit vectors.
        table: (T, S) the table's lit-and-seen fractions of its S facets.
        total: (T,) I/E with the table's fractions.
    """
    model = jax.tree_util.tree_map(lambda x: x[kit.rows], model)
    terms = facet_contributions(model, sun_b, obs_b)  # (T, K), unshadowed
    table = table[:, kit.rows]
    partial = (table > PARTIAL) & (table < 1.0 - PARTIAL)
    score = terms * jnp.where(partial, 1.0, UNSHADOWED_WEIGHT)
    best = jax.lax.top_k(score, min(TERMS_PER_INSTANT, terms.shape[1]))[1]  # (T, M)
    term = jnp.take_along_axis(terms, best, axis=1)
    looked_up = jnp.take_along_axis(table, best, axis=1)
    gate = (term > 0) & (term >= EXACT_SHARE * total[:, None])

    n_clip = kit.pieces.shape[0]

    def clipped(s_i, v_i, k_i):
        pieces = jax.tree_util.tree_map(lambda x: x[kit.pieces[k_i]], kit.clip)
        area = jax.vmap(blocked_area, in_axes=(0, None, None))(pieces, s_i, v_i)
        blocked = jnp.sum(jnp.where(kit.piece_ok[k_i], area, 0.0))
        return (1.0 - blocked / kit.area_m2[k_i]).astype(table.dtype)

    def cast(s_i, v_i, k_i):
        return ray_fraction(kit.rays, k_i, s_i, v_i).astype(table.dtype)

    def exact(s_i, v_i, k_i):
        if kit.rays is None:
            return clipped(s_i, v_i, k_i)
        if kit.clip is None:
            return cast(s_i, v_i, k_i)
        return jax.lax.cond(
            k_i < n_clip,
            lambda: clipped(s_i, v_i, jnp.minimum(k_i, n_clip - 1)),
            lambda: cast(s_i, v_i, jnp.maximum(k_i - n_clip, 0)),
        )

    def one(args):  # one instant: its chosen terms one after the other (a cond each)
        s_i, v_i, k_i, gate_i, table_i = args
        return jax.lax.map(
            lambda b: jax.lax.cond(b[1], lambda: exact(s_i, v_i, b[0]), lambda: b[2]),
            (k_i, gate_i, table_i),
        )

    fraction = jax.lax.map(one, (sun_b, obs_b, best, gate, looked_up))
    return jnp.sum(term * (fraction - looked_up), axis=1)

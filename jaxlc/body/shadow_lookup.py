"""The render-time half of self-shadowing: a table's device copy and its look-up.

:mod:`jaxlc.body.shadow` makes (or loads) the visibility bits of the facets that
can be shadowed; here the kernel looks them up: the lit *and* seen fraction of
facet f is Σ_ab w_a(s) w_b(v) popcount(B_f[a] & B_f[b]) / K over the grid corners
a of the Sun direction s and b of the observer direction v (interpolation weights,
:func:`jaxlc.body.octahedral.grid_corners`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, UInt32

from jaxlc.body.octahedral import grid_corners
from jaxlc.body.shadow import KEEP_TABLES, ShadowData

#: Device copies of tables in this process, by (cache key, interpolation, dtype).
_TABLES: dict[tuple[str, str, str], "ShadowTable"] = {}


class ShadowTable(eqx.Module):
    """Packed visibility bits of the facets that can be shadowed (traced input).

    Attributes:
        bits: (D, W) uint32 (see :class:`jaxlc.body.shadow.ShadowData`); bit b of a word says
            whether that sub-point sees the grid direction of the row.
        subpoints: (F_s,) sub-points per facet.
        groups: ((facets, sub-points per facet), …) runs of the word layout.
        grid: octahedral grid side N (D = N²).
        interpolation: one of :data:`jaxlc.body.shadow.INTERPOLATIONS`.
    """

    bits: UInt32[Array, "D W"]
    subpoints: Float[Array, " F"]
    groups: tuple[tuple[int, int], ...] = eqx.field(static=True)
    grid: int = eqx.field(static=True)
    interpolation: str = eqx.field(static=True)


def lit_seen_fraction(
    table: ShadowTable, sun_b: Float[Array, "T 3"], obs_b: Float[Array, "T 3"]
) -> Float[Array, "T F"]:
    """Fraction of each shadowable facet both lit and seen, (T, F_s) in [0, 1]."""
    idx_s, w_s = grid_corners(sun_b, table.grid, table.interpolation)
    idx_v, w_v = grid_corners(obs_b, table.grid, table.interpolation)
    dtype = sun_b.dtype
    c = idx_s.shape[1]
    rows = table.bits[jnp.concatenate([idx_s, idx_v], axis=1)]  # one gather: (T, 2C, W)
    shared = tuple(g for g in table.groups if g[1] < 32)  # runs that share words: first
    split = sum(-(-n * k // 32) for n, k in shared)
    count_shared, count = 0.0, 0.0
    for a in range(c):
        for b in range(c):
            both = rows[:, a] & rows[:, c + b]
            w = (w_s[:, a] * w_v[:, b])[:, None]
            if shared:
                count_shared = count_shared + w * _slot_counts(both[:, :split], shared, dtype)
            if split < table.bits.shape[1]:
                count = count + w * jax.lax.population_count(both[:, split:]).astype(dtype)
    parts, start = ([count_shared] if shared else []), 0
    for n_facets, k in table.groups[len(shared) :]:  # sum each facet's words: a static reshape
        words = k // 32
        block = count[:, start : start + n_facets * words]
        parts.append(block if words == 1 else block.reshape(-1, n_facets, words).sum(-1))
        start += n_facets * words
    per_facet = parts[0] if len(parts) == 1 else jnp.concatenate(parts, axis=1)
    return per_facet / table.subpoints.astype(dtype)[None, :]


def _slot_counts(words, groups, dtype):
    """(T, Σ facets) set bits of each facet in words (T, W) shared by 32/k facets each."""
    parts, start = [], 0
    for n_facets, k in groups:
        n_words = -(-n_facets * k // 32)
        shifts = jnp.arange(0, 32, k, dtype=jnp.uint32)[None, None, :]
        x = words[:, start : start + n_words, None]
        slots = jax.lax.population_count((x >> shifts) & jnp.uint32((1 << k) - 1))
        parts.append(slots.reshape(x.shape[0], -1)[:, :n_facets].astype(dtype))
        start += n_words
    return parts[0] if len(parts) == 1 else jnp.concatenate(parts, axis=1)


def shadow_table(data: ShadowData, dtype=jnp.float32) -> ShadowTable:
    """The kernel's view of a table (on the device; one copy per table and dtype)."""
    memo = (data.key, data.settings.interpolation, str(np.dtype(dtype))) if data.key else None
    if memo in _TABLES:
        return _TABLES[memo]
    table = ShadowTable(
        bits=jnp.asarray(data.bits),
        subpoints=jnp.asarray(data.counts, dtype=dtype),
        groups=data.groups,
        grid=data.settings.grid,
        interpolation=data.settings.interpolation,
    )
    if memo is not None:
        while len(_TABLES) >= KEEP_TABLES:
            _TABLES.pop(next(iter(_TABLES)))
        _TABLES[memo] = table
    return table

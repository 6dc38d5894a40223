"""The render-time half of self-shadowing: a table's device copy and its look-up.

:mod:`jaxlc.body.shadow` makes (or loads) the visibility bits of the facets that
can be shadowed; here the kernel looks them up: the lit *and* seen fraction of
facet f is Σ_ab w_a(s) w_b(v) popcount(B_f[a] & B_f[b]) / K over the grid corners
a of the Sun direction s and b of the observer direction v (interpolation weights,
:func:`jaxlc.body.octahedral.grid_corners`), computed per column (a word, or a facet
that shares words: :func:`lit_seen_columns`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int, UInt32

from jaxlc.body.octahedral import grid_corners
from jaxlc.body.shadow import KEEP_TABLES, ShadowData
from jaxlc.memo import remember

#: Device copies of tables in this process, by (cache key, interpolation, dtype).
_TABLES: dict[tuple[str, str, str], "ShadowTable"] = {}


class ShadowTable(eqx.Module):
    """Packed visibility bits of the facets that can be shadowed (traced input).

    Attributes:
        bits: (D, W) uint32 (see :class:`jaxlc.body.shadow.ShadowData`, its words in the
            order of :func:`word_major`); bit b of a word says whether that sub-point sees
            the grid direction of the row.
        divisor: (V,) sub-points of the facet that owns each column of the look-up
            (:func:`column_divisors`).
        groups: ((facets, sub-points per facet), …) runs of the word layout.
        grid: octahedral grid side N (D = N²).
        interpolation: one of :data:`jaxlc.body.shadow.INTERPOLATIONS`.
    """

    bits: UInt32[Array, "D W"]
    divisor: Float[Array, " V"]
    groups: tuple[tuple[int, int], ...] = eqx.field(static=True)
    grid: int = eqx.field(static=True)
    interpolation: str = eqx.field(static=True)


def lit_seen_columns(
    table: ShadowTable, sun_b: Float[Array, "T 3"], obs_b: Float[Array, "T 3"]
) -> Float[Array, "T V"]:
    """Each column's share of its facet's lit-and-seen fraction, (T, V) in [0, 1].

    A column is a facet that shares its words with others, or one 32-point word of a
    facet with whole words; a facet's fraction is the sum of its columns
    (:func:`run_fraction`). Every column is one element of a
    single fused loop over the gathered rows: summing a facet's words in the same
    loop (slices, reshapes, a concatenation) made XLA keep the gathered rows in
    memory, and the S4 look-up 2.3× slower. The kernel sums them in its next pass.
    """
    idx_s, w_s = grid_corners(sun_b, table.grid, table.interpolation)
    idx_v, w_v = grid_corners(obs_b, table.grid, table.interpolation)
    dtype = sun_b.dtype
    rows_s = [table.bits[idx_s[:, a]] for a in range(idx_s.shape[1])]  # (T, W) per corner
    rows_v = [table.bits[idx_v[:, b]] for b in range(idx_v.shape[1])]

    def weighted(count, lo, hi):
        total = 0.0
        for a, row_s in enumerate(rows_s):
            for b, row_v in enumerate(rows_v):
                w = (w_s[:, a] * w_v[:, b])[:, None]
                total = total + w * count(row_s[:, lo:hi] & row_v[:, lo:hi])
        return total

    parts, start = [], 0
    for n_facets, k in table.groups:  # runs that share words first (k < 32)
        if k >= 32:
            break
        n_words = run_words(n_facets, k)
        slots = [  # slot j of every word: facets j·n_words … (slot-major, shared_words)
            weighted(lambda x, j=j, k=k: _slot_count(x, j, k, dtype), start, start + n_words)
            for j in range(32 // k)
        ]
        parts.append(jnp.concatenate(slots, axis=1)[:, :n_facets])
        start += n_words
    if start < table.bits.shape[1]:
        count = lambda x: jax.lax.population_count(x).astype(dtype)  # noqa: E731
        parts.append(weighted(count, start, table.bits.shape[1]))
    columns = parts[0] if len(parts) == 1 else jnp.concatenate(parts, axis=1)
    return columns / table.divisor.astype(dtype)[None, :]


def facet_runs(table: ShadowTable) -> list[tuple[int, int, int, int]]:
    """(first column, first facet, facets, columns per facet) of each run of the table's
    layout: the facets with one column each (those sharing words, then those with one
    word) in one run, then one run per group of facets with several words."""
    single = sum(n for n, k in table.groups if k <= 32)
    runs = [(0, 0, single, 1)] if single else []
    column, facet = single, single
    for n_facets, k in table.groups:
        if k > 32:
            runs.append((column, facet, n_facets, k // 32))
            column, facet = column + n_facets * (k // 32), facet + n_facets
    return runs


def run_fraction(columns: Float[Array, "T V"], run: tuple[int, int, int, int]):
    """(T, facets) lit-and-seen fraction of the facets of one run of :func:`facet_runs`:
    the sum of its facets' columns, which the device copy lays out word by word
    (:func:`word_major`), so the sum is one of contiguous slices. (A reshape and a
    sum over the words made the S6 look-up 6.5× slower in XLA:CPU.)"""
    column, _, n_facets, words = run
    total = columns[:, column : column + n_facets]
    for j in range(1, words):
        total = total + columns[:, column + j * n_facets : column + (j + 1) * n_facets]
    return total


#: Most facets with several columns whose fractions :func:`weights_at` selects one by one.
SELECTED_FACETS = 16


def weights_at(
    table: ShadowTable, columns: Float[Array, "T V"], idx: Int[Array, "T K"]
) -> Float[Array, "T K"]:
    """Lit-and-seen fractions of facets ``idx`` (T, K) at each sample (1 for the facets
    after the table's, which cannot be shadowed), without a (T, F) array of every facet's:
    one scalar gather from ``columns`` for the facets with one column, and a select per
    facet with several (the large ones: few; more than :data:`SELECTED_FACETS` are
    gathered from their (T, M) fractions instead)."""
    runs = facet_runs(table)
    n_t, n_cols = columns.shape
    single = runs[0][2] if runs and runs[0][3] == 1 else 0  # facets 0 … single − 1
    end = max((first + n for _, first, n, _ in runs), default=0)
    rows = jnp.arange(n_t, dtype=idx.dtype)[:, None]
    out = jnp.ones(idx.shape, columns.dtype)
    if single:
        col = jnp.minimum(idx, single - 1)
        got = columns.reshape(-1).at[rows * n_cols + col].get(mode="promise_in_bounds")
        out = jnp.where(idx < single, got, out)
    many = [r for r in runs if r[3] > 1]
    if sum(r[2] for r in many) > SELECTED_FACETS:
        fractions = jnp.concatenate([run_fraction(columns, r) for r in many], axis=1)
        m = fractions.shape[1]
        slot = jnp.clip(idx - single, 0, m - 1)
        got = fractions.reshape(-1).at[rows * m + slot].get(mode="promise_in_bounds")
        return jnp.where((idx >= single) & (idx < end), got, out)
    for run in many:
        fraction = run_fraction(columns, run)
        for j in range(run[2]):
            out = jnp.where(idx == run[1] + j, fraction[:, j : j + 1], out)
    return out


def column_divisors(groups: tuple[tuple[int, int], ...]) -> np.ndarray:
    """(V,) sub-points of the facet that owns each column of :func:`lit_seen_columns`."""
    return np.concatenate([np.full(n if k < 32 else n * (k // 32), float(k)) for n, k in groups])


def word_major(groups: tuple[tuple[int, int], ...]) -> np.ndarray:
    """(W,) the stored words (:class:`jaxlc.body.shadow.ShadowData`: a facet's words in a
    row) in the device copy's order: in each group of facets with several words, first
    every facet's first word, then every facet's second, …"""
    order, start = [], 0
    for n_facets, k in groups:
        n_words = run_words(n_facets, k)
        if k < 32:
            order.append(start + np.arange(n_words))
        else:
            words = k // 32
            order.append(start + np.arange(n_words).reshape(n_facets, words).T.reshape(-1))
        start += n_words
    return np.concatenate(order)


def run_words(n_facets: int, k: int) -> int:
    """uint32 words of a run of ``n_facets`` facets with ``k`` sub-points each: 32/k
    facets to a word below 32 (the last word padded), k/32 words a facet from 32 on
    (:func:`jaxlc.body.raycast.word_layout`)."""
    return -(-n_facets * k // 32) if k < 32 else n_facets * (k // 32)


def lit_seen_fraction(
    table: ShadowTable, sun_b: Float[Array, "T 3"], obs_b: Float[Array, "T 3"]
) -> Float[Array, "T F"]:
    """Fraction of each shadowable facet both lit and seen, (T, F_s) in [0, 1]: the sum
    of its columns (:func:`lit_seen_columns`)."""
    return column_fractions(table, lit_seen_columns(table, sun_b, obs_b))


def column_fractions(table: ShadowTable, columns: Float[Array, "T V"]) -> Float[Array, "T F"]:
    """(T, F_s) each facet's lit-and-seen fraction from its columns (:func:`run_fraction`)."""
    parts = [run_fraction(columns, run) for run in facet_runs(table)]
    return parts[0] if len(parts) == 1 else jnp.concatenate(parts, axis=1)


def _slot_count(words, slot: int, k: int, dtype):
    """Set bits of slot ``slot`` (bits k·slot … k·slot + k − 1) of each word, as ``dtype``."""
    mask = jnp.uint32((1 << k) - 1)
    return jax.lax.population_count((words >> jnp.uint32(k * slot)) & mask).astype(dtype)


def shared_words(bits: np.ndarray, n_facets: int, k: int) -> np.ndarray:
    """The words of a run of facets with k < 32 sub-points each, slot-major.

    :func:`jaxlc.body.raycast.word_layout` packs facet i into slot i mod 32/k of word
    ⌊i k / 32⌋; the device copy puts it into slot ⌊i / W⌋ of word i mod W (W words),
    so that slot j of every word holds facets j W … (j + 1) W − 1 in order: the
    look-up counts each slot over all words at once, one fused loop per slot
    (counting every word's slots together and regrouping them made the look-up 6–7×
    slower: S4 with sub-points by area, 405 words, 23–30 against 4.1 ms per 1,800
    instants).

    Args:
        bits: (D, W) the run's words as stored (uint32).
    Returns:
        (D, W) the same bits, slot-major.
    """
    slots, n_words = 32 // k, bits.shape[1]
    mask = np.uint32((1 << k) - 1)
    i = np.arange(n_facets)
    values = (bits[:, i // slots] >> (k * (i % slots)).astype(np.uint32)) & mask
    out = np.zeros_like(bits)
    for j in range(slots):
        block = values[:, j * n_words : (j + 1) * n_words]
        out[:, : block.shape[1]] |= block << np.uint32(k * j)
    return out


def shadow_table(data: ShadowData, dtype=jnp.float32) -> ShadowTable:
    """The kernel's view of a table (on the device; one copy per table and dtype)."""
    memo = (data.key, data.settings.interpolation, str(np.dtype(dtype))) if data.key else None
    if memo in _TABLES:
        return _TABLES[memo]
    order = word_major(data.groups)
    bits, start = data.bits[:, order], 0
    for n_facets, k in data.groups:  # runs that share words first (k < 32)
        if k >= 32:
            break
        run = slice(start, start + run_words(n_facets, k))
        bits[:, run] = shared_words(bits[:, run], n_facets, k)
        start = run.stop
    table = ShadowTable(
        bits=jnp.asarray(bits),
        divisor=jnp.asarray(column_divisors(data.groups), dtype=dtype),
        groups=data.groups,
        grid=data.settings.grid,
        interpolation=data.settings.interpolation,
    )
    if memo is not None:
        remember(_TABLES, memo, table, KEEP_TABLES)
    return table

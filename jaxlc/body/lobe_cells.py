"""Specular candidates: the facets whose lobe can reach each cell of half-vector directions.

A facet's lobe (n·h)^z, with z ≥ min(nu, nv) (an anisotropic exponent lies between
the two), is below :data:`LOBE_FLOOR` of its peak once the half vector h is more than
θ_f = arccos(LOBE_FLOOR^(1/z)) from the facet's normal (z = 300: 22°), and the term
vanishes beyond 90° (a facet with n·h ≤ 0 is not both lit and seen). On a mesh of
many glossy facets most lobes are thus negligible at any one sample: the kernel sums
the diffuse terms of every facet but the specular terms only of the facets listed
for the cell of h on an octahedral grid (:data:`CELL_GRID` × :data:`CELL_GRID` cells;
h's cell is its :func:`~jaxlc.body.octahedral.nearest_node`): every facet whose normal
lies within θ_f of some direction of the cell (:func:`lobe_cells`). The lobes left out
are each below :data:`LOBE_FLOOR` of their own peak (25 magnitudes) in a float64 model,
so the sum is the full one to that level, and below :data:`LOBE_FLOOR_FLOAT32` (15
magnitudes) in a float32 one, where they are below the rounding of the sum.

The S4 rocket body (1,205 facets, a nozzle of 1,058 at z = 300): at most 152 facets a
cell in float64 and 120 in float32 (with the exponents on their ladder,
:func:`exponent_ladder`); on one core its facet sum over 1,800 instants took 3.0 ms
instead of 4.5, the shadowed kernel 5.5 instead of 6.5 (152 a cell;
``taskset -c 0 python experiments/profile_shard.py --shadow-stages``), and the bulk
mix's S4 curves 27.6 ms of kernel time instead of 41 (``--by-class``). Meshes under
:data:`MIN_FACETS` facets, or whose cells would list more than :data:`MAX_SHARE` of them,
keep the plain sum: the gathers cost more than they save there.
"""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from jaxlc.body.facet_model import FacetModel, dot_parts, half_vectors, lobe_terms
from jaxlc.body.octahedral import nearest_node, octahedral_decode
from jaxlc.memo import identity_memo

#: A lobe below this fraction of its peak is left out of a float64 sum.
LOBE_FLOOR = 1e-10
#: … and of a float32 sum (:func:`lobe_floor`): the terms left out are below the sum's
#: own rounding (S4 with an anisotropic nozzle, 48 glints and random directions: the
#: candidate sum within 1.2e-7 of the full float32 sum, as at 1e-10; 2.2e-7 at 1e-5,
#: 1.7e-6 at 1e-4). The S4 scene: 120 candidates a cell at most instead of 152.
LOBE_FLOOR_FLOAT32 = 1e-6
#: Side of the octahedral grid of half-vector cells (64² cells).
CELL_GRID = 64
#: Meshes with fewer facets keep the plain facet sum.
MIN_FACETS = 256
#: Candidate lists longer than this share of the facets are not used: a gathered lobe
#: costs ~4× one of the plain sum (S4, one core), so lists of more than about a quarter
#: of the facets save nothing (a dataset of S4s with exponents drawn down to 20: 38 ms a
#: curve either way; 51 ms with lists of up to half the facets).
MAX_SHARE = 0.2
#: Margin (rad) added to each cell's radius (its boundary is sampled, not solved).
RADIUS_MARGIN = 0.01
#: Points per cell edge where the cell's radius is sampled.
EDGE_POINTS = 17


class LobeCells(eqx.Module):
    """The candidate facets of every half-vector cell (traced input of the kernel).

    Attributes:
        facets: (C, K) int32 facet indices of each cell's candidates, padded with −1;
            C = grid².
        grid: side of the octahedral grid (static).
    """

    facets: Int[Array, "C K"]
    grid: int = eqx.field(static=True)


@functools.cache
def cell_extent(grid: int) -> tuple[np.ndarray, np.ndarray]:
    """(C, 3) unit centres of the cells and (C,) their radii (rad): the largest angle
    from the centre to a point of the cell's boundary (sampled; the angle from a point
    inside a cell has no maximum inside it), plus :data:`RADIUS_MARGIN`."""
    e = np.linspace(0.0, 1.0, EDGE_POINTS)
    zero, one = np.zeros_like(e), np.ones_like(e)
    square = np.concatenate(
        [np.stack(p, 1) for p in ((e, zero), (e, one), (zero, e), (one, e))] + [[[0.5, 0.5]]]
    )
    i, j = np.meshgrid(np.arange(grid), np.arange(grid), indexing="ij")
    u = -1.0 + (i.reshape(-1, 1) + square[None, :, 0]) * (2.0 / grid)
    v = -1.0 + (j.reshape(-1, 1) + square[None, :, 1]) * (2.0 / grid)
    d = octahedral_decode(u, v)  # (C, points, 3): the boundary's points, then the centre
    centre = d[:, -1]
    cos = np.clip(np.einsum("cpk,ck->cp", d[:, :-1], centre), -1.0, 1.0)
    return centre, np.arccos(cos).max(axis=1) + RADIUS_MARGIN


def lobe_reach_rad(exponent: np.ndarray, floor: float = LOBE_FLOOR) -> np.ndarray:
    """(F,) angle from the normal beyond which a lobe of exponent ``exponent`` (the
    smaller of nu, nv) is below ``floor`` of its peak, at most 90°."""
    z = np.asarray(exponent, np.float64)
    cos = np.exp(np.log(floor) / np.maximum(z, 1e-300))
    return np.where(z > 0, np.minimum(np.arccos(np.clip(cos, 0.0, 1.0)), 0.5 * math.pi), math.pi)


def lobe_floor(dtype) -> float:
    """The floor of a sum in ``dtype``: :data:`LOBE_FLOOR_FLOAT32` for float32 (and
    narrower), :data:`LOBE_FLOOR` for float64."""
    return LOBE_FLOOR if np.dtype(dtype).itemsize >= 8 else LOBE_FLOOR_FLOAT32


@identity_memo(maxsize=16)
def lobe_cells(
    normals: np.ndarray,
    exponent: np.ndarray,
    glossy: np.ndarray,
    grid: int,
    floor: float = LOBE_FLOOR,
):
    """(C, K) candidate facets of each cell, −1-padded to K a multiple of 8 (numpy, int32).

    Args:
        normals: (F, 3) unit facet normals (body frame).
        exponent: (F,) the smaller lobe exponent of each facet, min(nu, nv).
        glossy: (F,) whether the facet has a lobe at all (ks > 0).
        grid: side of the cell grid.
        floor: the fraction of its peak below which a lobe is left out.
    """
    centre, radius = cell_extent(grid)
    idx = np.flatnonzero(glossy)
    reach = lobe_reach_rad(np.asarray(exponent)[idx], floor)
    # angle(n, centre) ≤ reach + radius ⟺ n·centre ≥ cos r cos ρ − sin r sin ρ (a sum ≥ π:
    # always): no transcendental function per cell and facet
    cos = centre @ np.asarray(normals, np.float64)[idx].T
    limit = np.outer(np.cos(radius), np.cos(reach)) - np.outer(np.sin(radius), np.sin(reach))
    rows, cols = np.nonzero((cos >= limit) | (radius[:, None] + reach[None, :] >= math.pi))
    counts = np.bincount(rows, minlength=len(centre))
    k = max(8, -(-int(counts.max(initial=0)) // 8) * 8)
    table = np.full((len(centre), k), -1, np.int32)
    table[rows, np.arange(len(rows)) - (np.cumsum(counts) - counts)[rows]] = idx[cols]
    return table


def exponent_ladder(exponent: np.ndarray) -> np.ndarray:
    """Exponents rounded down to a ladder of four steps per octave (≥ 1; below 1 kept):
    a rounded-down exponent reaches farther, so its cells list every facet the exact one
    would, and models of nearby exponents share one table (:func:`lobe_cells` is memoized)."""
    z = np.asarray(exponent, np.float64)
    safe = np.maximum(z, 1.0)
    return np.where(z >= 1.0, np.exp2(np.floor(4.0 * np.log2(safe)) / 4.0), z)


def cells_for(models: FacetModel | list[FacetModel], grid: int = CELL_GRID) -> LobeCells | None:
    """The candidate cells of a model with concrete (host) coefficients — or one table
    valid for several models of one mesh (each facet's smallest exponent, any facet glossy
    in one of them) — or None where the plain sum is as fast: no lobes, fewer than
    :data:`MIN_FACETS` facets, traced coefficients, or candidate lists longer than
    :data:`MAX_SHARE` of the facets."""
    models = [models] if isinstance(models, FacetModel) else list(models)
    first = models[0]
    if not any(m.use_specular for m in models) or first.n_facets < MIN_FACETS:
        return None
    arrays = [a for m in models for a in (m.normals, m.nu, m.nv, m.ks)]
    if not all(isinstance(a, np.ndarray) for a in arrays):
        return None
    if any(m.normals.shape != first.normals.shape for m in models):
        return None
    exponent = exponent_ladder(np.min([np.minimum(m.nu, m.nv) for m in models], axis=0))
    glossy = np.any([np.asarray(m.ks) > 0 for m in models], axis=0)
    floor = min(lobe_floor(np.asarray(m.normals).dtype) for m in models)
    table = lobe_cells(np.asarray(first.normals, np.float64), exponent, glossy, grid, floor)
    if table.shape[1] > MAX_SHARE * first.n_facets:
        return None
    return LobeCells(facets=table, grid=grid)


def padded_cells(cells: LobeCells | None, n_facets: int, k: int, grid: int) -> LobeCells:
    """``cells`` with its lists padded to ``k`` (−1), or — for a model without cells —
    every one of its ``n_facets`` facets listed in every cell (its sum is then the full
    one): tables of one shape, to stack objects (:func:`jaxlc.stack_objects`)."""
    if cells is None:
        row = np.full(k, -1, np.int32)
        row[:n_facets] = np.arange(n_facets)
        return LobeCells(facets=np.tile(row, (grid * grid, 1)), grid=grid)
    table = np.asarray(cells.facets)
    wider = np.pad(table, ((0, 0), (0, k - table.shape[1])), constant_values=-1)
    return LobeCells(facets=wider, grid=cells.grid)


def lobe_intensity(
    model: FacetModel,
    cells: LobeCells,
    sun_b: Float[Array, "T 3"],
    obs_b: Float[Array, "T 3"],
    weight_at=None,
) -> Float[Array, " T"]:
    """Σ of the specular terms of each sample's candidate facets (m² sr⁻¹), (T,).

    Args:
        model: the facets (their lobes: :func:`~jaxlc.body.facet_model.lobe_terms`).
        cells: :func:`cells_for` of the model (or of a model whose exponents are no
            larger: the lists then hold every lobe above the floor).
        sun_b, obs_b: (T, 3) unit vectors in the body frame.
        weight_at: optional callable (T, K) facet indices → (T, K) factors (a shadowed
            facet's lit-and-seen fraction).
    """
    half = half_vectors(sun_b, obs_b)
    idx = jnp.asarray(cells.facets)[nearest_node(half[0], cells.grid, xp=jnp)]  # (T, K)
    valid = idx >= 0
    idx = jnp.maximum(idx, 0)

    def take(x):  # (F,) → (T, K): one scalar gather per array (a row gather is 2.5× slower)
        return jnp.asarray(x).at[idx].get(mode="promise_in_bounds")

    def vector(x):  # (F, 3) → its components, each (T, K)
        return tuple(take(x[:, c]) for c in range(3))

    normal = vector(model.normals)
    cosines = [jnp.maximum(dot_parts(d, normal), 0.0) for d in (sun_b, obs_b)]
    coef = {k: take(getattr(model, k)) for k in ("ks", "fa", "fb", "nu", "nv")}
    tangents = (vector(model.tangent_u), vector(model.tangent_w)) if model.anisotropic else None
    terms = lobe_terms(half, normal, coef, *cosines, tangents)
    if weight_at is not None:
        terms = terms * weight_at(idx)
    return jnp.sum(jnp.where(valid, terms, 0.0), axis=-1)

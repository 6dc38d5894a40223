"""The one kernel entry: a traced object and its exposures → I/E per exposure.

Every path that makes a light curve — :func:`jaxlc.render`, dataset
generation, the spin fit's forward model, the experiments — evaluates
:func:`exposure_intensity` on what :func:`jaxlc.rendering.prepare.prepare`
made (:class:`KernelInputs`): the mean, over the sub-exposure instants of each
exposure with their quadrature weights, of the radiant intensity per unit
irradiance I/E (m² sr⁻¹) of a :class:`SpaceObject`.

Pure, jittable, differentiable and ``vmap``-able over objects and inputs. The
instants are processed in chunks so that the (chunk × facets) temporaries stay
in cache; everything per facet-sample is one fused XLA loop.
"""

from __future__ import annotations

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int, PyTree

from jaxlc.body.attitude import AbstractAttitude
from jaxlc.body.facet_model import FacetModel, facet_intensity, facet_slice, pad_models
from jaxlc.body.lobe_cells import LobeCells, lobe_intensity, padded_cells
from jaxlc.body.shadow_lookup import (
    ShadowTable,
    column_fractions,
    facet_runs,
    lit_seen_columns,
    run_fraction,
    weights_at,
)
from jaxlc.errors import JaxlcError
from jaxlc.rendering.exact_glints import ExactKit, glint_correction

#: Target size of one (time chunk × facets) block, in elements (~1 MB of float32).
CHUNK_ELEMENTS = 1 << 18


class SpaceObject(eqx.Module):
    """Everything about the object that the kernel traces.

    Attributes:
        model: all facets. With shadows, those that can be shadowed come first, in
            the ``shadow`` table's order, and those that cannot follow.
        attitude: body → inertial rotation over time.
        shadow: visibility table of the facets that can be shadowed
            (:mod:`jaxlc.body.shadow_lookup`), or None (no shadow work).
        exact: the facets whose brightest terms get exact shadows
            (:mod:`jaxlc.rendering.exact_glints`), or None (the table alone).
        lobes: the candidate facets of each half-vector cell, whose specular terms
            alone are summed (:mod:`jaxlc.body.lobe_cells`), or None (every facet's).
    """

    model: FacetModel
    attitude: AbstractAttitude
    shadow: ShadowTable | None = None
    exact: ExactKit | None = None
    lobes: LobeCells | None = None

    @property
    def n_facets(self) -> int:
        return self.model.n_facets


@functools.partial(
    jax.tree_util.register_dataclass,
    data_fields=["times", "sun_dir", "obs_dir", "weight", "row"],
    meta_fields=["n_rows", "subsamples"],
)
@dataclasses.dataclass(frozen=True)
class KernelInputs:
    """The sub-exposure instants of the rendered exposures, as the kernel takes them.

    Made by :func:`jaxlc.rendering.prepare.kernel_inputs` from
    :class:`~jaxlc.rendering.prepare.Exposures` (host, float64). A plain dataclass
    registered as a pytree, not an ``eqx.Module``: a curve's refinement makes one per
    level, and a module took ~40 µs to make (~40 ms a shard of the standard mix).

    Attributes:
        times: (M,) attitude times of the instants (``attitude.times`` output).
        sun_dir, obs_dir: (M, 3) inertial unit vectors object→Sun, object→observer.
        weight: (M,) quadrature weights; the weights of one exposure sum to 1.
        row: (M,) int32 exposure (output row) of each instant, in [0, n_rows).
        n_rows: number of exposures (static).
        subsamples: S when exposure k owns instants k·S … k·S + S − 1 (the
            mean is then a reshape), None otherwise (a segment sum) (static).
    """

    times: PyTree
    sun_dir: Float[Array, "M 3"]
    obs_dir: Float[Array, "M 3"]
    weight: Float[Array, " M"]
    row: Int[Array, " M"]
    n_rows: int
    subsamples: int | None = None


def time_chunk(n_facets: int) -> int:
    """Instants per chunk so that a chunk × facets block is about CHUNK_ELEMENTS."""
    c = CHUNK_ELEMENTS // max(n_facets, 1)
    return int(min(1024, max(8, 1 << max(3, c.bit_length() - 1))))


def _inverse_rotate(r, x):
    """Rᵀ x for (T, 3, 3) rotations and (T, 3) vectors, written out elementwise: a
    batched 3 × 3 ``dot_general`` is a slow library call per instant on the CPU."""
    return r[:, 0, :] * x[:, 0, None] + r[:, 1, :] * x[:, 1, None] + r[:, 2, :] * x[:, 2, None]


def body_intensity(
    obj: SpaceObject, sun_b: Float[Array, "T 3"], obs_b: Float[Array, "T 3"]
) -> Float[Array, " T"]:
    """I/E (m² sr⁻¹) for body-frame Sun and observer directions (no attitude).

    Facets that can be shadowed are weighted by their lit-and-seen fraction.
    """
    if obj.shadow is None:
        return facet_sum(obj, sun_b, obs_b)
    return _shadowed_intensity(obj, sun_b, obs_b, lit_seen_columns(obj.shadow, sun_b, obs_b))


def lobes_apart(obj: SpaceObject) -> bool:
    """Whether the object's lobes are summed over each sample's candidate facets alone
    (:mod:`jaxlc.body.lobe_cells`) rather than in the facet sum."""
    return obj.lobes is not None and obj.model.use_specular


def facet_sum(obj: SpaceObject, sun_b, obs_b, weights=None, weight_at=None):
    """Σ over the facets of :func:`~jaxlc.body.facet_model.facet_intensity` with optional
    (T, F) ``weights``; with :attr:`SpaceObject.lobes`, the specular terms of each sample's
    candidate facets only (:func:`~jaxlc.body.lobe_cells.lobe_intensity`, their weights
    from ``weight_at``, else gathered from ``weights``)."""
    if not lobes_apart(obj):
        return facet_intensity(obj.model, sun_b, obs_b, weights=weights)
    if weight_at is None and weights is not None:
        weight_at = lambda idx: jnp.take_along_axis(weights, idx, axis=1)  # noqa: E731
    diffuse = facet_intensity(obj.model, sun_b, obs_b, weights=weights, specular=False)
    return diffuse + lobe_intensity(obj.model, obj.lobes, sun_b, obs_b, weight_at)


def _shadowed_intensity(obj: SpaceObject, sun_b, obs_b, columns):
    """The weighted facet sum, with the brightest terms' exact shadows if the object has
    an :class:`~jaxlc.rendering.exact_glints.ExactKit`."""
    out = _weighted_intensity(obj, sun_b, obs_b, columns)
    if obj.exact is None:
        return out
    table = column_fractions(obj.shadow, columns)
    return out + glint_correction(obj.model, obj.exact, sun_b, obs_b, table, out)


#: A table with a run of at least this many facets gets one facet sum per run
#: (:func:`_weighted_intensity`).
OWN_SUM_FACETS = 256


def _weighted_intensity(obj: SpaceObject, sun_b, obs_b, columns):
    """The facet sum with the shadowable facets weighted by their lit-and-seen fraction,
    the sum of their ``columns`` (T, V) of the table (1 for the other facets).

    A large mesh (a run of :data:`OWN_SUM_FACETS` facets or more) gets one facet sum per
    run of the table's layout and one for the facets without a table: XLA:CPU
    materialises a concatenation of the runs' weights (and models), which made the S4
    kernel 8–12 % slower. A small one gets one sum with the weights concatenated: more
    loops made the 24-facet box-wing's 20 % slower (bulk kernel, 2-core machine)."""
    runs = facet_runs(obj.shadow)
    parts = [run_fraction(columns, run) for run in runs]
    end = max((first + n for _, first, n, _ in runs), default=0)  # facets without a table
    if max((n for _, _, n, _ in runs), default=0) < OWN_SUM_FACETS:
        n_t, n_rest = columns.shape[0], obj.model.n_facets - end
        weights = jnp.concatenate([*parts, jnp.ones((n_t, n_rest), columns.dtype)], axis=1)
        return facet_sum(obj, sun_b, obs_b, weights=weights)
    lobes = lobes_apart(obj)  # summed below, for the candidate facets only
    total = 0.0
    for (_, first, n_facets, _), weights in zip(runs, parts, strict=True):
        part = facet_slice(obj.model, first, first + n_facets)
        total = total + facet_intensity(part, sun_b, obs_b, weights=weights, specular=not lobes)
    if end < obj.model.n_facets:
        rest = facet_slice(obj.model, end, obj.model.n_facets)
        total = total + facet_intensity(rest, sun_b, obs_b, specular=not lobes)
    if lobes:
        weight_at = lambda idx: weights_at(obj.shadow, columns, idx)  # noqa: E731
        total = total + lobe_intensity(obj.model, obj.lobes, sun_b, obs_b, weight_at)
    return total


def light_curve_intensity(
    obj: SpaceObject,
    times: PyTree,
    sun_dir: Float[Array, "T 3"],
    obs_dir: Float[Array, "T 3"],
    chunk: int | None = None,
) -> Float[Array, " T"]:
    """I/E (m² sr⁻¹) of one object at T instants (no exposure averaging).

    Args:
        obj: facets, materials and attitude.
        times: (T,) attitude times: ``obj.attitude.times(t_s)`` made on the
            host from float64 seconds (keeps fast spins precise in float32),
            or plain seconds from the attitude's time origin.
        sun_dir: (T, 3) unit vectors object→Sun, inertial frame.
        obs_dir: (T, 3) unit vectors object→observer, inertial frame.
        chunk: instants per chunk (static); default from the facet count.

    Returns:
        (T,) radiant intensity per unit irradiance. Flux = I/E · E / d².

    Example:
        >>> batched = jax.vmap(light_curve_intensity, in_axes=(0, 0, None, None))
    """
    n_t = sun_dir.shape[0]
    chunk = min(chunk or time_chunk(obj.n_facets), max(n_t, 1))
    n_chunks = -(-n_t // chunk)
    # Balanced chunks (a multiple of 8 instants, one vector's width): 1,800
    # instants in 15 chunks of 120, not 128 with 120 instants of padding.
    even = -(-n_t // n_chunks)
    chunk = min(chunk, -(-even // 8) * 8)
    pad = n_chunks * chunk - n_t

    def blocks(x):
        # Padding repeats the last instant (cut off below): zero directions would
        # give 0/0 in the shadow grid's look-up and NaN gradients in reverse mode.
        x = jnp.pad(x, ((0, pad),) + ((0, 0),) * (x.ndim - 1), mode="edge") if pad else x
        return x.reshape(n_chunks, chunk, *x.shape[1:])

    def to_body(args):
        t, s, v = args
        r = obj.attitude.rotation(t)  # (chunk, 3, 3) body → inertial
        return _inverse_rotate(r, s), _inverse_rotate(r, v)

    args = jax.tree_util.tree_map(blocks, (times, sun_dir, obs_dir))
    if obj.shadow is None:
        out = jax.lax.map(lambda a: facet_sum(obj, *to_body(a)), args)
        return out.reshape(-1)[:n_t]

    # Two passes: in one loop XLA fuses the bit counting into the facet sum,
    # which then runs 2-3× slower (measured); the fractions are small to keep.
    def lit_seen(a):
        s_b, v_b = to_body(a)
        return s_b, v_b, lit_seen_columns(obj.shadow, s_b, v_b)

    per_chunk = jax.lax.map(lit_seen, args)
    out = jax.lax.map(lambda a: _shadowed_intensity(obj, *a), per_chunk)
    return out.reshape(-1)[:n_t]


def exposure_intensity(
    obj: SpaceObject, inputs: KernelInputs, chunk: int | None = None
) -> Float[Array, " N"]:
    """Mean I/E (m² sr⁻¹) over each exposure's sub-exposure instants: the kernel entry.

    Args:
        obj: facets, materials and attitude.
        inputs: the instants, their directions, weights and exposures.
        chunk: instants per block of the facet sum (static; default sized for
            one object). Under ``vmap`` over W objects pass
            ``time_chunk(n_facets × W)`` so one block of all W fits the cache.

    Returns:
        (n_rows,) Σ_k w_k I/E(t_k) over the instants k of each exposure.
    """
    i = light_curve_intensity(obj, inputs.times, inputs.sun_dir, inputs.obs_dir, chunk)
    return exposure_mean(i, inputs)


def exposure_mean(values: Float[Array, "M ..."], inputs: KernelInputs) -> Float[Array, "N ..."]:
    """Σ_k w_k values_k over the instants k of each exposure: (M, …) → (n_rows, …)."""
    weighted = values * inputs.weight.reshape(-1, *(1,) * (values.ndim - 1))
    if inputs.subsamples is not None:
        return weighted.reshape(inputs.n_rows, inputs.subsamples, *values.shape[1:]).sum(axis=1)
    return jax.ops.segment_sum(
        weighted, inputs.row, num_segments=inputs.n_rows, indices_are_sorted=True
    )


def stack_objects(objects: list[SpaceObject]) -> SpaceObject:
    """Stack objects along a new leading axis for ``jax.vmap``, padding facets.

    Objects with fewer facets get zero-coefficient facets (which contribute
    nothing). All attitudes must be of the same type; objects with shadows must
    share one mesh (and so one shadow-table layout).
    """
    if not objects:
        raise JaxlcError("stack_objects: no objects given")
    kinds = {type(o.attitude) for o in objects}
    if len(kinds) > 1:
        raise JaxlcError(
            f"stack_objects: attitudes must share one type, got {sorted(k.__name__ for k in kinds)}"
        )
    shadowed = {o.shadow is not None for o in objects}
    if len(shadowed) > 1:
        raise JaxlcError(
            "stack_objects: mix of objects with and without shadows; render them apart"
        )
    if True in shadowed:
        layouts = {(o.shadow.bits.shape, o.shadow.groups) for o in objects}
        if len(layouts) > 1:
            raise JaxlcError(
                "stack_objects: shadowed objects must share one mesh (one table layout)"
            )
    models = pad_models([o.model for o in objects])
    lobes = [o.lobes for o in objects]
    grids = {c.grid for c in lobes if c is not None}
    if len(grids) == 1:  # one shape of candidate table; a model without one lists every facet
        pairs = list(zip(lobes, models, strict=True))
        k = max(m.n_facets if c is None else c.facets.shape[1] for c, m in pairs)
        lobes = [padded_cells(c, m.n_facets, k, *grids) for c, m in pairs]
    else:  # none, or tables of different grids: every object's full sum
        lobes = [None] * len(objects)
    padded = [
        SpaceObject(m, o.attitude, o.shadow, o.exact, c)
        for m, o, c in zip(models, objects, lobes, strict=True)
    ]
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *padded)

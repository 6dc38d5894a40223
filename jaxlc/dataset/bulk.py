"""Batched rendering of many curves of one shape class (the inside of a dataset shard).

Each curve is prepared exactly as :func:`jaxlc.render` prepares a light
curve — its scene (:func:`jaxlc.dataset.draw.curve_scene`: the drawn size,
materials and spin) over its geometry, by
:func:`jaxlc.rendering.prepare.prepare` — and evaluated by the same kernel
entry, :func:`jaxlc.rendering.kernel.exposure_intensity`. Batching only
changes how that work is cut and scheduled:

* every curve of a class shares the mesh, its facets and, for a non-convex
  mesh, one shadow table (derived once per process, whatever the curve's
  size: the scene's scale is an area factor);
* a curve's sub-exposure instants (as many per exposure as its own render
  plan asks) are cut into blocks of T instants (the adaptive quadrature's
  probes, one output per instant, into blocks of ~T/3: less padding at the
  end of each curve's level); the blocks of all curves of the class are
  evaluated ``batch_size`` at a time and the remainder in halving batches down
  to :data:`TAIL_BATCH` (padded), so a class compiles a few shapes once per process and a
  curve's result never depends on its batch neighbours;
* unshadowed classes ``jax.vmap`` over the batch; shadowed ones loop over it
  inside the jitted call (``lax.map``): vmapping the shadow lookup was 1.7×
  (S4) and 3.5× (S6) slower on the 2-core reference machine.
"""

from __future__ import annotations

import functools

import jax
import numpy as np

from jaxlc.body.brdf import BRDFS
from jaxlc.body.facet_model import pad_models
from jaxlc.body.lobe_cells import cells_for
from jaxlc.rendering.kernel import KernelInputs, SpaceObject, exposure_intensity
from jaxlc.rendering.prepare import Prepared, adapt, probe_inputs
from jaxlc.xla import jit

#: The smallest kernel call, in blocks: the last of a class's blocks after the full and
#: halving batches (:func:`batches`) are padded to it (25 blocks: 16 + 8 + 4, 28 evaluated).
TAIL_BATCH = 4


def class_flags(cls) -> dict:
    """The static facet-model flags of a shape class: the union over its material
    priors, so that every curve of the class shares one compilation."""
    kinds = [BRDFS[m.brdf] for m in cls.materials]
    return {
        "use_lambert": any(k.has_lambert for k in kinds),
        "use_as_diffuse": any(k.has_as_diffuse for k in kinds),
        "use_specular": any(k.has_specular for k in kinds),
        "anisotropic": any(
            m.nv is not None and (m.nv != m.nu or m.nv[0] != m.nv[1]) for m in cls.materials
        ),
    }


def _one(model, attitude, shared, inputs):
    table, exact, lobes = shared
    return exposure_intensity(SpaceObject(model, attitude, table, exact, lobes), inputs)


@functools.cache
def batch_kernel(sequential: bool):
    """Jitted (B, T) exposure sums of B blocks of one class.

    The kernel's own time chunk serves batches too (measured with a 64 × 64 shadow grid:
    blocks of 32 instants, once 15 % faster, made S4 1.6× and S6 1.4× slower; a
    smaller chunk under ``vmap`` made S3 and S5 slower).

    ``sequential`` loops over the batch inside the call (shadowed classes);
    otherwise the batch is vmapped.
    """
    if sequential:

        def f(models, attitudes, shared, inputs):
            return jax.lax.map(
                lambda a: _one(a[0], a[1], shared, a[2]), (models, attitudes, inputs)
            )

    else:
        f = jax.vmap(_one, in_axes=(0, 0, None, 0))
    return jit(f)


def _stack(trees):
    return jax.tree_util.tree_map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *trees)


def _blocks(trees, pad: np.ndarray, t_len: int, fill=None):
    """Each curve's leaves (its M_c instants first) padded by ``pad[c]`` copies of its
    last instant (or of ``fill``) and all curves' instants stacked in blocks of ``t_len``:
    leaves (n_blocks, t_len, …), so that a batch of consecutive blocks is a slice.

    Each leaf is copied once, into its place in one array (a concatenation per curve
    and then of all curves copied it twice: S5's probes, ~90,000 instants a curve)."""
    lengths = [len(jax.tree_util.tree_leaves(t)[0]) for t in trees]
    stops = np.cumsum(np.asarray(lengths, np.int64) + pad)

    def leaf(*xs):
        first = np.asarray(xs[0])
        out = np.empty((int(stops[-1]), *first.shape[1:]), first.dtype)
        start = 0
        for x, n, stop in zip(xs, lengths, stops, strict=True):
            out[start : start + n] = x
            if stop > start + n:
                out[start + n : stop] = x[-1] if fill is None else fill
            start = int(stop)
        return out.reshape(-1, t_len, *first.shape[1:])

    return jax.tree_util.tree_map(leaf, *trees)


def probe_block(samples: int) -> int:
    """Instants per block of probe evaluations: a third of a curve's rows, a multiple of 8."""
    return max(8, -(-samples // 24) * 8)


def batches(n_blocks: int, size: int) -> list[tuple[int, int]]:
    """(start, batch size) of the kernel calls over ``n_blocks`` blocks: full batches of
    ``size``, then the remainder in halving batches (size/2, size/4, … down to
    :data:`TAIL_BATCH`, each taken while it fits; the last padded). A class compiles a few
    shapes, and a remainder of 60 blocks takes 4 calls instead of 15 of 4 blocks: per
    block, a 4-block call cost 10–60 % more than a 64-block one (S4 … S5, one core), and
    the standard mix made 156 such calls a shard. The mix: 0.41 ms a curve less (−2.9 %,
    7 interleaved pairs, one core)."""
    full = n_blocks - n_blocks % size
    out = [(b, size) for b in range(0, full, size)]
    tails = []
    t = size // 2
    while t > TAIL_BATCH:
        tails.append(t)
        t //= 2
    tails.append(min(size, TAIL_BATCH))
    b = full
    for t in tails:
        while n_blocks - b >= t:
            out.append((b, t))
            b += t
    if b < n_blocks:
        out.append((b, tails[-1]))  # padded
    return out


def stacked_objects(cls, objects) -> tuple:
    """(models, attitudes, shared): every curve's padded model and attitude stacked (host
    arrays), the rows a kernel batch takes, and what the class's curves share: one shadow
    table, exact kit and table of specular candidate cells, made here for all the curves'
    exponents (:func:`~jaxlc.body.lobe_cells.cells_for`; None each where there are none)."""
    padded = pad_models([o.model for o in objects], class_flags(cls))
    shared = (objects[0].shadow, objects[0].exact, cells_for(padded))
    return _stack(padded), _stack([o.attitude for o in objects]), shared


def _batch_blocks(x, start: int, real: int, size: int):
    """Blocks ``start … start + real − 1`` of ``x``; a short batch repeats its first block up
    to ``size`` (a few compiled shapes per class)."""
    part = x[start : start + real]
    if size == real:
        return part
    return np.concatenate([part, np.repeat(part[:1], size - real, axis=0)])


def _evaluate(config, stacked, inputs, relative: bool) -> list[np.ndarray]:
    """Each curve's inputs cut into blocks (``config.samples`` instants; ``relative``:
    :func:`probe_block`), all blocks evaluated in :func:`batches`: per curve, the
    (samples,) sums of its output rows (``relative``: the (M,) values of its M instants).

    A block holds instants ``k … k + L − 1`` of one curve (padding past the curve's end
    repeats its last instant at weight zero); its output rows are the curve's (0 … L − 1
    must hold them), or with ``relative`` the block's own instants (one per instant).
    ``stacked`` is :func:`stacked_objects` of the curves (None when there are none).
    """
    t_len = probe_block(config.samples) if relative else config.samples
    n_inst = np.array([len(i.weight) for i in inputs], np.int64)
    out = [np.zeros(n if relative else t_len) for n in n_inst]
    curve = np.repeat(np.arange(len(inputs)), -(-n_inst // t_len))  # block → curve
    if not len(curve):
        return out
    first = np.concatenate([[0], np.cumsum(-(-n_inst // t_len))[:-1]])
    # every curve's model and attitude stacked once, its instants cut into blocks once
    models, attitudes, shared = stacked
    kernel = batch_kernel(shared[0] is not None)
    # padding past a curve's end repeats its last instant, at weight zero
    pad = -n_inst % t_len
    times, sun, obs = _blocks([(i.times, i.sun_dir, i.obs_dir) for i in inputs], pad, t_len)
    weight = _blocks([i.weight for i in inputs], pad, t_len, fill=0)
    if relative:  # each instant its own output row
        row = np.broadcast_to(np.arange(t_len, dtype=np.int32), (len(curve), t_len))
    else:
        row = _blocks([i.row for i in inputs], pad, t_len)
    blocks = (times, sun, obs, weight, row)
    got_all = np.empty((len(curve), t_len))
    for b0, size in batches(len(curve), config.batch_size):
        real = min(size, len(curve) - b0)
        j = np.concatenate([curve[b0 : b0 + real], np.full(size - real, curve[b0])])
        take = functools.partial(_batch_blocks, start=b0, real=real, size=size)
        times, sun, obs, weight, row = jax.tree_util.tree_map(take, blocks)
        batch = KernelInputs(
            times=times,
            sun_dir=sun,
            obs_dir=obs,
            weight=weight,
            row=row,
            n_rows=t_len,
            subsamples=None,
        )
        pick = functools.partial(jax.tree_util.tree_map, lambda x: np.take(x, j, axis=0))  # noqa: B023
        got = kernel(pick(models), pick(attitudes), shared, batch)
        got_all[b0 : b0 + real] = np.asarray(got, np.float64)[:real]
    for c in range(len(inputs)):  # a curve's blocks in order: fixed sums
        mine = got_all[first[c] : first[c] + -(-n_inst[c] // t_len)]
        if relative:
            out[c][:] = mine.reshape(-1)[: n_inst[c]]
        else:
            for block in mine:
                out[c] += block
    return out


def render_class(config, cls, prepared: list[Prepared], instants: list | None = None) -> np.ndarray:
    """Render C prepared curves of one class: (C, T) mean I/E over each exposure.

    Curves whose plan asks for adaptive sub-exposures are refined together
    (:func:`jaxlc.rendering.prepare.adapt`, each level's new instants of all
    curves in batches); the others are evaluated on their fixed instants.

    Args:
        config: the dataset config (samples, batch size).
        cls: the curves' shape class.
        prepared: each curve's :func:`~jaxlc.rendering.prepare.prepare` (float32).
        instants: if given, each curve's mean instants per rendered exposure (after
            the adaptive refinement) are appended to it (benchmarks).

    Returns:
        (C, T) float64 I/E (m² sr⁻¹) of every rendered row; NaN on rows not rendered.
    """

    stacks = {}  # the same curves' objects at every level: stacked once

    def stacked(objs):
        key = tuple(map(id, objs))
        if objs and key not in stacks:
            stacks[key] = stacked_objects(cls, objs)
        return stacks.get(key)

    def probes(requests):
        objs = [p.object for p, _ in requests]
        ins = [probe_inputs(p, probe, pad=False) for p, probe in requests]
        got = _evaluate(config, stacked(objs), ins, relative=True)
        return [g[: len(probe.t_s)] for g, (_, probe) in zip(got, requests, strict=True)]

    prepared = adapt(prepared, probes, instants=False)  # only the refined means are kept
    if instants is not None:
        instants += [
            (p.refinement.instants if p.refinement else len(p.exposures.t_s))
            / max(p.exposures.n_rows, 1)
            for p in prepared
        ]
    fixed = [j for j, p in enumerate(prepared) if p.refinement is None]
    objs = [prepared[j].object for j in fixed]
    sums = _evaluate(config, stacked(objs), [prepared[j].inputs for j in fixed], False)
    out = np.full((len(prepared), config.samples), np.nan)
    for j, s in zip(fixed, sums, strict=True):
        rows = prepared[j].exposures.rows
        out[j, rows] = s[: len(rows)]
    for j, p in enumerate(prepared):
        if p.refinement is not None:
            out[j, p.exposures.rows] = p.refinement.intensity
    return out

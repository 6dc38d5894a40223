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
  evaluated ``batch_size`` at a time and the remainder :data:`TAIL_BATCH` at a
  time (padded), so a class compiles a few shapes once per process and a
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
from jaxlc.rendering.kernel import KernelInputs, SpaceObject, exposure_intensity
from jaxlc.rendering.prepare import Prepared, adapt, probe_inputs
from jaxlc.xla import jit

#: Blocks per kernel call for the remainder of a class's blocks after the full batches
#: (a second compiled shape): 25 S4 curves' 25 blocks cost 28 block evaluations, not 32.
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


def _one(model, attitude, shadow, inputs):
    return exposure_intensity(SpaceObject(model, attitude, shadow), inputs)


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

        def f(models, attitudes, shadow, inputs):
            return jax.lax.map(
                lambda a: _one(a[0], a[1], shadow, a[2]), (models, attitudes, inputs)
            )

    else:
        f = jax.vmap(_one, in_axes=(0, 0, None, 0))
    return jit(f)


def _stack(trees):
    return jax.tree_util.tree_map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *trees)


def _concat(trees):
    return jax.tree_util.tree_map(lambda *xs: np.concatenate([np.asarray(x) for x in xs]), *trees)


def probe_block(samples: int) -> int:
    """Instants per block of probe evaluations: a third of a curve's rows, a multiple of 8."""
    return max(8, -(-samples // 24) * 8)


def batches(n_blocks: int, size: int) -> list[tuple[int, int]]:
    """(start, batch size) of the kernel calls over ``n_blocks`` blocks: full batches of
    ``size``, then the remainder in batches of :data:`TAIL_BATCH` (the last padded)."""
    tail = min(size, TAIL_BATCH)
    full = n_blocks - n_blocks % size
    return [(b, size) for b in range(0, full, size)] + [
        (b, tail) for b in range(full, n_blocks, tail)
    ]


def stacked_objects(cls, objects) -> tuple:
    """(models, attitudes, shadow): every curve's padded model and attitude stacked (host
    arrays), the rows a kernel batch takes, and the class's one shadow table (or None)."""
    models = _stack(pad_models([o.model for o in objects], class_flags(cls)))
    return models, _stack([o.attitude for o in objects]), objects[0].shadow


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
    offset = (np.arange(len(curve)) - first[curve]) * t_len  # block → its first instant
    # every curve's model, attitude and instants gathered once; a batch takes its rows
    models, attitudes, shadow = stacked
    kernel = batch_kernel(shadow is not None)
    flat = _concat([(i.times, i.sun_dir, i.obs_dir, i.weight, i.row) for i in inputs])
    start = np.concatenate([[0], np.cumsum(n_inst)[:-1]])
    step = np.arange(t_len)
    for b0, size in batches(len(curve), config.batch_size):
        real = min(size, len(curve) - b0)
        pad = np.full(size - real, b0)  # a few shapes per class: repeat the first block
        blk = np.concatenate([np.arange(b0, b0 + real), pad])
        j, k = curve[blk], offset[blk]
        pos = k[:, None] + step[None, :]  # (size, L) instants within their curve
        last = n_inst[j][:, None] - 1
        idx = start[j][:, None] + np.minimum(pos, last)
        times, sun, obs, weight, row = jax.tree_util.tree_map(lambda x: x[idx], flat)  # noqa: B023
        stacked = KernelInputs(
            times=times,
            sun_dir=sun,
            obs_dir=obs,
            weight=np.where(pos <= last, weight, 0.0).astype(weight.dtype),
            row=np.broadcast_to(step.astype(np.int32), pos.shape) if relative else row,
            n_rows=t_len,
            subsamples=None,
        )
        pick = functools.partial(jax.tree_util.tree_map, lambda x: x[j])  # noqa: B023
        got = np.asarray(kernel(pick(models), pick(attitudes), shadow, stacked), np.float64)
        for r in range(real):  # a curve's blocks in order: fixed sums
            c = j[r]
            if relative:
                n = min(t_len, n_inst[c] - k[r])
                out[c][k[r] : k[r] + n] = got[r, :n]
            else:
                out[c] += got[r]
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

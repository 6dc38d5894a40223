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
  plan asks) are cut into blocks of T instants; the blocks of all curves of
  the class are evaluated ``batch_size`` at a time (the last batch padded),
  so a class compiles once per process and a curve's result never depends
  on its batch neighbours;
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

#: Instants per block of the facet sum for shadowed classes: the shadow lookup runs
#: ~15 % faster in blocks of 32 than with the default (128 for S4's 1,205 facets;
#: the same bits, measured on the 2-core reference machine). None: the default.
SHADOW_CHUNK = 32


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


def _one(model, attitude, shadow, inputs, free, chunk):
    return exposure_intensity(SpaceObject(model, attitude, shadow, free), inputs, chunk)


@functools.cache
def batch_kernel(sequential: bool):
    """Jitted (B, T) exposure sums of B blocks of one class (static: free-facet count, chunk).

    ``sequential`` loops over the batch inside the call (shadowed classes);
    otherwise the batch is vmapped.
    """
    if sequential:

        def f(models, attitudes, shadow, inputs, free, chunk):
            return jax.lax.map(
                lambda a: _one(a[0], a[1], shadow, a[2], free, chunk), (models, attitudes, inputs)
            )

    else:
        f = jax.vmap(_one, in_axes=(0, 0, None, 0, None, None))
    return jit(f, static_argnums=(4, 5))


def _block(inputs: KernelInputs, start: int, size: int, relative: bool = False) -> KernelInputs:
    """Instants ``start … start + size`` of a curve's inputs (padding past the end carries
    zero weight). Output rows are the curve's (0 … size − 1 must hold them), or with
    ``relative`` the block's own instants (one output per instant: a probe)."""
    stop = min(start + size, len(inputs.weight))
    pad = size - (stop - start)

    def take(x):
        x = np.asarray(x)[start:stop]
        return np.concatenate([x, np.repeat(x[-1:], pad, axis=0)]) if pad else x

    block = jax.tree_util.tree_map(take, inputs)
    weight = block.weight.copy()
    if pad:
        weight[-pad:] = 0.0
    return KernelInputs(
        times=block.times,
        sun_dir=block.sun_dir,
        obs_dir=block.obs_dir,
        weight=weight,
        row=np.arange(size, dtype=np.int32) if relative else block.row,
        n_rows=size,
        subsamples=None,
    )


def _stack(trees):
    return jax.tree_util.tree_map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *trees)


def _evaluate(config, cls, objects, inputs, relative: bool) -> list[np.ndarray]:
    """Each curve's inputs cut into blocks of ``config.samples`` instants, all blocks
    evaluated ``config.batch_size`` at a time: per curve, the (samples,) sums of its
    output rows (``relative``: the (M,) values of its M instants)."""
    t_len, size = config.samples, config.batch_size
    n_inst = [len(i.weight) for i in inputs]
    blocks = [(j, k) for j, n in enumerate(n_inst) for k in range(0, n, t_len)]
    out = [np.zeros(n if relative else t_len) for n in n_inst]
    if not blocks:
        return out
    flags = class_flags(cls)
    shadow, free = objects[0].shadow, objects[0].free
    kernel = batch_kernel(shadow is not None)
    chunk = None if shadow is None else SHADOW_CHUNK
    for b0 in range(0, len(blocks), size):
        batch = blocks[b0 : b0 + size]
        real = len(batch)
        batch = batch + [batch[0]] * (size - real)  # pad: one shape per class
        objs = [objects[j] for j, _ in batch]
        models = _stack(pad_models([o.model for o in objs], flags))
        attitudes = _stack([o.attitude for o in objs])
        stacked = _stack([_block(inputs[j], k, t_len, relative) for j, k in batch])
        got = np.asarray(kernel(models, attitudes, shadow, stacked, free, chunk), np.float64)
        for r, (j, k) in enumerate(batch[:real]):  # a curve's blocks in order: fixed sums
            if relative:
                n = min(t_len, n_inst[j] - k)
                out[j][k : k + n] = got[r, :n]
            else:
                out[j] += got[r]
    return out


def render_class(config, cls, prepared: list[Prepared]) -> np.ndarray:
    """Render C prepared curves of one class: (C, T) mean I/E over each exposure.

    Curves whose plan asks for adaptive sub-exposures are refined together
    (:func:`jaxlc.rendering.prepare.adapt`, each level's new instants of all
    curves in batches); the others are evaluated on their fixed instants.

    Args:
        config: the dataset config (samples, batch size).
        cls: the curves' shape class.
        prepared: each curve's :func:`~jaxlc.rendering.prepare.prepare` (float32).

    Returns:
        (C, T) float64 I/E (m² sr⁻¹) of every rendered row; NaN on rows not rendered.
    """

    def probes(requests):
        objs = [p.object for p, _ in requests]
        ins = [probe_inputs(p, probe, pad=False) for p, probe in requests]
        got = _evaluate(config, cls, objs, ins, relative=True)
        return [g[: len(probe.t_s)] for g, (_, probe) in zip(got, requests, strict=True)]

    prepared = adapt(prepared, probes)
    fixed = [j for j, p in enumerate(prepared) if p.refinement is None]
    sums = _evaluate(
        config, cls, [prepared[j].object for j in fixed], [prepared[j].inputs for j in fixed], False
    )
    out = np.full((len(prepared), config.samples), np.nan)
    for j, s in zip(fixed, sums, strict=True):
        rows = prepared[j].exposures.rows
        out[j, rows] = s[: len(rows)]
    for j, p in enumerate(prepared):
        if p.refinement is not None:
            out[j, p.exposures.rows] = p.refinement.intensity
    return out

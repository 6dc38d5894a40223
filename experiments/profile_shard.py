"""Where one worker's time goes: shards of the standard bulk mix rendered in this process.

Renders ``--warm`` shards of ``experiments/configs/bulk_standard.toml`` (compilation,
caches), then times the next ``--shards`` with :func:`jaxlc.dataset.shards.render_shard`
(what a worker runs, without the store) and prints curves/s; with ``--profile`` also
cProfile's top functions by own and by cumulative time. Time spent waiting for the
kernel shows as ``numpy.asarray``; the rest is host work (preparation, the adaptive
refinement's bookkeeping, noise, labels). No CSV: compare runs of one session.

``--by-class`` renders each class alone and splits its time per curve into the batched
kernel's calls (waited for) and the rest, the host work. Run it on one core
(``taskset -c 0``) for what one of two pinned workers spends: the kernel's share
bounds the rate that any host-side work could reach.

``--shadow-stages`` times the stages of S4's shadowed kernel over one 1,800-instant
curve (blur off): the plain facet sum, the table's corner rows gathered alone, the
look-up pass (:func:`~jaxlc.body.shadow_lookup.lit_seen_columns`, its columns kept)
and the whole shadowed kernel, each jitted apart and timed in alternation (median ±
IQR; the stages do not add up exactly: XLA fuses each call on its own).

    python experiments/profile_shard.py [--warm 2] [--shards 4] [--profile] [--by-class]
    taskset -c 0 python experiments/profile_shard.py --shadow-stages
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import functools
import io
import os
import pstats
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

import jax  # noqa: E402

from jaxlc.dataset import bulk, load_config  # noqa: E402
from jaxlc.dataset.shards import render_shard  # noqa: E402

CONFIG = HERE / "configs" / "bulk_standard.toml"


def main(argv=None) -> float:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--warm", type=int, default=2, help="shards rendered first, untimed")
    parser.add_argument("--shards", type=int, default=4, help="shards timed")
    parser.add_argument("--profile", action="store_true", help="cProfile the timed shards")
    parser.add_argument("--top", type=int, default=40, help="functions listed per order")
    parser.add_argument("--by-class", action="store_true", help="each class alone: kernel/host")
    parser.add_argument("--shadow-stages", action="store_true", help="S4's shadowed kernel")
    args = parser.parse_args(argv)
    if args.shadow_stages:
        return shadow_stages()
    config = load_config(CONFIG)
    if args.by_class:
        return by_class(config, args.warm, args.shards)
    for shard in range(args.warm):
        render_shard(config, shard)
    prof = cProfile.Profile() if args.profile else None
    start = time.perf_counter()
    if prof:
        prof.enable()
    for shard in range(args.warm, args.warm + args.shards):
        render_shard(config, shard)
    if prof:
        prof.disable()
    seconds = time.perf_counter() - start
    curves = args.shards * config.shard_size
    rate = curves / seconds
    print(f"{curves} curves in {args.shards} shards: {seconds:.2f} s, {rate:.1f} curves/s")
    if prof:
        for key in ("tottime", "cumulative"):
            text = io.StringIO()
            pstats.Stats(prof, stream=text).sort_stats(key).print_stats(args.top)
            print(text.getvalue())
    return rate


def by_class(config, warm: int, shards: int) -> float:
    """Each class alone: ms per curve, of which in the batched kernel's calls; returns the
    rate of the mix (curves/s) that the kernel's time alone would allow."""
    spent = [0.0]
    plain = bulk.batch_kernel

    @functools.cache
    def timed(sequential):
        kernel = plain(sequential)

        def call(*args):
            start = time.perf_counter()
            out = jax.block_until_ready(kernel(*args))
            spent[0] += time.perf_counter() - start
            return out

        return call

    bulk.batch_kernel = timed
    kernel_ms = []
    try:
        for cls in config.classes:
            one = dataclasses.replace(config, classes=(cls,))
            for shard in range(warm):
                render_shard(one, shard)
            spent[0] = 0.0
            start = time.perf_counter()
            for shard in range(warm, warm + shards):
                render_shard(one, shard)
            curves = shards * one.shard_size
            total, kernel = (time.perf_counter() - start) / curves, spent[0] / curves
            kernel_ms.append(1e3 * kernel)
            print(
                f"{cls.name}: {1e3 * total:.2f} ms a curve, kernel {1e3 * kernel:.2f}, "
                f"host {1e3 * (total - kernel):.2f}"
            )
    finally:
        bulk.batch_kernel = plain
    bound = 1e3 / (sum(kernel_ms) / len(kernel_ms))
    print(
        f"the kernel alone: {1e3 / bound:.2f} ms a curve of the mix, {bound:.1f} curves/s a "
        f"core ({2 * bound:.0f} on two pinned workers, {os.cpu_count()} cores here)"
    )
    return bound


def shadow_stages(chunk: int = 120) -> float:
    """Milliseconds of S4's stages over one curve (module docstring); returns the whole's."""
    import functools as ft

    import jax.numpy as jnp
    import numpy as np

    import jaxlc
    from jaxlc.body.octahedral import grid_corners
    from jaxlc.body.shadow_lookup import lit_seen_columns
    from jaxlc.rendering.kernel import exposure_intensity
    from jaxlc.xla import jit

    sys.path.insert(0, str(HERE))
    from bench_render import PLAIN, pass_geometry
    from timing import timed_interleaved

    geo = pass_geometry(1800)
    shadowed = jaxlc.prepare("s4_falcon9", geo, jaxlc.RenderOptions(blur="off"))
    plain = jaxlc.prepare("s4_falcon9", geo, PLAIN)
    obj, inputs, table = shadowed.object, shadowed.inputs, shadowed.object.shadow
    r = np.asarray(obj.attitude.rotation(inputs.times))  # body → inertial; Rᵀ x below
    sun_b, obs_b = (
        jnp.asarray(np.einsum("tji,tj->ti", r, np.asarray(x)), jnp.float32)
        for x in (inputs.sun_dir, inputs.obs_dir)
    )
    n = len(sun_b) - len(sun_b) % chunk
    blocks = lambda x: x[:n].reshape(-1, chunk, 3)  # noqa: E731

    def gathered(a):  # the six corner rows of each instant, gathered and folded
        rows = []
        for d in a:
            idx, _ = grid_corners(d, table.grid, table.interpolation)
            rows += [table.bits[idx[:, k]] for k in range(idx.shape[1])]
        return ft.reduce(jnp.bitwise_xor, rows)

    columns = ft.partial(lit_seen_columns, table)
    stages = {
        "plain facet sum": (jit(exposure_intensity), (plain.object, plain.inputs)),
        "corner rows gathered": (
            jit(lambda s, v: jax.lax.map(gathered, (blocks(s), blocks(v)))),
            (sun_b, obs_b),
        ),
        "look-up pass": (
            jit(lambda s, v: jax.lax.map(lambda a: columns(*a), (blocks(s), blocks(v)))),
            (sun_b, obs_b),
        ),
        "shadowed kernel": (jit(exposure_intensity), (obj, inputs)),
    }
    timings = timed_interleaved({k: ft.partial(fn, *a) for k, (fn, a) in stages.items()})
    for name, (median_s, iqr_s, _) in timings.items():
        print(
            f"{name}: {1e3 * median_s:.2f} ± {1e3 * iqr_s:.2f} ms "
            f"({table.bits.shape[1]} words a row, {n} instants)"
        )
    return 1e3 * timings["shadowed kernel"][0]


if __name__ == "__main__":
    main()

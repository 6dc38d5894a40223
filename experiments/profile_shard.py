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

    python experiments/profile_shard.py [--warm 2] [--shards 4] [--profile] [--by-class]
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
    args = parser.parse_args(argv)
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


if __name__ == "__main__":
    main()

"""Where one worker's time goes: shards of the standard bulk mix rendered in this process.

Renders ``--warm`` shards of ``experiments/configs/bulk_standard.toml`` (compilation,
caches), then times the next ``--shards`` with :func:`jaxlc.dataset.shards.render_shard`
(what a worker runs, without the store) and prints curves/s; with ``--profile`` also
cProfile's top functions by own and by cumulative time. Time spent waiting for the
kernel shows as ``numpy.asarray``; the rest is host work (preparation, the adaptive
refinement's bookkeeping, noise, labels). No CSV: compare runs of one session.

    python experiments/profile_shard.py [--warm 2] [--shards 4] [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from jaxlc.dataset import load_config  # noqa: E402
from jaxlc.dataset.shards import render_shard  # noqa: E402

CONFIG = HERE / "configs" / "bulk_standard.toml"


def main(argv=None) -> float:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--warm", type=int, default=2, help="shards rendered first, untimed")
    parser.add_argument("--shards", type=int, default=4, help="shards timed")
    parser.add_argument("--profile", action="store_true", help="cProfile the timed shards")
    parser.add_argument("--top", type=int, default=40, help="functions listed per order")
    args = parser.parse_args(argv)
    config = load_config(CONFIG)
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


if __name__ == "__main__":
    main()

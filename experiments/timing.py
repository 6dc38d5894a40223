"""Timing helpers shared by the benchmark scripts (median and IQR after a warm-up)."""

from __future__ import annotations

import functools
import time

import jax
import numpy as np


def timed(fn, min_total_s=1.0, min_reps=5, max_reps=40):
    """(median, IQR, repeats) in seconds of repeated calls after one warm-up."""
    jax.block_until_ready(fn())
    times = []
    start = time.perf_counter()
    while len(times) < min_reps or (
        time.perf_counter() - start < min_total_s and len(times) < max_reps
    ):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    q25, med, q75 = np.percentile(times, [25, 50, 75])
    return float(med), float(q75 - q25), len(times)


def timed_interleaved(fns: dict, min_total_s=1.0, min_rounds=5, max_rounds=40):
    """:func:`timed` for several variants run in alternation, so that machine-load
    drift affects them alike (their ratios are what matters)."""
    for fn in fns.values():
        jax.block_until_ready(fn())
    times = {k: [] for k in fns}
    start = time.perf_counter()
    rounds = 0
    while rounds < min_rounds or (
        time.perf_counter() - start < min_total_s * len(fns) and rounds < max_rounds
    ):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            jax.block_until_ready(fn())
            times[k].append(time.perf_counter() - t0)
        rounds += 1
    out = {}
    for k, ts in times.items():
        q25, med, q75 = np.percentile(ts, [25, 50, 75])
        out[k] = (float(med), float(q75 - q25), len(ts))
    return out


@functools.cache
def _probe_call():
    from bench_render import pass_geometry

    import jaxlc
    from jaxlc.rendering.kernel import exposure_intensity
    from jaxlc.xla import jit

    prepared = jaxlc.prepare(
        "s4_falcon9", pass_geometry(1800), options=jaxlc.RenderOptions(blur="off")
    )
    kernel = jit(exposure_intensity)
    return lambda: kernel(prepared.object, prepared.inputs)


def speed_probe(min_total_s: float = 1.0) -> float:
    """The machine's speed now: milliseconds of one S4 kernel call (1,205 facets with
    shadows, 1,800 instants, float32; median over ``min_total_s``), the work that
    dominates bulk generation. These machines are shared and their speed drifts by up
    to 1.7× within an hour; a rate measured beside a probe can be compared with one
    measured beside another (the rate scales about as 1 / probe)."""
    return 1e3 * timed(_probe_call(), min_total_s=min_total_s)[0]

"""Timing helpers shared by the benchmark scripts (median and IQR after a warm-up)."""

from __future__ import annotations

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

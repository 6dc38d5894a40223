"""Bulk dataset generation speed: light curves/s for the standard bulk mix.

The standard bulk mix (``experiments/configs/bulk_standard.toml``: S3–S6,
random spins, 1,800 samples each, shadows and motion blur where the render
plan says a curve needs them, noise) rendered with ``jaxlc.dataset.generate``:

A. per shape class, in this process: renders (one per sub-exposure instant,
   the adaptive refinement's included) per second and light curves per second
   of preparation and the batched kernel, after warm-up;
B. whole runs into a fresh Zarr store: in-process (``workers=0``) and on a
   local Dask cluster with 1 and 2 worker processes — wall time of
   ``generate()`` including cluster start-up, compilation in every worker and
   writing, so light curves/s = count / wall time;
C. the error of the automatic choice (B), of the same mix with motion
   blur capped at ``--caps`` sub-exposures per exposure (2 workers; 1 = no
   blur) and of the adaptive quadrature at ``--tolerances`` (mag an exposure;
   the config's is 1 mmag), against a dense reference of ``--dense``
   sub-exposures for every curve, on the very same curves (same seed): median /
   95th percentile / max |Δm| over visible samples, for all curves and per
   class, and per curve (samples within 5 mag of its median): the worst curve's
   95th percentile and max, and how many curves miss p95 ≤ 2 mmag or max ≤ 10
   mmag. (A looser tolerance is faster, but its worst sample nears 10 mmag: on
   2026-12-07, 9.0 and 11.1 mmag at 2 and 3 mmag against 6.3 at 1.)

D. the marginal rate as issue 16 defines it: whole ``generate()`` runs of
   ``--marginal`` curves (default 200 and 2,200, two workers, fresh processes,
   interleaved pairs), (2,200 − 200) / (t₂₂₀₀ − t₂₀₀): start-up, compilation and
   the first shards cancel; the end of the run, where one worker waits for the
   other's last shard, stays in. Lower than "steady" below by that tail.

Rates are count / wall time of ``generate()``, and "steady": the curves of the
shards finished after each worker's first one, over the time from the W-th
finished shard to the last (W workers; without start-up and compilation). Each
worker's first shard ends at about the same time (they compile alike), so
counting from the first finished shard instead would credit the window with a
shard rendered before it: with 2 workers and 10 shards, 900 curves for 800
(+12.5 %; this file's figures before 2026-12-07 did so).

Each run of B and C is a fresh Python process (no compilation carried over).
The machine's load average is recorded beside each row: these machines are
shared, so compare rows of one run. Writes
``experiments/results/bench_generate.csv``.

    python experiments/bench_generate.py [--count 1000] [--caps 8,1] [--tolerances 0.002,0.003]
        [--pairs 2] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from run_info import provenance  # noqa: E402

import jaxlc  # noqa: E402
from jaxlc.dataset import draw_curve, load_config  # noqa: E402
from jaxlc.io.tables import write_table  # noqa: E402

CONFIG = HERE / "configs" / "bulk_standard.toml"

#: Runs in a fresh interpreter: time generate() only (not Python and JAX start-up).
RUN = """
import dataclasses as dc, json, sys, time
import jaxlc.dataset as d
cfg = d.load_config(sys.argv[1])
cap = int(sys.argv[5])
if cap > 0:  # cap the automatic sub-exposure count of every class
    cfg = dc.replace(cfg, classes=tuple(
        dc.replace(c, render=dc.replace(c.render, max_subsamples=cap)) for c in cfg.classes))
elif cap < 0:  # a fixed count for every curve: the dense reference
    cfg = dc.replace(cfg, classes=tuple(
        dc.replace(c, render=dc.replace(c.render, subsamples=-cap)) for c in cfg.classes))
tol = float(sys.argv[6])
if tol > 0:  # another tolerance of the adaptive quadrature for every class
    cfg = dc.replace(cfg, classes=tuple(
        dc.replace(c, render=dc.replace(c.render, blur_tolerance_mag=tol)) for c in cfg.classes))
stamps = []  # (time, shard) as each shard is written
n_workers = int(sys.argv[3])
workers = max(n_workers, 1)  # processes rendering (0: this one)
t0 = time.perf_counter()
ds = d.generate(cfg, sys.argv[2], workers=n_workers, count=int(sys.argv[4]),
                progress=False, on_shard=lambda k: stamps.append((time.perf_counter(), k)))
seconds = time.perf_counter() - t0
# the shards finished after every worker's first one, from the W-th finished shard
later = stamps[workers:]
steady = (sum(len(cfg.shard_rows(k)) for _, k in later) / (stamps[-1][0] - stamps[workers - 1][0])
          if later else float("nan"))
lab = ds.labels
print(json.dumps({"seconds": seconds, "curves": len(ds), "steady": steady,
                  "renders": float((lab["instants_per_exposure"] * lab["visible_samples"]).sum()),
                  "instants": float(lab["instants_per_exposure"].mean())}))
"""


def class_rates(config, count, repeats=2):
    """Table A: the batched kernel per class, in this process, after a warm-up call."""
    from jaxlc.dataset import bulk as R
    from jaxlc.dataset.draw import curve_geometry, curve_scene

    curves = [draw_curve(config, i) for i in range(count)]
    geos = [curve_geometry(config, c) for c in curves]

    def prepare(j):
        scene = jaxlc.scene_from_dict(curve_scene(config, curves[j]))
        return jaxlc.prepare(scene, geos[j].arrays, plan_instants=False)  # as a shard does

    rows = []
    for cid, cls in enumerate(config.classes):
        idx = [j for j, c in enumerate(curves) if c.class_id == cid]
        if not idx:
            continue
        R.render_class(config, cls, [prepare(idx[0])])  # compile
        best = np.inf
        for _ in range(repeats):  # per-curve preparation and the batched kernel
            subs = []  # instants per exposure, after the adaptive refinement
            t0 = time.perf_counter()
            prepared = [prepare(j) for j in idx]
            R.render_class(config, cls, prepared, subs)
            best = min(best, time.perf_counter() - t0)
        kit = prepared[0].object
        rows.append(
            dict(
                table="A",
                variant=cls.name,
                workers="in-process",
                facets=kit.n_facets,
                shadows=kit.shadow is not None,
                curves=len(idx),
                subsamples_mean=float(np.mean(subs)),
                seconds=best,
                renders_per_s=float(np.sum(subs)) / best,
                lightcurves_per_s=len(idx) / best,
                load_avg=os.getloadavg()[0],
            )
        )
    return rows


def run(store, workers, count, cap=0, tolerance_mag=0.0):
    """One generate() in a fresh process (``cap`` > 0: sub-exposures capped; < 0: that
    many for every exposure; ``tolerance_mag`` > 0: the adaptive quadrature's tolerance).

    Returns:
        (seconds, curves, renders (kernel instants), mean instants per exposure,
        curves/s after each worker's first shard, load average).
    """
    load = os.getloadavg()[0]
    r = subprocess.run(
        [sys.executable, "-c", RUN, str(CONFIG), str(store)]
        + [str(x) for x in (workers, count, cap, tolerance_mag)],
        capture_output=True,
        text=True,
        timeout=3600,
        env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )
    if r.returncode != 0:
        raise RuntimeError(f"generate (workers={workers}) failed:\n{r.stderr[-3000:]}")
    out = json.loads(r.stdout.strip().splitlines()[-1])
    load = max(load, os.getloadavg()[0])
    return out["seconds"], out["curves"], out["renders"], out["instants"], out["steady"], load


#: Samples fainter than this many magnitudes below their curve's median are left out of
#: the per-curve figures (under 1 % of the typical flux; the adaptive quadrature holds
#: samples 10 mag below the median to an absolute error, not a relative one).
FAINT_MAG = 5.0


def errors(a, b) -> list[dict]:
    """|Δm| between two stores of the same curves over samples visible in both, per class:
    median / 95th percentile / max over all such samples (``err_*``), and per curve over
    its samples within :data:`FAINT_MAG` of its median: the worst curve's 95th percentile
    and max, and how many curves miss p95 ≤ 2 mmag or max ≤ 10 mmag (the issue's bound)."""
    ma, mb = a.load("mag").astype(np.float64), b.load("mag").astype(np.float64)
    ok = np.isfinite(ma) & np.isfinite(mb)
    out = []
    classes = a.labels["class"].to_numpy()
    for name in [None, *dict.fromkeys(classes)]:
        rows = np.ones(len(classes), bool) if name is None else classes == name
        d = np.abs(ma[rows][ok[rows]] - mb[rows][ok[rows]])
        p95, worst = [], []
        for i in np.flatnonzero(rows):
            m = ma[i][ok[i]]
            if not len(m):
                continue
            di = np.abs(m - mb[i][ok[i]])[m < np.median(m) + FAINT_MAG]
            p95.append(np.percentile(di, 95))
            worst.append(di.max())
        p95, worst = np.array(p95), np.array(worst)
        out.append(
            dict(
                variant="all classes" if name is None else str(name),
                err_median_mag=float(np.median(d)),
                err_p95_mag=float(np.percentile(d, 95)),
                err_max_mag=float(d.max()),
                curve_p95_worst_mag=float(p95.max()),
                curve_max_worst_mag=float(worst.max()),
                curves_over_bound=int(np.sum((p95 > 0.002) | (worst > 0.010))),
            )
        )
    return out


def _fmt(x, spec: str) -> str:
    return "" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, spec)


def print_table(df: pd.DataFrame) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(
        title="jaxlc bulk generation: the standard mix (S3–S6, 1,800 samples, auto shadows/blur)",
        caption="A: batched kernel per class (in-process, warm); B: whole generate() runs "
        "(fresh process; curves/s includes cluster start-up and compilation, steady: after "
        "each worker's first shard); C: |Δm| of the automatic blur, capped or at other "
        "tolerances, against a fixed dense count; D: marginal curves/s, the difference of "
        "two whole runs (issue 16's measure); sub-exp.: instants per exposure, the adaptive "
        "refinement's included",
    )
    for col in (
        "table",
        "variant",
        "workers",
        "curves",
        "sub-exp.",
        "s",
        "renders/s",
        "curves/s",
        "steady",
        "|Δm| med / p95 / max",
        "worst curve p95 / max (over)",
        "load",
    ):
        table.add_column(col, justify="left" if col in ("table", "variant") else "right")
    for r in df.itertuples():
        err = per_curve = ""
        if isinstance(getattr(r, "err_max_mag", None), float) and np.isfinite(r.err_max_mag):
            err = f"{r.err_median_mag:.1e} / {r.err_p95_mag:.1e} / {r.err_max_mag:.1e}"
            per_curve = (
                f"{r.curve_p95_worst_mag:.1e} / {r.curve_max_worst_mag:.1e} "
                f"({int(r.curves_over_bound)})"
            )
        table.add_row(
            r.table,
            r.variant,
            str(r.workers),
            str(r.curves),
            _fmt(r.subsamples_mean, ".1f"),
            _fmt(r.seconds, ".1f"),
            _fmt(r.renders_per_s, ",.0f"),
            _fmt(r.lightcurves_per_s, ",.1f"),
            _fmt(getattr(r, "steady_lightcurves_per_s", np.nan), ",.1f"),
            err,
            per_curve,
            _fmt(r.load_avg, ".1f"),
        )
    Console(width=210).print(table)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=1000, help="curves per run of B and C")
    parser.add_argument("--caps", default="8,1", help="sub-exposure caps of table C")
    parser.add_argument("--workers", default="0,1,2", help="worker counts of table B")
    parser.add_argument(
        "--tolerances",
        default="0.002,0.003",
        help="other tolerances (mag an exposure) of the adaptive quadrature in table C",
    )
    parser.add_argument(
        "--dense", type=int, default=256, help="sub-exposures of the reference of table C"
    )
    parser.add_argument(
        "--marginal", default="200,2200", help="curve counts of table D's whole runs"
    )
    parser.add_argument("--pairs", type=int, default=2, help="interleaved pairs of table D")
    parser.add_argument("--quick", action="store_true", help="a few curves (smoke test)")
    parser.add_argument("--out", type=Path, default=HERE / "results" / "bench_generate.csv")
    args = parser.parse_args(argv)
    count = 24 if args.quick else args.count
    config = load_config(CONFIG)
    rows = class_rates(config, min(count, 200), repeats=1 if args.quick else 2)

    caps = [int(c) for c in args.caps.split(",") if c.strip()]
    tols = [float(t) for t in args.tolerances.split(",") if t.strip()]
    variants = (  # (cap, workers, tolerance): 0 = the config's own
        [(0, int(w), 0.0) for w in args.workers.split(",")]
        + [(c, 2, 0.0) for c in caps]
        + [(0, 2, t) for t in tols]
        + [(-args.dense, 2, 0.0)]
    )

    def label(cap, tol):
        if cap:
            return f"blur ≤ {cap} sub-exposure(s)"
        return f"auto, {1e3 * tol:g} mmag an exposure" if tol else "standard mix"

    with tempfile.TemporaryDirectory(prefix="bench_generate_") as tmp:
        stores = {}
        for cap, workers, tol in variants:
            store = Path(tmp) / f"cap{cap}_workers{workers}_tol{tol:g}.zarr"
            seconds, curves, renders, instants, steady, load = run(store, workers, count, cap, tol)
            stores[(cap, workers, tol)] = store
            if cap < 0:  # the reference: only its errors are reported
                continue
            rows.append(
                dict(
                    table="C" if cap or tol else "B",
                    variant=label(cap, tol),
                    workers=workers if workers else "in-process",
                    curves=curves,
                    subsamples_mean=instants,
                    seconds=seconds,
                    renders_per_s=renders / seconds,
                    lightcurves_per_s=curves / seconds,
                    steady_lightcurves_per_s=steady,
                    load_avg=load,
                )
            )
            name = f"cap {cap}" if cap else f"tolerance {tol:g} mag" if tol else "auto"
            print(
                f"{name}, workers {workers}: {curves / seconds:.1f} curves/s "
                f"({steady:.1f} after each worker's first shard)",
                flush=True,
            )
        auto = [k for k in stores if k[0] == 0 and k[2] == 0]
        auto_mag = jaxlc.dataset.open(stores[auto[-1]]).load("mag")
        same = [
            bool(
                np.array_equal(auto_mag, jaxlc.dataset.open(stores[k]).load("mag"), equal_nan=True)
            )
            for k in auto
        ]
        ref = jaxlc.dataset.open(stores[(-args.dense, 2, 0.0)])
        for cap, tol in [(0, 0.0), *((c, 0.0) for c in caps), *((0, t) for t in tols)]:
            capped = jaxlc.dataset.open(stores[(cap, 2, tol)] if cap or tol else stores[auto[-1]])
            per_class = errors(ref, capped)
            name = label(cap, tol) if cap or tol else f"auto vs {args.dense}"
            if not (cap or tol):
                rows.append(dict(table="C", variant=name, workers=auto[-1][1]))
            at = next(i for i, r in enumerate(rows) if r["variant"] == name)
            rows[at].update({k: v for k, v in per_class[0].items() if k != "variant"})
            subs = capped.labels.groupby("class", observed=True)["instants_per_exposure"].mean()
            for j, e in enumerate(per_class[1:], 1):
                rows.insert(
                    at + j,
                    dict(
                        table="C",
                        workers="",
                        curves=int((capped.labels["class"] == e["variant"]).sum()),
                        subsamples_mean=float(subs[e["variant"]]),
                        **{**e, "variant": f"  {e['variant']}"},
                    ),
                )
        small, large = (24, 48) if args.quick else map(int, args.marginal.split(","))
        for pair in range(1 if args.quick else args.pairs):
            t = {}
            for n in (small, large):
                t[n], *_, load = run(Path(tmp) / f"marginal{pair}_{n}.zarr", 2, n)
            rate = (large - small) / (t[large] - t[small])
            rows.append(
                dict(
                    table="D",
                    variant=f"marginal ({large:,} − {small:,} curves)",
                    workers=2,
                    curves=large - small,
                    seconds=t[large] - t[small],
                    lightcurves_per_s=rate,
                    load_avg=load,
                )
            )
            print(f"marginal, workers 2, pair {pair + 1}: {rate:.1f} curves/s", flush=True)
    df = pd.DataFrame(rows)
    df.attrs.update(
        provenance(
            "experiments/bench_generate.py",
            config=CONFIG.relative_to(HERE.parent),
            count=count,
            identical_mag_across_worker_counts=all(same),
            quick=args.quick,
        )
    )
    print_table(df)
    print(f"identical magnitudes for every worker count: {all(same)}")
    write_table(df, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

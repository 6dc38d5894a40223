"""The seed paper's §5 cost: one 30-minute pass in Cycles against the JAX facet model.

The seed reports ~1 light curve per hour on a 12-core CPU and ~10 per hour per
GPU for a 30-minute pass rendered in Blender. Here the same pass (1,800
exposures of 1 s: the first 30 minutes of the demo pass of Falcon 9 R/B 45921)
of the stage S4 spinning 82.6 s about body x, its materials in their
Cycles-matched form, is timed in one run:

* **JAX**: the whole pass with shadows and motion blur (the defaults), the first
  call in the process (compilation included; the shadow table is loaded from
  the disk cache ``~/.cache/jaxlc`` when an earlier run traced it, about 50 s
  on 2 cores when none did) and warm (the median of three calls);
* **Cycles**: ``--frames`` frames spread over the pass, per setting, timed per
  frame by the worker and scaled to 1,800 frames (stated as such, as
  BENCHMARKS.md asks), plus the worker's start-up once. The settings: the
  calibration default (128 px, 64 samples, direct light) and a heavier one
  nearer to a picture (256 px, 128 samples, 4 bounces).

Writes ``cost.csv`` (one row per renderer and setting: seconds per pass,
light curves per hour on this machine, the ratio to JAX warm) under ``--out-dir``.

    python experiments/paper/cost.py [--quick] [--frames 20] [--out-dir DIR]

``--quick``: 3 frames per Cycles setting and one warm JAX call.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jaxlc
from calibrate.crosscheck import same_material
from calibrate.job import BlenderOptions
from calibrate.render import blender_render
from paper.common import RESULTS, demo_pass, provenance, pyplot, save_png, seed_spin, write_result

PASS_S = 1800.0
SETTINGS = {
    "Cycles 128 px, 64 samples, direct": dict(resolution=128, samples=64, bounces=0),
    "Cycles 256 px, 128 samples, 4 bounces": dict(resolution=256, samples=128, bounces=4),
}


def main(argv=None) -> pd.DataFrame:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="3 Cycles frames, one warm JAX call")
    ap.add_argument("--frames", type=int, default=20, help="Cycles frames per setting")
    ap.add_argument("--out-dir", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    n_frames = 3 if args.quick else args.frames

    scene = same_material(seed_spin(jaxlc.load_scene("s4_falcon9"), "x"))
    geo = demo_pass(duration_s=PASS_S)
    t0 = time.perf_counter()
    lc = jaxlc.render(scene, geo)
    first_s = time.perf_counter() - t0
    warm = []
    for _ in range(1 if args.quick else 3):
        t0 = time.perf_counter()
        jaxlc.render(scene, geo)
        warm.append(time.perf_counter() - t0)
    warm_s = float(np.median(warm))
    rows = [
        dict(
            renderer="JAX, first call (compilation included)",
            frames_timed=len(geo),
            pass_s=first_s,
            scaled=False,
        ),
        dict(renderer="JAX, warm", frames_timed=len(geo), pass_s=warm_s, scaled=False),
    ]
    pick = np.linspace(0, len(geo) - 1, n_frames).round().astype(int)
    frames = geo.iloc[pick].reset_index(drop=True)
    for name, kw in SETTINGS.items():
        t0 = time.perf_counter()
        b = blender_render(scene, frames, BlenderOptions(**kw))
        wall = time.perf_counter() - t0
        per_frame = float(np.nanmean(b["blender_seconds"]))
        startup = max(wall - float(np.nansum(b["blender_seconds"])), 0.0)
        rows.append(
            dict(
                renderer=name,
                frames_timed=n_frames,
                s_per_frame=per_frame,
                startup_s=startup,
                pass_s=per_frame * len(geo) + startup,
                scaled=True,
            )
        )
    table = pd.DataFrame(rows)
    table["lightcurves_per_hour"] = 3600.0 / table["pass_s"]
    table["times_jax_warm"] = table["pass_s"] / warm_s
    table["visible_frames"] = int(lc["visible"].sum())
    out = Path(args.out_dir) / "cost.csv"
    write_result(
        table,
        out,
        **provenance(
            "cost.py",
            quick=args.quick,
            scene="s4_falcon9 (as-glossy), 82.6 s about body x",
            pass_s=PASS_S,
            threads=os.cpu_count(),
            paper="~1 light curve/hour on 12 CPU cores; ~10/hour per GPU (Blender)",
        ),
    )
    with pd.option_context("display.width", 200, "display.float_format", "{:.4g}".format):
        print(table.to_string(index=False))
    print(f"→ {out}")
    plot(table, out.with_suffix(".png"))
    return table


#: The seed's own figures (§5), light curves of a 30-minute pass per hour.
PAPER_RATES = {
    "seed: Blender, 12 CPU cores": 1.0,
    "seed: Blender, GTX 1080 Ti": 4.0,
    "seed: Blender, per GPU (parallel)": 10.0,
}


def plot(table: pd.DataFrame, path: Path) -> None:
    plt = pyplot()
    names = list(table["renderer"]) + list(PAPER_RATES)
    rates = list(table["lightcurves_per_hour"]) + list(PAPER_RATES.values())
    colours = ["tab:blue" if n.startswith("JAX") else "tab:orange" for n in table["renderer"]]
    colours += ["0.6"] * len(PAPER_RATES)
    fig, ax = plt.subplots(figsize=(9, 4))
    ax.barh(range(len(names)), rates, color=colours)
    for i, r in enumerate(rates):
        ax.text(r * 1.1, i, f"{r:.3g}", va="center", fontsize=8)
    ax.set_yticks(range(len(names)), names, fontsize=8)
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlabel("30-minute light curves per hour (Cycles: frames timed and scaled)")
    ax.set_title(
        f"S4 over a 30-min pass at 1 Hz on this machine ({os.cpu_count()} cores) "
        "and the seed paper's figures (grey)",
        fontsize=9,
    )
    save_png(fig, path)


if __name__ == "__main__":
    main()

"""Time one full spin fit (multi-start MAP + emcee) of a 1,200-sample S4 light curve.

The light curve is the S4 scene rendered over the demo's real pass (Falcon 9
R/B 45921 over Mt Stromlo, 1,200 s at 1 Hz), blur off, 0.05 mag noise.

    python experiments/bench_fit.py [--scene s4_falcon9] [--runs 2]

Fits ``--runs`` noisy copies in one process: the first includes compiling
(JAX's persistent cache is not used here), later ones are what a user
fitting many curves in one session pays. Prints the stage timings and
writes experiments/results/bench_fit_<scene>.csv.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sbc_fit import pass_geometry

import jaxlc
from jaxlc.fit import fit_spin
from jaxlc.mcmc import FitSettings
from jaxlc.plan import RenderOptions

REPO = Path(__file__).resolve().parent.parent


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="s4_falcon9")
    ap.add_argument("--max-steps", type=int, default=6000)
    ap.add_argument("--runs", type=int, default=2, help="fits in this process (1st compiles)")
    a = ap.parse_args(argv)
    scene = jaxlc.load_scene(REPO / "experiments" / "scenes" / f"{a.scene}.toml")
    geo = pass_geometry()
    clean = jaxlc.render(scene, geo, options=RenderOptions(blur="off"))
    att = scene.attitude
    rows = []
    for run in range(a.runs):
        lc = clean.copy()
        lc["mag"] = lc["mag"] + 0.05 * np.random.default_rng(run).standard_normal(len(lc))
        r = fit_spin(scene, lc, geo, FitSettings(max_steps=a.max_steps, seed=run), log=print)
        d = r["diagnostics"]
        rows.append(
            {
                "scene": a.scene,
                "run": run,
                "compiles": "yes" if run == 0 else "no (same process)",
                "samples": r["data"]["samples"],
                **r["timings_s"],
                "modes_sampled": sum("mcmc" in m for m in r["modes"]),
                "walkers": d["walkers"],
                "steps_kept": d["steps"],
                "adapt_steps": d["burn_in"],
                "tau_max": max(d["tau"].values()),
                "chain_length_tau": d["chain_length_tau"],
                "acceptance": d["acceptance"],
                "period_s": r["period_s"],
                "true_period_s": att.period_s,
                "pole_ra_deg": r["pole_ra_deg"],
                "pole_dec_deg": r["pole_dec_deg"],
                "true_pole": f"({att.pole_ra_deg}, {att.pole_dec_deg})",
            }
        )
        print(pd.Series(rows[-1]).to_string(), flush=True)
    df = pd.DataFrame(rows)
    df.attrs.update(
        {
            "generator": "experiments/bench_fit.py",
            "jaxlc": jaxlc.__version__,
            "cpu_count": str(os.cpu_count()),
            "load_avg": f"{os.getloadavg()[0]:.2f}",
            "date_utc": pd.Timestamp.now(tz="UTC").strftime("%Y-%m-%dT%H:%M:%SZ"),
        }
    )
    print(df.T.to_string())
    jaxlc.write_table(df, REPO / "experiments" / "results" / f"bench_fit_{a.scene}.csv")


if __name__ == "__main__":
    main()

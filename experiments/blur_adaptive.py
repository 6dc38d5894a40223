"""Motion blur: adaptive sub-exposures against a dense reference, and their cost.

For each standard scene S2–S6 over the demo's real pass (Falcon 9 R/B 45921
over Mt Stromlo, 1,200 s at 1 Hz, 1 s exposures), renders the light curve

* with a dense fixed quadrature (``--reference`` sub-exposures, default 729 =
  3⁶): the reference;
* with the default options (adaptive per exposure, 1 mmag tolerance);
* with the per-curve fixed rule that was the default before (one count per
  curve from the fastest motion, :func:`jaxlc.rendering.blur.choose_subsamples`);

and reports |Δm| against the reference over the exposures within 10 mag of
the curve's median (p50, p95, p99, max), the instants per exposure and the
render time (compiled, median of repeats). Writes
``experiments/results/blur_adaptive.csv``.

    python experiments/blur_adaptive.py [--reference 729] [--scenes S4 S5]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_render import SCENES  # noqa: E402
from sbc_fit import pass_geometry  # noqa: E402
from timing import timed  # noqa: E402

import jaxlc  # noqa: E402
from jaxlc.rendering.prepare import adapt, prepare  # noqa: E402
from jaxlc.rendering.render import evaluate_instants  # noqa: E402


def errors(mag, ref):
    ok = np.isfinite(ref) & (ref < np.nanmedian(ref) + 10.0)
    d = np.abs(np.where(np.isfinite(mag), mag, 99.0) - ref)[ok]
    return dict(
        zip(
            ("p50_mag", "p95_mag", "p99_mag", "max_mag"),
            np.percentile(d, [50, 95, 99, 100]),
            strict=True,
        )
    )


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--reference", type=int, default=729)
    ap.add_argument("--scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--out", default=str(HERE / "results" / "blur_adaptive.csv"))
    a = ap.parse_args(argv)
    geo = pass_geometry()
    rows = []
    for key in a.scenes:
        scene = jaxlc.load_scene(SCENES[key])
        base = scene.render
        dense = dataclasses.replace(base, subsamples=a.reference, max_subsamples=a.reference)
        ref = jaxlc.render(scene, geo, options=dense)["mag"].to_numpy()
        plan = prepare(scene, geo, base).plan
        fixed = dataclasses.replace(base, subsamples=plan.blur.subsamples)
        for name, opts in (("adaptive (default)", base), ("fixed rule (before)", fixed)):
            lc = jaxlc.render(scene, geo, options=opts)
            med, iqr, _ = timed(lambda s=scene, o=opts: jaxlc.render(s, geo, options=o), min_reps=3)
            p = prepare(scene, geo, opts)
            if name.startswith("adaptive"):
                p = adapt([p], evaluate_instants)[0]
            per = len(p.exposures.t_s) / max(p.exposures.n_rows, 1)
            row = {
                "scene": key,
                "blur": name,
                "instants_per_exposure": per,
                "seconds": med,
                "seconds_iqr": iqr,
                **errors(lc["mag"].to_numpy(), ref),
                "reference_subsamples": a.reference,
                "at_cap": p.refinement.capped if p.refinement is not None else 0,
            }
            rows.append(row)
            print(pd.Series(row).to_string(), "\n", flush=True)
    df = pd.DataFrame(rows)
    df.attrs["generator"] = "experiments/blur_adaptive.py"
    print(df.to_string(index=False))
    jaxlc.write_table(df, a.out)


if __name__ == "__main__":
    main()

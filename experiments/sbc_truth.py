"""Is the truth where the likelihood says? Δχ² of each SBC case's truth against the
optimum near it, on an accurate model with the noise known.

For case k of ``experiments/sbc_fit.py`` (the same draw: pole, period, phase, 0.05 mag
noise over the real pass), the fit model is prepared with sub-exposures chosen at the
truth to 0.3 mmag (the render's own rule; without least levels), Levenberg–Marquardt
runs from the truth to the optimum near it, and the χ² (σ = 0.05 mag, Δm profiled) of
the truth and of that optimum are compared. With a right model and likelihood,
Δχ² follows χ² with 4 degrees of freedom (pole, period, phase): mean 4. A larger mean
would say the data are not drawn from the model the fit uses; a mean near 4 puts any
miscalibration of the fit's intervals in its search or sampling, not its likelihood.
No fit is run, so cases need not be drawn in order:

    python experiments/sbc_truth.py [--cases 0 1 2 …]   # cases 0–19: ~6 min on 2 cores

Output: experiments/results/sbc_truth.csv (one row per case).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from run_info import provenance  # noqa: E402
from sbc_fit import OUT, draw, pass_geometry  # noqa: E402

import jaxlc  # noqa: E402
from jaxlc.inference.batched_solve import least_squares  # noqa: E402
from jaxlc.inference.data import fit_data, soft_clip  # noqa: E402
from jaxlc.inference.model import angle_between_deg, spin_model, truth_theta  # noqa: E402
from jaxlc.inference.search_starts import batch_magnitudes, match_offset  # noqa: E402

NOISE_MAG = 0.05


def truth_row(scene, geo, k: int) -> dict:
    truth, lc, u, _ra, _dec, period, signal = draw(scene, geo, k, NOISE_MAG)
    data = fit_data(lc, geo, default_exposure_s=scene.exposure_s)
    th = truth_theta(truth, data)
    model = spin_model(scene, data, period, theta=th, tolerance_mag=3e-4, least_levels=False)
    th = match_offset(model, data, th[None])
    opt = th
    for _ in range(2):  # two runs of 40 steps: to the optimum, not near it
        opt = least_squares(model, data, opt, 40, "to the optimum", stall=True)[0]
    m = np.asarray(batch_magnitudes(model, model.to_device(np.concatenate([th, opt]))))
    r = soft_clip(data.mag, data.limit_mag)[None, :] - m
    r -= r.mean(axis=1, keepdims=True)  # Δm profiled
    chi2 = np.sum(r**2, axis=1) / NOISE_MAG**2
    return {
        "case": k,
        "true_period_s": period,
        "signal_chi2": signal,
        "samples": data.n,
        "instants_per_exposure": model.instants_per_exposure,
        "chi2_truth": float(chi2[0]),
        "chi2_optimum": float(chi2[1]),
        "delta_chi2": float(chi2[0] - chi2[1]),
        "optimum_pole_off_deg": float(angle_between_deg(u, opt[0, :3])),
        "optimum_period_rel": float(np.exp(opt[0, 3]) / period - 1),
    }


def main(argv=None) -> pd.DataFrame:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", type=int, nargs="+", default=list(range(20)))
    ap.add_argument("--scene", default="s5_cubesat")
    ap.add_argument("--out", default=str(OUT / "sbc_truth.csv"))
    a = ap.parse_args(argv)
    scene = jaxlc.load_scene(a.scene)
    geo = pass_geometry().iloc[:1200]
    rows = []
    for k in a.cases:
        rows.append(truth_row(scene, geo, k))
        jax.clear_caches()
        print(pd.Series(rows[-1]).round(4).to_dict(), flush=True)
    df = pd.DataFrame(rows)
    df.attrs.update(provenance("experiments/sbc_truth.py", scene=a.scene, noise_mag=NOISE_MAG))
    jaxlc.write_table(df, Path(a.out))
    ident = df[df.signal_chi2 >= 50]
    print(
        f"{len(ident)} identifiable cases: mean Δχ² of the truth {ident.delta_chi2.mean():.2f} "
        f"(χ² with 4 degrees of freedom: 4 ± {2 * 2**0.5 / max(len(ident), 1) ** 0.5:.2f})"
    )
    return df


if __name__ == "__main__":
    main()

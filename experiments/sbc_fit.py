"""Simulation-based calibration of ``jaxlc fit`` (issue 6).

N identifiable synthetic cases: isotropic random poles, log-uniform periods in
5–200 s, uniform phases, 0.05 mag Gaussian noise, rendered over a real pass (Falcon 9
R/B 45921 over Mt Stromlo, 2020-08-10 18:00 UTC, 1,200 s at 1 Hz, the demo's
geometry); each is fitted by :func:`jaxlc.inference.fit.fit_spin` with the same scene.
Recorded per case: period and pole error of the best (MAP) mode and of the
sampled mode nearest the truth (symmetric shapes give several poles the same
light curve, Δχ² ≈ 0: only the set of modes can be right), and the truth's
rank in the mixture posterior of all sampled modes (weighted by their
evidence): period, the weighted fraction of samples below the true period
(in the 50 % interval when in [0.25, 0.75]); pole, the posterior mass of the
union of equal caps about the modes' mean poles that just reaches the truth
(inside the 50 % region when ≤ 0.5). Calibrated intervals put the truth in
the 50 % (90 %) region in 50 % (90 %) of the cases. Also the number of modes,
chain length in τ and the run time. Both sides model the 1 s exposures the
same way (the fit prepares its model as the renderer does, motion blur
included), so the fit model is the data model.

A flat draw (a CubeSat spinning about its long axis seen near that axis: the
noise-free curve's χ² against the trend below FLAT_CHI2) has no period any
method could find; it is fitted and kept in the table (the fit must refuse it:
"no period" is the right answer) but not counted, and the next seed is drawn,
so the calibration figures are over N cases that hold a period.

    python experiments/sbc_fit.py --cases 50 --scene s5_cubesat   # ~30 min on 2 cores

Output: experiments/results/sbc_fit.csv (one row per case, appended as it
goes) and sbc_fit.png.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import jax
import numpy as np
import pandas as pd

import jaxlc
from jaxlc.errors import JaxlcError
from jaxlc.inference.fit import FitSettings, fit_spin
from jaxlc.inference.mcmc import pole_unit
from jaxlc.inference.model import angle_between_deg

REPO = Path(__file__).resolve().parent.parent
OUT = REPO / "experiments" / "results"
GEOMETRY = REPO / "build" / "sbc" / "geometry.csv"
#: Below this χ² of the noise-free curve against its trend, no period is findable.
FLAT_CHI2 = 50.0


def pass_geometry() -> pd.DataFrame:
    if not GEOMETRY.is_file():
        from jaxlc.cli import main as cli

        code = cli(
            [
                "geometry", "pass",
                "--tle", str(REPO / "data/tle/falcon9_rb.tle"), "--norad", "45921",
                "--site", "mt-stromlo", "--start", "2020-08-10T18:00:00Z",
                "--duration-s", "1200", "--step-s", "1", "--exposure-s", "1",
                "-o", str(GEOMETRY),
            ]
        )  # fmt: skip
        if code:
            raise SystemExit(f"could not make the pass geometry (exit {code})")
    return jaxlc.read_geometry(GEOMETRY)


def draw(scene, geo, k: int, noise_mag: float = 0.05):
    """Case ``k``'s truth and data: (truth scene, noisy light curve, pole unit vector,
    RA, Dec, period, signal χ² of the noise-free curve)."""
    rng = np.random.default_rng(1000 + k)
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    ra, dec = math.degrees(math.atan2(u[1], u[0])) % 360, math.degrees(math.asin(u[2]))
    period = float(np.exp(rng.uniform(np.log(5), np.log(200))))
    phase = float(rng.uniform(0, 360))
    epoch = pd.Timestamp(geo["utc"].iloc[0])
    truth = scene.with_spin(period, ra, dec, phase, epoch)
    lc = jaxlc.render(truth, geo)  # as users render: 1 s exposures, motion blur
    signal = signal_chi2(lc, noise_mag)
    lc["mag"] = lc["mag"] + noise_mag * rng.standard_normal(len(lc))
    return truth, lc, u, ra, dec, period, signal


def case(scene, geo, k: int, settings: FitSettings, noise_mag: float = 0.05) -> dict:
    _truth, lc, u, ra, dec, period, signal = draw(scene, geo, k, noise_mag)
    t0 = time.perf_counter()
    try:
        r = fit_spin(scene, lc, geo, settings)
    except JaxlcError as exc:  # "no spin to fit": an answer of "I don't know", not a crash
        return {
            "case": k,
            "true_period_s": period,
            "true_pole_ra_deg": ra,
            "true_pole_dec_deg": dec,
            "signal_chi2": signal,
            "refused": True,
            "reason": str(exc)[:300],
            "seconds": time.perf_counter() - t0,
        }
    seconds = time.perf_counter() - t0
    s = r["samples"]
    w = s["weight"].to_numpy()
    su = pole_unit(s)
    # Each sampled mode's mean pole; the truth's distance to the nearest one.
    means, d_samples = {}, np.empty(len(s))
    for j in s["mode"].unique():
        rows = (s["mode"] == j).to_numpy()
        m = su[rows].mean(axis=0)
        means[j] = m / np.linalg.norm(m)
        d_samples[rows] = angle_between_deg(su[rows], means[j])
    d_truth = {j: float(angle_between_deg(u, m)) for j, m in means.items()}
    nearest = min(d_truth, key=d_truth.get)
    best = pole_unit(
        pd.DataFrame({"pole_ra_deg": [r["pole_ra_deg"]], "pole_dec_deg": [r["pole_dec_deg"]]})
    )
    pole_err = float(angle_between_deg(u, best[0]))
    # Credible level of the truth under the mixture: the region is the union of
    # equal-radius caps about the modes' means (weights from the modes' evidence).
    pole_rank = float(np.sum(w[d_samples < d_truth[nearest]]))
    p = s["period_s"].to_numpy()
    period_rank = float(np.sum(w[p < period]))
    # r["modes"] is listed by weight: the nearest mode is the row of that mode id
    near = next(m for m in r["modes"] if m["mode"] == int(nearest))
    iv = near["mcmc"]["intervals"]
    return {
        "case": k,
        "true_period_s": period,
        "true_pole_ra_deg": ra,
        "true_pole_dec_deg": dec,
        "signal_chi2": signal,
        "refused": False,
        "reason": "",
        "fit_period_s": r["period_s"],
        "fit_pole_ra_deg": r["pole_ra_deg"],
        "fit_pole_dec_deg": r["pole_dec_deg"],
        "period_rel_err": r["period_s"] / period - 1,
        "pole_err_deg": pole_err,
        "nearest_mode": int(nearest),
        "nearest_mode_weight": float(near["weight"]),
        "nearest_mode_delta_chi2": float(near["delta_chi2"]),
        "nearest_period_rel_err": iv["period_s"]["median"] / period - 1,
        "nearest_pole_err_deg": d_truth[nearest],
        "period_rank": period_rank,
        "period_in_50": bool(0.25 <= period_rank <= 0.75),
        "period_in_90": bool(0.05 <= period_rank <= 0.95),
        "pole_rank": pole_rank,
        "pole_in_50": pole_rank <= 0.5,
        "pole_in_90": pole_rank <= 0.9,
        "modes": len(r["modes"]),
        "modes_sampled": int(s["mode"].nunique()),
        "method": r["diagnostics"]["method"],
        "chain_length_tau": r["diagnostics"]["chain_length_tau"],
        "acceptance": r["diagnostics"]["acceptance"],
        "seconds": seconds,
        "map_s": r["timings_s"]["map_s"],
        "mcmc_s": r["timings_s"]["mcmc_s"],
    }


def signal_chi2(lc: pd.DataFrame, noise_mag: float) -> float:
    """χ² of the noise-free curve against the trend-only model (a quadratic in time, the
    period analysis's trend) at the noise level: how much rotation signal the data hold.
    A CubeSat spinning about its long axis seen near that axis varies by less than the
    noise (χ² ≲ 20 over 1,200 samples): no method can find its period."""
    ok = np.isfinite(lc["mag"].to_numpy())
    t, m = lc["t_s"].to_numpy()[ok], lc["mag"].to_numpy()[ok]
    resid = m - np.polyval(np.polyfit(t - t.mean(), m, 2), t - t.mean())
    return float(np.sum(resid**2) / noise_mag**2)


def plot(df: pd.DataFrame, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxlc.plot import save_figure

    fig, ax = plt.subplots(1, 3, figsize=(12, 3.6))
    ax[0].loglog(df.true_period_s, np.abs(df.period_rel_err) + 1e-9, "o", ms=4)
    ax[0].set_xlabel("true period (s)")
    ax[0].set_ylabel("|relative period error|")
    ax[1].semilogy(df.true_period_s, df.pole_err_deg + 1e-4, "o", ms=4, label="best mode")
    ax[1].semilogy(
        df.true_period_s, df.nearest_pole_err_deg + 1e-4, "x", ms=5, label="nearest sampled mode"
    )
    ax[1].legend(frameon=False, fontsize=8)
    ax[1].set_xscale("log")
    ax[1].set_xlabel("true period (s)")
    ax[1].set_ylabel("pole error (deg)")
    ax[2].hist([df.period_rank, df.pole_rank], bins=10, range=(0, 1), label=["period", "pole"])
    ax[2].set_xlabel("rank of the truth in the posterior")
    ax[2].legend(frameon=False)
    cov = (
        f"coverage 50%: period {df.period_in_50.mean():.2f}, pole {df.pole_in_50.mean():.2f}; "
        f"90%: period {df.period_in_90.mean():.2f}, pole {df.pole_in_90.mean():.2f}"
    )
    fig.suptitle(f"SBC, {len(df)} cases — {cov}", fontsize=10)
    save_figure(fig, path, dpi=110)


def main(argv=None) -> pd.DataFrame:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", type=int, default=50)
    ap.add_argument("--scene", default="s5_cubesat")
    ap.add_argument("--starts", type=int, default=1024)
    ap.add_argument("--max-steps", type=int, default=3000)
    ap.add_argument("--modes", type=int, default=4, help="modes sampled (Δχ² < 10)")
    ap.add_argument("--out", default=str(OUT / "sbc_fit.csv"))
    ap.add_argument("--duration-s", type=int, default=1200, help="the first seconds of the pass")
    ap.add_argument("--start", type=int, default=0, help="first case (appends to --out)")
    a = ap.parse_args(argv)
    scene = jaxlc.load_scene(a.scene)
    geo = pass_geometry().iloc[: a.duration_s]
    # the search range is the prior the cases are drawn from
    settings = FitSettings(
        n_starts=a.starts,
        max_steps=a.max_steps,
        mcmc_modes=a.modes,
        min_period_s=5.0,
        max_period_s=min(200.0, a.duration_s / 2),
    )
    out = Path(a.out)
    rows = jaxlc.read_table(out).to_dict("records") if a.start and out.is_file() else []
    rows = [r for r in rows if r["case"] < a.start]
    # --cases counts identifiable cases: a flat draw (its noise-free curve's χ² against
    # the trend below FLAT_CHI2) has no findable period; it is fitted and kept (the fit
    # must refuse it) but does not count, and the next seed is drawn.
    k = a.start
    while sum(r["signal_chi2"] >= FLAT_CHI2 for r in rows) < a.cases:
        rows.append(case(scene, geo, k, settings))
        # every case compiles models of its own sizes; kept, they filled 24 GB by case 71
        jax.clear_caches()
        print(pd.Series(rows[-1]).to_dict(), flush=True)
        df = pd.DataFrame(rows)
        jaxlc.write_table(df, out)
        k += 1
    df = pd.DataFrame(rows)  # (also when resumed with every case already in --out)
    df["refused"] = df.get("refused", pd.Series(False, index=df.index)).fillna(False).astype(bool)
    # Flat cases: the noise-free curve's rotation signal is below the noise
    # (χ² < FLAT_CHI2 over the whole curve); "no period" is the right answer there.
    flat = df["signal_chi2"] < FLAT_CHI2
    fitted = df[~df["refused"] & ~flat]
    plot(fitted, out.with_suffix(".png"))
    within = fitted.period_rel_err.abs() < 0.01
    n_id = int((~flat).sum())
    summary = {
        "identifiable cases": n_id,
        f"flat draws (signal χ² < {FLAT_CHI2:g})": int(flat.sum()),
        "flat draws refused (right)": int((df["refused"] & flat).sum()),
        "identifiable but refused": int((df["refused"] & ~flat).sum()),
        "true period in the best-weight mode (1 %), of identifiable cases": (
            f"{int(within.sum())}/{n_id}"
        ),
    }
    df_all, df = df, fitted
    summary |= {
        "period_median_abs_rel_err": float(df.period_rel_err.abs().median()),
        "period_within_1pct": float((df.period_rel_err.abs() < 0.01).mean()),
        "pole_median_err_deg": float(df.pole_err_deg.median()),
        "pole_within_5deg": float((df.pole_err_deg < 5).mean()),
        "nearest_pole_within_5deg": float((df.nearest_pole_err_deg < 5).mean()),
        "nearest_period_within_1e-3": float((df.nearest_period_rel_err.abs() < 1e-3).mean()),
        "coverage_period_50": float(df.period_in_50.mean()),
        "coverage_period_90": float(df.period_in_90.mean()),
        "coverage_pole_50": float(df.pole_in_50.mean()),
        "coverage_pole_90": float(df.pole_in_90.mean()),
        "median_seconds": float(df_all.seconds.median()),
    }
    # per sampler of the best mode (importance sampling where the Laplace proposal fits)
    method = (
        df["method"]
        if "method" in df
        else df.chain_length_tau.isna().map({True: "importance", False: "emcee"})
    )
    for name, part in df.groupby(method):
        summary[f"coverage_{name}"] = (
            f"{len(part)} cases: period {part.period_in_50.mean():.2f} / "
            f"{part.period_in_90.mean():.2f}, pole {part.pole_in_50.mean():.2f} / "
            f"{part.pole_in_90.mean():.2f}"
        )
    print(summary)
    return df_all


if __name__ == "__main__":
    main()

"""Period decisions on real MMT tracks against MMT's own verdicts (issue 14).

Every track in tests/data/mmt (copied from ../shared/data/mmt; see its
README) is analysed whole and, as further tracks "like them", in its two
halves (each half keeps MMT's verdict; a periodic half is scored only when it
still spans two of MMT's periods). For each: MMT's verdict and period,
jaxlc's verdict and period (``jaxlc period``, defaults) and a plain
Lomb–Scargle column (astropy's peak, called periodic when its white-noise
Baluev FAP < 0.01 — what a plain tool would report).

Scoring (the issue's): a periodic track is right when the reported period,
or exactly half or double it, is within max(1 %, ¼ P²/T) of MMT's period P
(T: the span); a track MMT calls not variable is right when no period is
reported. Aperiodic tracks are listed, not scored (tumbling bodies are
often called aperiodic).

    python experiments/period_mmt.py          # ~30 s; table + experiments/results/period_mmt.csv
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.inference.harmonics import median_step_s
from jaxlc.inference.period import analyse_period
from jaxlc.inference.period_result import period_agrees
from jaxlc.io.observations import observed_samples, read_observations
from jaxlc.io.tables import write_table

REPO = Path(__file__).resolve().parent.parent

VERDICTS = {"0": "not variable", "1": "aperiodic", "2": "periodic"}


def mmt_verdict(path: Path) -> str:
    for line in path.read_text().splitlines():
        if line.startswith("# variability:"):
            return VERDICTS.get(line.split(":", 1)[1].split()[0], "?")
    return "?"


def plain_lomb_scargle(t, y) -> tuple[float, float]:
    """(peak period, Baluev FAP) of astropy's periodogram over 2.5 steps … span/2."""
    from astropy.timeseries import LombScargle

    step = median_step_s(t)
    ls = LombScargle(t, y - np.mean(y))
    f_lo, f_hi = 2.0 / np.ptp(t), 1.0 / (2.5 * step)
    f, p = ls.autopower(minimum_frequency=f_lo, maximum_frequency=f_hi, samples_per_peak=10)
    k = int(np.argmax(p))
    fap = float(
        ls.false_alarm_probability(
            p[k], method="baluev", minimum_frequency=f_lo, maximum_frequency=f_hi
        )
    )
    return float(1.0 / f[k]), fap


#: Verdicts that claim a period ("two periods": a tumbler's, its first period scored).
CLAIMS = ("periodic", "two periods")


def score(verdict: str, period_s: float, mmt: str, mmt_period: float, span: float):
    """True/False for a scored row, None for an unscored one."""
    if mmt == "periodic":
        if mmt_period > span / 2:  # fewer than two of MMT's cycles in this piece
            return None
        return bool(verdict in CLAIMS and period_agrees(period_s, mmt_period, span))
    if mmt == "not variable":
        return verdict not in CLAIMS
    return None


def rows_for(path: Path) -> list[dict]:
    obs = read_observations(path)
    t_all, y_all, _ = observed_samples(obs, "std_mag")
    mmt = mmt_verdict(path)
    mmt_p = float(obs.attrs["catalogue_period_s"])
    mid = t_all[0] + 0.5 * np.ptp(t_all)
    pieces = {"whole": np.ones(len(t_all), bool), "half 1": t_all < mid, "half 2": t_all >= mid}
    out = []
    for piece, m in pieces.items():
        t, y = t_all[m], y_all[m]
        if len(t) < 30:
            continue
        t0 = time.perf_counter()
        r = analyse_period(t, y)
        seconds = time.perf_counter() - t0
        ls_p, ls_fap = plain_lomb_scargle(t, y)
        span = float(np.ptp(t))
        ls_verdict = "periodic" if ls_fap < 0.01 else "no period"
        out.append(
            {
                "track": path.stem,
                "piece": piece,
                "samples": len(t),
                "span_s": span,
                "mmt_verdict": mmt,
                "mmt_period_s": mmt_p if mmt_p > 0 else np.nan,
                "jaxlc_verdict": r.verdict,
                "jaxlc_period_s": r.period_s,
                "jaxlc_second_period_s": r.second_period_s,
                "jaxlc_multiple": r.harmonic_factor,
                "jaxlc_fap": r.false_alarm_probability,
                "jaxlc_delta_bic": r.delta_bic,
                "jaxlc_right": score(r.verdict, r.period_s, mmt, mmt_p, span),
                "ls_period_s": ls_p,
                "ls_fap_white": ls_fap,
                "ls_right": score(ls_verdict, ls_p, mmt, mmt_p, span),
                "seconds": seconds,
            }
        )
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=REPO / "tests" / "data" / "mmt")
    ap.add_argument("--out", type=Path, default=REPO / "experiments" / "results" / "period_mmt.csv")
    args = ap.parse_args(argv)
    rows = [row for p in sorted(args.data.glob("*.txt")) for row in rows_for(p)]
    df = pd.DataFrame(rows)
    from rich.console import Console
    from rich.table import Table

    table = Table(title="period decisions on MMT tracks (P in s)")
    for c in ("track", "piece", "MMT", "P_MMT", "jaxlc", "P_jaxlc", "FAP", "ok", "LS P", "LS ok"):
        table.add_column(c, justify="right")

    def mark(v):
        return "—" if v is None or (isinstance(v, float) and np.isnan(v)) else ("✓" if v else "✗")

    for r in rows:
        table.add_row(
            r["track"],
            r["piece"],
            r["mmt_verdict"],
            f"{r['mmt_period_s']:.4g}",
            r["jaxlc_verdict"],
            f"{r['jaxlc_period_s']:.4g}",
            f"{r['jaxlc_fap']:.1g}",
            mark(r["jaxlc_right"]),
            f"{r['ls_period_s']:.4g}",
            mark(r["ls_right"]),
        )
    console = Console()
    console.print(table)
    for who in ("jaxlc", "ls"):
        for verdict in ("periodic", "not variable"):
            sel = df[(df["mmt_verdict"] == verdict) & df[f"{who}_right"].notna()]
            for label, part in (("whole tracks", sel[sel["piece"] == "whole"]), ("all", sel)):
                ok = int(part[f"{who}_right"].astype(bool).sum())
                console.print(
                    f"{'jaxlc' if who == 'jaxlc' else 'plain LS':8s} MMT {verdict:12s} "
                    f"({label}): {ok}/{len(part)} right"
                )
    console.print(
        f"jaxlc time per track: median {df['seconds'].median():.2f} s, "
        f"max {df['seconds'].max():.2f} s"
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_table(df, args.out)
    console.print(f"→ {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

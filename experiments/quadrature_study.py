"""Which nested rule the adaptive sub-exposures use: midpoints (3ᴸ) or Gauss–Patterson.

For random spins of the standard mix's classes (S3–S6, the bulk mix's period
ranges) over the demo's real pass (1,200 s at 1 Hz, 1 s exposures), the
instantaneous I/E is evaluated at the 729 midpoints of every exposure (the
reference, and every nested-midpoint level as a subset) and at the points of
the Gauss–Patterson levels. Both adaptive schemes are then replayed from these
values with the same tolerance (1 mmag), error law (ε = |Q_k − Q_{k−1}|/D_k,
D_k = (n_k/n_{k−1})² − 1: 8 for midpoints) and cap rule (at most 3 ×
``max_subsamples`` instants), each with its own first level:

* **midpoint** (the rule before 12-2026): first level from the sharpest feature
  *including* shadow edges (instants no farther apart than its scale), D = 8;
* **patterson** (the default now): first level from lobes only (largest gap
  within the lobe's scale σ), D_k once the level's gaps are within σ/2, 1 before
  — the same as :func:`jaxlc.render`, whose refinement is also run, so the replay
  is checked against the code (the render also starts a spin's exposures that no
  lobe reaches from the diffuse scale, :mod:`jaxlc.rendering.glint_bound`: its
  instants can be fewer than the replay's); and three variants of it: D_k
  throughout, D = 1 throughout (ε = |ΔQ|), and the first level at gaps within σ/2.

Also the *oracle*: per exposure, the fewest instants of each family from which
every finer level is within 1 mmag of the reference — what any error estimate
could at best achieve. Errors are |Δm| over exposures within 5 mag of the
curve's median (the bulk benchmark's selection). Writes
``experiments/results/quadrature_study.csv`` (one row per curve and scheme).

    python experiments/quadrature_study.py [--curves 10]     # ~6 min on 2 cores
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from sbc_fit import pass_geometry  # noqa: E402

import jaxlc  # noqa: E402
from jaxlc.rendering.adaptive import (  # noqa: E402
    CARRY_POWER,
    MAG_PER_REL,
    first_level_for,
    max_level_for,
)
from jaxlc.rendering.exposures import probe_instants  # noqa: E402
from jaxlc.rendering.patterson import level_count, level_rule  # noqa: E402
from jaxlc.rendering.prepare import adapt, prepare  # noqa: E402
from jaxlc.rendering.render import evaluate_instants  # noqa: E402

OUT = HERE / "results" / "quadrature_study.csv"
#: The bulk mix's classes: scene, period range (s), max_subsamples (bulk_standard.toml).
CLASSES = {
    "S3": ("s3_cylinder", (20.0, 200.0), 64),
    "S4": ("s4_falcon9", (20.0, 200.0), 64),
    "S5": ("s5_cubesat", (5.0, 60.0), 243),
    "S6": ("s6_boxwing", (60.0, 600.0), 64),
}
REFERENCE = 729
TOLERANCE_MAG = 1e-3
FAINT_MAG = 5.0


def values_at(prep, fractions) -> np.ndarray:
    """(N, F) instantaneous I/E at ``fractions`` of each exposure of a prepared curve."""
    rows = prep.exposures.rows
    probe = probe_instants(prep.geometry, rows, fractions, prep.t0_s)
    return evaluate_instants([(prep, probe)])[0].reshape(len(rows), len(fractions))


def replay(q: np.ndarray, counts, first: int, floor: float, resolved: int = 0):
    """Instants and estimate per exposure of the adaptive scheme over level estimates
    q (N, K) with ``counts`` instants per level (the law of
    :func:`jaxlc.rendering.adaptive.refine`: D_k from level ``resolved`` on, else 1;
    an estimate no smaller than the level below's × (n_{k−1}/n_k)^CARRY_POWER)."""
    tol = TOLERANCE_MAG / MAG_PER_REL
    n, k_max = q.shape
    accept = np.zeros((n, k_max), bool)
    own = np.zeros(n)
    for k in range(1, k_max):
        law = (counts[k] / counts[k - 1]) ** 2 - 1.0 if k >= resolved else 1.0
        change = np.abs(q[:, k] - q[:, k - 1]) / law
        err = np.maximum(change, own * (counts[k - 1] / counts[k]) ** CARRY_POWER)
        own = change
        accept[:, k] = (k >= first) & (err <= tol * np.maximum(q[:, k], floor))
    accept[:, -1] = True
    level = np.argmax(accept, axis=1)
    return np.asarray(counts)[level], q[np.arange(n), level]


def oracle(q: np.ndarray, counts, ref: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Fewest instants per exposure from which every finer level is within tolerance."""
    ok = MAG_PER_REL * np.abs(q - ref[:, None]) / scale[:, None] <= TOLERANCE_MAG
    tail = np.flip(np.cumprod(np.flip(ok, 1), 1), 1).astype(bool)
    first = np.where(tail.any(1), np.argmax(tail, 1), q.shape[1] - 1)
    return np.asarray(counts)[first]


def study_curve(label: str, k: int, geo: pd.DataFrame, rng) -> list[dict]:
    name, (lo, hi), cap = CLASSES[label]
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    ra, dec = math.degrees(math.atan2(u[1], u[0])) % 360, math.degrees(math.asin(u[2]))
    period = float(np.exp(rng.uniform(math.log(lo), math.log(hi))))
    scene = jaxlc.load_scene(name).with_spin(period, ra, dec, float(rng.uniform(0, 360)))
    options = jaxlc.RenderOptions(max_subsamples=cap)
    prep = prepare(scene, geo, options, "float32")
    blur = prep.plan.blur
    dense = values_at(prep, (np.arange(REFERENCE) + 0.5) / REFERENCE)
    ref = dense.mean(axis=1)
    keep = np.isfinite(ref) & (ref > 0)
    median = float(np.median(ref[keep]))
    floor = 1e-4 * median
    scale = np.maximum(ref, floor)
    sel = keep & (ref >= median * 10 ** (-0.4 * FAINT_MAG))
    # nested midpoints: level L is every 3^(6−L)-th of the 729 (its centres)
    last_mid = min(6, math.floor(math.log(3 * cap) / math.log(3) + 1e-9))
    q_mid = np.stack(
        [
            dense[:, np.arange(3**lv) * 3 ** (6 - lv) + (3 ** (6 - lv) - 1) // 2].mean(axis=1)
            for lv in range(last_mid + 1)
        ],
        axis=1,
    )
    mid_counts = [3**lv for lv in range(last_mid + 1)]
    ratio = blur.sweep_rad / blur.scale_rad if blur.scale_rad > 0 else 0.0
    first_mid = max(1, math.ceil(math.log(ratio) / math.log(3) - 1e-9)) if ratio > 1 else 1
    first_mid = min(first_mid, last_mid)
    last_p = max_level_for(cap)
    q_p = np.stack(
        [values_at(prep, level_rule(lv)[0]) @ level_rule(lv)[1] for lv in range(last_p + 1)],
        axis=1,
    )
    p_counts = [level_count(lv) for lv in range(last_p + 1)]
    first_p = min(first_level_for(blur.sweep_rad, blur.start_scale), last_p)
    done = adapt([prep], evaluate_instants)[0].refinement  # what jaxlc.render does
    code_err = 1e3 * MAG_PER_REL * np.abs(done.intensity[keep] - ref[keep]) / scale[keep]
    rows = []
    resolved = first_level_for(blur.sweep_rad, blur.start_scale / 2)  # as adapt()
    finer = min(resolved, last_p)
    never = len(p_counts)
    for scheme, q, counts, first, law_from in (
        ("midpoint", q_mid, mid_counts, first_mid, 0),
        ("patterson, ε = |ΔQ|", q_p, p_counts, first_p, never),
        ("patterson, D_k throughout", q_p, p_counts, first_p, 0),
        ("patterson, start gap σ/2", q_p, p_counts, finer, 0),
        ("patterson", q_p, p_counts, first_p, resolved),
    ):
        inst, est = replay(q[keep], counts, first, floor, law_from)
        err = 1e3 * MAG_PER_REL * np.abs(est - ref[keep]) / scale[keep]
        err = err[sel[keep]]
        best = oracle(q[keep], counts, ref[keep], scale[keep])
        rows.append(
            {
                "class": label,
                "curve": k,
                "period_s": period,
                "scheme": scheme,
                "first_level_instants": counts[first],
                "instants_per_exposure": float(inst.mean()),
                "oracle_instants": float(best.mean()),
                "p95_mmag": float(np.percentile(err, 95)),
                "max_mmag": float(err.max()),
            }
        )
    # over the same exposures as the replay (dark ones, left out there, stop early)
    rows[-1]["render_instants"] = float(np.mean(np.asarray(p_counts)[done.level[keep]]))
    rows[-1]["render_max_mmag"] = float(code_err[sel[keep]].max())
    return rows


def main(argv=None) -> pd.DataFrame:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--curves", type=int, default=10, help="random spins per class")
    ap.add_argument("--classes", nargs="+", default=list(CLASSES))
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args(argv)
    geo = pass_geometry().iloc[:1200]
    rows = []
    for label in a.classes:
        rng = np.random.default_rng(11)
        for k in range(a.curves):
            rows += study_curve(label, k, geo, rng)
            print(
                f"{label} curve {k}: "
                + "; ".join(
                    f"{r['scheme']} {r['instants_per_exposure']:.1f} inst, "
                    f"max {r['max_mmag']:.2f} mmag"
                    for r in rows[-5:]
                ),
                flush=True,
            )
    df = pd.DataFrame(rows)
    table = df.groupby(["class", "scheme"]).agg(
        instants=("instants_per_exposure", "mean"),
        oracle=("oracle_instants", "mean"),
        p95_mmag=("p95_mmag", "mean"),
        worst_p95_mmag=("p95_mmag", "max"),
        max_mmag=("max_mmag", "max"),
        render_instants=("render_instants", "mean"),
        render_max_mmag=("render_max_mmag", "max"),
    )
    with pd.option_context("display.width", 160, "display.precision", 3):
        print(table)
    jaxlc.write_table(df, a.out)
    print(f"→ {a.out}")
    return df


if __name__ == "__main__":
    main()

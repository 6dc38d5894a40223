"""A fit's sampled modes as one posterior: evidence weights, the mixture's samples and
one summary row per mode (every fit: spin and tumble)."""

from __future__ import annotations

import pandas as pd

from jaxlc.inference.mcmc import mode_weights


def weighted_samples(runs: dict, tables: list[pd.DataFrame], sampled: list[int]) -> pd.DataFrame:
    """The mixture posterior: each sampled mode's table (in ``sampled`` order) with a
    ``weight`` column, its evidence weight spread over its samples (sums to 1); sets
    ``runs[i]["weight"]``."""
    weights = mode_weights([runs[i]["log_evidence"] for i in sampled])
    for i, w, table in zip(sampled, weights, tables, strict=True):
        runs[i]["weight"] = float(w)
        table["weight"] = w / len(table)
    return pd.concat(tables, ignore_index=True)


def mode_rows(
    modes, runs: dict, samples: pd.DataFrame, best_chi2: float, names, walkers: int, summarise
) -> list[dict]:
    """One row per mode (``describe``, and for a sampled one its weight and chain:
    intervals by ``summarise``, evidence, acceptance, τ per coordinate ``names`` (or
    the run's own ``tau_names``: those it was sampled in),
    lengths, plus any extra ``runs[i]["report"]`` entries), listed by weight, the
    unsampled ones after them by χ². The first is the fit's answer: the mode of
    highest posterior weight (not of least χ²: a narrow mode can fit best and still
    hold little probability)."""
    rows = []
    for i, m in enumerate(modes):
        row = {"mode": i, **m.describe(best_chi2)}
        if i in runs:
            r = runs[i]
            row["weight"] = r["weight"]
            row["mcmc"] = {
                "intervals": summarise(samples[samples["mode"] == i]),
                "log_evidence": r["log_evidence"],
                "acceptance": r["acceptance"],
                "tau": dict(zip(r.get("tau_names", names), map(float, r["tau"]), strict=True)),
                "steps": r["steps"],
                "burn_in": r["burn"],
                "walkers": walkers,
                "chain_length_tau": r["chain_length_tau"],
                "converged": r["converged"],
                "seconds": r["seconds"],
                **r.get("report", {}),
            }
        rows.append(row)
    rows.sort(key=lambda r: (-r.get("weight", -1.0), r["chi2"]))
    return rows

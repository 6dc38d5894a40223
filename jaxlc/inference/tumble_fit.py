"""``jaxlc fit --attitude tumble``: a torque-free tumble fitted to a light curve.

1. ``jaxlc period`` with its second-period search (:mod:`jaxlc.inference.two_periods`):
   a curve that does not vary is refused; its one or two periods seed the search;
2. :func:`jaxlc.inference.tumble_search.tumble_multistart`: batched LM from
   bodies whose (P_ψ, T_ω) make the observed periods small combinations;
3. emcee around the best modes (within Δχ² < ``mode_delta_chi2``), in the
   chart of :mod:`jaxlc.inference.tumble_model` about each mode with both
   periods as coordinates (:mod:`jaxlc.inference.tumble_chart`), with the
   sampler of the spin fit (:func:`jaxlc.inference.mcmc.sample_posterior`), Δm
   integrated out as in the spin fit (:mod:`jaxlc.inference.offset_marginal`)
   and drawn from its conditional afterwards;
4. the summary: both periods (P_ψ, the mean rotation about L, and T_ω, ω's
   period in the body), the mode (SAM/LAM), excitation, L's direction, the
   moment ratios, Δm and noise, with 50 %/90 % intervals; the best mode is the
   one of highest posterior weight.

Priors: :mod:`jaxlc.inference.tumble_posterior`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.errors import JaxlcError
from jaxlc.inference import mcmc
from jaxlc.inference.data import fit_data, local_noise_mag
from jaxlc.inference.fit import write_outputs
from jaxlc.inference.mcmc import FitSettings
from jaxlc.inference.model import check_fittable
from jaxlc.inference.offset_marginal import marginal_ball
from jaxlc.inference.period import analyse_period
from jaxlc.inference.posterior_modes import mode_rows, weighted_samples
from jaxlc.inference.tumble_chart import in_period_chart, plain_run
from jaxlc.inference.tumble_model import (
    N_TUMBLE_LM,
    N_TUMBLE_MC,
    TUMBLE_MC_NAMES,
    tumble_model,
)
from jaxlc.inference.tumble_posterior import (
    DMAG_MC,
    MarginalLogProb,
    initial_ball,
    interval_summary,
    samples_table,
)
from jaxlc.inference.tumble_search import (
    frequency_hypotheses,
    rank_hypotheses,
    tumble_multistart,
)
from jaxlc.scene import Scene

#: The corner plot's columns.
CORNER_COLUMNS = (
    "precession_period_s",
    "body_period_s",
    "excitation",
    "l_ra_deg",
    "l_dec_deg",
    "dmag",
)
#: Least samples of the search model: a tumble's fastest combination frequencies need
#: several samples per cycle (64 over a 20-minute pass missed the shipped tumbler's L).
TUMBLE_SEARCH_SAMPLES = 256
#: Walkers of the tumble's emcee: at least 2 × its parameters, with a margin.
MIN_WALKERS = 2 * N_TUMBLE_MC + 4
#: A best tumble whose scatter about the data exceeds this multiple of the curve's
#: white noise (its errors, or :func:`~jaxlc.inference.data.local_noise_mag` without
#: them) does not explain the curve (summary ``poor_fit``): the blind cylinder search's
#: best state left 0.20 mag where the noise is 0.02 (a one-period Fourier series
#: leaves 0.20 mag too: it is no yardstick for a tumbler).
POOR_FIT_FACTOR = 1.5


def fit_tumble(
    scene: Scene,
    lightcurve: pd.DataFrame,
    geometry: pd.DataFrame,
    settings: FitSettings | None = None,
    out_dir: str | Path | None = None,
    log=None,
    progress=None,
) -> dict:
    """Fit a torque-free tumble (both periods, mode, L, moment ratios, Δm, noise).

    Arguments as :func:`jaxlc.inference.fit.fit_spin` (``settings.walkers`` is
    raised to :data:`MIN_WALKERS`; ``settings.period_s`` seeds the first period).

    Returns:
        The summary dict (also ``summary.json``) with ``samples`` (DataFrame) added.
    """
    settings = settings or FitSettings()
    log = log or (lambda msg: None)
    progress = progress or (lambda stage, done, total: None)
    rng = np.random.default_rng(settings.seed)
    t0 = time.perf_counter()
    timings = {}
    check_fittable(scene)
    data = fit_data(lightcurve, geometry, default_exposure_s=scene.exposure_s)
    pr = analyse_period(
        data.t_s, data.mag, min_period_s=settings.min_period_s, max_period_s=settings.max_period_s
    )
    if not pr.variable and settings.period_s is None:
        raise JaxlcError(
            f"tumble fit: the light curve does not vary beyond its noise and trend "
            f"({pr.decision}); there is no rotation to fit. Give --period-s to fit anyway"
        )
    found = pr.period_s if math.isfinite(pr.period_s) else pr.best_period_s
    first = settings.period_s or found
    if settings.period_s is not None and settings.body_period_s is not None:
        hypotheses = [(1.0 / settings.period_s, 1.0 / settings.body_period_s, 0.0)]
        log(f"given P_ψ = {settings.period_s:.6g} s and T_ω = {settings.body_period_s:.6g} s")
    else:
        second = pr.second_period_s if pr.two_periods and settings.period_s is None else None
        candidates = frequency_hypotheses(1.0 / first, None if second is None else 1.0 / second)
        errors = np.all(data.mag_err > 0)
        w = 1.0 / data.mag_err**2 if errors else np.ones(data.n)
        hypotheses = rank_hypotheses(data.t_s, data.mag, w, candidates)
        log(
            f"period analysis: {pr.verdict}; seeds {first:.5g} s"
            + (f" and {second:.5g} s" if second else "")
            + f": {len(candidates)} hypotheses for (P_ψ, T_ω), the best "
            + ", ".join(describe_hypothesis(h) for h in hypotheses)
        )
    timings["periodogram_s"] = time.perf_counter() - t0
    rate_ref = 2.0 * math.pi / first
    t1 = time.perf_counter()
    modes, reports = tumble_multistart(
        scene,
        data,
        hypotheses,
        rate_ref,
        n_starts=settings.n_starts,
        search_samples=max(settings.search_samples, TUMBLE_SEARCH_SAMPLES),
        rng=rng,
        log=log,
    )
    timings["map_s"] = time.perf_counter() - t1
    dof = max(data.n - N_TUMBLE_LM, 1)
    errors = float(np.median(data.mag_err**2))
    map_scatter = math.sqrt(modes[0].chi2 / dof * (errors if errors > 0 else 1.0))
    noise = math.sqrt(errors) if errors > 0 else local_noise_mag(data.mag)
    if map_scatter > POOR_FIT_FACTOR * noise:  # a warning before minutes of sampling
        log(
            f"the best state found leaves {map_scatter:.3g} mag of scatter about a curve "
            f"with {noise:.3g} mag of noise: the search has likely missed the tumble (give "
            "both periods, or raise --starts); sampling it anyway"
        )
    if np.all(data.mag_err == 0):  # χ² in units of the best mode's residual variance
        var = modes[0].chi2 / dof
        modes = [dataclasses.replace(m, chi2=m.chi2 / var) for m in modes]
    best_chi2 = modes[0].chi2

    t2 = time.perf_counter()
    walkers = max(settings.walkers, MIN_WALKERS)
    sampled = [
        i
        for i, m in enumerate(modes)
        if m.chi2 - best_chi2 < settings.mode_delta_chi2 and i < settings.mcmc_modes
    ]
    runs, tables, model = {}, [], None
    for n, i in enumerate(sampled):
        model = tumble_model(scene, data, modes[i].theta_lm, rate_ref, exact=True, adapted=True)
        p0, centre, cov, q_mode = initial_ball(model, data, modes[i], walkers, rng)
        lp = MarginalLogProb(model, data, centre, q_mode)
        p0, centre9, cov = marginal_ball(p0, centre, cov, DMAG_MC)
        lp, p0, centre9, cov = in_period_chart(lp, p0, centre9, cov, rate_ref, log)
        if not mcmc.pull_inside(lp, p0, centre9):
            log(
                f"mode {i} left out: its Laplace ball lies outside the prior (centre "
                + ", ".join(f"{n} {v:.4g}" for n, v in zip(TUMBLE_MC_NAMES, centre, strict=True))
                + ")"
            )
            continue
        stage = f"emcee mode {n + 1}/{len(sampled)}"
        run = mcmc.sample_posterior(
            lp,
            p0,
            centre9,
            cov,
            settings,
            rng,
            log=log,
            progress=lambda steps, total, _length, s=stage: progress(s, steps, total),
        )
        runs[i] = {**plain_run(mcmc.full_coordinates(run, lp, rng), lp), "model": model}
        tables.append(samples_table(runs[i]["chain"], runs[i]["log_prob"], i, q_mode, rate_ref))
    sampled = [i for i in sampled if i in runs]
    if not sampled:
        raise JaxlcError(
            f"tumble fit: the best state found (reduced χ² {modes[0].chi2 / max(data.n, 1):.3g}) "
            "lies outside the prior, so the search did not find the tumble; give both periods "
            "(--period-s P_ψ --body-period-s T_ω) or raise --starts"
        )
    samples = weighted_samples(runs, tables, sampled)
    timings["mcmc_s"] = time.perf_counter() - t2
    timings["total_s"] = time.perf_counter() - t0

    rows = mode_rows(modes, runs, samples, best_chi2, TUMBLE_MC_NAMES, walkers, interval_summary)
    best = rows[0]
    iv = best["mcmc"]["intervals"]
    scatter = math.sqrt(errors + iv["noise_mag"]["median"] ** 2)
    summary = {
        "attitude": "tumble",
        "precession_period_s": iv["precession_period_s"]["median"],
        "body_period_s": iv["body_period_s"]["median"],
        "tumble_mode": "SAM" if iv["sam_fraction"] >= 0.5 else "LAM",
        "excitation": iv["excitation"]["median"],
        "l_ra_deg": iv["l_mean"]["ra_deg"],
        "l_dec_deg": iv["l_mean"]["dec_deg"],
        "dmag": iv["dmag"]["median"],
        "noise_mag": iv["noise_mag"]["median"],
        "epoch_utc": data.epoch_utc.isoformat(),
        # χ² per degree of freedom of the best mode with the data's own errors (null
        # without errors): well above 1, the state is a local optimum or the shape is wrong.
        "reduced_chi2": best["chi2"] / dof if np.all(data.mag_err > 0) else None,
        # The best tumble's scatter about the data (errors and excess noise) against the
        # curve's own noise: far above it, the search missed the state.
        "scatter_mag": scatter,
        "data_noise_mag": noise,
        "poor_fit": bool(scatter > POOR_FIT_FACTOR * noise),
        "intervals": iv,
        "map": {k: best[k] for k in ("inertia_ratios", "omega_body_rad_s", "quaternion")},
        "best_mode": best["mode"],
        "best_weight": best["weight"],
        "modes": rows,
        "diagnostics": {
            k: best["mcmc"][k]
            for k in ("acceptance", "tau", "steps", "burn_in", "walkers", "chain_length_tau")
        }
        | {"converged": best["mcmc"]["converged"]},
        "periodogram": pr.summary(),
        "data": {"samples": data.n, "limit_mag": data.limit_mag},
        "solver": [dataclasses.asdict(r) for r in reports],
        "scene": scene.source,
        "settings": dataclasses.asdict(settings) | {"walkers": walkers},
        "timings_s": timings,
    }
    if out_dir is not None:
        write_outputs(
            Path(out_dir),
            summary,
            samples,
            runs[best["mode"]]["model"],
            data,
            modes[best["mode"]].theta_lm,
            title(summary),
            CORNER_COLUMNS,
        )
    summary["samples"] = samples
    return summary


def describe_hypothesis(h) -> str:
    """A (P_ψ, T_ω) hypothesis in words."""
    if math.isfinite(h[1]):
        return f"(P_ψ {1 / h[0]:.4g} s, T_ω {1 / h[1]:.4g} s)"
    return f"(1/{1 / h[0]:.4g} s = {h[2]}/P_ψ {h[3]:+d}/T_ω)"


def title(summary: dict) -> str:
    """One line of a tumble fit: the mode, both periods, L and the noise."""
    return (
        f"{summary['tumble_mode']}: P_ψ = {summary['precession_period_s']:.5g} s, "
        f"T_ω = {summary['body_period_s']:.5g} s, L ({summary['l_ra_deg']:.1f}°, "
        f"{summary['l_dec_deg']:.1f}°), noise {summary['noise_mag']:.3f} mag"
    )

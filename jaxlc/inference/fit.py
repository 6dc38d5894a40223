"""``jaxlc fit``: the whole spin-state fit and its outputs (see :mod:`jaxlc.inference.mcmc`).

Output folder:

* ``summary.json`` — ``period_s``, ``pole_ra_deg``, ``pole_dec_deg``,
  ``phase_deg`` (at ``epoch_utc``), ``dmag``, ``noise_mag`` of the best mode
  (``best_mode``: the one of highest posterior weight, ``best_weight``)
  with 50 %/90 % intervals, the pole's credible radii, every mode found,
  the periodogram, diagnostics (the sampler: ``method`` and its effective size
  ``ess``, or emcee's acceptance, τ and chain length in τ) and timings;
* ``samples.parquet`` — posterior samples of every sampled mode (user units),
  with ``weight`` (the mode's probability from its Laplace evidence, spread
  over its samples: weighted, the table is the mixture posterior);
* ``corner.png`` — pairwise posterior of the best mode (highest posterior weight);
* ``fit.png`` — the data with the MAP model and residuals.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.errors import JaxlcError
from jaxlc.inference import mcmc, posterior_modes
from jaxlc.inference.data import fit_data, soft_clip
from jaxlc.inference.harmonics import median_step_s
from jaxlc.inference.mcmc import FitSettings
from jaxlc.inference.model import MC_NAMES, N_LM, check_fittable, spin_model
from jaxlc.inference.period import analyse_period
from jaxlc.inference.period_result import distinct_periods
from jaxlc.inference.posterior_modes import weighted_samples
from jaxlc.inference.search import multistart
from jaxlc.io.files import atomic_output
from jaxlc.scene import Scene

__all__ = ["FitSettings", "fit_spin", "write_outputs"]


#: The fit's model error budget per sample, as a fraction of the data's noise. Measured
#: before the adaptive quadrature's first level resolved the sharpest feature (when its
#: error could exceed the tolerance several times at a glint): at σ/10 (5 mmag) the S5
#: model was 29 mmag off the render in places, χ² 2.6 over a curve, and the period
#: 2.5 σ off (SBC case 3);
#: at σ/30 (1.7 mmag) they cost χ² ≤ 0.4 on the same curves (a bias ≲ 0.6 σ).
BLUR_NOISE_FRACTION = 1 / 30
#: … and its largest value (mag).
BLUR_TOLERANCE_CAP_MAG = 0.02


def blur_tolerance_mag(scene: Scene, data, mode) -> float:
    """Tolerance of the MCMC model's adaptive sub-exposures: a thirtieth of the data's
    typical noise (errors and the mode's excess noise), at least the scene's own
    ``blur_tolerance_mag`` and at most :data:`BLUR_TOLERANCE_CAP_MAG` (see
    :data:`BLUR_NOISE_FRACTION`); 1 mmag on a 0.05 mag curve only costs time."""
    sigma = math.sqrt(float(np.median(data.mag_err**2)) + mode.noise_mag**2)
    tol = min(BLUR_NOISE_FRACTION * sigma, BLUR_TOLERANCE_CAP_MAG)
    return max(scene.render.blur_tolerance_mag, tol)


def fit_spin(
    scene: Scene,
    lightcurve: pd.DataFrame,
    geometry: pd.DataFrame,
    settings: FitSettings | None = None,
    out_dir: str | Path | None = None,
    log=None,
    progress=None,
) -> dict:
    """Fit pole, period, phase, brightness offset and noise to an observed light curve.

    Args:
        scene: shape and materials (its attitude's ``body_axis`` is the spin axis).
        lightcurve: light-curve table (``utc``, ``mag``, optional ``mag_err``, ``visible``).
        geometry: the geometry table of the same rows.
        settings: :class:`FitSettings`.
        out_dir: where to write summary, samples and plots (None: nothing written).
        log: optional callable(str) for a few lines per stage.
        progress: optional callable(stage: str, done: int, total: int) for a progress bar.

    Returns:
        The summary dict (also ``summary.json``) with ``samples`` (DataFrame) added.
    """
    settings = settings or FitSettings()
    log = log or (lambda msg: None)
    progress = progress or (lambda stage, done, total: None)
    rng = np.random.default_rng(settings.seed)
    timings = {}
    t0 = time.perf_counter()
    check_fittable(scene)
    data = fit_data(lightcurve, geometry, default_exposure_s=scene.exposure_s)
    if settings.period_s is not None:
        seeds = [settings.period_s]
        period_info = {"given_period_s": settings.period_s}
    else:
        # The range bounds the *spin*: its periodogram peak may be up to 4× shorter.
        lo = settings.min_period_s
        if lo is not None:
            lo = max(lo / 4, 2.5 * median_step_s(np.sort(data.t_s)))
        pr = analyse_period(
            data.t_s,
            data.mag,
            min_period_s=lo,
            max_period_s=settings.max_period_s,
            two_periods=False,  # the spin fit seeds from one period's candidates
        )
        if not pr.variable:
            raise JaxlcError(
                f"spin fit: the light curve does not vary beyond its noise and trend "
                f"({pr.decision}); there is no spin to fit. Give --period-s to fit anyway"
            )
        # The candidates the period analysis scored (multiples of its peaks), best first,
        # and 2–4 × the best: a body can repeat its light curve two, three or four times
        # a turn (identical halves, glints), which a Fourier model cannot tell apart
        # but the shape model can; without those seeds the fit settled confidently on
        # P/3 in 2 of 50 SBC cases (weight 1.0, true period in no mode).
        ranked = [c["period_s"] for c in pr.candidates]
        hi = min(settings.max_period_s or pr.span_s, pr.span_s)
        multiples = [k * pr.best_period_s for k in (2, 3, 4)]
        seeds = _distinct([*ranked[:6], *multiples], settings.min_period_s or pr.min_period_s, hi)
        if not seeds:
            raise JaxlcError(
                f"spin fit: no candidate period within [{settings.min_period_s}, {hi:.4g}] s "
                f"(period analysis: {pr.decision}); widen --min-period-s/--max-period-s"
            )
        period_info = pr.summary()
        log(
            f"period analysis: {pr.verdict}, best {pr.best_period_s:.4g} s "
            f"(FAP {pr.false_alarm_probability:.1e}); seeds "
            + ", ".join(f"{s:.4g}" for s in seeds)
            + " s"
        )
    timings["periodogram_s"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    modes, reports = multistart(
        scene,
        data,
        seeds,
        n_starts=settings.n_starts,
        search_samples=settings.search_samples,
        search_steps=settings.search_steps,
        refine_steps=settings.refine_steps,
        rng=rng,
        log=log,
    )
    timings["map_s"] = time.perf_counter() - t1
    # At least one turn within the data: a longer period is not a spin this curve shows.
    within = [m for m in modes if m.period_s <= data.span_s]
    if not within:
        raise JaxlcError(
            f"spin fit: every mode has a period beyond the data span ({data.span_s:.4g} s; "
            f"best {modes[0].period_s:.4g} s): the curve does not show one turn"
        )
    modes = within
    if np.all(data.mag_err == 0):  # χ² in units of the best mode's residual variance
        var = modes[0].chi2 / max(data.n - N_LM, 1)
        modes = [dataclasses.replace(m, chi2=m.chi2 / var) for m in modes]
    best_chi2 = modes[0].chi2
    log(
        f"MAP: {len(modes)} distinct modes; best P = {modes[0].period_s:.5g} s, pole "
        f"({modes[0].pole_radec_deg[0]:.1f}°, {modes[0].pole_radec_deg[1]:.1f}°)"
    )

    t2 = time.perf_counter()
    sampled = [
        i
        for i, m in enumerate(modes)
        if m.chi2 - best_chi2 < settings.mode_delta_chi2 and i < settings.mcmc_modes
    ]
    # The exact model of each sampled mode: its exposures sampled as the render
    # plan samples them for the mode's spin (adaptive sub-exposures chosen at the
    # mode, as a render of that spin chooses them), its reference period the
    # fastest sampled spin's.
    period_ref = min(modes[i].period_s for i in sampled)
    runs, tables = {}, []
    for n, i in enumerate(sampled):
        tolerance = blur_tolerance_mag(scene, data, modes[i])
        model = spin_model(
            scene,
            data,
            period_ref,
            exact=True,
            theta=modes[i].theta_lm,
            tolerance_mag=tolerance,
        )
        stage = f"sampling mode {n + 1}/{len(sampled)} (P {modes[i].period_s:.4g} s)"
        log(f"sampling mode {i} (Δχ² = {modes[i].chi2 - best_chi2:.1f})")
        try:
            runs[i] = mcmc.sample_mode(
                model,
                data,
                modes[i],
                settings,
                rng,
                log=log,
                progress=lambda steps, total, _length, s=stage: progress(s, steps, total),
                importance=modes[i].chi2 - best_chi2 >= settings.importance_delta_chi2,
            )
        except mcmc.OutsidePriorError as exc:  # a mode at a bound is not a posterior mode
            log(f"mode {i} left out: {exc}")
            continue
        runs[i]["report"] = {
            "method": runs[i]["method"],
            **({"ess": runs[i]["ess"], "draws": runs[i]["draws"]} if "ess" in runs[i] else {}),
            "instants_per_exposure": model.instants_per_exposure,
            "blur_tolerance_mag": tolerance,
        }
        tables.append(mcmc.samples_table(runs[i]["chain"], runs[i]["log_prob"], i))
    sampled = [i for i in sampled if i in runs]
    if not sampled:
        raise JaxlcError(
            "spin fit: every mode within Δχ² < "
            f"{settings.mode_delta_chi2:g} lies outside the prior (noise or Δm at a bound); "
            "check the light curve's units (magnitudes) or give --period-s"
        )
    samples = weighted_samples(runs, tables, sampled)
    timings["mcmc_s"] = time.perf_counter() - t2
    timings["total_s"] = time.perf_counter() - t0

    mode_rows = posterior_modes.mode_rows(
        modes, runs, samples, best_chi2, MC_NAMES, settings.walkers, mcmc.interval_summary
    )
    best = mode_rows[0]
    iv = best["mcmc"]["intervals"]
    summary = {
        "period_s": iv["period_s"]["median"],
        "pole_ra_deg": iv["pole_mean"]["ra_deg"],
        "pole_dec_deg": iv["pole_mean"]["dec_deg"],
        "phase_deg": iv["phase_deg"]["median"],
        "dmag": iv["dmag"]["median"],
        "noise_mag": iv["noise_mag"]["median"],
        "epoch_utc": data.epoch_utc.isoformat(),
        "intervals": iv,
        "map": {k: best[k] for k in ("period_s", "pole_ra_deg", "pole_dec_deg", "phase_deg")},
        "best_mode": best["mode"],
        "best_weight": best["weight"],
        "modes": mode_rows,
        "diagnostics": {
            k: best["mcmc"][k]
            for k in (
                "acceptance",
                "tau",
                "steps",
                "burn_in",
                "walkers",
                "chain_length_tau",
                "converged",
            )
        }
        | {k: best["mcmc"][k] for k in ("method", "ess", "draws") if k in best["mcmc"]},
        "periodogram": period_info,
        "data": {"samples": data.n, "limit_mag": data.limit_mag},
        "solver": [dataclasses.asdict(r) for r in reports],
        "model": {
            "subsamples": model.instants_per_exposure,
            "facets": model.obj.n_facets,
            "shadows": model.obj.shadow is not None,
        },
        "scene": scene.source,
        "settings": dataclasses.asdict(settings),
        "timings_s": timings,
    }
    if out_dir is not None:
        write_outputs(
            Path(out_dir),
            summary,
            samples,
            model,
            data,
            modes[best["mode"]].theta_lm,
            spin_title(summary),
        )
    summary["samples"] = samples
    return summary


def _distinct(periods, lo: float, hi: float) -> list[float]:
    """Periods within [lo, hi] (at most the span: one turn seen), each more than 1 % from the
    ones before it, in order."""
    return distinct_periods(p for p in periods if lo <= p <= hi)


def json_clean(x):
    """A summary made JSON-safe: numpy scalars as Python numbers, non-finite floats as null."""
    if isinstance(x, dict):
        return {k: json_clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_clean(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def spin_title(summary: dict) -> str:
    """One line of a spin fit: period, pole and noise."""
    return (
        f"P = {summary['period_s']:.5g} s, pole ({summary['pole_ra_deg']:.1f}°, "
        f"{summary['pole_dec_deg']:.1f}°), noise {summary['noise_mag']:.3f} mag"
    )


def write_outputs(
    out_dir: Path,
    summary: dict,
    samples: pd.DataFrame,
    model,
    data,
    theta_lm,
    title: str | None = None,
    corner_columns=None,
) -> None:
    """summary.json, samples.parquet, corner.png (the best mode's ``corner_columns``) and
    fit.png (the data and ``model`` at host LM coordinates ``theta_lm``), each written
    atomically: the outputs of every fit (spin or tumble)."""

    from jaxlc.io.tables import write_table
    from jaxlc.plot import plot_corner, plot_fit

    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_output(out_dir / "summary.json") as tmp:
        Path(tmp).write_text(json.dumps(json_clean(summary), indent=2))
    write_table(samples, out_dir / "samples.parquet")
    best = samples[samples["mode"] == summary["best_mode"]]
    plot_corner(best, out_dir / "corner.png", corner_columns)
    m = np.asarray(model.magnitudes(model.to_device(theta_lm)))
    plot_fit(data.t_s, soft_clip(data.mag, data.limit_mag), m, out_dir / "fit.png", title)

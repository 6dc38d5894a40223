"""``jaxlc period`` and ``jaxlc fit``: spin periods and spin-state fits of light curves."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import typer

from jaxlc.cli.app import app, console
from jaxlc.errors import JaxlcError

#: Reduced χ² above which a fit's best mode is reported as fitting worse than the errors.
POOR_FIT_CHI2 = 1.5


@app.command()
def period(
    lightcurve: Annotated[
        Path, typer.Argument(help="Light-curve table (.csv/.parquet) or MMT track (.txt).")
    ],
    json_out: Annotated[
        bool, typer.Option("--json", help="Print one JSON object instead of a table.")
    ] = False,
    plot: Annotated[
        Path | None, typer.Option("--plot", help="Periodogram and folded curve (.png).")
    ] = None,
    column: Annotated[
        str | None,
        typer.Option(help="Magnitude column (default: std_mag for MMT tracks, else mag)."),
    ] = None,
    min_period_s: Annotated[float | None, typer.Option(help="Shortest period searched.")] = None,
    max_period_s: Annotated[
        float | None, typer.Option(help="Longest period searched (at most half the span).")
    ] = None,
    detrend: Annotated[
        int, typer.Option(help="Degree of the slow polynomial trend removed (0: the mean).")
    ] = 2,
    permutations: Annotated[
        int, typer.Option(help="Most block shuffles behind the false-alarm probability (≥ 30).")
    ] = 300,
    seed: Annotated[int, typer.Option(help="Random seed of the shuffles.")] = 0,
):
    """Spin period of an observed light curve, or "no period" when the data do not hold one.

    A period is reported only when a trend + Fourier-series model at it beats
    the trend alone (ΔBIC > 10, effective samples) and block-shuffled data
    rarely reach its periodogram peak (FAP < 0.01). Candidates are 1–4 × the
    strongest periodogram peaks. A tumbling body's second period is reported
    too ("second_period_s", verdict "two periods") when a series in both
    frequencies beats every one-period model by the same evidence. JSON:
    "period_s" is null and "variable" says whether the curve varies at all
    when no period is found.
    """
    import json as _json

    from jaxlc.inference.period import analyse_period
    from jaxlc.inference.period_result import format_p
    from jaxlc.io.files import check_output
    from jaxlc.io.observations import observed_samples, read_observations

    check_output(plot, "plot", "--plot")
    obs = read_observations(lightcurve)
    col = column or ("std_mag" if "std_mag" in obs.columns else "mag")
    t, y, err = observed_samples(obs, col)
    result = analyse_period(
        t,
        y,
        err,
        min_period_s=min_period_s,
        max_period_s=max_period_s,
        detrend_degree=detrend,
        n_permutations=permutations,
        seed=seed,
        catalogue_period_s=float(obs.attrs.get("catalogue_period_s", float("nan"))),
    )
    if plot is not None:
        from jaxlc.plot import plot_period

        ylabel = "StdMag (MMT: mag at 1,000 km)" if col == "std_mag" else col
        plot_period(result, plot, ylabel=ylabel)
    summary = {"file": str(lightcurve), "column": col, **result.summary()}
    if json_out:
        print(_json.dumps(summary))
        return
    from rich.table import Table

    table = Table(title=f"period of {lightcurve.name}", show_header=False)
    for key in (
        "verdict",
        "period_s",
        "period_err_s",
        "second_period_s",
        "best_period_s",
        "harmonic_factor",
        "alternative_period_s",
        "ls_period_s",
        "false_alarm_probability",
        "false_alarm_probability_white",
        "delta_bic",
        "effective_samples",
        "n_samples",
        "span_s",
        "catalogue_period_s",
    ):
        v = summary[key]
        if v is None:
            text = "—"
        elif key.startswith("false_alarm"):
            text = format_p(v)
        else:
            text = f"{v:.6g}" if isinstance(v, float) else str(v)
        table.add_row(key, text)
    out = console(stderr=False)
    out.print(table)
    out.print(result.decision, highlight=False)
    if plot is not None:
        out.print(f"plot → {plot}")


@app.command()
def fit(
    scene: Annotated[Path, typer.Argument(help="Scene file (shape, materials, body_axis).")],
    lightcurve: Annotated[Path, typer.Argument(help="Observed light-curve table.")],
    geometry: Annotated[Path, typer.Option("--geometry", help="Geometry table of the same rows.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Output folder.")],
    starts: Annotated[int, typer.Option(help="Multi-start LM solves (one vmap).")] = 1024,
    walkers: Annotated[int, typer.Option(help="emcee walkers (≥ 12).")] = 12,
    max_steps: Annotated[int, typer.Option(help="emcee step cap.")] = 6000,
    min_tau: Annotated[float, typer.Option(help="Chain length target in τ.")] = 50.0,
    sampler: Annotated[
        str,
        typer.Option(
            help="Spin fits: 'auto' importance-samples each mode's Laplace approximation "
            "(emcee where it misses); 'emcee' runs emcee for every main mode."
        ),
    ] = "auto",
    mcmc_modes: Annotated[int, typer.Option(help="Modes sampled (within Δχ² < 10).")] = 4,
    period_s: Annotated[
        float | None, typer.Option(help="Seed period instead of the periodogram's.")
    ] = None,
    min_period_s: Annotated[
        float | None, typer.Option(help="Shortest period searched (default 2.5 steps).")
    ] = None,
    max_period_s: Annotated[
        float | None, typer.Option(help="Longest period searched (default span / 2).")
    ] = None,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    attitude: Annotated[
        str | None,
        typer.Option(
            help="'spin' (pole, period, phase) or 'tumble' (torque-free: both periods, "
            "mode, L, moment ratios); default: 'tumble' for a tumbling scene, else 'spin'."
        ),
    ] = None,
    body_period_s: Annotated[
        float | None,
        typer.Option(help="Tumble: T_ω, ω's period in the body (with --period-s as P_ψ)."),
    ] = None,
    shadow_exact: Annotated[
        str | None,
        typer.Option(help="off: fit with the shadow table when the scene asks for glints."),
    ] = None,
):
    """Fit the spin state (pole, period, phase, brightness, noise) to a light curve,
    or with --attitude tumble a torque-free tumble (P_ψ, T_ω, mode, L, excitation).

    Compiled solvers are kept in JAX's persistent cache ($JAXLC_XLA_CACHE,
    default ~/.cache/jaxlc/xla; "off" disables it), so later fits start faster.
    """
    import jaxlc
    from jaxlc.cli.render import render_options
    from jaxlc.inference.fit import fit_spin
    from jaxlc.inference.mcmc import FitSettings
    from jaxlc.inference.model import check_fittable
    from jaxlc.inference.tumble_fit import fit_tumble, title
    from jaxlc.io.files import check_output
    from jaxlc.xla import enable_persistent_cache

    check_output(output, "folder", "-o")
    err = console()
    settings = FitSettings(
        n_starts=starts,
        walkers=walkers,
        max_steps=max_steps,
        min_tau=min_tau,
        sampler=sampler,
        mcmc_modes=mcmc_modes,
        period_s=period_s,
        min_period_s=min_period_s,
        max_period_s=max_period_s,
        seed=seed,
    )
    sc = jaxlc.load_scene(scene)
    if shadow_exact is not None:
        sc = dataclasses.replace(sc, render=render_options(sc, None, None, None, shadow_exact))
    check_fittable(sc)  # before reading the data: a fit the options cannot afford
    attitude = attitude or ("tumble" if sc.attitude.model == "tumble" else "spin")
    if attitude not in ("spin", "tumble"):
        raise JaxlcError(f"--attitude {attitude!r}: give 'spin' or 'tumble'")
    if body_period_s is not None and (attitude != "tumble" or period_s is None):
        raise JaxlcError(
            "--body-period-s: only with --attitude tumble and --period-s (P_ψ and T_ω together)"
        )
    settings = dataclasses.replace(settings, body_period_s=body_period_s)
    lc = jaxlc.read_lightcurve(lightcurve)
    geo = jaxlc.read_geometry(geometry)
    enable_persistent_cache()
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total} steps"),
        TimeElapsedColumn(),
        console=err,
        transient=True,
    ) as bar:
        task = bar.add_task("spin fit", total=None)

        def progress(stage: str, done: int, total: int) -> None:
            bar.update(task, description=stage, completed=done, total=total)

        run = fit_spin if attitude == "spin" else fit_tumble
        result = run(
            sc,
            lc,
            geo,
            settings,
            out_dir=output,
            log=lambda m: bar.console.print(m, highlight=False),
            progress=progress,
        )
    iv = result["intervals"]
    d = result["diagnostics"]
    if attitude == "tumble":
        p, b = iv["precession_period_s"], iv["body_period_s"]
        answer = (
            f"{title(result)}; 90%: P_ψ [{p['p05']:.5g}, {p['p95']:.5g}] s, T_ω "
            f"[{b['p05']:.5g}, {b['p95']:.5g}] s, L ± {iv['l_radius_deg']['r90']:.1f}°"
        )
    else:
        answer = (
            f"period {result['period_s']:.6g} s [90%: {iv['period_s']['p05']:.6g}, "
            f"{iv['period_s']['p95']:.6g}], pole ({result['pole_ra_deg']:.1f}°, "
            f"{result['pole_dec_deg']:.1f}°) ± {iv['pole_radius_deg']['r90']:.1f}° (90%)"
        )
    err.print(
        f"{answer}, {len(result['modes'])} modes (best weight {result['best_weight']:.2f}); "
        f"{sampler_line(d)}; {result['timings_s']['total_s']:.1f} s → {output}",
        highlight=False,
    )
    if (result.get("reduced_chi2") or 0.0) > POOR_FIT_CHI2:
        err.print(
            f"warning: the best tumble fits the data worse than their errors (reduced χ² "
            f"{result['reduced_chi2']:.2f}): it may be a local optimum with the right periods "
            "but another state; raise --starts or check the scene's shape",
            style="yellow",
        )
    if result.get("poor_fit"):
        err.print(
            f"warning: the best tumble leaves {result['scatter_mag']:.3f} mag of scatter "
            f"about a curve with {result['data_noise_mag']:.3f} mag of noise: it is not "
            "this curve's tumble (the search missed it, or the shape is wrong); give both "
            "periods (--period-s P_ψ --body-period-s T_ω) or raise --starts",
            style="yellow",
        )
    if not d["converged"]:
        err.print(
            f"warning: chain only {d['chain_length_tau']:.0f} τ long; raise --max-steps",
            style="yellow",
        )


def sampler_line(d: dict) -> str:
    """How the best mode was sampled, from a fit's ``diagnostics``."""
    if d.get("method") == "importance":
        return f"importance sampling, effective size {d['ess']:.0f} of {d['draws']}"
    return f"chain {d['chain_length_tau']:.0f} τ, acceptance {d['acceptance']:.2f}"

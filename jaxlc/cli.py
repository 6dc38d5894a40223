"""Command line: ``jaxlc render``, ``jaxlc geometry synthetic``, ``jaxlc info``.

A wrong input exits with status 1 and one line on stderr (``error: …``); add
``--debug`` (before the command) or set ``JAXLC_DEBUG=1`` for the traceback.
"""

from __future__ import annotations

import os
import sys
import time
import warnings
from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer(
    name="jaxlc",
    help="Light curves of resident space objects: JAX facet model, Blender reference.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
geometry_app = typer.Typer(help="Make geometry tables (object, Sun, observer per sample).")
app.add_typer(geometry_app, name="geometry")
calibrate_app = typer.Typer(help="The Blender/Cycles reference renderer (.venv-blender).")
app.add_typer(calibrate_app, name="calibrate")


def _console(stderr: bool = True):
    """A rich console; wide when output goes to a file or pipe, not a terminal."""
    from rich.console import Console

    console = Console(stderr=stderr)
    return console if console.is_terminal else Console(stderr=stderr, width=160)


@app.callback()
def _root(
    debug: Annotated[bool, typer.Option("--debug", help="Show tracebacks of errors.")] = False,
):
    """jaxlc: scene + geometry → light curve."""


def _render_options(scene, shadows, shadow_grid, subsamples):
    """The scene's [render] options with the command line's overrides."""
    import dataclasses

    from jaxlc.errors import JaxlcError
    from jaxlc.shadow import ShadowSettings

    opts = scene.render
    if shadows is not None:
        opts = dataclasses.replace(opts, shadows=shadows)
    if shadow_grid is not None:
        opts = dataclasses.replace(opts, shadow=dataclasses.replace(opts.shadow, grid=shadow_grid))
        ShadowSettings.__post_init__(opts.shadow)
    if subsamples is not None:
        if subsamples == "auto":
            opts = dataclasses.replace(opts, blur="auto", subsamples=None)
        elif subsamples == "off":
            opts = dataclasses.replace(opts, blur="off", subsamples=None)
        else:
            try:
                n = int(subsamples)
            except ValueError:
                raise JaxlcError(
                    f"--subsamples = {subsamples!r} must be auto, off or a whole number"
                ) from None
            opts = dataclasses.replace(opts, subsamples=n)
    return opts


@app.command()
def render(
    scene: Annotated[Path, typer.Argument(help="Scene file (TOML).")],
    geometry: Annotated[Path, typer.Argument(help="Geometry table (.csv or .parquet).")],
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Light-curve table (.csv or .parquet).")
    ],
    plot: Annotated[
        Path | None, typer.Option("--plot", help="Also save a plot (.png, .pdf, .svg).")
    ] = None,
    precision: Annotated[str, typer.Option(help="float32 (fast) or float64.")] = "float32",
    explain: Annotated[
        bool, typer.Option("--explain", help="Print the render plan before rendering.")
    ] = False,
    shadows: Annotated[
        str | None, typer.Option(help="auto or off (default: the scene's [render]).")
    ] = None,
    shadow_grid: Annotated[
        int | None, typer.Option(help="Shadow direction grid side N (N² directions).")
    ] = None,
    subsamples: Annotated[
        str | None, typer.Option(help="Sub-exposures: auto, off or a number.")
    ] = None,
):
    """Render SCENE over GEOMETRY into a light-curve table."""
    from rich.progress import Progress

    import jaxlc
    from jaxlc.plan import make_plan
    from jaxlc.render import geometry_arrays
    from jaxlc.tables import write_table

    t0 = time.perf_counter()
    sc = jaxlc.load_scene(scene)
    table = jaxlc.read_geometry(geometry)
    options = _render_options(sc, shadows, shadow_grid, subsamples)
    plan = make_plan(sc, geometry_arrays(table, sc.exposure_s), options)
    if explain:
        _console().print(plan.explain(), highlight=False)
    with Progress(console=_console(), transient=True) as bar:
        task = None

        def traced(done, total):
            nonlocal task
            if task is None:
                task = bar.add_task("tracing the shadow table (cached afterwards)", total=total)
            bar.update(task, completed=done)

        lc = jaxlc.render(sc, table, precision=precision, options=options, progress=traced)
    elapsed = time.perf_counter() - t0
    write_table(lc, output)
    if plot is not None:
        from jaxlc.plot import plot_lightcurve

        plot_lightcurve(lc, plot, title=f"{Path(sc.source).stem}: {sc.mesh_path.name}")
    vis = int(lc["visible"].sum())
    _console().print(
        f"rendered {len(lc)} samples ({vis} visible) of {sc.mesh_path.name} "
        f"({plan.triangles} triangles → {plan.facets} facets, "
        f"{'convex' if plan.convex else 'non-convex'}, "
        f"{'shadows' if plan.shadow else 'no shadows'}, {plan.subsamples} sub-exposure(s)) "
        f"in {elapsed:.2f} s, {precision} → {output}" + (f", {plot}" if plot else "")
    )


@geometry_app.command("synthetic")
def geometry_synthetic(
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Geometry table (.csv or .parquet).")
    ],
    duration_s: Annotated[float, typer.Option(help="Length of the table (s).")] = 1200.0,
    step_s: Annotated[float, typer.Option(help="Time between rows (s).")] = 1.0,
    phase_start_deg: Annotated[float, typer.Option(help="Phase angle at the start (°).")] = 20.0,
    phase_end_deg: Annotated[float, typer.Option(help="Phase angle at the end (°).")] = 120.0,
    range_km: Annotated[float, typer.Option(help="Observer distance at the start (km).")] = 1000.0,
    range_end_km: Annotated[
        float | None, typer.Option(help="Distance at the end (km); default constant.")
    ] = None,
    exposure_s: Annotated[float, typer.Option(help="Exposure time per row (s).")] = 1.0,
    start_utc: Annotated[
        str, typer.Option(help="Time of the first row (ISO 8601).")
    ] = "2019-07-07T12:00:00Z",
    sun_ra_deg: Annotated[float, typer.Option(help="Sun right ascension (°).")] = 0.0,
    sun_dec_deg: Annotated[float, typer.Option(help="Sun declination (°).")] = 0.0,
    tilt_deg: Annotated[
        float, typer.Option(help="Tilt of the observer's plane about the Sun line (°).")
    ] = 0.0,
):
    """Write a synthetic table: fixed Sun, observer sweeping a phase-angle range."""
    from jaxlc.geometry import synthetic_geometry
    from jaxlc.tables import write_table

    df = synthetic_geometry(
        duration_s=duration_s,
        step_s=step_s,
        phase_start_deg=phase_start_deg,
        phase_end_deg=phase_end_deg,
        range_start_m=range_km * 1e3,
        range_end_m=None if range_end_km is None else range_end_km * 1e3,
        exposure_s=exposure_s,
        start_utc=start_utc,
        sun_ra_deg=sun_ra_deg,
        sun_dec_deg=sun_dec_deg,
        tilt_deg=tilt_deg,
    )
    write_table(df, output)
    _console().print(
        f"wrote {len(df)} rows, phase {phase_start_deg:g}° → {phase_end_deg:g}° → {output}"
    )


# Options shared by the orbit-based commands.
SiteOpt = Annotated[str | None, typer.Option("--site", help="Registered site (see `jaxlc sites`).")]
LatOpt = Annotated[float | None, typer.Option("--lat-deg", help="Site latitude (°, north +).")]
LonOpt = Annotated[float | None, typer.Option("--lon-deg", help="Site longitude (°, east +).")]
AltOpt = Annotated[float | None, typer.Option("--alt-m", help="Site height above WGS84 (m).")]
MinElOpt = Annotated[float, typer.Option(help="Object visible above this elevation (°).")]
MaxSunOpt = Annotated[float, typer.Option(help="Sun below this elevation at the site (°).")]
MinNuOpt = Annotated[
    float, typer.Option(help="Object sunlit: Earth-shadow ν above this (0 = any sunlight).")
]
TleOpt = Annotated[
    Path, typer.Option("--tle", help="TLE file (2- or 3-line, any number of epochs).")
]
StartOpt = Annotated[str, typer.Option("--start", help="Window start, ISO 8601 UTC.")]
NoradOpt = Annotated[
    list[int] | None, typer.Option("--norad", help="Object(s) by catalogue number.")
]
NameOpt = Annotated[list[str] | None, typer.Option("--name", help="Object(s) by name.")]


def _utc(text: str, what: str = "--start"):
    import pandas as pd

    from jaxlc.errors import JaxlcError

    try:
        ts = pd.Timestamp(text)
    except (ValueError, TypeError):
        raise JaxlcError(
            f"{what} = {text!r} is not an ISO 8601 time like 2020-08-10T18:00:00Z"
        ) from None
    return ts.tz_localize("UTC") if ts.tzinfo is None else ts.tz_convert("UTC")


def _objects(tle, norad, name, start):
    from jaxlc.geometry.tle import latest_before, read_tles, select_objects

    return latest_before(select_objects(read_tles(tle), norad, name), start)


@app.command()
def sites():
    """List the registered observing sites."""
    from rich.table import Table

    from jaxlc.geometry.sites import SITES

    table = Table(title="sites (--site NAME)")
    for col in ("name", "lat (°)", "lon (°)", "alt (m)", "description"):
        table.add_column(col)
    for s in SITES.values():
        table.add_row(
            s.name, f"{s.lat_deg:.4f}", f"{s.lon_deg:.4f}", f"{s.alt_m:.0f}", s.description
        )
    _console(stderr=False).print(table)


@app.command()
def passes(
    tle: TleOpt,
    start: StartOpt,
    days: Annotated[float, typer.Option(help="Window length (days).")] = 1.0,
    site: SiteOpt = None,
    lat_deg: LatOpt = None,
    lon_deg: LonOpt = None,
    alt_m: AltOpt = None,
    norad: NoradOpt = None,
    name: NameOpt = None,
    step_s: Annotated[float, typer.Option(help="Sampling step (s); start/end accuracy.")] = 1.0,
    min_elevation_deg: MinElOpt = 15.0,
    max_sun_elevation_deg: MaxSunOpt = -6.0,
    min_shadow_nu: MinNuOpt = 0.0,
    csv: Annotated[
        Path | None, typer.Option("--csv", help="Also write the passes (.csv/.parquet).")
    ] = None,
):
    """List visible passes of the TLE file's objects (or --norad/--name) from a site."""
    from rich.progress import Progress
    from rich.table import Table

    from jaxlc.geometry.observe import Visibility, find_passes
    from jaxlc.geometry.sites import site_from
    from jaxlc.tables import write_table

    where = site_from(site, lat_deg, lon_deg, alt_m)
    t0 = _utc(start)
    rules = Visibility(min_elevation_deg, max_sun_elevation_deg, min_shadow_nu)
    objs = _objects(tle, norad, name, t0)
    with Progress(console=_console(), transient=True) as bar:
        task = bar.add_task(f"{len(objs)} object(s), {days:g} d", total=None)
        found = find_passes(
            objs,
            where,
            t0,
            days * 86400.0,
            step_s,
            rules,
            progress=lambda done, total: bar.update(task, completed=done, total=total),
        )
    if csv is not None:
        write_table(found, csv)
    if found.empty:
        _console().print(
            f"no visible passes of {len(objs)} object(s) from {where.name} in {days:g} d "
            f"after {t0:%Y-%m-%d %H:%M} UTC (elevation > {min_elevation_deg:g}°, "
            f"Sun < {max_sun_elevation_deg:g}°, sunlit)"
        )
        return
    table = Table(
        title=f"visible passes from {where.name}, {days:g} d from {t0:%Y-%m-%d %H:%M} UTC"
    )
    for col in (
        "object",
        "start (UTC)",
        "end (UTC)",
        "duration",
        "max el",
        "phase angle",
        "min range",
    ):
        table.add_column(col)
    for r in found.itertuples():
        table.add_row(
            f"{r.norad_id} {r.name}".strip(),
            r.start_utc,
            r.end_utc + (" (cut)" if r.cut_by_window else ""),
            f"{r.duration_s / 60:.1f} min",
            f"{r.max_elevation_deg:.1f}°",
            f"{r.phase_min_deg:.0f}–{r.phase_max_deg:.0f}°",
            f"{r.min_range_km:,.0f} km",
        )
    _console(stderr=False).print(table)


@geometry_app.command("pass")
def geometry_pass(
    tle: TleOpt,
    start: StartOpt,
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Geometry table (.csv or .parquet).")
    ],
    norad: NoradOpt = None,
    name: NameOpt = None,
    site: SiteOpt = None,
    lat_deg: LatOpt = None,
    lon_deg: LonOpt = None,
    alt_m: AltOpt = None,
    duration_s: Annotated[float, typer.Option(help="Window length (s).")] = 1200.0,
    step_s: Annotated[float, typer.Option(help="Time between rows (s).")] = 1.0,
    exposure_s: Annotated[float, typer.Option(help="Exposure time per row (s).")] = 1.0,
    min_elevation_deg: MinElOpt = 15.0,
    max_sun_elevation_deg: MaxSunOpt = -6.0,
    min_shadow_nu: MinNuOpt = 0.0,
):
    """Write the geometry table of one object over a window (every row; `visible` flags)."""
    from jaxlc.errors import JaxlcError
    from jaxlc.geometry.observe import Visibility, explain_invisible, geometry_table
    from jaxlc.geometry.sites import site_from
    from jaxlc.tables import write_table

    where = site_from(site, lat_deg, lon_deg, alt_m)
    t0 = _utc(start)
    objs = _objects(tle, norad, name, t0)
    if len(objs) != 1:
        labels = ", ".join(o.label for o in objs[:6])
        raise JaxlcError(
            f"{tle} holds {len(objs)} objects ({labels}…); choose one with --norad or --name"
        )
    rules = Visibility(min_elevation_deg, max_sun_elevation_deg, min_shadow_nu)
    df = geometry_table(objs[0], where, t0, duration_s, step_s, exposure_s, rules)
    write_table(df, output)
    n_vis = int(df["visible"].sum())
    if n_vis == 0:
        _console().print(f"warning: {explain_invisible(df, rules)}")
    _console().print(
        f"wrote {len(df)} rows ({n_vis} visible) of {objs[0].label} from {where.name} → {output}"
    )


def _frame_bar(description: str):
    """A rich progress bar and its callback(done, total) for Blender frames."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
    )

    bar = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=_console(),
        transient=True,
    )
    tasks = {}

    def update(done, total, key=description):
        if key not in tasks:
            tasks[key] = bar.add_task(key, total=total)
        bar.update(tasks[key], completed=done, total=total)

    return bar, update


@calibrate_app.command("render")
def calibrate_render(
    scene: Annotated[Path, typer.Argument(help="Scene file (TOML).")],
    geometry: Annotated[Path, typer.Argument(help="Geometry table (.csv or .parquet).")],
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Light-curve table (.csv or .parquet).")
    ],
    camera: Annotated[
        str, typer.Option(help="ortho (far field, no fitted constant) or seed (the paper's).")
    ] = "ortho",
    bounces: Annotated[
        int, typer.Option(help="0: direct light only; more: secondary reflections.")
    ] = 0,
    samples: Annotated[int, typer.Option(help="Cycles samples per pixel.")] = 64,
    resolution: Annotated[int, typer.Option(help="Image side in pixels.")] = 128,
    motion_blur: Annotated[
        bool,
        typer.Option("--motion-blur/--no-motion-blur", help="Blur the spin over each exposure."),
    ] = False,
    keep_images: Annotated[
        Path | None, typer.Option(help="Keep the EXR images in this folder.")
    ] = None,
    timeout_s: Annotated[
        float | None, typer.Option(help="Stop the worker after this long.")
    ] = None,
    plot: Annotated[Path | None, typer.Option("--plot", help="Also save a plot.")] = None,
):
    """Render SCENE over GEOMETRY with Blender/Cycles into a light-curve table."""
    import jaxlc
    from calibrate.job import BlenderOptions
    from calibrate.render import blender_render
    from jaxlc.tables import write_table

    t0 = time.perf_counter()
    sc = jaxlc.load_scene(scene)
    table = jaxlc.read_geometry(geometry)
    options = BlenderOptions(
        camera=camera,
        resolution=resolution,
        samples=samples,
        bounces=bounces,
        motion_blur=motion_blur,
        timeout_s=timeout_s,
        keep_images=keep_images,
    )
    bar, update = _frame_bar("Cycles")
    with bar:
        lc = blender_render(sc, table, options, progress=update)
    write_table(lc, output)
    if plot is not None:
        from jaxlc.plot import plot_lightcurve

        plot_lightcurve(lc, plot, title=f"{Path(sc.source).stem} (Cycles): {sc.mesh_path.name}")
    n = int(lc["visible"].sum())
    _console().print(
        f"rendered {n} frames with Cycles ({camera} camera, {resolution}² px, {samples} samples, "
        f"{bounces} bounces{', motion blur' if motion_blur else ''}) in "
        f"{time.perf_counter() - t0:.1f} s → {output}" + (f", {plot}" if plot else "")
    )


@calibrate_app.command("crosscheck")
def calibrate_crosscheck(
    scenes: Annotated[
        str, typer.Option(help="Scenes, comma-separated (S1…S6).")
    ] = "S1,S2,S3,S4,S5,S6",
    modes: Annotated[
        str, typer.Option(help="direct, bounces, blur (comma-separated).")
    ] = "direct,bounces,blur",
    frames: Annotated[int, typer.Option(help="Frames per scene and mode.")] = 24,
    resolution: Annotated[int, typer.Option(help="Image side in pixels.")] = 128,
    samples: Annotated[int, typer.Option(help="Cycles samples per pixel.")] = 64,
    timing: Annotated[
        bool,
        typer.Option(
            "--timing/--no-timing", help="Also time Cycles against resolution and samples."
        ),
    ] = False,
    out: Annotated[Path, typer.Option(help="Folder for the table and plots.")] = Path(
        "experiments/results/crosscheck"
    ),
):
    """Cycles against the JAX model for the standard scenes: table and plots."""
    from rich.table import Table

    from calibrate.crosscheck import MODES, SCENES, run_crosscheck, timing_sweep
    from jaxlc.errors import JaxlcError

    scene_ids = [x.strip().upper() for x in scenes.split(",") if x.strip()]
    mode_ids = [x.strip().lower() for x in modes.split(",") if x.strip()]
    bad = [x for x in scene_ids if x not in SCENES] + [m for m in mode_ids if m not in MODES]
    if bad:
        known = f"scenes {', '.join(SCENES)}, modes {', '.join(MODES)}"
        raise JaxlcError(f"unknown scene or mode {bad[0]!r}; {known}")
    bar, update = _frame_bar("crosscheck")
    with bar:
        summary, _ = run_crosscheck(
            scene_ids,
            mode_ids,
            frames,
            resolution,
            samples,
            out,
            progress=lambda s, m, d, n: update(d, n, key=f"{s} {m}"),
        )
        if timing:
            timing_sweep(out_dir=out)
    table = Table(
        title=f"Cycles − JAX, same material ({frames} frames, {resolution}² px, {samples} samples)"
    )
    for col in (
        "scene",
        "mode",
        "RMS",
        "median",
        "p95",
        "max",
        "target",
        "Cycles s/frame",
        "JAX s/frame",
        "ratio",
    ):
        table.add_column(col, justify="left" if col in ("scene", "mode") else "right")
    for r in summary.itertuples():
        target = (
            "" if r.mode != "direct" else f"≤ {r.target_rms_mag:g} {'✓' if r.meets_target else '✗'}"
        )
        table.add_row(
            r.scene,
            r.mode,
            f"{r.rms_mag:.4f}",
            f"{r.median_abs_mag:.4f}",
            f"{r.p95_abs_mag:.4f}",
            f"{r.max_abs_mag:.4f}",
            target,
            f"{r.blender_s_per_frame:.3f}",
            f"{r.jax_s_per_frame:.2e}",
            f"{r.speed_ratio:,.0f}",
        )
    _console(stderr=False).print(table)
    _console().print(f"wrote {out}/crosscheck.csv, crosscheck_frames.csv and crosscheck_S*.png")


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
    max_period_s: Annotated[float | None, typer.Option(help="Longest period searched.")] = None,
    detrend: Annotated[
        int, typer.Option(help="Degree of the slow polynomial trend removed (-1: mean only).")
    ] = 2,
):
    """Spin period of an observed light curve: Lomb–Scargle, FAP and the P vs 2P decision."""
    import json as _json

    from jaxlc.observations import observed_samples, read_observations
    from jaxlc.period import analyse_period

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
        catalogue_period_s=float(obs.attrs.get("catalogue_period_s", float("nan"))),
    )
    if plot is not None:
        from jaxlc.plot import plot_period

        plot_period(result, t, y, plot, title=None)
    summary = {"file": str(lightcurve), "column": col, **result.summary()}
    if json_out:
        print(_json.dumps(summary))
        return
    from rich.table import Table

    table = Table(title=f"period of {lightcurve.name}", show_header=False)
    for key in (
        "period_s",
        "ls_period_s",
        "ls_period_err_s",
        "harmonic_factor",
        "alternative_period_s",
        "false_alarm_probability",
        "delta_bic",
        "halves_p",
        "amplitude_mag",
        "n_samples",
        "span_s",
        "catalogue_period_s",
    ):
        v = summary[key]
        table.add_row(key, "—" if v is None else (f"{v:.6g}" if isinstance(v, float) else str(v)))
    console = _console(stderr=False)
    console.print(table)
    console.print(result.decision, highlight=False)
    if plot is not None:
        console.print(f"plot → {plot}")


@app.command()
def generate(
    config: Annotated[Path, typer.Argument(help="Dataset config (TOML).")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Dataset store (.zarr folder).")],
    workers: Annotated[
        int | None,
        typer.Option(help="Local worker processes (default: one per core; 0: in this process)."),
    ] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Address of a running Dask scheduler instead.")
    ] = None,
    count: Annotated[int | None, typer.Option(help="Number of light curves (overrides).")] = None,
    seed: Annotated[int | None, typer.Option(help="Random seed (overrides the config's).")] = None,
):
    """Render a bulk dataset (Zarr) from CONFIG; an unfinished OUTPUT is resumed."""
    from jaxlc.dataset import generate as make_dataset
    from jaxlc.dataset import load_config

    t0 = time.perf_counter()
    cfg = load_config(config)
    ds = make_dataset(cfg, output, workers=workers, scheduler=scheduler, count=count, seed=seed)
    elapsed = time.perf_counter() - t0
    n = len(ds)
    _console().print(
        f"{n} light curves × {ds.attrs['samples']} samples "
        f"({ds.attrs['n_shards']} shards, {len(ds.attrs['classes'])} shape class(es)"
        f"{', noise' if ds.attrs.get('noise') else ''}) in {elapsed:.1f} s → {output}"
    )


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
):
    """Fit the spin state (pole, period, phase, brightness, noise) to a light curve.

    Compiled solvers are kept in JAX's persistent cache ($JAXLC_XLA_CACHE,
    default ~/.cache/jaxlc/xla; "off" disables it), so later fits start faster.
    """
    import jaxlc
    from jaxlc import compile_cache
    from jaxlc.fit import fit_spin
    from jaxlc.mcmc import FitSettings

    console = _console()
    settings = FitSettings(
        n_starts=starts,
        walkers=walkers,
        max_steps=max_steps,
        min_tau=min_tau,
        mcmc_modes=mcmc_modes,
        period_s=period_s,
        min_period_s=min_period_s,
        max_period_s=max_period_s,
        seed=seed,
    )
    sc = jaxlc.load_scene(scene)
    lc = jaxlc.read_lightcurve(lightcurve)
    geo = jaxlc.read_geometry(geometry)
    compile_cache.enable()
    result = fit_spin(
        sc, lc, geo, settings, out_dir=output, log=lambda m: console.print(m, highlight=False)
    )
    iv = result["intervals"]
    d = result["diagnostics"]
    console.print(
        f"period {result['period_s']:.6g} s [90%: {iv['period_s']['p05']:.6g}, "
        f"{iv['period_s']['p95']:.6g}], pole ({result['pole_ra_deg']:.1f}°, "
        f"{result['pole_dec_deg']:.1f}°) ± {iv['pole_radius_deg']['r90']:.1f}° (90%), "
        f"{len(result['modes'])} modes; chain {d['chain_length_tau']:.0f} τ, acceptance "
        f"{d['acceptance']:.2f}; {result['timings_s']['total_s']:.1f} s → {output}",
        highlight=False,
    )
    if not d["converged"]:
        console.print(
            f"warning: chain only {d['chain_length_tau']:.0f} τ long; raise --max-steps",
            style="yellow",
        )


@app.command()
def info():
    """Versions, JAX backend and devices, precision, optional parts."""
    from jaxlc.info import print_info

    print_info()


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the CLI, turning user errors into one line and exit status 1.

    Usage errors (unknown option, missing argument) are reported by typer with
    status 2.
    """
    from jaxlc.errors import JaxlcError

    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv or os.environ.get("JAXLC_DEBUG", "") not in ("", "0")
    if not debug:  # warnings as one line each, without source locations
        warnings.showwarning = lambda message, category, *a, **k: print(
            f"warning: {message}", file=sys.stderr
        )
    try:
        app(args=argv, prog_name="jaxlc")  # standalone: always ends in SystemExit
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (JaxlcError, OSError) as exc:
        if debug:
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``jaxlc sites``, ``jaxlc passes`` and ``jaxlc geometry synthetic|pass``: geometry tables."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from jaxlc.cli.app import app, console, geometry_app


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
    from jaxlc.io.files import check_output
    from jaxlc.io.tables import write_table

    check_output(output, "table", "-o")
    check_time_range(utc_option(start_utc, "--start-utc"), duration_s, "--start-utc")
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
    console().print(
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


def utc_option(text: str, what: str = "--start"):
    from jaxlc.io.utc import utc_timestamp

    return utc_timestamp(text, what)


def check_time_range(start, duration_s: float, what: str = "--start") -> None:
    """Refuse a window outside the DE421 ephemeris (every jaxlc time lies inside it).

    Compares seconds, so that absurd durations fail here rather than overflow.
    """
    from jaxlc.errors import JaxlcError
    from jaxlc.geometry.ephemeris import EPHEMERIS_END, EPHEMERIS_START

    if start < EPHEMERIS_START or duration_s > (EPHEMERIS_END - start).total_seconds():
        raise JaxlcError(
            f"{what} {start:%Y-%m-%d %H:%M} UTC plus {duration_s:.6g} s leaves "
            f"{EPHEMERIS_START:%Y-%m-%d} … {EPHEMERIS_END:%Y-%m-%d}, the range of the shipped "
            "DE421 ephemeris; give a window inside it"
        )


def window_options(start: str, duration_s: float, step_s: float, max_samples: int):
    """The window start, after checking the window, before any other work."""
    from jaxlc.geometry.observe import check_window

    t0 = utc_option(start)
    check_window(duration_s, step_s, max_samples)
    check_time_range(t0, duration_s)
    return t0


def site_option(site, lat_deg, lon_deg, alt_m):
    """The site of --site or --lat-deg/--lon-deg/--alt-m (coordinates in --site get a hint)."""
    from jaxlc.errors import JaxlcError
    from jaxlc.geometry.sites import SITES, site_from

    if site is not None and site.strip().lower() not in SITES and "," in site:
        raise JaxlcError(
            f"--site {site!r} is not a registered site (see `jaxlc sites`); give coordinates "
            "as --lat-deg LAT --lon-deg LON --alt-m HEIGHT (degrees, metres)"
        )
    return site_from(site, lat_deg, lon_deg, alt_m)


def tle_objects(tle, norad, name, start, one: bool = False):
    """One element set per selected object (``one``: exactly one object), for ``start``."""
    from jaxlc.errors import JaxlcError
    from jaxlc.geometry.tle import latest_before, read_tles, select_objects

    chosen = select_objects(read_tles(tle), norad, name)
    labels = list(dict.fromkeys(t.label for t in chosen))
    if one and len(labels) != 1:
        more = "…" if len(labels) > 6 else ""
        raise JaxlcError(
            f"{tle} holds {len(labels)} objects ({', '.join(labels[:6])}{more}); "
            "choose one with --norad or --name"
        )
    return latest_before(chosen, start)


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
    console(stderr=False).print(table)


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
    """List visible passes of the TLE file's objects (or --norad/--name) from a site.

    Passes whose TLE epoch is more than 14 days from the pass start are marked
    stale (SGP4 errors grow by ~1–3 km per day).
    """
    import math

    from rich.progress import Progress
    from rich.table import Table

    from jaxlc.errors import JaxlcError
    from jaxlc.geometry.observe import MAX_SEARCH_SAMPLES, Visibility, find_passes
    from jaxlc.geometry.tle import STALE_EPOCH_DAYS
    from jaxlc.io.files import check_output
    from jaxlc.io.tables import write_table

    check_output(csv, "table", "--csv")
    if not (math.isfinite(days) and days > 0):
        raise JaxlcError(f"--days {days!r} must be > 0 (the window length in days, e.g. 1)")
    where = site_option(site, lat_deg, lon_deg, alt_m)
    t0 = window_options(start, days * 86400.0, step_s, MAX_SEARCH_SAMPLES)
    rules = Visibility(min_elevation_deg, max_sun_elevation_deg, min_shadow_nu)
    objs = tle_objects(tle, norad, name, t0)
    with Progress(console=console(), transient=True) as bar:
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
        console().print(
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
        "TLE age",
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
            f"{r.tle_age_days:.1f} d" + (" STALE" if r.stale else ""),
        )
    console(stderr=False).print(table)
    n_stale = int(found["stale"].sum())
    if n_stale:
        console().print(
            f"warning: {n_stale} of {len(found)} passes use a TLE more than "
            f"{STALE_EPOCH_DAYS:g} days from its epoch (marked STALE; SGP4 errors grow by "
            "~1–3 km per day): get element sets nearer the window, or drop those objects",
            markup=False,
            soft_wrap=True,
        )


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
    from jaxlc.geometry.observe import (
        MAX_TABLE_ROWS,
        Visibility,
        explain_invisible,
        geometry_table,
    )
    from jaxlc.io.files import check_output
    from jaxlc.io.tables import write_table

    check_output(output, "table", "-o")
    where = site_option(site, lat_deg, lon_deg, alt_m)
    t0 = window_options(start, duration_s, step_s, MAX_TABLE_ROWS)
    rules = Visibility(min_elevation_deg, max_sun_elevation_deg, min_shadow_nu)
    objs = tle_objects(tle, norad, name, t0, one=True)
    df = geometry_table(objs[0], where, t0, duration_s, step_s, exposure_s, rules)
    write_table(df, output)
    n_vis = int(df["visible"].sum())
    if n_vis == 0:
        console().print(f"warning: {explain_invisible(df, rules)}")
    console().print(
        f"wrote {len(df)} rows ({n_vis} visible) of {objs[0].label} from {where.name} → {output}"
    )

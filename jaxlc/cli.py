"""Command line: ``jaxlc render``, ``jaxlc geometry synthetic``, ``jaxlc info``.

A wrong input exits with status 1 and one line on stderr (``error: …``); add
``--debug`` (before the command) or set ``JAXLC_DEBUG=1`` for the traceback.
"""

from __future__ import annotations

import os
import sys
import time
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


def _console():
    from rich.console import Console

    return Console(stderr=True)


@app.callback()
def _root(
    debug: Annotated[bool, typer.Option("--debug", help="Show tracebacks of errors.")] = False,
):
    """jaxlc: scene + geometry → light curve."""


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
):
    """Render SCENE over GEOMETRY into a light-curve table."""
    import jaxlc
    from jaxlc.tables import write_table

    t0 = time.perf_counter()
    sc = jaxlc.load_scene(scene)
    table = jaxlc.read_geometry(geometry)
    lc = jaxlc.render(sc, table, precision=precision)
    elapsed = time.perf_counter() - t0
    write_table(lc, output)
    if plot is not None:
        from jaxlc.plot import plot_lightcurve

        plot_lightcurve(lc, plot, title=f"{Path(sc.source).stem}: {sc.mesh_path.name}")
    f = sc.facets
    vis = int(lc["visible"].sum())
    _console().print(
        f"rendered {len(lc)} samples ({vis} visible) of {sc.mesh_path.name} "
        f"({f.n_triangles} triangles → {f.n_facets} facets, "
        f"{'convex' if f.convex else 'non-convex'}) in {elapsed:.2f} s, {precision} → {output}"
        + (f", {plot}" if plot else "")
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

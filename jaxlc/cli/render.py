"""``jaxlc render``: scene + geometry table → light-curve table (and plot)."""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Annotated

import typer

from jaxlc.cli.app import app, console


def render_options(scene, shadows, shadow_grid, subsamples, shadow_exact=None):
    """The scene's [render] options with the command line's overrides."""
    import dataclasses

    from jaxlc.errors import JaxlcError

    opts = scene.render
    if shadows is not None:
        opts = dataclasses.replace(opts, shadows=shadows)
    if shadow_grid is not None:
        opts = dataclasses.replace(opts, shadow=dataclasses.replace(opts.shadow, grid=shadow_grid))
    if shadow_exact is not None:
        try:
            opts = dataclasses.replace(opts, shadow_exact=shadow_exact)
        except JaxlcError as exc:
            raise JaxlcError(f"--shadow-exact: {exc}") from None
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
    shadow_exact: Annotated[
        str | None,
        typer.Option(help="glints (clip bright shadowed terms exactly; slower) or off."),
    ] = None,
):
    """Render SCENE over GEOMETRY into a light-curve table."""
    from rich.progress import Progress

    import jaxlc
    from jaxlc.io.files import atomic_outputs, check_output
    from jaxlc.io.tables import write_table
    from jaxlc.rendering.observation import geometry_arrays
    from jaxlc.rendering.plan import make_plan

    check_output(output, "table", "-o")
    check_output(plot, "plot", "--plot")
    t0 = time.perf_counter()
    sc = jaxlc.load_scene(scene)
    table = jaxlc.read_geometry(geometry)
    options = render_options(sc, shadows, shadow_grid, subsamples, shadow_exact)
    # The plan alone first, so that --explain shows before a shadow table is traced.
    plan = make_plan(sc, geometry_arrays(table, sc.exposure_s), options)
    if explain:
        console().print(plan.explain(), highlight=False)
    with Progress(console=console(), transient=True) as bar:
        task = None

        def traced(done, total):
            nonlocal task
            if task is None:
                task = bar.add_task("tracing the shadow table (cached afterwards)", total=total)
            bar.update(task, completed=done)

        lc = jaxlc.render(sc, table, precision=precision, options=options, progress=traced)
    elapsed = time.perf_counter() - t0
    with atomic_outputs(output, plot) as (table_tmp, plot_tmp):
        write_table(lc, table_tmp)
        if plot is not None:
            from jaxlc.plot import plot_lightcurve

            plot_lightcurve(lc, plot_tmp, title=f"{Path(sc.source).stem}: {sc.mesh_path.name}")
    vis = int(lc["visible"].sum())
    blur = f"{plan.subsamples} sub-exposure(s)"
    found = re.search(r"[\d.]+ instants per exposure", lc.attrs.get("plan", ""))
    if plan.blur.adaptive and found:
        blur = f"adaptive blur, {found.group(0)}"
    console().print(
        f"rendered {len(lc)} samples ({vis} visible) of {sc.mesh_path.name} "
        f"({plan.triangles} triangles → {plan.facets} facets, "
        f"{'convex' if plan.convex else 'non-convex'}, "
        f"{'shadows' if plan.shadow else 'no shadows'}, {blur}) "
        f"in {elapsed:.2f} s, {precision} → {output}" + (f", {plot}" if plot else "")
    )

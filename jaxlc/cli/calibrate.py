"""``jaxlc calibrate render|crosscheck``: the Blender/Cycles reference (``.venv-blender``)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from jaxlc.cli.app import calibrate_app, console


def frame_bar(description: str):
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
        console=console(),
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
    from jaxlc.io.files import atomic_outputs, check_output
    from jaxlc.io.tables import write_table

    check_output(output, "table", "-o")
    check_output(plot, "plot", "--plot")
    check_output(keep_images, "folder", "--keep-images")
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
    bar, update = frame_bar("Cycles")
    with bar:
        lc = blender_render(sc, table, options, progress=update)
    with atomic_outputs(output, plot) as (table_tmp, plot_tmp):
        write_table(lc, table_tmp)
        if plot is not None:
            from jaxlc.plot import plot_lightcurve

            title = f"{Path(sc.source).stem} (Cycles): {sc.mesh_path.name}"
            plot_lightcurve(lc, plot_tmp, title=title)
    n = int(lc["visible"].sum())
    console().print(
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
    out: Annotated[
        Path,
        typer.Option(
            help="Folder for the table and plots (the committed results live in "
            "experiments/results/crosscheck; write there only on purpose)."
        ),
    ] = Path("build/crosscheck"),
    material: Annotated[
        str,
        typer.Option(
            help="matched: every material in its Cycles-exact form, modes direct, bounces, "
            "blur; as: the scenes' own materials (exact BRDF with Cycles' visibility) and "
            "Cycles' bounces, per phase-angle bin, over S1–S8."
        ),
    ] = "matched",
    visibility_resolution: Annotated[
        int, typer.Option(help="Image side of the visibility renders (--material as).")
    ] = 512,
):
    """Cycles against the JAX model for the standard scenes: table and plots."""
    from rich.table import Table

    from calibrate.crosscheck import MODES, SCENES, run_crosscheck, timing_sweep
    from jaxlc.errors import JaxlcError
    from jaxlc.io.files import check_output

    check_output(out, "folder", "--out")
    if material not in ("matched", "as"):
        raise JaxlcError(f"--material {material!r} must be 'matched' or 'as'")
    if material == "as":
        return _as_crosscheck(scenes, frames, resolution, samples, visibility_resolution, out)
    scene_ids = [x.strip().upper() for x in scenes.split(",") if x.strip()]
    mode_ids = [x.strip().lower() for x in modes.split(",") if x.strip()]
    bad = [x for x in scene_ids if x not in SCENES] + [m for m in mode_ids if m not in MODES]
    if bad:
        known = f"scenes {', '.join(SCENES)}, modes {', '.join(MODES)}"
        raise JaxlcError(f"unknown scene or mode {bad[0]!r}; {known}")
    bar, update = frame_bar("crosscheck")
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
    console(stderr=False).print(table)
    console().print(f"wrote {out}/crosscheck.csv, crosscheck_frames.csv and crosscheck_S*.png")


def _as_crosscheck(scenes: str, frames, resolution, samples, visibility_resolution, out) -> None:
    """``crosscheck --material as``: the table of :mod:`calibrate.as_crosscheck`."""
    from rich.table import Table

    from calibrate.as_crosscheck import AS_SCENES, run_as_crosscheck
    from jaxlc.errors import JaxlcError

    ids = [x.strip().upper() for x in scenes.split(",") if x.strip()]
    if ids == ["S1", "S2", "S3", "S4", "S5", "S6"]:  # the option's default: all of them
        ids = list(AS_SCENES)
    bad = [x for x in ids if x not in AS_SCENES]
    if bad:
        raise JaxlcError(f"unknown scene {bad[0]!r}; scenes {', '.join(AS_SCENES)}")
    bar, update = frame_bar("crosscheck (as)")
    with bar:
        summary, _ = run_as_crosscheck(
            ids,
            frames,
            visibility_resolution,
            resolution,
            samples,
            out,
            progress=lambda s, m, d, n: update(d, n, key=f"{s} {m}"),
        )
    table = Table(title=f"|Δm| per scene and phase-angle bin ({frames} frames)")
    for col in ("scene", "comparison", "phase", "frames", "median", "p95", "max", "RMS"):
        table.add_column(col, justify="left" if col in ("scene", "comparison") else "right")
    for r in summary.itertuples():
        if r.frames == 0:
            continue
        mark = "" if r.meets_target is None else (" ✓" if r.meets_target else " ✗")
        table.add_row(
            r.scene,
            r.comparison,
            r.phase_bin,
            str(r.frames),
            f"{r.median_abs_mag:.4f}",
            f"{r.p95_abs_mag:.4f}",
            f"{r.max_abs_mag:.4f}",
            f"{r.rms_mag:.4f}{mark}",
        )
    console(stderr=False).print(table)
    console().print(f"wrote {out}/as_crosscheck.csv, as_crosscheck_frames.csv, as_crosscheck.png")

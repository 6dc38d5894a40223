"""``jaxlc frames`` (light curve → FITS frames) and ``jaxlc extract`` (frames → light curves)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from jaxlc.cli.app import app, console


def _progress(label: str):
    from rich.progress import Progress

    bar = Progress(console=console(), transient=True)
    task = bar.add_task(label, total=None)

    def update(done, total):
        bar.update(task, completed=done, total=total)

    return bar, update


@app.command()
def frames(
    scene: Annotated[Path, typer.Argument(help="Scene file (TOML).")],
    geometry: Annotated[Path, typer.Argument(help="Geometry table (.csv or .parquet).")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Folder for the FITS frames.")],
    catalog: Annotated[
        Path | None,
        typer.Option(help="Star table (ra_deg, dec_deg, mag); default the shipped Hipparcos."),
    ] = None,
    width_px: Annotated[int, typer.Option(help="Frame width (pixels).")] = 1024,
    height_px: Annotated[int, typer.Option(help="Frame height (pixels).")] = 1024,
    pixel_scale_arcsec: Annotated[float, typer.Option(help="Pixel scale (arcsec/px).")] = 10.0,
    fwhm_px: Annotated[float, typer.Option(help="PSF FWHM (pixels).")] = 2.5,
    sky_mag_arcsec2: Annotated[float, typer.Option(help="Sky (mag/arcsec²).")] = 20.5,
    read_noise_e: Annotated[float, typer.Option(help="Read noise (e⁻).")] = 8.0,
    gain: Annotated[float, typer.Option(help="Gain (e⁻/ADU).")] = 2.0,
    dark_e_per_s: Annotated[float, typer.Option(help="Dark current (e⁻/s/px).")] = 0.5,
    zero_point: Annotated[float, typer.Option(help="Magnitude giving 1 e⁻/s.")] = 20.0,
    readout_s: Annotated[
        float, typer.Option(help="Readout dead time; exposures are shortened to fit (s).")
    ] = 0.0,
    seed: Annotated[int, typer.Option(help="Noise seed.")] = 0,
):
    """Render SCENE over GEOMETRY and write one FITS frame per exposure into OUTPUT/."""
    import numpy as np

    import jaxlc
    from jaxlc.imaging import Sensor, load_catalog, simulate_frames
    from jaxlc.io.files import check_output

    check_output(output, "folder", "-o")
    t0 = time.perf_counter()
    sensor = Sensor(
        width_px=width_px, height_px=height_px, pixel_scale_arcsec=pixel_scale_arcsec,
        psf_fwhm_px=fwhm_px, sky_mag_arcsec2=sky_mag_arcsec2, read_noise_e=read_noise_e,
        gain_e_per_adu=gain, dark_e_per_s=dark_e_per_s, zero_point_mag=zero_point,
        readout_s=readout_s,
    )  # fmt: skip
    stars = load_catalog(catalog)
    sc = jaxlc.load_scene(scene)
    table = jaxlc.read_geometry(geometry)
    if readout_s > 0 and len(table) > 1:
        t = table["t_s"].to_numpy(float)
        room = np.append(np.diff(t) - readout_s, np.inf)
        exposure = table["exposure_s"].to_numpy(float)
        if (exposure > room + 1e-9).any():
            if (room <= 0).any():
                raise jaxlc.JaxlcError(
                    f"--readout-s {readout_s:g} is not shorter than the cadence "
                    f"({np.diff(t).min():g} s); lower it or use a sparser geometry table"
                )
            console().print(f"exposures shortened to ≤ cadence − readout ({room.min():g} s)")
            table["exposure_s"] = np.minimum(exposure, room)
    lc = jaxlc.render(sc, table)
    bar, update = _progress("writing frames")
    with bar:
        index = simulate_frames(lc, table, output, sensor, stars, seed, sc.mesh_path.stem, update)
    console().print(
        f"wrote {len(index)} frames ({width_px}×{height_px} px, {pixel_scale_arcsec:g}″/px, "
        f"median {int(index['n_stars'].median())} stars) of {sc.mesh_path.name} in "
        f"{time.perf_counter() - t0:.1f} s → {output}/ (injected curve: {output}/frames.csv)"
    )


@app.command()
def extract(
    frames_dir: Annotated[Path, typer.Argument(help="Folder of FITS frames (or one file).")],
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Light-curve table (.csv or .parquet).")
    ],
    catalog: Annotated[
        Path | None,
        typer.Option(help="Star table (ra_deg, dec_deg, mag); default the shipped Hipparcos."),
    ] = None,
    zero_point: Annotated[
        float | None, typer.Option(help="A fixed zero point instead of one from stars (mag).")
    ] = None,
    fwhm_px: Annotated[
        float, typer.Option(help="PSF FWHM when the header has no PSF_FWHM (px).")
    ] = 2.5,
    snr: Annotated[float, typer.Option(help="Detection threshold (matched-filter S/N).")] = 5.0,
    exptime_key: Annotated[str, typer.Option(help="Header keyword of the exposure (s).")] = (
        "EXPTIME"
    ),
    date_key: Annotated[str, typer.Option(help="Header keyword of the UTC start.")] = "DATE-OBS",
    gain_key: Annotated[str, typer.Option(help="Header keyword of the gain (e⁻/ADU).")] = "GAIN",
    plot: Annotated[
        Path | None, typer.Option("--plot", help="Extracted light curve(s) (.png).")
    ] = None,
    frame_plot: Annotated[
        Path | None, typer.Option("--frame-plot", help="The first frame with its detections.")
    ] = None,
):
    """Extract light curves from rate-tracked FITS frames (one table per object)."""

    from jaxlc.imaging import HeaderKeys, extract_lightcurves, load_catalog
    from jaxlc.imaging.detect import DetectSettings
    from jaxlc.imaging.extract import ExtractSettings
    from jaxlc.io.files import atomic_outputs, check_output
    from jaxlc.io.tables import write_table

    check_output(output, "table", "-o")
    check_output(plot, "plot", "--plot")
    check_output(frame_plot, "plot", "--frame-plot")
    t0 = time.perf_counter()
    stars = None if zero_point is not None and catalog is None else load_catalog(catalog)
    keys = HeaderKeys(exptime=exptime_key, date_obs=date_key, gain=gain_key)
    settings = ExtractSettings(
        fwhm_px=fwhm_px, zero_point=zero_point, detect=DetectSettings(snr=snr)
    )
    bar, update = _progress("extracting")
    with bar:
        curves, log = extract_lightcurves(frames_dir, stars, settings, keys, update)
    elapsed = time.perf_counter() - t0
    for _, row in log[log["note"] != ""].head(20).iterrows():
        console().print(f"{row['file']}: unusable: {row['note']}", highlight=False)
    if not curves:
        from jaxlc.errors import JaxlcError

        raise JaxlcError(
            f"no object found in {len(log)} frames (a point source that is not a catalogue star, "
            f"seen in ≥ {settings.min_frames} frames); lower --snr or check --fwhm-px"
        )
    outputs = [output] + [
        output.with_name(f"{output.stem}_{k + 1}{output.suffix}") for k in range(1, len(curves))
    ]
    with atomic_outputs(*outputs, plot, frame_plot) as tmps:
        for lc, tmp in zip(curves, tmps, strict=False):
            write_table(lc, tmp)
        if plot is not None:
            from jaxlc.imaging.plots import plot_extracted

            plot_extracted(curves, tmps[len(curves)])
        if frame_plot is not None:
            from jaxlc.imaging.fitsframe import read_frame
            from jaxlc.imaging.plots import plot_frame

            folder = frames_dir if frames_dir.is_dir() else frames_dir.parent
            first = read_frame(folder / log["file"].iloc[0], keys)
            plot_frame(first, stars, settings, tmps[len(curves) + 1])
    for k, (lc, path) in enumerate(zip(curves, outputs, strict=True)):
        lost = lc.loc[~lc["visible"], "note"].value_counts()
        why = "; ".join(f"{n} {note}" for note, n in lost.items())
        console().print(
            f"object {k + 1} near ({lc['x_px'].median():.0f}, {lc['y_px'].median():.0f}) px: "
            f"{int(lc['visible'].sum())}/{len(lc)} frames measured"
            + (f" (not: {why})" if why else "")
            + f" → {path}",
            highlight=False,
        )
    console().print(
        f"extracted {len(curves)} object(s) from {len(log)} frames in {elapsed:.1f} s "
        f"({1e3 * elapsed / len(log):.0f} ms/frame)" + (f", plot {plot}" if plot else ""),
        highlight=False,
    )

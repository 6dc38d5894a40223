"""A light curve over a pass → one FITS frame per exposure of a rate-tracked sensor.

The telescope follows the object, so the object stays at the detector centre
as a PSF of the exposure's mean flux (the light curve's ``mag``, blur included)
and the stars streak opposite to the object's apparent motion. Each frame
carries a TAN WCS valid at mid-exposure (the object's topocentric direction
then at the centre), ``DATE-OBS`` (UTC start) and ``EXPTIME``; noise is
Poisson (object, stars, sky, dark) plus Gaussian read noise, then gain, bias,
rounding and 16-bit saturation. A ``frames.csv`` beside the frames lists what
was injected.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.errors import JaxlcError
from jaxlc.imaging.catalog import load_catalog, stars_near
from jaxlc.imaging.draw import add_path
from jaxlc.imaging.sensor import Sensor, tangent_wcs
from jaxlc.io.tables import float_column, write_table

#: Straight pieces per star streak (even: the middle point is mid-exposure).
STREAK_SEGMENTS = 4
INDEX_NAME = "frames.csv"


def object_radec(geometry: pd.DataFrame, times_s) -> tuple[np.ndarray, np.ndarray]:
    """The object's topocentric direction (ICRS-aligned GCRS RA, Dec in degrees) at ``times_s``.

    The observer-to-object vectors of the table's rows are interpolated with a
    cubic spline in time (linear for two rows, constant for one).
    """
    from scipy.interpolate import make_interp_spline

    t = float_column(geometry, "t_s")
    rel = np.stack(
        [
            float_column(geometry, f"rso_{a}_m") - float_column(geometry, f"obs_{a}_m")
            for a in "xyz"
        ],
        axis=-1,
    )
    times_s = np.asarray(times_s, dtype=np.float64)
    if len(t) == 1:
        vec = np.broadcast_to(rel[0], (*times_s.shape, 3))
    else:
        vec = make_interp_spline(t, rel, k=min(3, len(t) - 1))(times_s)
    ra = np.degrees(np.arctan2(vec[..., 1], vec[..., 0])) % 360.0
    dec = np.degrees(np.arcsin(vec[..., 2] / np.linalg.norm(vec, axis=-1)))
    return ra, dec


def observable_rows(lightcurve: pd.DataFrame, geometry: pd.DataFrame) -> np.ndarray:
    """Rows a telescope would expose: object above the horizon, Sun below −6°.

    The object need not be sunlit (an eclipsed object gives a frame without it).
    Rows without elevations (synthetic geometry: NaN or no column) are kept.
    """
    ok = np.ones(len(lightcurve), dtype=bool)
    for column, test in (("elevation_deg", np.greater), ("sun_elevation_deg", np.less)):
        if column in geometry.columns:
            value = float_column(geometry, column)
            ok &= ~np.isfinite(value) | test(value, 0.0 if column == "elevation_deg" else -6.0)
    return ok


def check_exposures(t_s: np.ndarray, exposure_s: np.ndarray, readout_s: float) -> None:
    """Refuse exposures that overlap the next one's start (with the readout dead time)."""
    if len(t_s) < 2:
        return
    late = t_s[:-1] + exposure_s[:-1] + readout_s - t_s[1:] > 1e-6
    if late.any():
        i = int(np.flatnonzero(late)[0])
        raise JaxlcError(
            f"exposure of row {i + 1} ({exposure_s[i]:g} s) plus readout ({readout_s:g} s) runs "
            f"past the next exposure's start ({t_s[i + 1] - t_s[i]:g} s later); shorten the "
            "exposures (geometry --exposure-s) or lower --readout-s"
        )


def frame_image(sensor, wcs, stars, path_px, flux_e, exposure_s, rng):
    """One noisy 16-bit frame.

    Args:
        sensor: the :class:`Sensor`.
        wcs: the frame's mid-exposure WCS (object at the centre).
        stars: catalogue rows near the field.
        path_px: (K+1, 2) the object's mid-WCS pixel positions over the exposure.
        flux_e: the object's electrons in this exposure.
        exposure_s: exposure (s).
        rng: numpy Generator.

    Returns:
        (H, W) uint16 ADU and the number of stars drawn.
    """
    shape = (sensor.height_px, sensor.width_px)
    sigma = sensor.psf_sigma_px
    expected = np.full(shape, (sensor.sky_e_per_s_px + sensor.dark_e_per_s) * exposure_s)
    cx, cy = sensor.centre_px
    add_path(expected, np.array([cx]), np.array([cy]), flux_e, sigma)
    px, py = wcs.wcs_world2pix(stars["ra_deg"].to_numpy(), stars["dec_deg"].to_numpy(), 0)
    shift = path_px - path_px[len(path_px) // 2]
    star_e = sensor.electron_rate(stars["mag"].to_numpy()) * exposure_s
    drawn = 0
    margin = 6.0 * sigma
    for x, y, e in zip(px, py, star_e, strict=True):
        xs, ys = x - shift[:, 0], y - shift[:, 1]
        if xs.max() < -margin or ys.max() < -margin:
            continue
        if xs.min() > shape[1] + margin or ys.min() > shape[0] + margin:
            continue
        add_path(expected, xs, ys, e, sigma)
        drawn += 1
    electrons = rng.poisson(expected).astype(np.float64)
    electrons += rng.normal(0.0, sensor.read_noise_e, shape)
    adu = np.round(electrons / sensor.gain_e_per_adu + sensor.bias_adu)
    return np.clip(adu, 0, sensor.saturation_adu).astype(np.uint16), drawn


def frame_header(sensor, wcs, utc: str, exposure_s: float, name: str):
    """The FITS header: WCS at mid-exposure, DATE-OBS (start, UTC), EXPTIME and the sensor."""
    header = wcs.to_header()
    header["DATE-OBS"] = (utc, "UTC start of exposure")
    header["EXPTIME"] = (float(exposure_s), "[s] exposure time")
    header["GAIN"] = (sensor.gain_e_per_adu, "[e-/ADU]")
    header["RDNOISE"] = (sensor.read_noise_e, "[e-] read noise")
    header["SATURATE"] = (sensor.saturation_adu, "[ADU] saturation level")
    header["PSF_FWHM"] = (sensor.psf_fwhm_px, "[px] PSF FWHM")
    header["PIXSCALE"] = (sensor.pixel_scale_arcsec, "[arcsec/px]")
    header["BUNIT"] = "ADU"
    header["OBJECT"] = name
    header["ORIGIN"] = "jaxlc frames"
    return header


def simulate_frames(
    lightcurve: pd.DataFrame,
    geometry: pd.DataFrame,
    out_dir: str | Path,
    sensor: Sensor | None = None,
    stars: pd.DataFrame | None = None,
    seed: int = 0,
    name: str = "",
    progress: Callable[[int, int], None] | None = None,
) -> pd.DataFrame:
    """Write one FITS frame per observable exposure of ``lightcurve`` into ``out_dir``.

    Args:
        lightcurve: the light-curve table rendered over ``geometry`` (same rows).
        geometry: the geometry table (GCRS positions; ``utc`` = exposure start).
        out_dir: folder for ``frame_NNNNN.fits`` and ``frames.csv`` (made if
            missing; must not already hold frames).
        sensor: the :class:`Sensor` (default: the class defaults).
        stars: catalogue (:func:`load_catalog`; default the shipped Hipparcos).
        seed: noise seed (frame i uses ``[seed, i]``).
        name: the object's name for the OBJECT keyword.
        progress: ``progress(done, total)`` after each frame.

    Returns:
        The index written as ``frames.csv``: file, utc, t_s, exposure_s,
        mag (injected; NaN when the object is eclipsed), x_px, y_px, n_stars.
    """
    from astropy.io import fits

    sensor = sensor or Sensor()
    stars = load_catalog() if stars is None else stars
    if len(lightcurve) != len(geometry):
        raise JaxlcError(
            f"the light curve has {len(lightcurve)} rows but the geometry {len(geometry)}; "
            "render the light curve over this geometry table"
        )
    out_dir = Path(out_dir)
    if out_dir.is_dir() and any(out_dir.glob("*.fits")):
        raise JaxlcError(f"{out_dir} already holds FITS frames; give an empty or new folder")
    out_dir.mkdir(parents=True, exist_ok=True)
    t_s = float_column(lightcurve, "t_s")
    exposure = float_column(lightcurve, "exposure_s")
    check_exposures(t_s, exposure, sensor.readout_s)
    rows = np.flatnonzero(observable_rows(lightcurve, geometry))
    if len(rows) == 0:
        raise JaxlcError("no row is observable (object above the horizon, Sun below −6°)")
    mags = np.where(lightcurve["visible"].to_numpy(bool), lightcurve["mag"].to_numpy(float), np.nan)
    k = STREAK_SEGMENTS
    records = []
    for done, i in enumerate(rows):
        times = t_s[i] + exposure[i] * np.linspace(0.0, 1.0, k + 1)
        ra, dec = object_radec(geometry, times)
        mid = len(times) // 2
        wcs = tangent_wcs(sensor, ra[mid], dec[mid])
        path_px = np.stack(wcs.wcs_world2pix(ra, dec, 0), axis=-1)
        motion_deg = float(np.abs(path_px - path_px[mid]).max()) * sensor.pixel_scale_deg
        near = stars_near(stars, ra[mid], dec[mid], sensor.half_diagonal_deg + motion_deg + 0.05)
        flux_e = 0.0 if not np.isfinite(mags[i]) else float(sensor.electron_rate(mags[i]))
        rng = np.random.default_rng([seed, int(i)])
        adu, drawn = frame_image(sensor, wcs, near, path_px, flux_e * exposure[i], exposure[i], rng)
        utc = pd.Timestamp(lightcurve["utc"].iloc[i]).strftime("%Y-%m-%dT%H:%M:%S.%f")
        header = frame_header(sensor, wcs, utc, exposure[i], name)
        file = f"frame_{i:05d}.fits"
        tmp = out_dir / f".{file}.{os.getpid()}.part"
        fits.PrimaryHDU(data=adu, header=header).writeto(tmp, overwrite=True)
        os.replace(tmp, out_dir / file)
        cx, cy = sensor.centre_px
        records.append((file, utc, t_s[i], exposure[i], mags[i], cx, cy, drawn))
        if progress is not None:
            progress(done + 1, len(rows))
    index = pd.DataFrame(
        records, columns=["file", "utc", "t_s", "exposure_s", "mag", "x_px", "y_px", "n_stars"]
    )
    index.attrs["sensor"] = repr(sensor)
    write_table(index, out_dir / INDEX_NAME)
    return index

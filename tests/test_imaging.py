"""Telescope frames from light curves and back (issue 18): jaxlc frames / jaxlc extract.

References are independent of the pipeline: the injected light curve and the
sensor's own zero point (10**(-0.4 (m − ZP)) e⁻/s, divided by the gain),
flux conservation of the drawn PSF, the Hipparcos position of Sirius.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pandas as pd
import pytest

import jaxlc
from jaxlc.errors import JaxlcError
from jaxlc.imaging import Sensor, extract_lightcurves, load_catalog, simulate_frames
from jaxlc.imaging.catalog import unit_vector
from jaxlc.imaging.draw import add_streak
from jaxlc.imaging.extract import measure_frame
from jaxlc.imaging.fitsframe import read_frame
from jaxlc.imaging.frames import object_radec

SENSOR = Sensor(width_px=512, height_px=512, pixel_scale_arcsec=20.0)
#: Instrument zero point in ADU/s implied by the sensor (the value extraction must find).
TRUE_ZP = SENSOR.zero_point_mag - 2.5 * math.log10(SENSOR.gain_e_per_adu)


def leo_geometry(n=60, range_m=8e5):
    """A LEO-like pass (0.77°/s across the sky), 1 s exposures back to back."""
    return jaxlc.synthetic_geometry(
        duration_s=n, step_s=1, phase_start_deg=30, phase_end_deg=60, range_start_m=range_m,
        range_end_m=range_m,
    )  # fmt: skip


def random_stars(geo, path, per_deg2=4.0, bright=(), seed=1):
    """A random star table (V 6–9.5) around the pass, plus ``bright`` extra magnitudes."""
    rng = np.random.default_rng(seed)
    ra, dec = object_radec(geo, geo["t_s"].to_numpy())
    centre = unit_vector(ra, dec).mean(axis=0)
    centre /= np.linalg.norm(centre)
    cap_deg = 30.0
    n = int(per_deg2 * 2 * np.pi * (1 - np.cos(np.radians(cap_deg))) * (180 / np.pi) ** 2)
    v = rng.normal(size=(4 * n, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    v = v[v @ centre > np.cos(np.radians(cap_deg))][:n]
    mags = rng.uniform(6.0, 9.5, len(v))
    if len(bright):  # bright stars a little off the object's track
        extra = np.stack([unit_vector(ra[k * 7 + 3], dec[k * 7 + 3]) for k in range(len(bright))])
        v = np.concatenate([v, extra + 0.004])
        mags = np.concatenate([mags, bright])
    v /= np.linalg.norm(v, axis=1)[:, None]
    stars = pd.DataFrame({
        "ra_deg": np.degrees(np.arctan2(v[:, 1], v[:, 0])) % 360,
        "dec_deg": np.degrees(np.arcsin(v[:, 2])), "mag": mags,
    })  # fmt: skip
    stars.to_csv(path, index=False)
    return load_catalog(path)


def sine_curve(geo, mean=7.5, amp=0.5, visible=None):
    return pd.DataFrame({
        "utc": geo["utc"], "t_s": geo["t_s"], "mag": mean + amp * np.sin(geo["t_s"] / 5.0),
        "exposure_s": geo["exposure_s"], "visible": True if visible is None else visible,
    })  # fmt: skip


@pytest.fixture(scope="module")
def roundtrip(tmp_path_factory):
    """60 frames of a sine curve with a second object added to every frame."""
    from astropy.io import fits

    tmp = tmp_path_factory.mktemp("frames")
    geo = leo_geometry(60)
    stars = random_stars(geo, tmp / "stars.csv", bright=(1.0, 1.5))
    visible = np.ones(len(geo), dtype=bool)
    visible[40:44] = False  # eclipsed: frames without the object
    lc = sine_curve(geo, visible=visible)
    index = simulate_frames(lc, geo, tmp / "frames", SENSOR, stars, seed=3)
    rng = np.random.default_rng(9)
    second_mag = 8.0
    for f in index["file"]:  # a second object, fixed on the detector
        with fits.open(tmp / "frames" / f, mode="update") as hdul:
            extra = np.zeros(hdul[0].data.shape)
            add_streak(extra, 100.0, 400.0, 100.0, 400.0, float(SENSOR.electron_rate(second_mag)),
                       SENSOR.psf_sigma_px)  # fmt: skip
            adu = hdul[0].data.astype(float) + rng.poisson(extra) / SENSOR.gain_e_per_adu
            hdul[0].data = np.clip(np.round(adu), 0, 65535).astype(np.uint16)
    curves, log = extract_lightcurves(tmp / "frames", stars)
    return dict(tmp=tmp, stars=stars, index=index, curves=curves, log=log, second=second_mag)


def test_extracted_magnitudes_match_injected_within_ccd_errors(roundtrip):
    index, curves = roundtrip["index"], roundtrip["curves"]
    main = min(curves, key=lambda c: np.nanmedian(np.hypot(c["x_px"] - 255.5, c["y_px"] - 255.5)))
    res = main["mag"].to_numpy() - index["mag"].to_numpy()
    good = np.isfinite(res) & (main["snr"].to_numpy() >= 20)
    assert good.sum() >= 35
    assert abs(np.mean(res[good])) <= 0.02
    chi2 = np.mean((res[good] / main["mag_err"].to_numpy()[good]) ** 2)
    assert 0.7 <= chi2 <= 1.5, chi2
    zp = roundtrip["log"]["zero_point"].to_numpy()
    assert np.nanmedian(np.abs(zp - TRUE_ZP)) < 0.01


def test_two_objects_each_get_a_light_curve(roundtrip):
    curves = roundtrip["curves"]
    assert len(curves) == 2
    second = next(c for c in curves if np.nanmedian(c["x_px"]) < 150)
    assert np.nanmedian(np.abs(second["x_px"] - 100)) < 0.5
    assert abs(np.nanmedian(second["mag"]) - roundtrip["second"]) < 0.02
    for c in curves:  # the project's light-curve table
        assert set(jaxlc.io.tables.LIGHTCURVE_COLUMNS) <= set(c.columns)


def test_frames_without_the_object_are_marked_not_lost(roundtrip):
    curves, index = roundtrip["curves"], roundtrip["index"]
    main = next(c for c in curves if np.nanmedian(c["x_px"]) > 200)
    assert len(main) == len(index)  # one row per frame
    assert not main["visible"].iloc[40:44].any()
    assert main["note"].iloc[40:44].str.contains("not detected").all()
    assert main["visible"].iloc[44:].sum() >= 10  # tracked again after the gap


def test_partial_and_saturated_streaks_never_set_the_zero_point(roundtrip):
    log = roundtrip["log"]
    assert log["partial"].sum() > 0
    frame = read_frame(roundtrip["tmp"] / "frames" / roundtrip["index"]["file"].iloc[3])
    from jaxlc.imaging.extract import ExtractSettings

    res = measure_frame(frame, roundtrip["stars"], ExtractSettings())
    det = res["detections"]
    assert det["saturated"].any()  # the V = 1 star
    zp, zp_err, _, n = res["zp"]
    assert n <= int(((det["star"] >= 0) & ~det["saturated"] & ~det["edge"]).sum())
    assert abs(zp - TRUE_ZP) < max(3 * zp_err, 0.01)


def test_streak_predicted_from_the_pointing_matches_the_sky_motion(roundtrip):
    from jaxlc.imaging.fitsframe import frame_pointing, list_frames
    from jaxlc.imaging.starmatch import pointing_streak

    paths = list_frames(roundtrip["tmp"] / "frames")
    pointing = [frame_pointing(p, jaxlc.imaging.HeaderKeys()) for p in paths]
    times = np.asarray([(s - pointing[0][0]).total_seconds() for s, _, _ in pointing])
    centres = np.asarray([c[1:] for c in pointing])
    k = 20
    vec = pointing_streak(read_frame(paths[k]), times, centres, k)
    # reference: the object's own angular motion over this exposure (start to end)
    ra, dec = object_radec(leo_geometry(60), np.array([times[k], times[k] + 1.0]))
    u = unit_vector(ra, dec)
    angle_arcsec = np.degrees(np.arccos(np.clip(u[0] @ u[1], -1, 1))) * 3600
    assert np.hypot(*vec) == pytest.approx(angle_arcsec / SENSOR.pixel_scale_arcsec, rel=0.01)


def test_gap_in_the_sequence_is_bridged(tmp_path):
    geo = leo_geometry(40)
    keep = np.r_[0:15, 30:40]
    geo_gap = geo.iloc[keep].reset_index(drop=True)
    stars = random_stars(geo, tmp_path / "stars.csv")
    lc = sine_curve(geo_gap)
    simulate_frames(lc, geo_gap, tmp_path / "frames", SENSOR, stars, seed=4)
    curves, log = extract_lightcurves(tmp_path / "frames", stars)
    assert len(curves) == 1
    assert np.diff(log["t_s"].to_numpy()).max() == pytest.approx(16.0)
    assert curves[0]["visible"].iloc[15:].sum() >= 5


def test_saturated_object_and_exposure_overlap(tmp_path):
    geo = leo_geometry(6)
    stars = random_stars(geo, tmp_path / "stars.csv")
    lc = sine_curve(geo, mean=3.0, amp=0.0)  # a core of ~2 px radius above full well
    simulate_frames(lc, geo, tmp_path / "frames", SENSOR, stars)
    curves, _ = extract_lightcurves(tmp_path / "frames", stars)
    assert not curves[0]["visible"].any()  # never a magnitude from a saturated core
    assert (curves[0]["note"] == "object saturated").sum() >= 3
    with pytest.raises(JaxlcError, match="readout"):
        simulate_frames(lc, geo, tmp_path / "f2", Sensor(readout_s=0.2), stars)
    with pytest.raises(JaxlcError, match="already holds FITS"):
        simulate_frames(lc, geo, tmp_path / "frames", SENSOR, stars)


def test_streak_conserves_flux():
    image = np.zeros((200, 200))
    add_streak(image, 40.3, 50.1, 150.7, 120.9, 1000.0, 1.1)
    assert image.sum() == pytest.approx(1000.0, rel=1e-6)
    point = np.zeros((50, 50))
    add_streak(point, 20.2, 25.7, 20.2, 25.7, 7.0, 0.9)
    assert point.sum() == pytest.approx(7.0, rel=1e-6)
    y, x = np.unravel_index(point.argmax(), point.shape)
    assert (x, y) == (20, 26)


def test_shipped_hipparcos_catalogue():
    stars = load_catalog()
    assert len(stars) == 42212
    sirius = stars.loc[stars["mag"].idxmin()]
    assert sirius["ra_deg"] == pytest.approx(101.287, abs=0.01)
    assert sirius["dec_deg"] == pytest.approx(-16.716, abs=0.01)


def test_bad_frames_get_one_line(tmp_path, capsys):
    from astropy.io import fits

    from jaxlc.cli import main

    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x.fits").write_text("not a fits file")
    assert main(["extract", str(tmp_path / "a"), "-o", str(tmp_path / "lc.csv")]) == 1
    assert "not a readable FITS" in capsys.readouterr().err
    (tmp_path / "b").mkdir()
    hdr = fits.Header({"EXPTIME": 1.0, "DATE-OBS": "2020-01-01T00:00:00"})
    fits.PrimaryHDU(np.zeros((32, 32), np.uint16), hdr).writeto(tmp_path / "b" / "f.fits")
    with pytest.raises(JaxlcError, match="no celestial WCS"):
        read_frame(tmp_path / "b" / "f.fits")
    wcs_hdr = jaxlc.imaging.sensor.tangent_wcs(SENSOR, 10.0, 20.0).to_header()
    wcs_hdr["DATE-OBS"] = "2020-01-01T00:00:00"
    fits.PrimaryHDU(np.zeros((32, 32), np.uint16), wcs_hdr).writeto(tmp_path / "c.fits")
    with pytest.raises(JaxlcError, match="no EXPTIME keyword"):
        read_frame(tmp_path / "c.fits")
    err = capsys.readouterr().err
    assert "Traceback" not in err


def test_cli_frames_then_extract(tmp_path, capsys):
    from jaxlc.cli import main

    geo = leo_geometry(60, range_m=8e6).iloc[:8]  # S4 at V ≈ 7.4
    jaxlc.write_table(geo, tmp_path / "geo.csv")
    random_stars(geo, tmp_path / "stars.csv")
    args = ["--catalog", str(tmp_path / "stars.csv")]
    size = ["--width-px", "512", "--height-px", "512", "--pixel-scale-arcsec", "20"]
    code = main(["frames", "s4_falcon9", str(tmp_path / "geo.csv"), "-o", str(tmp_path / "fr"),
                 *args, *size])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    assert len(list((tmp_path / "fr").glob("*.fits"))) == 8
    out = tmp_path / "lc.csv"
    plots = ["--plot", str(tmp_path / "lc.png"), "--frame-plot", str(tmp_path / "f.png")]
    code = main(["extract", str(tmp_path / "fr"), "-o", str(out), *args, *plots])
    err = capsys.readouterr().err
    assert code == 0, err
    assert re.search(r"object 1 near \(25[56], 25[56]\) px: \d+/8 frames measured", err), err
    lc = jaxlc.read_lightcurve(out)
    injected = pd.read_csv(tmp_path / "fr" / "frames.csv", comment="#")
    ok = lc["visible"].to_numpy()
    assert ok.sum() >= 4, err
    assert np.abs(lc["mag"][ok] - injected["mag"][ok]).max() < 5 * lc["mag_err"][ok].max()
    assert (tmp_path / "lc.png").stat().st_size > 0 and (tmp_path / "f.png").stat().st_size > 0

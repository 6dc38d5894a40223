"""Observation geometry against independent implementations.

* frames and the Sun against astropy/ERFA (its own TEME, GCRS, AltAz and Sun);
* the conic Earth shadow against its limits and skyfield's binary test;
* visibility windows against a per-object skyfield computation of the same rules.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest
from helpers import DATA

import jaxlc
from jaxlc.errors import JaxlcError
from jaxlc.geometry import ephemeris, observe
from jaxlc.geometry.eclipse import R_EARTH_M, shadow_nu
from jaxlc.geometry.observe import (
    Visibility,
    explain_invisible,
    find_passes,
    geometry_table,
    observe_chunk,
)
from jaxlc.geometry.orbit import propagate_gcrs_m
from jaxlc.geometry.sites import get_site, site_from
from jaxlc.geometry.tle import read_tles

TLE_DIR = DATA / "tle"
AU = 1.495978707e11


@pytest.fixture(scope="module")
def falcon():
    return {t.norad_id: t for t in read_tles(TLE_DIR / "falcon9_rb.tle")}


def _angle_deg(a, b):
    cos = np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


@pytest.mark.parametrize(
    ("norad", "site", "start"),
    [
        (41381, "mt-stromlo", "2016-03-27T18:00:00Z"),
        (45921, "mt-stromlo", "2020-08-10T15:00:00Z"),
        (58348, "mmt-sao", "2023-12-11T00:00:00Z"),
    ],
)
def test_frames_and_sun_against_astropy(falcon, norad, site, start):
    """Sun direction within 0.01° and topocentric elevation within 0.01° of astropy."""
    import astropy.units as u
    from astropy.coordinates import (
        GCRS,
        ITRS,
        TEME,
        AltAz,
        CartesianRepresentation,
        EarthLocation,
        get_body,
    )
    from astropy.time import Time
    from astropy.utils import iers

    iers.conf.auto_download = False  # bundled IERS tables only, no network
    where = get_site(site)
    t0 = pd.Timestamp(start)
    offsets = np.arange(0.0, 8 * 3600.0, 900.0)
    ob = observe_chunk([falcon[norad]], where, t0, offsets, Visibility())
    times = Time([(t0 + pd.Timedelta(seconds=o)).to_pydatetime() for o in offsets], scale="utc")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # astropy: IERS-B extrapolation notes
        sun = get_body("sun", times).cartesian.xyz.to_value(u.m).T
        # the satellite: astropy's own TEME → GCRS and TEME → AltAz from jaxlc's SGP4 output
        from jaxlc.geometry.orbit import propagate_teme_km, utc_julian_dates

        _, r_km, _ = propagate_teme_km(
            [falcon[norad]], *utc_julian_dates(ephemeris.times(t0, offsets))
        )
        teme = TEME(CartesianRepresentation(r_km[0].T * u.km), obstime=times)
        gcrs = teme.transform_to(GCRS(obstime=times)).cartesian.xyz.to_value(u.m).T
        loc = EarthLocation.from_geodetic(
            where.lon_deg * u.deg, where.lat_deg * u.deg, where.alt_m * u.m
        )
        topo = teme.transform_to(ITRS(obstime=times)).cartesian - loc.get_itrs(times).cartesian
        altaz = ITRS(topo, obstime=times, location=loc).transform_to(
            AltAz(obstime=times, location=loc)
        )
        sun_alt = get_body("sun", times, location=loc).transform_to(
            AltAz(obstime=times, location=loc)
        )
    assert _angle_deg(ob.sun_m, sun).max() < 0.01
    assert np.linalg.norm(ob.rso_m[0] - gcrs, axis=1).max() < 1.0  # metres
    assert np.abs(altaz.alt.deg - ob.elevation_deg[0]).max() < 0.01
    assert np.abs(sun_alt.alt.deg - ob.sun_elevation_deg).max() < 0.01


# ---------------------------------------------------------------------------
# Earth shadow


def test_shadow_limits():
    sun = np.array([AU, 0.0, 0.0])
    r = 7.0e6
    assert shadow_nu(np.array([r, 0, 0]), sun) == 1.0  # between Earth and Sun
    assert shadow_nu(np.array([0, r, 0]), sun) == 1.0  # beside the Earth
    assert shadow_nu(np.array([-r, 0, 0]), sun) == 0.0  # behind it: umbra
    # Sun's centre on Earth's limb (separation c = apparent Earth radius b, i.e. the
    # object at θ = π − b from the Sun direction): about half the disc is hidden
    b = np.arcsin(R_EARTH_M / r)
    theta = np.pi - b
    nu = float(shadow_nu(r * np.array([np.cos(theta), np.sin(theta), 0.0]), sun))
    assert 0.45 < nu < 0.55
    assert np.isnan(shadow_nu(np.array([np.nan, 0, 0]), sun))


def test_leo_shadow_entry_monotone_with_10s_penumbra():
    """A 400 km circular orbit in the ecliptic plane: ν falls monotonically from 1 to 0
    over the penumbra, which lasts about 8–15 s (PHYSICS.md §3)."""
    r = R_EARTH_M + 400e3
    omega = np.sqrt(3.986004418e14 / r**3)
    t = np.arange(0.0, 2 * np.pi / omega, 0.05)  # one full orbit: one entry, one exit
    pos = r * np.stack([np.cos(omega * t), np.sin(omega * t), np.zeros_like(t)], 1)
    nu = shadow_nu(pos, np.array([AU, 0.0, 0.0]))
    entry = slice(0, int(np.argmax(nu == 0.0)) + 1)  # sunlit … first umbra sample
    assert np.all(np.diff(nu[entry]) <= 1e-12)
    penumbra_s = np.count_nonzero((nu > 0) & (nu < 1)) * 0.05 / 2  # entry and exit
    assert 8.0 <= penumbra_s <= 15.0


def test_skyfield_binary_test_flips_near_half(falcon):
    """skyfield's is_sunlit (point Sun) flips where ν ≈ 0.5."""
    from skyfield.api import EarthSatellite

    tle = read_tles(TLE_DIR / "tle-new_2016-03_perfilev.txt")[0]  # ISS, 2008
    ts = ephemeris.timescale()
    sat = EarthSatellite(tle.line1, tle.line2, ts=ts)
    t0 = tle.epoch_utc
    offsets = np.arange(0.0, 6000.0, 0.2)
    t = ephemeris.times(t0, offsets)
    lit = sat.at(t).is_sunlit(ephemeris.planets())
    flips = np.flatnonzero(np.diff(lit.astype(int)))
    assert len(flips) >= 2
    rso, _ = propagate_gcrs_m([tle], t)
    sun = (
        ephemeris.planets()["earth"]
        .at(t)
        .observe(ephemeris.planets()["sun"])
        .apparent()
        .position.m.T
    )
    nu = shadow_nu(rso[0], sun)
    for k in flips:
        assert 0.35 < nu[k] < 0.65 or 0.35 < nu[k + 1] < 0.65


# ---------------------------------------------------------------------------
# Visibility and passes


def test_visibility_agrees_with_skyfield_rules(falcon):
    """45921 from Mt Stromlo over two nights, 10 s steps: jaxlc's mask against
    per-object skyfield (altaz of satellite and Sun, is_sunlit); they may differ
    only at samples within 0.02° of a threshold or in penumbra."""
    from skyfield.api import EarthSatellite

    tle, site = falcon[45921], get_site("mt-stromlo")
    t0 = pd.Timestamp("2020-08-09T06:00:00Z")
    offsets = np.arange(0.0, 2 * 86400.0, 10.0)
    ob = observe_chunk([tle], site, t0, offsets, Visibility())
    ts = ephemeris.timescale()
    t = ts.utc(2020, 8, 9, 6, 0, offsets)
    eph = ephemeris.planets()
    sat = EarthSatellite(tle.line1, tle.line2, ts=ts)
    where = site.skyfield()
    el = (sat - where).at(t).altaz()[0].degrees
    sun_el = (eph["earth"] + where).at(t).observe(eph["sun"]).apparent().altaz()[0].degrees
    lit = sat.at(t).is_sunlit(eph)
    reference = (el > 15.0) & (sun_el < -6.0) & lit
    ours = ob.visible[0]
    assert ours.sum() > 1000  # long passes near apogee
    differ = ours != reference
    near = (
        (np.abs(el - 15.0) < 0.02)
        | (np.abs(sun_el + 6.0) < 0.02)
        | ((ob.shadow_nu[0] > 0) & (ob.shadow_nu[0] < 1))
    )
    assert np.all(near[differ]), np.flatnonzero(differ & ~near)[:5]
    # passes: the same windows, boundaries within one step
    passes = find_passes([tle], site, t0, 2 * 86400.0, 10.0)
    edges = np.diff(np.r_[0, reference.astype(int), 0])
    starts, stops = offsets[np.flatnonzero(edges == 1)], offsets[np.flatnonzero(edges == -1) - 1]
    assert len(passes) == len(starts)
    for row, a, b in zip(passes.itertuples(), starts, stops, strict=True):
        got_a = (pd.Timestamp(row.start_utc) - t0).total_seconds()
        got_b = (pd.Timestamp(row.end_utc) - t0).total_seconds()
        assert abs(got_a - a) <= 10.0 and abs(got_b - b) <= 10.0


def test_passes_split_across_time_chunks_are_merged(falcon, monkeypatch):
    """The same passes whatever the chunk size (a pass spanning chunks is one pass)."""
    tle, site = falcon[45921], get_site("mt-stromlo")
    t0 = pd.Timestamp("2020-08-10T00:00:00Z")
    whole = find_passes([tle], site, t0, 86400.0, 5.0)
    monkeypatch.setattr(observe, "TIME_CHUNK", 97)
    chunked = observe.find_passes([tle], site, t0, 86400.0, 5.0)
    pd.testing.assert_frame_equal(whole, chunked)
    assert whole["duration_s"].max() > 3600  # the 5-hour pass crosses many chunks


def test_geometry_table_contract_and_render(falcon):
    tle, site = falcon[45921], get_site("mt-stromlo")
    df = geometry_table(tle, site, pd.Timestamp("2020-08-10T18:00:00Z"), 600.0, 1.0, 1.0)
    clean = jaxlc.io.tables.validate_geometry(df)
    assert len(clean) == 600 and clean.attrs["frame"] == "GCRS"
    assert clean["visible"].all() and (clean["sgp4_error"] == 0).all()
    assert list(clean.columns[:16]) == list(jaxlc.io.tables.GEOMETRY_COLUMNS)
    # geocentric ranges: object ~GTO, Sun ~1 AU, site on the Earth's surface
    assert 6.0e6 < np.linalg.norm(clean[["obs_x_m", "obs_y_m", "obs_z_m"]], axis=1).mean() < 6.4e6
    assert (
        0.98 * AU
        < np.linalg.norm(clean[["sun_x_m", "sun_y_m", "sun_z_m"]], axis=1).mean()
        < 1.02 * AU
    )
    lc = jaxlc.render("s4_falcon9", clean)
    assert lc["mag"].notna().all()
    assert lc.attrs["frame"] == "GCRS"


def test_sgp4_failures_are_flagged_rows():
    (tle,) = read_tles(TLE_DIR / "decaying_28872.tle")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        df = geometry_table(tle, get_site("haleakala"), tle.epoch_utc, 7200.0, 60.0)
    failed = df["sgp4_error"] != 0
    assert failed.any() and (~failed).any()
    assert (df.loc[failed, "sgp4_error"] == 6).all()
    assert df.loc[failed, "sgp4_message"].str.contains("decayed").all()
    assert df.loc[failed, "rso_x_m"].isna().all() and not df.loc[failed, "visible"].any()
    first = int(np.flatnonzero(failed)[0])
    assert 50 * 60 <= df["t_s"][first] <= 60 * 60  # decays 52 min after epoch
    lc = jaxlc.render("s5_cubesat", df)
    assert lc.loc[failed, "mag"].isna().all()


def test_empty_window_gives_clear_message_and_valid_tables(falcon):
    tle, site = falcon[45921], get_site("mt-stromlo")
    day = pd.Timestamp("2020-08-10T03:00:00Z")  # local early afternoon
    df = geometry_table(tle, site, day, 600.0, 10.0)
    assert not df["visible"].any()
    message = explain_invisible(df, Visibility())
    assert "no visible sample among 60" in message and "Sun at or above -6° in 60" in message
    jaxlc.io.tables.validate_geometry(df)
    passes = find_passes([tle], site, day, 600.0, 10.0)
    assert passes.empty and list(passes.columns)[:3] == ["norad_id", "name", "start_utc"]


def test_custom_site_and_thresholds(falcon):
    tle = falcon[45921]
    here = site_from(lat_deg=-35.3161, lon_deg=149.0099, alt_m=805.0)
    t0 = pd.Timestamp("2020-08-10T18:00:00Z")
    a = geometry_table(tle, here, t0, 300.0, 10.0)
    b = geometry_table(tle, get_site("mt-stromlo"), t0, 300.0, 10.0)
    np.testing.assert_allclose(a["elevation_deg"], b["elevation_deg"], atol=1e-12)
    strict = geometry_table(tle, here, t0, 300.0, 10.0, rules=Visibility(min_elevation_deg=80.0))
    assert not strict["visible"].any()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(name="moon-base"), "unknown site 'moon-base'; known sites: mt-stromlo"),
        (dict(lat_deg=10.0), "no site given"),
        (dict(name="mt-stromlo", lat_deg=1.0), "either --site or"),
        (dict(lat_deg=95.0, lon_deg=0.0, alt_m=0.0), r"lat_deg = 95.0 must be in \[-90, 90\]"),
    ],
)
def test_site_errors(kwargs, message):
    with pytest.raises(JaxlcError, match=message):
        site_from(**kwargs)


def test_times_outside_ephemeris(falcon):
    with pytest.raises(JaxlcError, match="outside the ephemeris range"):
        geometry_table(
            falcon[45921], get_site("mt-stromlo"), pd.Timestamp("2060-01-01T00:00:00Z"), 60.0
        )


def test_bad_rules_and_durations(falcon):
    with pytest.raises(JaxlcError, match="min elevation"):
        Visibility(min_elevation_deg=100.0)
    with pytest.raises(JaxlcError, match="duration"):
        geometry_table(falcon[45921], get_site("mt-stromlo"), pd.Timestamp("2020-08-10"), -5.0)
    with pytest.raises(JaxlcError, match="step"):
        geometry_table(falcon[45921], get_site("mt-stromlo"), pd.Timestamp("2020-08-10"), 5.0, 0.0)


@pytest.mark.parametrize(
    ("duration_s", "step_s", "message"),
    [
        (np.nan, 1.0, r"window length nan s must be > 0 \(--duration-s or --days\)"),
        (60.0, np.inf, r"step inf s must be > 0 \(--step-s\)"),
        (1e12, 1.0, r"1e\+12 samples; at most 1,000,000 are allowed \(memory and time\)"),
        (1e300, 1e-300, r"is inf samples; at most 1,000,000"),  # no integer overflow
        (1e12, 1e7, r"2020-08-10 … 2053-10-09 are outside the ephemeris"),  # no Timedelta overflow
    ],
)
def test_windows_are_bounded_before_any_work(falcon, duration_s, step_s, message):
    start = pd.Timestamp("2020-08-10T00:00:00Z")
    with pytest.raises(JaxlcError, match=message):
        geometry_table(falcon[45921], get_site("mt-stromlo"), start, duration_s, step_s)


def test_pass_search_limit_is_larger_than_table_limit(falcon):
    assert observe.check_window(86400.0 * 100, 1.0, observe.MAX_SEARCH_SAMPLES) == 8_640_000
    with pytest.raises(JaxlcError, match="at most 10,000,000"):
        find_passes([falcon[45921]], get_site("mt-stromlo"), pd.Timestamp("2020-08-10"), 2e7)


def test_chunks_shrink_with_the_number_of_objects(falcon, monkeypatch):
    """Memory per chunk is bounded by objects × samples, not by samples alone."""
    monkeypatch.setattr(observe, "CHUNK_CELLS", 300)
    chunks = list(
        observe.observe_chunks(
            list(falcon.values()),
            get_site("mt-stromlo"),
            pd.Timestamp("2020-08-10T18:00:00Z"),
            250.0,
            1.0,
            Visibility(),
        )
    )
    assert [len(c.offsets_s) for c in chunks] == [100, 100, 50]
    assert chunks[0].rso_m.shape == (3, 100, 3)


def test_passes_carry_tle_age_and_stale_mark(falcon):
    """The 2016 set of 41381 is ~1,600 days old in 2020; 45921's set is 1–3 days old."""
    start = pd.Timestamp("2020-08-10T00:00:00Z")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        passes = find_passes(
            [falcon[41381], falcon[45921]], get_site("mt-stromlo"), start, 86400.0, 30.0
        )
    assert list(passes.columns) == list(observe.PASS_COLUMNS)
    old, fresh = passes[passes.norad_id == 41381], passes[passes.norad_id == 45921]
    assert len(old) and len(fresh)
    assert old["stale"].all() and (old["tle_age_days"] > 1590).all()
    assert not fresh["stale"].any() and fresh["tle_age_days"].between(1.0, 2.5).all()
    for row in passes.itertuples():  # |pass start − epoch|
        epoch = falcon[row.norad_id].epoch_utc
        age = abs((pd.Timestamp(row.start_utc) - epoch).total_seconds()) / 86400.0
        assert row.tle_age_days == pytest.approx(age, abs=1e-3)

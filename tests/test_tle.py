"""TLE reading: real files, validation errors naming line and field, selection, epochs."""

from __future__ import annotations

import warnings

import pandas as pd
import pytest
from helpers import DATA

from jaxlc.geometry.tle import (
    STALE_EPOCH_DAYS,
    TLEError,
    TLEWarning,
    checksum,
    latest_before,
    parse_tles,
    read_tles,
    select_objects,
)

TLE_DIR = DATA / "tle"
ISS = [
    "ISS (ZARYA)",
    "1 25544U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  2927",
    "2 25544  51.6416 247.4627 0006703 130.5360 325.0288 15.72125391563537",
]


def test_checksum_of_published_iss_set():
    assert checksum(ISS[1]) == 7 and checksum(ISS[2]) == 7


@pytest.mark.parametrize(
    ("name", "n_sets", "n_objects"),
    [
        ("falcon9_rb.tle", 3, 3),
        ("cubesat_3U_extract.tle", 10, 7),
        ("optus-D3-16-08-01-to-16-09-30.txt", 86, 1),  # two-line history, CRLF
        ("tle-new_2016-03_perfilev.txt", 16, 16),  # mixed LF/CRLF
        ("mmt_objects.tle", 50, 50),
    ],
)
def test_real_files(name, n_sets, n_objects):
    tles = read_tles(TLE_DIR / name)
    assert len(tles) == n_sets and len({t.norad_id for t in tles}) == n_objects
    assert all(len(t.line1) == len(t.line2) == 69 for t in tles)


def test_fields_of_a_known_set():
    first = read_tles(TLE_DIR / "falcon9_rb.tle")[0]
    assert (first.name, first.norad_id, first.lineno) == ("FALCON 9 R/B", 41381, 2)
    # 16087.98861961: 2016 is a leap year, day 87 = 27 March, 0.98861961 d = 23:43:36.734
    assert first.epoch_utc == pd.Timestamp("2016-03-27T23:43:36.734304Z")
    optus = read_tles(TLE_DIR / "optus-D3-16-08-01-to-16-09-30.txt")
    assert optus[0].name == "" and optus[0].norad_id == 35756


def test_three_line_with_zero_prefix_and_alpha5():
    line1 = "1 A0001U 98067A   08264.51782528 -.00002182  00000-0 -11606-4 0  292"
    line2 = "2 A0001  51.6416 247.4627 0006703 130.5360 325.0288 15.72125391563537"
    line1 += str(checksum(line1))
    line2 = line2[:68] + str(checksum(line2))
    (t,) = parse_tles(f"0 FUTURE SAT\n{line1}\n{line2}\n")
    assert (t.name, t.norad_id) == ("FUTURE SAT", 100001)


def _fixed(line: str) -> str:
    """The line with a correct checksum (so that another check is the one that fails)."""
    return line[:68] + str(checksum(line))


def _damage(lineno: int, text: str):
    lines = list(ISS)
    lines[lineno] = text
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            _damage(2, ISS[2][:60]),
            r"TLE line 2 is truncated: 60 characters, expected 69 \(line 3 of t\.tle\)",
        ),
        (
            _damage(2, ISS[2][:68] + "3"),
            r"TLE line 2 checksum is 3, expected 7 \(line 3 of t\.tle\)",
        ),
        (
            _damage(2, _fixed(ISS[2].replace("25544", "25545"))),
            r"catalogue number '25544' on line 1 but '25545' on line 2 \(lines 2–3 of t\.tle\)",
        ),
        (
            _damage(2, _fixed(ISS[2][:8] + " 51.6x16" + ISS[2][16:])),
            r"line 2 field 'inclination' \(columns 9–16\) is ' 51\.6x16', not a number",
        ),
        ("\n".join(ISS[:2]) + "\n", r"line 1 at line 2 of t\.tle is not followed by its line 2"),
        (ISS[2] + "\n", r"TLE line 2 at line 1 of t\.tle has no line 1 before it"),
        (
            "\n".join([ISS[0], ISS[1], "garbage", ISS[2]]),
            r"is followed by 'garbage' instead of its line 2",
        ),
    ],
)
def test_bad_tles_name_line_and_field(text, message):
    with pytest.raises(TLEError, match=message):
        parse_tles(text, source="/some/dir/t.tle")


def test_checksum_warning_mode():
    text = _damage(2, ISS[2][:68] + "3")
    with pytest.warns(TLEWarning, match="checksum is 3, expected 7"):
        (t,) = parse_tles(text, checksums="warn")
    assert t.norad_id == 25544


def _columns(line: str, first: int, last: int, text: str) -> str:
    """``line`` with columns first…last (1-based, inclusive) replaced, checksum fixed."""
    assert len(text) == last - first + 1
    return _fixed(line[: first - 1] + text + line[last:])


@pytest.mark.parametrize(
    ("lineno", "first", "last", "text", "message"),
    [
        (
            1,
            21,
            32,
            "999.51782528",
            r"epoch day 999\.51782528 \(columns 21–32\) is outside "
            r"1 … 366\.99999999 for 2008 \(a leap year\) \(line 2 of t\.tle\)",
        ),
        (1, 21, 32, "366.51782528", r"epoch day 366\.51782528 .* for 2009 \(not a leap year\)"),
        (1, 21, 32, "000.51782528", r"epoch day 000\.51782528 .* outside 1 …"),
        (1, 21, 32, "264.5178x528", r"'epoch day' \(columns 21–32\) is '264\.5178x528', not a"),
        (1, 21, 32, "nan         ", r"'epoch day' .* is 'nan         ', not a number"),
        (1, 19, 20, "0x", r"'epoch year' \(columns 19–20\) is '0x', not a number"),
        (1, 34, 43, " .1e-00005", r"'first derivative of mean motion' .* not a number"),
        (
            1,
            45,
            52,
            " 0000a-0",
            r"'second derivative of mean motion' \(columns 45–52\) is ' 0000a-0'",
        ),
        (
            1,
            54,
            61,
            " 1x005-2",
            r"'BSTAR drag term' \(columns 54–61\) is ' 1x005-2', not of the form",
        ),
        (1, 33, 33, "1", r"line 1 column 33 is '1', expected a blank between fields"),
        (
            2,
            9,
            16,
            "181.0000",
            r"'inclination' \(columns 9–16\) is 181\.0000, outside 0 … 180 "
            r"\(line 3 of t\.tle\)",
        ),
        (2, 9, 16, " -1.0000", r"'inclination' .* is -1\.0000, outside 0 … 180"),
        (2, 18, 25, "400.0000", r"'right ascension of the ascending node' .* outside 0 … 360"),
        (2, 27, 33, "-006703", r"'eccentricity' \(columns 27–33\) is '-006703', not a number"),
        (2, 27, 33, "0.06703", r"'eccentricity' .* is '0\.06703', not a number"),
        (2, 35, 42, "361.0000", r"'argument of perigee' .* outside 0 … 360"),
        (2, 44, 51, "     inf", r"'mean anomaly' .* is '     inf', not a number"),
        (
            2,
            53,
            63,
            " 0.00000000",
            r"'mean motion' \(columns 53–63\) is 0\.00000000 rev/day; "
            r"it must be > 0",
        ),
        (2, 53, 63, "-1.72125391", r"'mean motion' .* is -1\.72125391 rev/day; it must be > 0"),
        (2, 52, 52, "7", r"line 2 column 52 is '7', expected a blank"),
        (2, 53, 63, " 1673912024", r"'mean motion' .* is ' 1673912024', not a number"),
    ],
)
def test_fields_sgp4_would_misread_are_refused(lineno, first, last, text, message):
    """Each of these reaches SGP4 as another orbit (or as inf) if not caught."""
    lines = list(ISS)
    if "2009" in message:
        lines[1] = _columns(lines[1], 19, 20, "09")
    lines[lineno] = _columns(lines[lineno], first, last, text)
    with pytest.raises(TLEError, match=message) as info:
        parse_tles("\n".join(lines) + "\n", source="/x/t.tle")
    assert "get the element set again" in str(info.value)


@pytest.mark.parametrize(
    ("year", "day", "epoch"),
    [
        ("20", "366.50000000", "2020-12-31T12:00:00Z"),  # leap year: day 366 exists
        ("21", "365.99999999", "2021-12-31T23:59:59.999136Z"),
        ("57", "001.00000000", "1957-01-01T00:00:00Z"),  # 57 → 1957, 56 → 2056
        ("56", "001.00000000", "2056-01-01T00:00:00Z"),
    ],
)
def test_epoch_day_limits_accepted(year, day, epoch):
    line1 = _columns(_columns(ISS[1], 19, 20, year), 21, 32, day)
    (t,) = parse_tles(f"{line1}\n{ISS[2]}\n")
    assert abs((t.epoch_utc - pd.Timestamp(epoch)).total_seconds()) < 1e-3


def test_file_errors(tmp_path):
    with pytest.raises(TLEError, match="does not exist"):
        read_tles(tmp_path / "none.tle")
    with pytest.raises(TLEError, match="is a folder; give the TLE file inside it"):
        read_tles(tmp_path)
    (tmp_path / "empty.tle").write_text("")
    with pytest.raises(TLEError, match=r"empty\.tle is empty: expected pairs of 69-character"):
        read_tles(tmp_path / "empty.tle")
    (tmp_path / "comment.tle").write_text("\n# just a comment\n")
    with pytest.raises(TLEError, match=r"comment\.tle holds no TLE"):
        read_tles(tmp_path / "comment.tle")
    (tmp_path / "bin.tle").write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(TLEError, match=r"not a plain-text TLE file \(byte b'\\xff' at line 1\)"):
        read_tles(tmp_path / "bin.tle")
    (tmp_path / "nul.tle").write_bytes(("\n".join(ISS) + "\n\x00\x00\n").encode())
    with pytest.raises(TLEError, match=r"byte b'\\x00' at line 4"):
        read_tles(tmp_path / "nul.tle")


def test_select_by_norad_and_name():
    tles = read_tles(TLE_DIR / "cubesat_3U_extract.tle")
    assert {t.norad_id for t in select_objects(tles, norad_ids=[32789])} == {32789}
    assert {t.name for t in select_objects(tles, names=["canx-2"])} == {"CANX-2"}
    assert {t.norad_id for t in select_objects(tles, names=["delfi"])} == {32789}
    with pytest.raises(TLEError, match="NORAD 1 is not in"):
        select_objects(tles, norad_ids=[1])
    with pytest.raises(TLEError, match=r"no object named 'hubble' .* or --norad"):
        select_objects(tles, names=["hubble"])
    with pytest.raises(TLEError, match="matches several objects"):
        select_objects(tles, names=["e"])


def test_latest_epoch_before_window_start():
    """The seed's rule on a GEO history of 86 epochs."""
    history = read_tles(TLE_DIR / "optus-D3-16-08-01-to-16-09-30.txt")
    start = pd.Timestamp("2016-09-10T12:00:00Z")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a fresh epoch gives no warning
        (pick,) = latest_before(history, start)
    earlier = [t.epoch_utc for t in history if t.epoch_utc <= start]
    assert pick.epoch_utc == max(earlier)
    assert all(t.epoch_utc <= start or t.epoch_utc > pick.epoch_utc for t in history)


def test_stale_and_future_epoch_warnings():
    history = read_tles(TLE_DIR / "optus-D3-16-08-01-to-16-09-30.txt")
    with pytest.warns(TLEWarning, match=r"days before the window start"):
        latest_before(history, pd.Timestamp("2016-11-01T00:00:00Z"))
    with pytest.warns(TLEWarning, match=r"window starts .* days before the first TLE epoch"):
        (pick,) = latest_before(history, pd.Timestamp("2016-07-01T00:00:00Z"))
    assert pick.epoch_utc == min(t.epoch_utc for t in history)
    assert pick.age_days(pd.Timestamp("2016-07-01T00:00:00Z")) > STALE_EPOCH_DAYS
    # within STALE_EPOCH_DAYS of an epoch, before or after it: no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        first = min(t.epoch_utc for t in history)
        latest_before(history, first - pd.Timedelta(days=STALE_EPOCH_DAYS - 1))
        last = max(t.epoch_utc for t in history)
        latest_before(history, last + pd.Timedelta(days=STALE_EPOCH_DAYS - 1))


def test_window_before_the_first_satellite_is_refused():
    history = read_tles(TLE_DIR / "falcon9_rb.tle")
    with pytest.raises(TLEError, match=r"1950-01-01 00:00 UTC is before 1957-10-04, the launch"):
        latest_before(history, pd.Timestamp("1950-01-01T00:00:00Z"))

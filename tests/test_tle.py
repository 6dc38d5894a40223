"""TLE reading: real files, validation errors naming line and field, selection, epochs."""

from __future__ import annotations

import warnings

import pandas as pd
import pytest
from helpers import DATA

from jaxlc.geometry.tle import (
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


def test_file_errors(tmp_path):
    with pytest.raises(TLEError, match="does not exist"):
        read_tles(tmp_path / "none.tle")
    (tmp_path / "empty.tle").write_text("\n# just a comment\n")
    with pytest.raises(TLEError, match="no TLE found"):
        read_tles(tmp_path / "empty.tle")
    (tmp_path / "bin.tle").write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(TLEError, match="not a plain-text TLE file"):
        read_tles(tmp_path / "bin.tle")


def test_select_by_norad_and_name():
    tles = read_tles(TLE_DIR / "cubesat_3U_extract.tle")
    assert {t.norad_id for t in select_objects(tles, norad_ids=[32789])} == {32789}
    assert {t.name for t in select_objects(tles, names=["canx-2"])} == {"CANX-2"}
    assert {t.norad_id for t in select_objects(tles, names=["delfi"])} == {32789}
    with pytest.raises(TLEError, match="NORAD 1 is not in"):
        select_objects(tles, norad_ids=[1])
    with pytest.raises(TLEError, match="no object named 'hubble'"):
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

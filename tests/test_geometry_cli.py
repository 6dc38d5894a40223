"""`jaxlc passes`, `jaxlc geometry pass`, `jaxlc sites` as a user runs them."""

from __future__ import annotations

import pandas as pd
import pytest
from helpers import DATA, REPO, SCENES
from test_cli import run_cli

import jaxlc

FALCON = DATA / "tle" / "falcon9_rb.tle"


def test_sites_lists_registry():
    r = run_cli("sites")
    assert r.returncode == 0
    assert "mt-stromlo" in r.stdout and "mmt-sao" in r.stdout


def test_passes_then_geometry_then_render(tmp_path):
    """From a shipped TLE: real passes over Mt Stromlo, a table for one, a light curve."""
    csv = tmp_path / "passes.csv"
    r = run_cli(
        "passes",
        "--tle",
        FALCON,
        "--site",
        "mt-stromlo",
        "--start",
        "2020-08-09T00:00:00Z",
        "--days",
        "3",
        "--norad",
        "45921",
        "--csv",
        csv,
    )
    assert r.returncode == 0, r.stderr
    passes = jaxlc.read_table(csv)
    assert len(passes) == 3 and (passes["norad_id"] == 45921).all()
    assert "45921 FALCON 9 R/B" in r.stdout and "min" in r.stdout
    # the README's example: elements 1–3 days old, none stale, no warning
    assert passes["tle_age_days"].between(1.0, 3.5).all() and not passes["stale"].any()
    assert "TLE age" in r.stdout and "STALE" not in r.stdout and "warning" not in r.stderr
    longest = passes.loc[passes["duration_s"].idxmax()]
    start = pd.Timestamp(longest["start_utc"]) + pd.Timedelta(minutes=30)

    geo = tmp_path / "geo.parquet"
    r = run_cli(
        "geometry",
        "pass",
        "--tle",
        FALCON,
        "--norad",
        "45921",
        "--site",
        "mt-stromlo",
        "--start",
        start.isoformat(),
        "--duration-s",
        "600",
        "--step-s",
        "2",
        "--exposure-s",
        "0.5",
        "-o",
        geo,
    )
    assert r.returncode == 0, r.stderr
    assert "wrote 300 rows (300 visible)" in r.stderr
    table = jaxlc.read_geometry(geo)
    assert (table["exposure_s"] == 0.5).all() and table.attrs["frame"] == "GCRS"

    lc = tmp_path / "lc.csv"
    r = run_cli("render", SCENES / "s4_falcon9.toml", geo, "-o", lc)
    assert r.returncode == 0, r.stderr
    assert jaxlc.read_lightcurve(lc)["mag"].notna().all()


def test_passes_for_every_object_of_a_file(tmp_path):
    r = run_cli(
        "passes",
        "--tle",
        FALCON,
        "--lat-deg",
        "-35.3161",
        "--lon-deg",
        "149.0099",
        "--alt-m",
        "805",
        "--start",
        "2020-08-10T00:00:00Z",
        "--days",
        "1",
        "--step-s",
        "10",
    )
    assert r.returncode == 0, r.stderr
    # in 2020 the 2016 set is stale and the 2023 set lies in the future: one line each,
    # then one line counting the passes marked STALE in the table
    warnings = [line for line in r.stderr.splitlines() if line.startswith("warning: ")]
    assert len(warnings) == 3
    assert "41381" in warnings[0] and "days before the window start" in warnings[0]
    assert "58348" in warnings[1] and "before the first TLE epoch" in warnings[1]
    n_stale = r.stdout.count("STALE")
    assert n_stale > 0 and f"{n_stale} of " in warnings[2] and "more than 14 days" in warnings[2]


def test_no_passes_gives_clear_message_and_empty_csv(tmp_path):
    csv = tmp_path / "none.csv"
    r = run_cli(
        "passes",
        "--tle",
        FALCON,
        "--norad",
        "45921",
        "--site",
        "mt-stromlo",
        "--start",
        "2020-08-10T01:00:00Z",
        "--days",
        "0.1",
        "--csv",
        csv,
    )
    assert r.returncode == 0, r.stderr
    assert "no visible passes" in r.stderr
    assert jaxlc.read_table(csv).empty


def test_geometry_pass_in_daylight_warns_but_writes(tmp_path):
    out = tmp_path / "day.csv"
    r = run_cli(
        "geometry",
        "pass",
        "--tle",
        FALCON,
        "--norad",
        "45921",
        "--site",
        "mt-stromlo",
        "--start",
        "2020-08-10T03:00:00Z",
        "--duration-s",
        "60",
        "-o",
        out,
    )
    assert r.returncode == 0
    assert "warning: no visible sample among 60" in r.stderr
    assert len(jaxlc.read_geometry(out)) == 60


def test_readme_mentions_geometry_commands():
    text = (REPO / "README.md").read_text()
    assert "jaxlc passes" in text and "jaxlc geometry pass" in text
    # its `passes` example is the one test_passes_then_geometry_then_render runs
    example = text[text.index("jaxlc passes") :].split("\n", 2)[:2]
    assert all(
        w in " ".join(example) for w in ("--norad 45921", "2020-08-09T00:00:00Z", "--days 3")
    )


# ---------------------------------------------------------------------------
# Hostile input, in-process: one `error:` line, status 1, no output left behind

TLE_LINES = FALCON.read_text().splitlines()


def _with_checksum(line: str) -> str:
    from jaxlc.geometry.tle import checksum

    return line[:68] + str(checksum(line))


BAD_TLE_FILES = {
    "empty.tle": b"",
    "comments.tle": b"# nothing but a comment\n\n",
    "binary.tle": bytes(range(256)) * 4,
    "line1_only.tle": ("\n".join(TLE_LINES[3:5]) + "\n").encode(),
    "day999.tle": "\n".join(
        [TLE_LINES[3], _with_checksum(TLE_LINES[4][:20] + "999" + TLE_LINES[4][23:]), TLE_LINES[5]]
    ).encode(),
    "bstar.tle": "\n".join(
        [TLE_LINES[3], _with_checksum(TLE_LINES[4][:54] + "1x" + TLE_LINES[4][56:]), TLE_LINES[5]]
    ).encode(),
    "checksum.tle": "\n".join([*TLE_LINES[:2], TLE_LINES[2][:68] + "8", *TLE_LINES[3:]]).encode(),
    "incl.tle": "\n".join(
        [
            TLE_LINES[3],
            TLE_LINES[4],
            _with_checksum(TLE_LINES[5][:8] + "227.5948" + TLE_LINES[5][16:]),
        ]
    ).encode(),
}

WINDOW = ["--start", "2020-08-09"]
STROMLO = ["--site", "mt-stromlo"]
PASSES = ["passes", *STROMLO, *WINDOW, "--csv", "out.csv"]
PASS = ["geometry", "pass", "--norad", "45921", *STROMLO, *WINDOW]
SYNTH = ["geometry", "synthetic", "-o", "out.csv"]


@pytest.mark.parametrize(
    ("args", "words"),
    [
        # TLE files
        ([*PASSES, "--tle", "empty.tle"], ["empty.tle is empty", "'1 ' and '2 '"]),
        ([*PASSES, "--tle", "comments.tle"], ["comments.tle holds no TLE"]),
        ([*PASSES, "--tle", "binary.tle"], ["not a plain-text TLE file", "at line 1"]),
        ([*PASSES, "--tle", "line1_only.tle"], ["line 1 at line 2 of line1_only.tle", "line 2"]),
        ([*PASSES, "--tle", "day999.tle"], ["epoch day 999.56418502", "line 2 of day999.tle"]),
        ([*PASSES, "--tle", "bstar.tle"], ["'BSTAR drag term'", "' 1x005-2'", "line 2 of"]),
        ([*PASSES, "--tle", "incl.tle"], ["'inclination'", "227.5948", "outside 0 … 180"]),
        ([*PASSES, "--tle", "checksum.tle"], ["line 2 checksum is 8, expected", "line 3 of"]),
        ([*PASSES, "--tle", "missing.tle"], ["'missing.tle' does not exist"]),
        ([*PASSES, "--tle", "."], ["is a folder"]),
        ([*PASSES, "--tle", FALCON, "--norad", "99999"], ["NORAD 99999 is not in", "--norad"]),
        ([*PASSES, "--tle", FALCON, "--name", "hubble"], ["no object named 'hubble'"]),
        # windows
        ([*PASSES, "--tle", FALCON, "--days", "0"], ["--days 0.0 must be > 0"]),
        ([*PASSES, "--tle", FALCON, "--days", "-2"], ["--days -2.0 must be > 0"]),
        ([*PASSES, "--tle", FALCON, "--days", "nan"], ["--days nan must be > 0"]),
        ([*PASSES, "--tle", FALCON, "--days", "1e9"], ["8.64e+13 samples", "at most 10,000,000"]),
        ([*PASSES, "--tle", FALCON, "--step-s", "0"], ["step 0.0 s must be > 0", "--step-s"]),
        ([*PASSES, "--tle", FALCON, "--step-s", "-inf"], ["step -inf s must be > 0"]),
        (["passes", *STROMLO, "--start", "1950-01-01", "--tle", FALCON], ["before 1957-10-04"]),
        (
            ["passes", *STROMLO, "--start", "2070-01-01", "--tle", FALCON],
            ["--start 2070-01-01", "DE421"],
        ),
        (
            ["passes", *STROMLO, "--start", "2020-13-45", "--tle", FALCON],
            ["'2020-13-45' is not an ISO"],
        ),
        (["passes", *STROMLO, "--start", "", "--tle", FALCON], ["--start = ''", "ISO 8601"]),
        # sites and outputs
        (
            ["passes", *WINDOW, "--tle", FALCON, "--site", "-35.3,149.0"],
            ["--lat-deg LAT --lon-deg LON"],
        ),
        (["passes", *WINDOW, "--tle", FALCON, "--site", "moon"], ["unknown site 'moon'"]),
        (
            [
                "passes",
                *WINDOW,
                "--tle",
                FALCON,
                "--lat-deg",
                "100",
                "--lon-deg",
                "0",
                "--alt-m",
                "0",
            ],
            ["lat_deg = 100.0 must be in [-90, 90]"],
        ),
        (
            ["passes", *STROMLO, *WINDOW, "--tle", FALCON, "--csv", "out.txt"],
            ["--csv out.txt", ".csv or .parquet"],
        ),
        ([*PASSES, "--tle", FALCON, "--min-elevation-deg", "91"], ["--min-elevation-deg"]),
        # geometry pass
        ([*PASS, "--tle", FALCON, "-o", "out.csv", "--duration-s", "1e12"], ["at most 1,000,000"]),
        (
            [
                *PASS,
                "--tle",
                FALCON,
                "-o",
                "out.csv",
                "--duration-s",
                "1e300",
                "--step-s",
                "1e-300",
            ],
            ["inf samples"],
        ),
        (
            [*PASS, "--tle", FALCON, "-o", "out.csv", "--duration-s", "1e12", "--step-s", "1e7"],
            ["plus 1e+12 s leaves", "DE421"],
        ),
        ([*PASS, "--tle", FALCON, "-o", "out.csv", "--step-s", "0"], ["step 0.0 s must be > 0"]),
        ([*PASS, "--tle", FALCON, "-o", "out.csv", "--exposure-s", "-1"], ["--exposure-s"]),
        (["geometry", "pass", *WINDOW, "--tle", FALCON, "-o", "out.csv"], ["no site given"]),
        ([*PASS, "--tle", FALCON, "-o", "out.xlsx"], ["-o out.xlsx", ".csv or .parquet"]),
        ([*PASS, "--tle", "day999.tle", "-o", "out.csv"], ["epoch day 999.56418502"]),
        (
            ["geometry", "pass", *STROMLO, *WINDOW, "--tle", FALCON, "-o", "out.csv"],
            ["holds 3 objects", "--norad"],
        ),
        # geometry synthetic
        ([*SYNTH, "--start-utc", "0001-01-01"], ["--start-utc", "DE421"]),
        ([*SYNTH, "--start-utc", "garbage"], ["--start-utc = 'garbage'"]),
        ([*SYNTH, "--duration-s", "1e12"], ["plus 1e+12 s leaves"]),
        ([*SYNTH, "--step-s", "0"], ["step_s = 0.0 must be > 0"]),
        (["geometry", "synthetic", "-o", "out.xlsx"], ["-o out.xlsx"]),
    ],
    ids=lambda v: None if v[0] in ("passes", "geometry") else "_".join(v[0].split())[:40],
)
def test_hostile_inputs_give_one_line(tmp_path, monkeypatch, capsys, args, words):
    from jaxlc.cli import main

    for name, data in BAD_TLE_FILES.items():
        (tmp_path / name).write_bytes(data)
    before = set(tmp_path.iterdir())
    monkeypatch.chdir(tmp_path)
    code = main([str(a) for a in args])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 1, err
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert all(w in lines[0] for w in words), lines[0]
    assert "Traceback" not in err
    assert set(tmp_path.iterdir()) == before  # no output, not even a temporary file

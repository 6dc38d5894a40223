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
    # in 2020 the 2016 set is stale and the 2023 set lies in the future: one line each
    warnings = [line for line in r.stderr.splitlines() if line.startswith("warning: ")]
    assert len(warnings) == 2
    assert "41381" in warnings[0] and "days before the window start" in warnings[0]
    assert "58348" in warnings[1] and "before the first TLE epoch" in warnings[1]


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


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["passes", "--tle", FALCON, "--site", "moon", "--start", "2020-08-10"],
            "unknown site 'moon'",
        ),
        (["passes", "--tle", FALCON, "--start", "2020-08-10"], "no site given"),
        (
            ["passes", "--tle", FALCON, "--site", "mt-stromlo", "--start", "yesterday"],
            "--start = 'yesterday' is not an ISO 8601",
        ),
        (
            ["passes", "--tle", "@BAD", "--site", "mt-stromlo", "--start", "2020-08-10"],
            "checksum is 8, expected",
        ),
        (
            ["passes", "--tle", FALCON, "--site", "mt-stromlo", "--start", "2070-01-01"],
            "outside the ephemeris range",
        ),
        (
            [
                "passes",
                "--tle",
                FALCON,
                "--norad",
                "99999",
                "--site",
                "mt-stromlo",
                "--start",
                "2020-08-10",
            ],
            "NORAD 99999 is not in",
        ),
        (
            [
                "geometry",
                "pass",
                "--tle",
                FALCON,
                "--site",
                "mt-stromlo",
                "--start",
                "2020-08-10",
                "-o",
                "g.csv",
            ],
            "holds 3 objects",
        ),
    ],
)
def test_errors_are_one_line(tmp_path, args, message):
    bad = tmp_path / "bad.tle"
    lines = FALCON.read_text().splitlines()
    lines[2] = lines[2][:68] + "8"  # damage a checksum
    bad.write_text("\n".join(lines) + "\n")
    args = [bad if a == "@BAD" else a for a in args]
    r = run_cli(*args, cwd=tmp_path)
    assert r.returncode == 1, r.stderr
    errors = [line for line in r.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and message in errors[0], r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "g.csv").exists()


def test_readme_mentions_geometry_commands():
    text = (REPO / "README.md").read_text()
    assert "jaxlc passes" in text and "jaxlc geometry pass" in text

"""Table contracts: round trips, metadata, validation errors, atomic writes."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from helpers import SCENES

import jaxlc
from jaxlc.errors import TableError
from jaxlc.io.files import atomic_output
from jaxlc.io.tables import (
    GEOMETRY_COLUMNS,
    read_geometry,
    read_table,
    validate_geometry,
    write_table,
)


@pytest.mark.parametrize("ext", ["csv", "parquet"])
def test_geometry_round_trip(tmp_path, ext):
    geo = jaxlc.synthetic_geometry(duration_s=50, step_s=0.5, range_start_m=1.23456789e6)
    path = write_table(geo, tmp_path / f"g.{ext}")
    back = read_geometry(path)
    assert back.attrs["frame"] == "synthetic"
    assert tuple(back.columns) == GEOMETRY_COLUMNS
    for col in ("t_s", "obs_x_m", "obs_y_m", "sun_x_m"):
        np.testing.assert_array_equal(back[col].to_numpy(), geo[col].to_numpy())  # bit-exact
    assert list(back["utc"]) == list(geo["utc"])


def test_csv_has_frame_comment(tmp_path):
    path = write_table(jaxlc.synthetic_geometry(duration_s=2), tmp_path / "g.csv")
    assert path.read_text().splitlines()[0] == "# frame: synthetic"


def test_optional_columns_get_defaults(tmp_path):
    geo = jaxlc.synthetic_geometry(duration_s=3)
    minimal = geo[["utc", "t_s", *jaxlc.io.tables.POSITION_COLUMNS]]
    out = validate_geometry(minimal)
    assert out["visible"].all() and (out["shadow_nu"] == 1).all()
    assert out["exposure_s"].isna().all()
    lc = jaxlc.render(SCENES / "s5_cubesat.toml", minimal)
    assert (lc["exposure_s"] == 1.0).all()  # the scene's [sensor] default


def test_visible_column_text_forms():
    geo = jaxlc.synthetic_geometry(duration_s=4)
    geo["visible"] = ["True", "false", "1", "0"]
    assert list(validate_geometry(geo)["visible"]) == [True, False, True, False]


def _bad(modify):
    geo = jaxlc.synthetic_geometry(duration_s=5)
    geo.attrs["source"] = "geom.csv"
    modify(geo)
    return geo


BAD = [
    (lambda g: g.__delitem__("obs_y_m"), "missing column.*obs_y_m"),
    (lambda g: g.__setitem__("t_s", [0, 1, 2, np.nan, 4]), "'t_s' .* row 3 .* must be finite"),
    (lambda g: g.__setitem__("t_s", [0, 1, 2, 1.5, 4]), "'t_s' .* must not decrease"),
    (lambda g: g.__setitem__("t_s", [0, 1, 2, 3, 5]), "disagrees with the utc column"),
    (
        lambda g: g.__setitem__("obs_x_m", ["1", "2", "x", "4", "5"]),
        "'obs_x_m' has a non-number 'x' at row 2",
    ),
    (
        lambda g: g.__setitem__("rso_x_m", [0, 0, np.inf, 0, 0]),
        "'rso_x_m' .* finite on visible rows",
    ),
    (
        lambda g: g.__setitem__("shadow_nu", [1, 1, 1.5, 1, 1]),
        "'shadow_nu' .* must be in \\[0, 1\\]",
    ),
    (lambda g: g.__setitem__("exposure_s", [1, -1, 1, 1, 1]), "'exposure_s' .* must be ≥ 0"),
    (
        lambda g: g.__setitem__("visible", ["yes", "no", "1", "0", "1"]),
        "'visible' must be true/false, got 'yes'",
    ),
    (
        lambda g: g.__setitem__("utc", ["2019-07-07T12:00:00Z", "bad", "x", "y", "z"]),
        r"'utc' = 'bad' \(row 1\) is not an ISO 8601",
    ),
    (
        lambda g: [g.__setitem__(f"obs_{c}_m", g[f"rso_{c}_m"]) for c in "xyz"],
        "puts the obs at the object",
    ),
]


@pytest.mark.parametrize(("modify", "message"), BAD)
def test_bad_geometry_errors(modify, message):
    with pytest.raises(TableError, match=message):
        validate_geometry(_bad(modify))


def test_invisible_rows_may_have_nan_positions():
    geo = jaxlc.synthetic_geometry(duration_s=5)
    geo.loc[2, ["rso_x_m", "rso_y_m", "rso_z_m"]] = np.nan
    geo.loc[2, "visible"] = False
    lc = jaxlc.render(SCENES / "s5_cubesat.toml", geo)
    assert np.isnan(lc["mag"][2]) and np.isfinite(lc["mag"].drop(index=2)).all()


def test_error_points_at_csv_line(tmp_path):
    geo = jaxlc.synthetic_geometry(duration_s=5)
    geo.loc[3, "shadow_nu"] = 7.0
    path = write_table(geo, tmp_path / "g.csv")
    with pytest.raises(TableError, match=r"row 3 \(line 6 of the file\)"):
        read_geometry(path)


def test_unknown_extension_and_missing_file(tmp_path):
    with pytest.raises(TableError, match=r"use \.csv or \.parquet"):
        read_table(tmp_path / "g.xlsx")
    with pytest.raises(TableError, match="does not exist"):
        read_table(tmp_path / "g.csv")
    (tmp_path / "junk.parquet").write_bytes(b"PAR1 not really")
    with pytest.raises(TableError, match="cannot read table"):
        read_table(tmp_path / "junk.parquet")


def test_atomic_output_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.csv"
    target.write_text("old content\n")
    with pytest.raises(RuntimeError), atomic_output(target) as tmp:
        tmp.write_text("half written")
        raise RuntimeError("crash mid-write")
    assert target.read_text() == "old content\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_lightcurve_round_trip(tmp_path):
    geo = jaxlc.synthetic_geometry(duration_s=20)
    geo.loc[4, "visible"] = False
    lc = jaxlc.render(SCENES / "s4_falcon9.toml", geo)
    for ext in ("csv", "parquet"):
        back = jaxlc.read_lightcurve(write_table(lc, tmp_path / f"lc.{ext}"))
        pd.testing.assert_frame_equal(back, lc, check_dtype=False)
        assert back.attrs["scene"].endswith("s4_falcon9.toml")

"""Property-based tests of every parser: a user-facing error or a valid result, nothing else.

Random bytes, random text and random-but-well-typed values (hypothesis) go
to the readers of scenes, meshes, tables, MMT tracks, TLEs and dataset
configs. Each must either return a result that passes its own contract or
raise :class:`jaxlc.errors.JaxlcError` (which the CLI prints as one line);
any other exception is a bug.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from helpers import MESHES, SCENES
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxlc.errors import JaxlcError
from jaxlc.geometry.tle import parse_tles
from jaxlc.io.observations import observed_samples, read_observations
from jaxlc.io.tables import POSITION_COLUMNS, read_geometry, validate_geometry
from jaxlc.scene import load_scene, scene_from_dict

SETTINGS = settings(
    max_examples=60,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

# Values of any TOML-ish type, including the awkward numbers.
NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(10**20), max_value=10**20),
    st.sampled_from([0, -1, 1e-300, 1e300, 0.5, 1.0, 90.0, 1e9]),
)
VALUES = st.one_of(
    NUMBERS,
    st.text(max_size=12),
    st.booleans(),
    st.lists(NUMBERS, max_size=5),
    st.dictionaries(st.text(max_size=5), NUMBERS, max_size=3),
)


def parse_file(suffix: str, content: bytes, reader):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"input{suffix}"
        path.write_bytes(content)
        try:
            return reader(path)
        except JaxlcError:
            return None


# --- random bytes --------------------------------------------------------------


@pytest.mark.parametrize(
    ("suffix", "reader"),
    [
        (".toml", load_scene),
        (".csv", read_geometry),
        (".parquet", read_geometry),
        (".txt", read_observations),
        (".csv", read_observations),
    ],
    ids=["scene", "geometry-csv", "geometry-parquet", "mmt", "lightcurve"],
)
@SETTINGS
@given(content=st.binary(max_size=400))
def test_random_bytes(suffix, reader, content):
    parse_file(suffix, content, reader)


@SETTINGS
@given(content=st.binary(max_size=400))
def test_random_bytes_mesh(content):
    from jaxlc.body.mesh import load_mesh

    mesh = parse_file(".obj", content, load_mesh)
    if mesh is not None:
        assert np.all(np.isfinite(mesh.vertices_m[mesh.faces]))


@SETTINGS
@given(text=st.text(alphabet="0123456789 .-+eE\n12U#", max_size=400))
def test_random_tle_text(text):
    try:
        tles = parse_tles(text, "fuzz.tle")
    except JaxlcError:
        return
    for tle in tles:  # a parsed TLE has a real epoch and propagates or says why not
        assert 1957 <= tle.epoch_utc.year <= 2100


def mmt_line(draw_values):
    return " ".join(str(v) for v in draw_values)


@SETTINGS
@given(
    rows=st.lists(
        st.tuples(
            st.sampled_from(["2016-01-21", "2016-13-01", "x", "2016-02-30"]),
            st.sampled_from(["01:15:50.993000", "25:00:00", "01:15:5", "01:15:51"]),
            NUMBERS,
            NUMBERS,
            st.sampled_from(["Clear", "V", "1"]),
            st.sampled_from(["0", "1", "x"]),
            NUMBERS,
            NUMBERS,
            st.sampled_from(["7", "x"]),
        ),
        max_size=30,
    ),
    period=st.one_of(st.text(max_size=6), NUMBERS),
)
def test_mmt_tracks_with_random_fields(rows, period):
    head = f"# satellite: 1 X\n# variability_period: {period}\n"
    content = (head + "\n".join(mmt_line(r) for r in rows) + "\n").encode()
    obs = parse_file(".txt", content, read_observations)
    if obs is None:
        return
    assert np.all(np.diff(obs["t_s"].to_numpy()) >= 0)
    try:
        t, y, _ = observed_samples(obs, "std_mag")
    except JaxlcError:
        return
    assert np.all(np.isfinite(t)) and np.all(np.isfinite(y)) and len(t) >= 10


# --- well-typed but hostile values ------------------------------------------------

BASE_SCENE = load_scene(SCENES / "s4_falcon9.toml")
SCENE_KEYS = [
    ("object", "scale"),
    ("attitude", "period_s"),
    ("attitude", "pole_dec_deg"),
    ("attitude", "pole_ra_deg"),
    ("attitude", "phase_deg"),
    ("attitude", "epoch_utc"),
    ("attitude", "body_axis"),
    ("attitude", "model"),
    ("sensor", "exposure_s"),
    ("material", "rd"),
    ("material", "rs"),
    ("material", "nu"),
    ("material", "brdf"),
]


def scene_dict() -> dict:
    import tomllib

    text = (SCENES / "s4_falcon9.toml").read_text().replace('"../meshes/', f'"{MESHES}/')
    return tomllib.loads(text)


@SETTINGS
@given(edits=st.lists(st.tuples(st.sampled_from(SCENE_KEYS), VALUES), min_size=1, max_size=3))
def test_scene_values(edits):
    data = scene_dict()
    for (table, key), value in edits:
        target = data[table][0] if table == "material" else data.setdefault(table, {})
        target[key] = value
    try:
        scene = scene_from_dict(data, "fuzz.toml")
    except JaxlcError:
        return
    att = scene.attitude
    assert math.isfinite(scene.scale) and scene.scale > 0
    assert 0 < scene.exposure_s <= 3600
    if att.model == "spin":
        assert 1e-3 <= att.period_s <= 1e9 and -90 <= att.pole_dec_deg <= 90
        assert np.isclose(np.linalg.norm(att.body_axis), 1.0)
    for m in scene.materials:
        assert 0 <= m.brdf.rd <= 1


COLUMN_VALUES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.sampled_from([0.0, 1.0, 1.5e11, 7e6, 7e3, -1e300]),
)


@SETTINGS
@given(
    column=st.sampled_from([*POSITION_COLUMNS, "t_s", "exposure_s", "shadow_nu", "visible"]),
    row=st.integers(0, 9),
    value=st.one_of(COLUMN_VALUES, st.text(max_size=5)),
)
def test_geometry_cells(column, row, value):
    from jaxlc.geometry.synthetic import synthetic_geometry

    df = synthetic_geometry(duration_s=10)
    df[column] = df[column].astype(object)
    df.loc[row, column] = value
    try:
        out = validate_geometry(df)
    except JaxlcError:
        return
    vis = out["visible"].to_numpy()
    for name in POSITION_COLUMNS:
        assert np.all(np.isfinite(out[name].to_numpy()[vis]))
    assert np.all((out["shadow_nu"].to_numpy()[vis] >= 0) & (out["shadow_nu"].to_numpy()[vis] <= 1))
    sun = (
        out[[f"sun_{c}_m" for c in "xyz"]].to_numpy()
        - out[[f"rso_{c}_m" for c in "xyz"]].to_numpy()
    )
    au = np.linalg.norm(sun, axis=1)[vis] / 1.495978707e11
    assert np.all((au > 0.9) & (au < 1.1))


@SETTINGS
@given(
    edits=st.lists(
        st.tuples(
            st.sampled_from(
                [
                    "count",
                    "samples",
                    "cadence_s",
                    "exposure_s",
                    "shard_size",
                    "seed",
                    "scale",
                    "period_s",
                ]
            ),
            VALUES,
        ),
        min_size=1,
        max_size=3,
    )
)
def test_dataset_config_values(edits):
    import tomllib

    from jaxlc.dataset.config_file import config_from_dict

    text = (Path(__file__).parent.parent / "experiments/configs/bulk_example.toml").read_text()
    data = tomllib.loads(text)
    tables = [data["dataset"], *data["class"]]
    for key, value in edits:
        for table in tables:  # the key wherever the example config has it
            if key in table:
                table[key] = value
    try:
        config_from_dict(data, source="fuzz.toml", base_dir=SCENES.parent)
    except JaxlcError:
        return

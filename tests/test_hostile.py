"""Hostile input, command by command: one line naming the input, status 1, nothing left.

Each case writes its inputs into an empty folder, runs the command line in
process (:func:`jaxlc.cli.main`) and asserts the exit status, that stderr is
one line starting ``error:`` (no traceback) with the case's words in it, and
that no file other than the inputs remains (no output, no temporary file).
TLE and geometry-command cases live in ``test_tle.py``/``test_geometry_cli.py``,
dataset configs in ``test_dataset.py``; the parsers' property-based tests are
in ``test_parsers_fuzz.py``.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from helpers import MESHES, SCENES

from jaxlc.cli import main
from jaxlc.geometry.synthetic import synthetic_geometry

# --- inputs ------------------------------------------------------------------

SCENE = (SCENES / "s5_cubesat.toml").read_text().replace('"../meshes/', f'"{MESHES}/')
EPOCH = 'epoch_utc = "2019-07-07T12:00:00Z"'
assert EPOCH in SCENE and "period_s = 10.0" in SCENE


def scene(*edits, append: str = "") -> str:
    """The S5 scene with text replacements (old, new) and extra lines."""
    text = SCENE
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new)
    return text + append


def geo_table(n: int = 30):
    """A 30-row table in GCRS: the object 7,000 km from the Earth's centre."""
    g = synthetic_geometry(duration_s=n, phase_start_deg=30, phase_end_deg=60)
    offset = np.array([7.0e6, 0.0, 0.0])
    for body in ("rso", "sun", "obs"):
        for k, c in enumerate("xyz"):
            g[f"{body}_{c}_m"] += offset[k]
    g.attrs["frame"] = "GCRS"
    return g


def geometry_csv(edit=None, frame: str = "GCRS") -> str:
    """The GCRS table as CSV text, after ``edit(df)``."""
    df = geo_table()
    if edit is not None:
        edit(df)
    lines = [f"# frame: {frame}", df.to_csv(index=False, float_format="%.17g").strip()]
    return "\n".join(lines) + "\n"


def set_cell(column, row, value):
    def edit(df):
        df[column] = df[column].astype(object)
        df.loc[row, column] = value

    return edit


def scale_positions(factor, bodies=("rso", "sun", "obs")):
    def edit(df):
        for b in bodies:
            for c in "xyz":
                df[f"{b}_{c}_m"] *= factor

    return edit


def move(body, to="rso", by=(0.0, 0.0, 0.0)):
    def edit(df):
        for k, c in enumerate("xyz"):
            df[f"{body}_{c}_m"] = df[f"{to}_{c}_m"] + by[k]

    return edit


def mmt(rows=None, header=None) -> str:
    head = header or [
        "# satellite: 12345 TEST R/B",
        "# track: 1",
        "# variability: 2 Periodic",
        "# variability_period: 10.0",
        "#",
        "# Date Time StdMag Mag Filter Penumbra Distance Phase Channel",
    ]
    if rows is None:
        rows = [
            f"2016-01-21 01:15:{s:02d}.000 {5 + 0.3 * np.sin(s):.3f} 9.1 Clear 0 1000.0 60.0 7"
            for s in range(40)
        ]
    return "\n".join([*head, *rows]) + "\n"


def lightcurve_csv(n=40, columns=("t_s", "mag"), bad=None) -> str:
    t = np.arange(n, dtype=float)
    cols = {"t_s": t, "utc": [f"2020-01-01T00:00:{i:02d}Z" for i in range(n)]}
    cols["mag"] = 10 + 0.3 * np.sin(t)
    text = ",".join(columns) + "\n"
    for i in range(n):
        text += ",".join(str(cols[c][i]) for c in columns) + "\n"
    if bad is not None:
        text = text.replace(*bad, 1)
    return text


OBJ_NO_FACES = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
# every face uses the NaN vertex (a mesh with some NaN faces renders the rest, with a warning)
OBJ_NAN = "v 0 0 0\nv nan 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 4 2\nf 2 4 3\n"


def with_mesh(name: str) -> str:
    return scene((f"{MESHES}/cubesat_3u.obj", name))


# --- the catalogue -----------------------------------------------------------
# (id, argv, files {name: text or bytes}, words expected in the error line)

R = ["render", "sc.toml", "geo.csv", "-o", "out.csv"]
FIT = ["fit", "sc.toml", "lc.csv", "--geometry", "geo.csv", "-o", "fit"]
P = ["period", "lc.csv"]
PM = ["period", "track.txt"]
OK = {"sc.toml": SCENE, "geo.csv": geometry_csv()}

CASES = [
    # scene files
    ("scene missing", ["render", "nope.toml", "geo.csv", "-o", "out.csv"], OK, "does not exist"),
    ("scene binary", R, {**OK, "sc.toml": os.urandom(300)}, "sc.toml"),
    ("scene not toml", R, {**OK, "sc.toml": "[object\nmesh = 1"}, "not valid TOML"),
    (
        "scene no object",
        R,
        {**OK, "sc.toml": scene(("[object]", "[objekt]"))},
        "missing required key 'object'",
    ),
    ("scene unknown key", R, {**OK, "sc.toml": scene(append="\n[sensor2]\nx = 1\n")}, "sensor2"),
    ("mesh not found", R, {**OK, "sc.toml": with_mesh("/nowhere/x.obj")}, "not found"),
    ("brdf unknown", R, {**OK, "sc.toml": scene(('"ashikhmin-shirley"', '"phong"'))}, "phong"),
    ("rd above 1", R, {**OK, "sc.toml": scene(("rd = 0.", "rd = 1.5 #"))}, "rd = 1.5"),
    ("rd text", R, {**OK, "sc.toml": scene(("rd = 0.", 'rd = "high" #'))}, "must be a number"),
    ("nu negative", R, {**OK, "sc.toml": scene(("nu = ", "nu = -5 #"))}, "nu = -5"),
    (
        "as-glossy over 1",
        R,
        {
            **OK,
            "sc.toml": scene(
                ('"ashikhmin-shirley"', '"as-glossy"'),
                ("rd = 0.", "rd = 0.9 #"),
                ("rs = 0.", "rs = 0.5 #"),
            ),
        },
        "rd + rs",
    ),
    (
        "period tiny",
        R,
        {**OK, "sc.toml": scene(("period_s = 10.0", "period_s = 1e-300"))},
        "period_s",
    ),
    ("period nan", R, {**OK, "sc.toml": scene(("period_s = 10.0", "period_s = nan"))}, "finite"),
    ("period inf", R, {**OK, "sc.toml": scene(("period_s = 10.0", "period_s = inf"))}, "finite"),
    (
        "period text",
        R,
        {**OK, "sc.toml": scene(("period_s = 10.0", 'period_s = "10 s"'))},
        "number",
    ),
    ("epoch now", R, {**OK, "sc.toml": scene((EPOCH, 'epoch_utc = "now"'))}, "'now'"),
    ("epoch empty", R, {**OK, "sc.toml": scene((EPOCH, 'epoch_utc = ""'))}, "epoch_utc = ''"),
    (
        "epoch month 13",
        R,
        {**OK, "sc.toml": scene((EPOCH, 'epoch_utc = "2019-13-45T00:00:00Z"'))},
        "ISO 8601",
    ),
    ("epoch number", R, {**OK, "sc.toml": scene((EPOCH, "epoch_utc = 2019"))}, "epoch_utc"),
    (
        "pole dec 95",
        R,
        {**OK, "sc.toml": scene(("pole_dec_deg = ", "pole_dec_deg = 95 #"))},
        "pole_dec_deg",
    ),
    (
        "axis zero",
        R,
        {**OK, "sc.toml": scene(("body_axis = [", "body_axis = [0, 0, 0] #"))},
        "zero vector",
    ),
    (
        "axis two numbers",
        R,
        {**OK, "sc.toml": scene(("body_axis = [", "body_axis = [1, 0] #"))},
        "3 finite",
    ),
    (
        "model unknown",
        R,
        {**OK, "sc.toml": scene(('model = "spin"', 'model = "wobble"'))},
        "wobble",
    ),
    ("exposure huge", R, {**OK, "sc.toml": scene(append="")}, None),  # placeholder, replaced below
    ("scale zero", R, {**OK, "sc.toml": scene(("[object]", "[object]\nscale = 0"))}, "scale = 0"),
    ("part unknown", R, {**OK, "sc.toml": scene(('part = "*"', 'part = "wing"'))}, "'wing'"),
    (
        "render option",
        R,
        {**OK, "sc.toml": scene(append='\n[render]\nshadows = "maybe"\n')},
        "shadows",
    ),
    # meshes
    (
        "mesh binary",
        R,
        {**OK, "sc.toml": with_mesh("bin.obj"), "bin.obj": os.urandom(2000)},
        "bin.obj",
    ),
    ("mesh empty", R, {**OK, "sc.toml": with_mesh("e.obj"), "e.obj": ""}, "e.obj"),
    ("mesh no faces", R, {**OK, "sc.toml": with_mesh("v.obj"), "v.obj": OBJ_NO_FACES}, "v.obj"),
    ("mesh nan vertex", R, {**OK, "sc.toml": with_mesh("n.obj"), "n.obj": OBJ_NAN}, "non-finite"),
    ("mesh wrong format", R, {**OK, "sc.toml": with_mesh("m.xyz"), "m.xyz": "1 2 3\n"}, "m.xyz"),
    # geometry tables
    ("geometry missing", ["render", "sc.toml", "no.csv", "-o", "out.csv"], OK, "does not exist"),
    (
        "geometry xlsx",
        ["render", "sc.toml", "g.xlsx", "-o", "out.csv"],
        {**OK, "g.xlsx": "x"},
        ".xlsx",
    ),
    ("geometry empty file", R, {**OK, "geo.csv": ""}, "geo.csv"),
    ("geometry binary", R, {**OK, "geo.csv": os.urandom(500)}, "geo.csv"),
    (
        "geometry parquet is csv",
        ["render", "sc.toml", "g.parquet", "-o", "out.csv"],
        {**OK, "g.parquet": geometry_csv()},
        "cannot read table",
    ),
    (
        "geometry no column",
        R,
        {**OK, "geo.csv": geometry_csv(lambda d: d.pop("rso_x_m"))},
        "rso_x_m",
    ),
    (
        "geometry text",
        R,
        {**OK, "geo.csv": geometry_csv(set_cell("rso_y_m", 4, "abc"))},
        "non-number 'abc'",
    ),
    (
        "geometry nan",
        R,
        {**OK, "geo.csv": geometry_csv(set_cell("obs_z_m", 2, float("nan")))},
        "must be finite",
    ),
    (
        "geometry inf",
        R,
        {**OK, "geo.csv": geometry_csv(set_cell("sun_x_m", 2, float("inf")))},
        "finite",
    ),
    ("geometry frame ITRF", R, {**OK, "geo.csv": geometry_csv(frame="ITRF")}, "frame 'ITRF'"),
    (
        "geometry kilometres",
        R,
        {**OK, "geo.csv": geometry_csv(scale_positions(1e-3))},
        "kilometres",
    ),
    ("geometry sun 1 m", R, {**OK, "geo.csv": geometry_csv(move("sun", by=(1.0, 0, 0)))}, "AU"),
    (
        "geometry observer at object",
        R,
        {**OK, "geo.csv": geometry_csv(move("obs", by=(1e-9, 0, 0)))},
        "parallel rays",
    ),
    (
        "geometry observer at 1 m",
        R,
        {**OK, "geo.csv": geometry_csv(move("obs", by=(1.0, 0, 0)))},
        "parallel rays",
    ),
    (
        "geometry object in Earth",
        R,
        {**OK, "geo.csv": geometry_csv(scale_positions(0.5, ("rso",)))},
        "inside the Earth",
    ),
    (
        "geometry time backwards",
        R,
        {**OK, "geo.csv": geometry_csv(set_cell("t_s", 5, -1.0))},
        "t_s",
    ),
    (
        "geometry utc garbage",
        R,
        {**OK, "geo.csv": geometry_csv(set_cell("utc", 3, "yesterday"))},
        "yesterday",
    ),
    ("geometry utc now", R, {**OK, "geo.csv": geometry_csv(set_cell("utc", 0, "now"))}, "'now'"),
    (
        "geometry visible maybe",
        R,
        {**OK, "geo.csv": geometry_csv(set_cell("visible", 1, "maybe"))},
        "true/false",
    ),
    (
        "geometry shadow_nu 2",
        R,
        {**OK, "geo.csv": geometry_csv(set_cell("shadow_nu", 1, 2.0))},
        "[0, 1]",
    ),
    (
        "geometry exposure negative",
        R,
        {**OK, "geo.csv": geometry_csv(set_cell("exposure_s", 1, -1.0))},
        "exposure_s",
    ),
    (
        "geometry semicolons",
        R,
        {**OK, "geo.csv": geometry_csv().replace(",", ";")},
        "separated by semicolons",
    ),
    ("geometry header only", R, {**OK, "geo.csv": "# frame: GCRS\nutc,t_s\n"}, "missing column"),
    # render options and outputs
    ("render precision", [*R, "--precision", "half"], OK, "precision = 'half'"),
    ("render subsamples", [*R, "--subsamples", "lots"], OK, "--subsamples = 'lots'"),
    ("render shadows", [*R, "--shadows", "maybe"], OK, "shadows"),
    ("render shadow grid 0", [*R, "--shadow-grid", "0"], OK, "grid"),
    ("render shadow exact", [*R, "--shadow-exact", "yes"], OK, "--shadow-exact: shadow_exact"),
    ("render output xlsx", ["render", "sc.toml", "geo.csv", "-o", "out.xlsx"], OK, ".xlsx"),
    (
        "render output is folder",
        ["render", "sc.toml", "geo.csv", "-o", "d.csv"],
        {**OK, "d.csv/keep": ""},
        "is a folder",
    ),
    (
        "render output under file",
        ["render", "sc.toml", "geo.csv", "-o", "f.txt/out.csv"],
        {**OK, "f.txt": ""},
        "is a file",
    ),
    ("render plot format", [*R, "--plot", "lc.xyz"], OK, "cannot save a plot as .xyz"),
    # observed light curves (period)
    ("period missing", ["period", "none.csv"], {}, "does not exist"),
    (
        "period text file",
        ["period", "notes.txt"],
        {"notes.txt": "hello\n"},
        "neither a light-curve table",
    ),
    ("period no time column", P, {"lc.csv": lightcurve_csv(columns=("mag",))}, "time column"),
    ("period no mag column", P, {"lc.csv": lightcurve_csv(columns=("t_s",))}, "no column 'mag'"),
    (
        "period unknown column",
        [*P, "--column", "flux"],
        {"lc.csv": lightcurve_csv()},
        "no column 'flux'",
    ),
    (
        "period text in mag",
        P,
        {"lc.csv": lightcurve_csv(bad=("\n5.0,", "\n5.0,bright #"))},
        "non-number",
    ),
    ("period few samples", P, {"lc.csv": lightcurve_csv(n=5)}, "at least 10"),
    (
        "period bad utc",
        ["period", "u.csv"],
        {"u.csv": lightcurve_csv(columns=("utc", "mag"), bad=("2020-01-01T00:00:03Z", "03:00"))},
        "03:00",
    ),
    (
        "period plot format",
        [*P, "--plot", "p.docx"],
        {"lc.csv": lightcurve_csv()},
        "cannot save a plot",
    ),
    (
        "period min negative",
        [*P, "--min-period-s", "-1"],
        {"lc.csv": lightcurve_csv()},
        "min_period_s",
    ),
    (
        "period max below min",
        [*P, "--min-period-s", "20", "--max-period-s", "5"],
        {"lc.csv": lightcurve_csv()},
        "max_period_s",
    ),
    (
        "period permutations 0",
        [*P, "--permutations", "0"],
        {"lc.csv": lightcurve_csv()},
        "permutations",
    ),
    (
        "mmt truncated row",
        PM,
        {"track.txt": mmt() + "2016-01-21 01:16:00.000 5.1\n"},
        "expected 9 columns",
    ),
    (
        "mmt bad date",
        PM,
        {"track.txt": mmt(rows=["2016-99-21 01:15:00 5 9 Clear 0 1000 60 7"])},
        "not a UTC time",
    ),
    (
        "mmt text mag",
        PM,
        {"track.txt": mmt(rows=["2016-01-21 01:15:00 bright 9 Clear 0 1000 60 7"])},
        "StdMag",
    ),
    (
        "mmt bad period header",
        PM,
        {"track.txt": mmt().replace("period: 10.0", "period: ten")},
        "variability_period",
    ),
    ("mmt no rows", PM, {"track.txt": mmt(rows=[])}, "no data rows"),
    (
        "mmt backwards",
        PM,
        {
            "track.txt": mmt(
                rows=[f"2016-01-21 01:15:{59 - s:02d} 5 9 Clear 0 1000 60 7" for s in range(20)]
            )
        },
        "backwards",
    ),
    (
        "mmt nan",
        PM,
        {"track.txt": mmt(rows=["2016-01-21 01:15:00 nan 9 Clear 0 1000 60 7"])},
        "not finite",
    ),
    # fit and calibrate options
    (
        "fit output is file",
        ["fit", "sc.toml", "lc.csv", "--geometry", "geo.csv", "-o", "f.txt"],
        {**OK, "lc.csv": "", "f.txt": ""},
        "is a file",
    ),
    (
        "fit light curve missing",
        ["fit", "sc.toml", "none.csv", "--geometry", "geo.csv", "-o", "fit"],
        OK,
        "does not exist",
    ),
    (
        "fit walkers 2",
        ["fit", "sc.toml", "lc.csv", "--geometry", "geo.csv", "-o", "fit", "--walkers", "2"],
        {**OK, "lc.csv": ""},
        "walkers",
    ),
    (
        "fit shadow exact glints",
        [*FIT, "--shadow-exact", "glints"],
        OK,
        "shadow_exact = 'glints' is for single renders",
    ),
    ("fit shadow exact yes", [*FIT, "--shadow-exact", "yes"], OK, "--shadow-exact: shadow_exact"),
    ("crosscheck scene", ["calibrate", "crosscheck", "--scenes", "S9", "--out", "cc"], {}, "'S9'"),
    (
        "crosscheck material",
        ["calibrate", "crosscheck", "--material", "cycles", "--out", "cc"],
        {},
        "'cycles'",
    ),
    (
        "crosscheck as scene",
        ["calibrate", "crosscheck", "--material", "as", "--scenes", "S9", "--out", "cc"],
        {},
        "'S9'",
    ),
    (
        "calibrate output ext",
        ["calibrate", "render", "sc.toml", "geo.csv", "-o", "c.txt"],
        OK,
        ".txt",
    ),
    # telescope frames (jaxlc frames / jaxlc extract)
    (
        "extract not fits",
        ["extract", "fr", "-o", "lc.csv"],
        {"fr/a.fits": "text"},
        "not a readable FITS",
    ),
    ("extract no fits", ["extract", "fr", "-o", "lc.csv"], {"fr/a.txt": "x"}, "holds no FITS"),
    ("extract no folder", ["extract", "nope", "-o", "lc.csv"], {}, "no such folder"),
    (
        "extract catalog columns",
        ["extract", "fr", "-o", "lc.csv", "--catalog", "cat.csv"],
        {"fr/a.fits": "text", "cat.csv": "ra,dec,vmag\n1,2,3\n"},
        "needs ra_deg, dec_deg, mag",
    ),
    ("extract output ext", ["extract", "fr", "-o", "lc.txt"], {"fr/a.fits": "x"}, ".txt"),
    (
        "frames catalog missing",
        ["frames", "sc.toml", "geo.csv", "-o", "fr", "--catalog", "nope.csv"],
        OK,
        "no such file",
    ),
    ("frames gain", ["frames", "sc.toml", "geo.csv", "-o", "fr", "--gain", "-1"], OK, "gain"),
    (
        "frames readout",
        ["frames", "sc.toml", "geo.csv", "-o", "fr", "--readout-s", "1e6"],
        OK,
        "--readout-s",
    ),
]
# the placeholder above: an exposure of one day
CASES = [
    c
    if c[0] != "exposure huge"
    else (
        c[0],
        R,
        {**OK, "sc.toml": scene(("exposure_s = 1.0", "exposure_s = 86400"))},
        "exposure_s",
    )
    for c in CASES
]


def write_inputs(folder, files):
    for name, content in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)


def snapshot(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.mark.parametrize(
    ("argv", "files", "words"), [c[1:] for c in CASES], ids=[c[0] for c in CASES]
)
def test_bad_input_one_line_nothing_left(tmp_path, monkeypatch, capsys, argv, files, words):
    write_inputs(tmp_path, files)
    before = snapshot(tmp_path)
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    status = main(list(argv))
    err = capsys.readouterr().err
    lines = [x for x in err.strip().splitlines() if x.strip() and not x.startswith("warning:")]
    assert status == 1, err
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err and "unexpected" not in err, err
    assert words in lines[0], err
    assert snapshot(tmp_path) == before


def test_catalogue_is_large_and_distinct():
    names = [c[0] for c in CASES]
    assert len(names) >= 60 and len(set(names)) == len(names)


def test_unexpected_exception_is_one_line_with_debug_hint(monkeypatch, capsys):
    """The guard: an internal error becomes one line; --debug brings the traceback back."""

    def boom():
        raise KeyError("internal")

    monkeypatch.setattr("jaxlc.info.print_info", boom)
    assert main(["info"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unexpected KeyError" in err[0] and "--debug" in err[0]
    assert "jaxlc info" in err[0]
    with pytest.raises(KeyError):
        main(["--debug", "info"])


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["render"], "Missing argument 'scene'"),
        (["render", "a.toml", "g.csv"], "Missing option '-o'"),
        (["render", "a.toml", "g.csv", "-o", "x.csv", "--precision"], "requires an argument"),
        (["period", "x.csv", "--max-period-s", "abc"], "Invalid value for '--max-period-s'"),
        (
            ["fit", "a.toml", "lc.csv", "--geometry", "g.csv", "-o", "f", "--walkers", "x"],
            "walkers",
        ),
        (["geometry"], "Missing command"),
        (["sites", "extra"], "unexpected extra argument"),
        (["rendr"], "No such command 'rendr'"),
        (["render", "--shadow-grid", "1.5", "a", "b", "-o", "c"], "shadow-grid"),
    ],
)
def test_usage_errors_one_line_status_2(tmp_path, monkeypatch, capsys, argv, words):
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and words in err[0], err
    assert "--help" in err[0] and not list(tmp_path.iterdir())

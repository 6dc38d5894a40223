"""The command line, run as a user would: one clear line on error, no partial files."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from helpers import MESHES, REPO, SCENES

import jaxlc
from jaxlc.cli import main


def run_cli(*args, cwd=REPO):
    return subprocess.run(
        [sys.executable, "-m", "jaxlc.cli", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=300,
    )


def test_synthetic_then_render_with_plot(tmp_path):
    geo = tmp_path / "geo.parquet"
    r = run_cli("geometry", "synthetic", "-o", geo, "--duration-s", 120, "--phase-start-deg", 30)
    assert r.returncode == 0, r.stderr
    lc_path, png = tmp_path / "lc.csv", tmp_path / "lc.png"
    r = run_cli("render", SCENES / "s4_falcon9.toml", geo, "-o", lc_path, "--plot", png)
    assert r.returncode == 0, r.stderr
    assert "1205 facets" in r.stderr and "non-convex" in r.stderr
    lc = jaxlc.read_lightcurve(lc_path)
    assert len(lc) == 120 and lc["mag"].notna().all()
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    ref = jaxlc.render(SCENES / "s4_falcon9.toml", geo)
    assert (abs(lc["mag"] - ref["mag"]) < 1e-12).all()


def test_float64_option(tmp_path):
    geo = tmp_path / "geo.csv"
    assert main(["geometry", "synthetic", "-o", str(geo), "--duration-s", "30"]) == 0
    out = tmp_path / "lc.parquet"
    assert (
        main(
            [
                "render",
                str(SCENES / "s5_cubesat.toml"),
                str(geo),
                "-o",
                str(out),
                "--precision",
                "float64",
            ]
        )
        == 0
    )
    assert jaxlc.read_lightcurve(out).attrs["precision"] == "float64"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["render", "nope.toml", "geo.csv", "-o", "out.csv"],
            "scene file 'nope.toml' does not exist",
        ),
        (
            ["render", "bad.toml", "geo.csv", "-o", "out.csv"],
            "period_s = -1.0 is outside [0.001, 1e+09]",
        ),
        (
            ["render", "@S5", "missing.csv", "-o", "out.csv"],
            "table file 'missing.csv' does not exist",
        ),
        (
            ["render", "@S5", "geo.csv", "-o", "out.csv", "--precision", "half"],
            "precision = 'half'",
        ),
        (["render", "@S5", "geo.csv", "-o", "out.xlsx"], "unknown table extension '.xlsx'"),
        (
            ["geometry", "synthetic", "-o", "g.csv", "--phase-end-deg", "200"],
            "phase_end_deg = 200.0 must be in",
        ),
    ],
)
def test_errors_are_one_line_without_traceback(tmp_path, args, message):
    (tmp_path / "bad.toml").write_text(
        (SCENES / "s5_cubesat.toml")
        .read_text()
        .replace("period_s = 10.0", "period_s = -1.0")
        .replace('"../meshes/', f'"{MESHES}/')
    )
    assert (
        main(["geometry", "synthetic", "-o", str(tmp_path / "geo.csv"), "--duration-s", "5"]) == 0
    )
    args = [str(SCENES / "s5_cubesat.toml") if a == "@S5" else a for a in args]
    r = run_cli(*args, cwd=tmp_path)
    assert r.returncode == 1
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert message in lines[0]
    assert "Traceback" not in r.stderr
    # nothing half-written
    assert not (tmp_path / "out.csv").exists() and not (tmp_path / "out.xlsx").exists()
    assert not list(tmp_path.glob(".*.tmp*"))


def test_debug_shows_traceback(tmp_path):
    r = run_cli("--debug", "render", "nope.toml", "g.csv", "-o", "o.csv", cwd=tmp_path)
    assert r.returncode != 0 and "Traceback" in r.stderr and "SceneError" in r.stderr


def test_usage_error_exit_code(tmp_path):
    r = run_cli("render", cwd=tmp_path)
    assert r.returncode == 2 and "Missing argument" in r.stderr


def test_python_m_jaxlc_reports_environment():
    r = subprocess.run([sys.executable, "-m", "jaxlc"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    for word in ("jax", "JAX backend", "cpu", "precision", "blender", "dask"):
        assert word in r.stdout, word


def test_info_dict():
    from jaxlc.info import info

    d = info()
    assert d["backend"] in ("cpu", "gpu", "tpu")
    assert set(d["optional"]) == {"blender", "dask"}


def test_console_script_installed():
    exe = Path(sys.executable).parent / "jaxlc"
    r = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "render" in r.stdout and "geometry" in r.stdout

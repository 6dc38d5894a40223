"""Benchmark scripts still run (smoke test; no timing is asserted)."""

from __future__ import annotations

import subprocess
import sys

import pytest
from helpers import REPO

import jaxlc


def run_experiment(script: str, *args: str, timeout: int = 600) -> subprocess.CompletedProcess:
    """Run ``experiments/<script>`` with ``args`` in a fresh interpreter; fail on a non-zero
    exit with its stderr."""
    r = subprocess.run(
        [sys.executable, str(REPO / "experiments" / script), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert r.returncode == 0, r.stderr
    return r


def test_bench_render_quick(tmp_path):
    out = tmp_path / "bench.csv"
    run_experiment("bench_render.py", "--quick", "--out", str(out))
    df = jaxlc.read_table(out)
    assert set(df["table"]) == {"A", "B", "C", "D"}
    assert set(df[df.table == "A"]["scene"]) == {"S2", "S3", "S4", "S5", "S6"}
    assert (df["facet_samples_per_s"] > 0).all()
    # the naive and the fused kernels compute the same sum
    assert (df[df.table == "C"]["naive_vs_fused_max_rel_diff"] < 1e-5).all()
    assert df.attrs["backend"] and df.attrs["jax"]  # provenance travels with the CSV
    costs = df[df.table == "D"]
    assert set(costs["scene"]) == {"S4", "S5", "S6"} and (costs["cost_vs_plain"] > 0).all()


def test_bench_geometry_quick(tmp_path):
    out = tmp_path / "geo.csv"
    run_experiment("bench_geometry.py", "--quick", "--out", str(out))
    df = jaxlc.read_table(out)
    assert df["stage"].iloc[0].startswith("find_passes")
    assert (df["object_samples_per_s"] > 0).all()
    assert (df["position_error_vs_skyfield_m"] < 0.01).all()  # interpolated nutation: < 1 cm


def test_pareto_quick(tmp_path):
    out = tmp_path / "pareto.csv"
    run_experiment("pareto.py", "--quick", "--out", str(out), timeout=900)
    df = jaxlc.read_table(out)
    assert set(df["knob"]) == {"facets", "shadows", "blur"}
    assert out.with_suffix(".png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.slow
def test_sbc_fit_small(tmp_path):
    """The calibration study in small: its first case (a fixed seed: random pole,
    period and phase, 0.05 mag noise over the first 400 s of the real pass) with
    fewer starts. It
    must recover the period and, in one of its modes, the pole (the render → fit
    round trips of tests/test_consistency.py check recovery more widely)."""
    out = tmp_path / "sbc.csv"
    run_experiment(
        "sbc_fit.py",
        *("--cases", "1", "--starts", "512", "--max-steps", "1000", "--modes", "2"),
        *("--duration-s", "400"),
        *("--out", str(out)),
        timeout=900,
    )
    df = jaxlc.read_table(out)
    assert len(df) == 1
    assert (df["period_rel_err"].abs() < 1e-3).all()
    assert (df["nearest_pole_err_deg"] < 3.0).all()
    assert df["period_rank"].between(0, 1).all() and df["pole_rank"].between(0, 1).all()
    assert out.with_suffix(".png").read_bytes()[:4] == b"\x89PNG"


def test_shadow_curves_quick(tmp_path):
    """The per-curve shadow check (issue 16's 2 % of the median flux) runs and writes one
    row per curve that is lit and seen."""
    out = tmp_path / "curves.csv"
    r = run_experiment(
        "shadow_curves.py",
        *("--curves", "3", "--samples", "8", "--workers", "1"),
        *("--scenes", "s7_antenna_box", "--out", str(out)),
    )
    df = jaxlc.read_table(out)
    assert len(df) >= 1 and set(df["scene"]) == {"s7_antenna_box"}
    assert (df["lit_samples"] >= 3).all() and (df["max_err_of_median_flux"] >= 0).all()
    assert "every error ≤ 2 %" in r.stdout


def test_quadrature_study_replays_the_code(tmp_path):
    """The quadrature study's replay of the adaptive scheme (from dense instants, its own
    code) gives the instants and errors of jaxlc's refinement on the same curve."""
    out = tmp_path / "quad.csv"
    run_experiment("quadrature_study.py", "--curves", "1", "--classes", "S3", "--out", str(out))
    df = jaxlc.read_table(out)
    code = df[df["scheme"] == "patterson"].iloc[0]
    assert code["instants_per_exposure"] == pytest.approx(code["render_instants"], rel=0.05)
    assert code["max_mmag"] == pytest.approx(code["render_max_mmag"], rel=1e-3, abs=1e-3)
    assert {"midpoint", "patterson"} <= set(df["scheme"])

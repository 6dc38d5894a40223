"""Two periods: a tumbling body's light curve shows both, a spinning body's shows one.

The reference for a tumble is its motion (:meth:`jaxlc.body.tumble.Tumble.periods_s`,
itself checked against an integrator of Euler's equations in test_tumble.py): its
light curve's frequencies are the combinations j/P_ψ + k/T_ω, so each reported
period must be one of them (small j, k, within the span's resolution), and the two
must not be one combination's multiples. Spinning bodies (one period by
construction) over the same pass must never be given two.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from helpers import REPO

import jaxlc
from jaxlc.inference.period import analyse_period
from jaxlc.inference.two_periods import lattice_combination


@pytest.fixture(scope="module")
def demo_pass(tmp_path_factory):
    from jaxlc.cli import main

    geo = tmp_path_factory.mktemp("pass") / "geometry.csv"
    tle = REPO / "data" / "tle" / "falcon9_rb.tle"
    args = ["--tle", str(tle), "--norad", "45921", "--site", "mt-stromlo"]
    when = ["--start", "2020-08-10T18:00:00Z", "--duration-s", "1200", "--step-s", "1"]
    assert main(["geometry", "pass", *args, *when, "--exposure-s", "1", "-o", str(geo)]) == 0
    return jaxlc.read_geometry(geo)


def _observed(scene, geo, seed: int, noise_mag: float = 0.05):
    lc = jaxlc.render(scene, geo)
    v = lc[lc["visible"]]
    y = v["mag"].to_numpy() + noise_mag * np.random.default_rng(seed).standard_normal(len(v))
    return v["t_s"].to_numpy(), y


def test_the_tumbling_stage_shows_its_two_periods(demo_pass):
    """The shipped tumbling Falcon 9 stage (SAM, P_ψ 48.0 s, T_ω 166 s) over the demo
    pass, 0.05 mag noise, three noise draws (measured: 67.5 s = 1/(1/P_ψ − 1/T_ω)
    and 56.1 s ≈ T_ω/3)."""
    scene = jaxlc.load_scene("falcon9_tumble")
    body, precession = scene.attitude.tumble().periods_s()
    lc = jaxlc.render(scene, demo_pass)
    v = lc[lc["visible"]]
    for seed in range(3):
        y = v["mag"].to_numpy() + 0.05 * np.random.default_rng(seed).standard_normal(len(v))
        r = analyse_period(v["t_s"].to_numpy(), y)
        assert r.verdict == "two periods" and r.two_periods and r.periodic, r.decision
        tol = 1.0 / r.span_s
        first = lattice_combination(1 / r.period_s, 1 / precession, 1 / body, tol)
        second = lattice_combination(1 / r.second_period_s, 1 / precession, 1 / body, tol)
        assert first is not None and second is not None, (r.period_s, r.second_period_s)
        assert first[0] * second[1] - first[1] * second[0] != 0  # two directions, not one
        assert r.second_delta_bic > 10 and r.second_false_alarm_probability < 0.01


@pytest.mark.parametrize(
    ("name", "period_s", "seed"),
    [("s3_cylinder", 41.5, 1), ("s5_cubesat", 16.3, 2), ("s6_boxwing", 12.0, 3)],
)
def test_spinning_bodies_show_one_period(demo_pass, name, period_s, seed):
    rng = np.random.default_rng(seed)
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    ra, dec = math.degrees(math.atan2(u[1], u[0])) % 360, math.degrees(math.asin(u[2]))
    scene = jaxlc.load_scene(name).with_spin(period_s, ra, dec, float(rng.uniform(0, 360)))
    t, y = _observed(scene, demo_pass, seed)
    r = analyse_period(t, y)
    assert r.verdict == "periodic" and not r.two_periods, r.decision
    assert math.isnan(r.second_period_s)


def test_a_tumble_without_noise_or_with_one_dominant_period_is_not_forced(demo_pass):
    """A principal-axis spin written as a tumble (excitation 0) is a spin: one period."""
    from jaxlc.body.tumble import tumble_from_invariants

    spin = tumble_from_invariants([9.5e4, 1.0e5, 2.0e4], "SAM", 0.0, 40.0, 30.0, 50.0)
    scene = jaxlc.load_scene("s3_cylinder")
    tumble = jaxlc.load_scene("falcon9_tumble").attitude
    attitude = dataclasses.replace(
        tumble,
        inertia_kg_m2=tuple(float(x) for x in spin.inertia_kg_m2),
        omega_body_rad_s=tuple(float(x) for x in spin.omega_body_rad_s),
        quaternion=tuple(float(x) for x in spin.quaternion),
        epoch_utc=None,
    )
    t, y = _observed(dataclasses.replace(scene, attitude=attitude), demo_pass, 4)
    r = analyse_period(t, y)
    assert r.periodic and not r.two_periods, r.decision

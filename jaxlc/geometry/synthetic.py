"""Synthetic geometry: a fixed Sun and an observer sweeping phase angle and range."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from jaxlc.errors import JaxlcError
from jaxlc.io.tables import geometry_frame
from jaxlc.io.utc import utc_timestamp
from jaxlc.rendering.photometry import AU_M


def synthetic_geometry(
    duration_s: float = 1200.0,
    step_s: float = 1.0,
    phase_start_deg: float = 20.0,
    phase_end_deg: float = 120.0,
    range_start_m: float = 1.0e6,
    range_end_m: float | None = None,
    exposure_s: float = 1.0,
    start_utc: str = "2019-07-07T12:00:00Z",
    sun_ra_deg: float = 0.0,
    sun_dec_deg: float = 0.0,
    tilt_deg: float = 0.0,
) -> pd.DataFrame:
    """A geometry table with no orbit behind it.

    The object sits at the origin, the Sun at 1 AU in the direction
    (``sun_ra_deg``, ``sun_dec_deg``). The observer is at ``range`` metres in a
    direction making the phase angle α(t) with the Sun direction; α and the
    range change linearly from start to end. The observer moves in the plane
    through the Sun direction and Q = ẑ × ŝ (the equator's node), tilted about
    ŝ by ``tilt_deg``.

    Args:
        duration_s: length of the table; ``round(duration_s / step_s)`` rows.
        step_s: time between rows (s).
        phase_start_deg, phase_end_deg: phase angle at the first and last row, 0…180.
        range_start_m, range_end_m: observer distance (default: constant).
        exposure_s: exposure time of every row (s).
        start_utc: ISO 8601 time of the first row.
        sun_ra_deg, sun_dec_deg: inertial direction of the Sun.
        tilt_deg: rotation of the observer's plane about the Sun direction.

    Returns:
        A geometry table (``frame = synthetic``) with every row visible.

    Example:
        >>> geo = synthetic_geometry(duration_s=600, phase_start_deg=10, phase_end_deg=90)
        >>> len(geo), geo.attrs["frame"]
        (600, 'synthetic')
    """
    range_end_m = range_start_m if range_end_m is None else range_end_m
    checks = [
        ("duration_s", duration_s, duration_s > 0, "must be > 0"),
        ("step_s", step_s, step_s > 0, "must be > 0"),
        ("phase_start_deg", phase_start_deg, 0 <= phase_start_deg <= 180, "must be in [0, 180]"),
        ("phase_end_deg", phase_end_deg, 0 <= phase_end_deg <= 180, "must be in [0, 180]"),
        ("range_start_m", range_start_m, range_start_m > 0, "must be > 0"),
        ("range_end_m", range_end_m, range_end_m > 0, "must be > 0"),
        ("exposure_s", exposure_s, exposure_s >= 0, "must be ≥ 0"),
        ("sun_dec_deg", sun_dec_deg, -90 <= sun_dec_deg <= 90, "must be in [-90, 90]"),
    ]
    for name, value, ok, why in checks:
        if not (math.isfinite(value) and ok):
            raise JaxlcError(f"synthetic geometry: {name} = {value!r} {why}")
    n = round(duration_s / step_s)
    if not 1 <= n <= 10_000_000:
        raise JaxlcError(f"synthetic geometry: duration_s / step_s = {n} rows; must be 1 … 10⁷")
    start = utc_timestamp(start_utc, "synthetic geometry: start_utc")
    t, rso, sun, obs = synthetic_positions(
        n,
        step_s,
        phase_start_deg,
        phase_end_deg,
        range_start_m,
        range_end_m,
        sun_ra_deg,
        sun_dec_deg,
        tilt_deg,
    )
    return geometry_frame(start, t, rso, sun, obs, float(exposure_s), frame="synthetic")


def synthetic_positions(
    n: int,
    step_s: float,
    phase_start_deg: float,
    phase_end_deg: float,
    range_start_m: float,
    range_end_m: float,
    sun_ra_deg: float = 0.0,
    sun_dec_deg: float = 0.0,
    tilt_deg: float = 0.0,
) -> tuple[np.ndarray, ...]:
    """The rows of :func:`synthetic_geometry` as arrays (no checks, no table).

    Returns:
        ``t_s`` (n,) and the object, Sun and observer positions (n, 3) in m.
    """
    t = np.arange(n) * step_s
    frac = t / t[-1] if n > 1 else np.zeros(1)
    alpha = np.radians(phase_start_deg + (phase_end_deg - phase_start_deg) * frac)
    rng = range_start_m + (range_end_m - range_start_m) * frac

    ra, dec = math.radians(sun_ra_deg), math.radians(sun_dec_deg)
    s = np.array([math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra), math.sin(dec)])
    q = np.array([-math.sin(ra), math.cos(ra), 0.0])
    tilt = math.radians(tilt_deg)
    s_q = np.array([-s[2] * q[1], s[2] * q[0], s[0] * q[1] - s[1] * q[0]])  # s × q (q_z = 0)
    e = math.cos(tilt) * q + math.sin(tilt) * s_q
    obs = np.outer(rng * np.cos(alpha), s) + np.outer(rng * np.sin(alpha), e)
    sun = np.broadcast_to(AU_M * s, (n, 3))
    return t, np.zeros((n, 3)), sun, obs

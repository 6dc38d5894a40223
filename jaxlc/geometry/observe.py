"""Object, Sun and observer per sample; visibility; passes; geometry tables.

Everything is vectorised over objects × times and processed in time chunks:
per chunk, the TEME → GCRS rotation, the Sun (DE421) and the site are
computed once for all objects. Rules (the seed paper's, thresholds are
options): object elevation > 15°, Sun elevation < −6°, object sunlit
(conic shadow function ν > 0).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import numpy as np
import pandas as pd

from jaxlc.errors import JaxlcError
from jaxlc.geometry import ephemeris
from jaxlc.geometry.eclipse import shadow_nu
from jaxlc.geometry.orbit import propagate_gcrs_m, sgp4_messages
from jaxlc.geometry.sites import Site
from jaxlc.geometry.tle import STALE_EPOCH_DAYS, TLE
from jaxlc.io.tables import geometry_frame

#: Samples per time chunk, at most (see :data:`CHUNK_CELLS`).
TIME_CHUNK = 7200
#: Objects × samples per chunk, at most: bounds the memory of a chunk (a few
#: (N, T, 3) float64 arrays, 48 MB each) whatever the number of objects.
CHUNK_CELLS = 2_000_000
#: Rows of one geometry table, at most: 10⁶ rows (11.6 days at 1 s) take
#: ~0.75 GB and ~2 minutes on one core, and 260 MB as CSV.
MAX_TABLE_ROWS = 1_000_000
#: Samples per object of one pass search, at most: chunked, so this bounds the
#: time (~10⁵ samples per second), not the memory: 116 days at 1 s, 3 years at 10 s.
MAX_SEARCH_SAMPLES = 10_000_000


@dataclasses.dataclass(frozen=True)
class Visibility:
    """The visibility rules.

    Attributes:
        min_elevation_deg: object above this elevation at the site.
        max_sun_elevation_deg: Sun below this elevation at the site.
        min_shadow_nu: object sunlit: ν above this (0: any part of the Sun's disc).
    """

    min_elevation_deg: float = 15.0
    max_sun_elevation_deg: float = -6.0
    min_shadow_nu: float = 0.0

    def __post_init__(self):
        if not -90 <= self.min_elevation_deg <= 90:
            raise JaxlcError(
                f"min elevation {self.min_elevation_deg}° must be in [-90, 90] "
                "(--min-elevation-deg)"
            )
        if not -90 <= self.max_sun_elevation_deg <= 90:
            raise JaxlcError(
                f"max Sun elevation {self.max_sun_elevation_deg}° must be in [-90, 90] "
                "(--max-sun-elevation-deg)"
            )
        if not 0 <= self.min_shadow_nu < 1:
            raise JaxlcError(
                f"min shadow ν {self.min_shadow_nu} must be in [0, 1) (--min-shadow-nu)"
            )


@dataclasses.dataclass
class Observation:
    """Geometry of N objects at T samples (one time chunk or a whole window).

    Arrays: ``rso_m`` (N, T, 3), ``sun_m`` and ``obs_m`` (T, 3), geocentric
    GCRS metres; ``elevation_deg``, ``shadow_nu``, ``phase_angle_deg``,
    ``range_m``, ``visible``, ``sgp4_error`` (N, T); ``sun_elevation_deg`` (T,);
    ``offsets_s`` (T,) seconds from the window start.
    """

    offsets_s: np.ndarray
    rso_m: np.ndarray
    sun_m: np.ndarray
    obs_m: np.ndarray
    elevation_deg: np.ndarray
    sun_elevation_deg: np.ndarray
    shadow_nu: np.ndarray
    phase_angle_deg: np.ndarray
    range_m: np.ndarray
    sgp4_error: np.ndarray
    visible: np.ndarray


def _elevation_deg(rotation, vectors):
    """Elevation of (…, T, 3) GCRS vectors in a site's horizon frame (rotation (3, 3, T))."""
    up = np.einsum("jt,...tj->...t", rotation[2], vectors)
    return np.degrees(np.arcsin(np.clip(up / np.linalg.norm(vectors, axis=-1), -1, 1)))


def observe_chunk(
    tles: list[TLE], site: Site, start_utc: pd.Timestamp, offsets_s: np.ndarray, rules: Visibility
) -> Observation:
    """Geometry of every object at ``start_utc + offsets_s`` (one chunk)."""
    t = ephemeris.times(start_utc, offsets_s)
    eph = ephemeris.planets()
    rso, err = propagate_gcrs_m(tles, t)
    # Apparent (light time, aberration, deflection): the direction sunlight arrives
    # from in the geocentric frame, which moves with the Earth.
    sun = eph["earth"].at(t).observe(eph["sun"]).apparent().position.m.T  # (T, 3)
    where = site.skyfield()
    obs = where.at(t).position.m.T
    rot = where.rotation_at(t).reshape(3, 3, -1)  # GCRS → horizon (z up)
    with np.errstate(invalid="ignore"):
        elev = _elevation_deg(rot, rso - obs[None])
        sun_elev = _elevation_deg(rot, sun - obs)
        nu = shadow_nu(rso, sun[None])
        to_sun = sun[None] - rso
        to_obs = obs[None] - rso
        rng = np.linalg.norm(to_obs, axis=-1)
        phase = np.degrees(
            np.arctan2(
                np.linalg.norm(np.cross(to_sun, to_obs), axis=-1), np.sum(to_sun * to_obs, axis=-1)
            )
        )
        visible = (
            (err == 0)
            & (elev > rules.min_elevation_deg)
            & (sun_elev < rules.max_sun_elevation_deg)[None]
            & (nu > rules.min_shadow_nu)
        )
    return Observation(offsets_s, rso, sun, obs, elev, sun_elev, nu, phase, rng, err, visible)


def observe_chunks(
    tles: list[TLE],
    site: Site,
    start_utc: pd.Timestamp,
    duration_s: float,
    step_s: float,
    rules: Visibility,
    chunk: int | None = None,
    max_samples: int = MAX_TABLE_ROWS,
) -> Iterator[Observation]:
    """:func:`observe_chunk` over a whole window, ``chunk`` samples at a time (default
    :data:`TIME_CHUNK`, fewer for many objects: at most :data:`CHUNK_CELLS` in all)."""
    offsets = sample_offsets(duration_s, step_s, max_samples)
    # capped just past the ephemeris, so that centuries-long windows fail there, not overflow
    beyond_s = (ephemeris.EPHEMERIS_END - start_utc).total_seconds() + 86400.0
    last_s = min(float(offsets[-1]), max(beyond_s, 0.0))
    ephemeris.check_range(start_utc, start_utc + pd.Timedelta(seconds=last_s))
    if chunk is None:
        chunk = max(1, min(TIME_CHUNK, CHUNK_CELLS // max(len(tles), 1)))
    for i in range(0, len(offsets), chunk):
        yield observe_chunk(tles, site, start_utc, offsets[i : i + chunk], rules)


def sample_offsets(
    duration_s: float, step_s: float, max_samples: int = MAX_TABLE_ROWS
) -> np.ndarray:
    """Sample times 0, step, … < duration in seconds: (n,), n from :func:`check_window`."""
    return np.arange(check_window(duration_s, step_s, max_samples)) * float(step_s)


def check_window(duration_s: float, step_s: float, max_samples: int = MAX_TABLE_ROWS) -> int:
    """Samples n ≥ 1 of a window; commands call it before any other work.

    Raises:
        JaxlcError: a duration or step that is not a finite number > 0, or more
        than ``max_samples`` samples (the limit bounds memory and time).
    """
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise JaxlcError(f"window length {duration_s!r} s must be > 0 (--duration-s or --days)")
    if not (np.isfinite(step_s) and step_s > 0):
        raise JaxlcError(f"step {step_s!r} s must be > 0 (--step-s)")
    n = np.ceil(duration_s / step_s - 1e-9)  # a float: 1e300 / 1e-300 must not overflow
    if n > max_samples:
        raise JaxlcError(
            f"a window of {duration_s:.6g} s at a step of {step_s:.6g} s is {n:.3g} samples; "
            f"at most {max_samples:,} are allowed (memory and time): use a larger step "
            "(--step-s) or a shorter window (--duration-s or --days)"
        )
    return max(int(n), 1)


# ---------------------------------------------------------------------------
# Geometry table of one object


def geometry_table(
    tle: TLE,
    site: Site,
    start_utc: pd.Timestamp,
    duration_s: float,
    step_s: float = 1.0,
    exposure_s: float = 1.0,
    rules: Visibility | None = None,
) -> pd.DataFrame:
    """The geometry table (ARCHITECTURE.md) of one object seen from one site.

    Every sample is a row; ``visible`` applies the rules; SGP4 failures give
    NaN positions, ``visible = false`` and the library's message in
    ``sgp4_message``.
    """
    rules = rules or Visibility()
    if not (np.isfinite(exposure_s) and exposure_s >= 0):
        raise JaxlcError(f"exposure {exposure_s!r} s must be ≥ 0 (--exposure-s)")
    parts = list(observe_chunks([tle], site, start_utc, duration_s, step_s, rules))

    def cat(name, first_object=True):
        arr = np.concatenate([getattr(p, name) for p in parts], axis=1 if first_object else 0)
        return arr[0] if first_object else arr

    offsets = cat("offsets_s", first_object=False)
    rso = cat("rso_m")
    sun = cat("sun_m", first_object=False)
    obs = cat("obs_m", first_object=False)
    err = cat("sgp4_error")
    messages = sgp4_messages()
    df = geometry_frame(
        start_utc,
        offsets,
        rso,
        sun,
        obs,
        float(exposure_s),
        cat("elevation_deg"),
        cat("sun_elevation_deg", first_object=False),
        cat("shadow_nu"),
        cat("visible"),
    )
    df["sgp4_error"] = err.astype(int)
    df["sgp4_message"] = [messages.get(int(e), "") if e else "" for e in err]
    df.attrs.update(
        {
            "frame": "GCRS",
            "object": tle.label,
            "norad_id": str(tle.norad_id),
            "tle_epoch_utc": tle.epoch_utc.strftime("%Y-%m-%dT%H:%M:%S.%fZ"),
            "tle_source": tle.source,
            "site": f"{site.name} ({site.lat_deg:.5f}, {site.lon_deg:.5f}, {site.alt_m:.0f} m)",
            "rules": f"elevation > {rules.min_elevation_deg:g} deg, Sun < "
            f"{rules.max_sun_elevation_deg:g} deg, shadow nu > {rules.min_shadow_nu:g}",
        }
    )
    return df


def explain_invisible(df: pd.DataFrame, rules: Visibility) -> str:
    """Why no sample of a geometry table is visible, as counts per rule."""
    n = len(df)
    low = int((df["elevation_deg"] <= rules.min_elevation_deg).sum())
    day = int((df["sun_elevation_deg"] >= rules.max_sun_elevation_deg).sum())
    dark = int((df["shadow_nu"] <= rules.min_shadow_nu).sum())
    failed = int((df["sgp4_error"] != 0).sum()) if "sgp4_error" in df else 0
    text = (
        f"no visible sample among {n}: object at or below {rules.min_elevation_deg:g}° in "
        f"{low}, Sun at or above {rules.max_sun_elevation_deg:g}° in {day}, object in "
        f"Earth's shadow in {dark}"
    )
    if failed:
        text += f", SGP4 failed in {failed}"
    if df["elevation_deg"].notna().any():
        text += f"; max elevation {df['elevation_deg'].max():.1f}°"
    return text


# ---------------------------------------------------------------------------
# Passes

PASS_COLUMNS = (
    "norad_id",
    "name",
    "start_utc",
    "end_utc",
    "duration_s",
    "max_elevation_deg",
    "phase_min_deg",
    "phase_max_deg",
    "min_range_km",
    "cut_by_window",
    "tle_age_days",
    "stale",
)


def find_passes(
    tles: list[TLE],
    site: Site,
    start_utc: pd.Timestamp,
    duration_s: float,
    step_s: float = 1.0,
    rules: Visibility | None = None,
    progress=None,
) -> pd.DataFrame:
    """Visible passes: maximal runs of visible samples, per object.

    Args:
        tles: one element set per object (see :func:`jaxlc.geometry.tle.latest_before`).
        site: the sensor.
        start_utc, duration_s: the window.
        step_s: sampling step; pass start and end are accurate to it.
        rules: visibility rules.
        progress: optional callable(done_samples, total_samples).

    Returns:
        A table with :data:`PASS_COLUMNS`, sorted by start (empty when none).
        ``cut_by_window`` marks passes that began before or end after the window;
        ``tle_age_days`` is |pass start − TLE epoch| (days) and ``stale`` marks
        ages over :data:`jaxlc.geometry.tle.STALE_EPOCH_DAYS`.

    Raises:
        JaxlcError: a window of more than :data:`MAX_SEARCH_SAMPLES` samples.
    """
    rules = rules or Visibility()
    running: list[dict | None] = [None] * len(tles)  # a pass still open at the chunk's end
    rows = []
    total = check_window(duration_s, step_s, MAX_SEARCH_SAMPLES)
    done = 0
    chunks = observe_chunks(
        tles, site, start_utc, duration_s, step_s, rules, max_samples=MAX_SEARCH_SAMPLES
    )
    for ob in chunks:
        for i, tle in enumerate(tles):
            vis = ob.visible[i]
            if running[i] is not None and not vis[0]:
                rows.append(_pass_row(tle, start_utc, running[i], step_s))
                running[i] = None
            if not vis.any():
                continue
            edges = np.diff(np.r_[0, vis.astype(np.int8), 0])
            for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
                stats = _run_stats(ob, i, a, b)
                if a == 0 and running[i] is not None:
                    stats = _merge(running[i], stats)
                    running[i] = None
                if b == len(vis):
                    running[i] = stats
                else:
                    rows.append(_pass_row(tle, start_utc, stats, step_s))
        done += len(ob.offsets_s)
        if progress is not None:
            progress(done, total)
    for tle, stats in zip(tles, running, strict=True):
        if stats is not None:
            rows.append(_pass_row(tle, start_utc, {**stats, "cut": True}, step_s))
    df = pd.DataFrame(rows, columns=list(PASS_COLUMNS))
    df = df.sort_values(["start_utc", "norad_id"], kind="stable").reset_index(drop=True)
    df.attrs.update(
        {
            "site": f"{site.name} ({site.lat_deg:.5f}, {site.lon_deg:.5f}, {site.alt_m:.0f} m)",
            "window_start_utc": start_utc.strftime("%Y-%m-%dT%H:%M:%SZ"),
            "window_duration_s": f"{duration_s:g}",
            "step_s": f"{step_s:g}",
        }
    )
    return df


def _run_stats(ob: Observation, i: int, a: int, b: int) -> dict:
    seg = slice(a, b)
    return dict(
        t0=ob.offsets_s[a],
        t1=ob.offsets_s[b - 1],
        max_el=np.nanmax(ob.elevation_deg[i, seg]),
        ph_min=np.nanmin(ob.phase_angle_deg[i, seg]),
        ph_max=np.nanmax(ob.phase_angle_deg[i, seg]),
        rng_min=np.nanmin(ob.range_m[i, seg]),
        cut=bool(ob.offsets_s[a] == 0.0),  # visible from the window's first sample
    )


def _merge(first: dict, then: dict) -> dict:
    return dict(
        t0=first["t0"],
        t1=then["t1"],
        max_el=max(first["max_el"], then["max_el"]),
        ph_min=min(first["ph_min"], then["ph_min"]),
        ph_max=max(first["ph_max"], then["ph_max"]),
        rng_min=min(first["rng_min"], then["rng_min"]),
        cut=first["cut"],
    )


def _pass_row(tle: TLE, start_utc: pd.Timestamp, st: dict, step_s: float) -> dict:
    t0 = start_utc + pd.Timedelta(seconds=float(st["t0"]))
    t1 = start_utc + pd.Timedelta(seconds=float(st["t1"]))
    age_days = tle.age_days(t0)
    return {
        "norad_id": tle.norad_id,
        "name": tle.name,
        "start_utc": t0.strftime("%Y-%m-%dT%H:%M:%SZ"),
        "end_utc": t1.strftime("%Y-%m-%dT%H:%M:%SZ"),
        "duration_s": float(st["t1"] - st["t0"] + step_s),
        "max_elevation_deg": round(float(st["max_el"]), 3),
        "phase_min_deg": round(float(st["ph_min"]), 3),
        "phase_max_deg": round(float(st["ph_max"]), 3),
        "min_range_km": round(float(st["rng_min"]) / 1e3, 3),
        "cut_by_window": bool(st["cut"]),
        "tle_age_days": round(age_days, 3),
        "stale": bool(age_days > STALE_EPOCH_DAYS),
    }

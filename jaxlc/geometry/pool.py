"""A pool of real pass geometries, computed once and drawn from many times.

For bulk datasets with real geometry: the visible passes of the objects of
some TLE files over some sites during a window (:func:`find_passes`), each
turned into a geometry table (:func:`geometry_table`) from the start of the
pass at the dataset's cadence, at least as long as one light curve and at
most as long as the pass (capped at ``max_window`` samples). A curve then
takes ``samples`` consecutive rows from a drawn pass and offset; rows after
the end of the pass are real rows with ``visible = false``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd

from jaxlc.errors import JaxlcError
from jaxlc.geometry.observe import Visibility, find_passes, geometry_table
from jaxlc.geometry.sites import get_site
from jaxlc.geometry.tle import latest_before, read_tles, select_objects
from jaxlc.io.utc import utc_timestamp

#: Per-pass arrays of a pool, their dtypes and trailing shapes.
POOL_ARRAYS = {
    "rso_m": (np.float64, (3,)),
    "sun_m": (np.float64, (3,)),
    "obs_m": (np.float64, (3,)),
    "shadow_nu": (np.float64, ()),
    "elevation_deg": (np.float64, ()),
    "visible": (np.bool_, ()),
}


@dataclasses.dataclass(frozen=True)
class PassPool:
    """Geometry of P passes, each L_p ≤ L rows at one cadence (padded to L).

    Attributes:
        rso_m, sun_m, obs_m: (P, L, 3) GCRS positions (m), NaN padding.
        shadow_nu, elevation_deg: (P, L) Earth-shadow function and object elevation.
        visible: (P, L) the visibility rules (False on padding).
        length: (P,) rows of each pass.
        utc_start: (P,) ISO 8601 UTC of each pass's first row.
        norad_id: (P,) catalogue numbers; ``name``, ``site``: (P,) strings.
        site_alt_m: (P,) altitude of the site (m).
        cadence_s: time between rows.
    """

    rso_m: np.ndarray
    sun_m: np.ndarray
    obs_m: np.ndarray
    shadow_nu: np.ndarray
    elevation_deg: np.ndarray
    visible: np.ndarray
    length: np.ndarray
    utc_start: np.ndarray
    norad_id: np.ndarray
    name: np.ndarray
    site: np.ndarray
    site_alt_m: np.ndarray
    cadence_s: float

    def __len__(self) -> int:
        return int(self.length.shape[0])

    def rows(self, pass_id: int, offset: int, n: int) -> dict:
        """``n`` rows of pass ``pass_id`` from row ``offset`` (padding beyond L is invisible)."""
        stop = offset + n
        out = {}
        for key in POOL_ARRAYS:
            x = getattr(self, key)[pass_id, offset:stop]
            if x.shape[0] < n:  # only when L < offset + n: pad as the pool pads
                fill = False if key == "visible" else np.nan
                pad = np.full((n - x.shape[0], *x.shape[1:]), fill, dtype=x.dtype)
                x = np.concatenate([x, pad])
            out[key] = x
        return out


def build_pool(
    tle_paths,
    sites,
    start_utc: str,
    days: float,
    samples: int,
    cadence_s: float,
    exposure_s: float,
    norad=None,
    search_step_s: float = 10.0,
    rules: Visibility | None = None,
    min_pass_s: float = 60.0,
    max_passes: int = 500,
    max_window: int | None = None,
    progress=None,
) -> PassPool:
    """Find the passes and compute their geometry tables (see the module docstring).

    Args:
        tle_paths: TLE files; ``norad`` optionally selects objects.
        sites: registered site names.
        start_utc, days: the search window.
        samples, cadence_s, exposure_s: rows per light curve, their spacing and exposure.
        search_step_s: step of the pass search (pass starts are accurate to it).
        rules: visibility rules.
        min_pass_s: shorter passes are left out.
        max_passes: at most this many passes, the earliest first.
        max_window: rows per pass at most (default 8 × samples).
        progress: optional callable(done, total) over passes.

    Raises:
        JaxlcError: when no pass is found.
    """
    rules = rules or Visibility()
    start = utc_timestamp(start_utc, "pass pool: start_utc")
    tles = []
    for p in tle_paths:
        tles += read_tles(p)
    objs = latest_before(select_objects(tles, list(norad) if norad else None), start)
    by_id = {t.norad_id: t for t in objs}
    found = []
    for name in sites:
        site = get_site(name)
        table = find_passes(objs, site, start, days * 86400.0, search_step_s, rules)
        table = table[table["duration_s"] >= min_pass_s]
        found += [(site, r) for r in table.itertuples()]
    if not found:
        raise JaxlcError(
            f"no visible pass of {len(objs)} object(s) from {', '.join(sites)} in {days:g} d "
            f"after {start:%Y-%m-%d %H:%M} UTC lasts {min_pass_s:g} s or more; widen the window, "
            "add sites or objects, or relax the visibility rules"
        )
    found.sort(key=lambda sr: (sr[1].start_utc, sr[1].norad_id, sr[0].name))
    found = found[:max_passes]
    cap = max_window or 8 * samples
    lengths = [
        int(min(max(samples, math.ceil(r.duration_s / cadence_s)), max(cap, samples)))
        for _, r in found
    ]
    width = max(lengths)
    arrays = {
        k: np.full((len(found), width, *shape), False if k == "visible" else np.nan, dtype)
        for k, (dtype, shape) in POOL_ARRAYS.items()
    }
    for i, ((site, r), n) in enumerate(zip(found, lengths, strict=True)):
        t0 = pd.Timestamp(r.start_utc)
        df = geometry_table(
            by_id[r.norad_id], site, t0, n * cadence_s, cadence_s, exposure_s, rules
        )
        df = df.iloc[:n]
        for b in ("rso", "sun", "obs"):
            arrays[f"{b}_m"][i, : len(df)] = df[[f"{b}_{c}_m" for c in "xyz"]].to_numpy()
        arrays["shadow_nu"][i, : len(df)] = df["shadow_nu"].to_numpy()
        arrays["elevation_deg"][i, : len(df)] = df["elevation_deg"].to_numpy()
        arrays["visible"][i, : len(df)] = df["visible"].to_numpy(bool)
        if progress is not None:
            progress(i + 1, len(found))
    return PassPool(
        **arrays,
        length=np.asarray(lengths, dtype=np.int64),
        utc_start=np.asarray(
            [pd.Timestamp(r.start_utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ") for _, r in found]
        ),
        norad_id=np.asarray([int(r.norad_id) for _, r in found], dtype=np.int64),
        name=np.asarray([str(r.name) for _, r in found]),
        site=np.asarray([s.name for s, _ in found]),
        site_alt_m=np.asarray([s.alt_m for s, _ in found], dtype=np.float64),
        cadence_s=float(cadence_s),
    )

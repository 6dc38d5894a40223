"""Offline time scale and planetary ephemeris (no download, ever).

The Sun comes from JPL DE421 as shipped by the ``skyfield-data`` package
(valid 1899-07-29 … 2053-10-09); UTC/TT/UT1 from skyfield's built-in tables.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np
import pandas as pd

from jaxlc.errors import JaxlcError

#: Validity of de421.bsp.
EPHEMERIS_START = pd.Timestamp("1899-07-30", tz="UTC")
EPHEMERIS_END = pd.Timestamp("2053-10-08", tz="UTC")


@functools.cache
def timescale():
    """skyfield's built-in timescale (leap seconds and ΔT tables in the package)."""
    from skyfield.api import load

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load.timescale(builtin=True)


@functools.cache
def planets():
    """DE421 from ``skyfield-data`` (its finals2000A.all expiry warning is harmless
    here: the built-in timescale does not use that file)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import skyfield_data
        from skyfield.api import Loader

        return Loader(skyfield_data.get_skyfield_data_path())("de421.bsp")


def check_range(start: pd.Timestamp, end: pd.Timestamp) -> None:
    """Error unless [start, end] lies inside the ephemeris."""
    if start < EPHEMERIS_START or end > EPHEMERIS_END:
        raise JaxlcError(
            f"times {start:%Y-%m-%d} … {end:%Y-%m-%d} are outside the ephemeris range "
            f"{EPHEMERIS_START:%Y-%m-%d} … {EPHEMERIS_END:%Y-%m-%d} (de421)"
        )


#: Nutation is interpolated from a grid this coarse (s). Its fastest sizeable
#: term (13.7 days, 0.5") makes linear interpolation good to ~1e-5 arcsec.
NUTATION_GRID_S = 3600.0


def times(start_utc: pd.Timestamp, offsets_s: np.ndarray):
    """A skyfield Time array at ``start_utc + offsets_s`` (float64 seconds).

    The IAU 2000A nutation series dominates skyfield's cost per time; for long
    arrays it is evaluated on an hourly grid and interpolated (skyfield allows
    setting the nutation angles of a Time; see ``Time._nutation_angles``).
    """
    ts = timescale()
    s = start_utc
    offsets_s = np.asarray(offsets_s, dtype=np.float64)
    second0 = s.second + s.microsecond * 1e-6 + s.nanosecond * 1e-9
    t = ts.utc(s.year, s.month, s.day, s.hour, s.minute, second0 + offsets_s)
    span = float(offsets_s.max() - offsets_s.min()) if offsets_s.size else 0.0
    if offsets_s.size > 64:
        n_grid = max(2, int(np.ceil(span / NUTATION_GRID_S)) + 1)
        grid = np.linspace(offsets_s.min(), offsets_s.max(), n_grid)
        coarse = ts.utc(s.year, s.month, s.day, s.hour, s.minute, second0 + grid)
        d_psi, d_eps = coarse._nutation_angles_radians
        t._nutation_angles_radians = (
            np.interp(t.tt, coarse.tt, d_psi),
            np.interp(t.tt, coarse.tt, d_eps),
        )
    return t

"""SGP4 propagation of many objects at many times, TEME → GCRS.

``sgp4.api.SatrecArray`` propagates every object at every time in C++; the
TEME → GCRS rotation (GMST1982 and precession–nutation, as skyfield's
``EarthSatellite`` applies it) is computed once per time and shared by all
objects. SGP4 failures (e.g. a decayed orbit) come back as per-sample error
codes with the library's message, never as exceptions.
"""

from __future__ import annotations

import numpy as np

from jaxlc.geometry.tle import TLE


def sgp4_messages() -> dict[int, str]:
    """sgp4's messages for its error codes (1–6)."""
    from sgp4.api import SGP4_ERRORS

    return {int(k): str(v) for k, v in SGP4_ERRORS.items()}


def utc_julian_dates(t) -> tuple[np.ndarray, np.ndarray]:
    """(whole, fraction) UTC Julian dates of a skyfield Time, as SGP4 expects them."""
    jd = np.atleast_1d(t.whole)
    fr = np.atleast_1d(t.tai_fraction - t._leap_seconds() / 86400.0)
    return jd, fr


def propagate_teme_km(
    tles: list[TLE], jd: np.ndarray, fr: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """SGP4 positions and velocities in TEME for every object at every time.

    Args:
        tles: N element sets.
        jd, fr: (T,) UTC Julian dates split in whole and fraction.

    Returns:
        (error (N, T) int8, r_km (N, T, 3), v_km_s (N, T, 3)); samples with an
        error code other than 0 are NaN.
    """
    from sgp4.api import SatrecArray

    sats = SatrecArray([tle.satrec() for tle in tles])
    err, r, v = sats.sgp4(np.asarray(jd, np.float64), np.asarray(fr, np.float64))
    bad = err != 0
    r[bad] = np.nan
    v[bad] = np.nan
    return err.astype(np.int8), r, v


def teme_to_gcrs_matrices(t) -> np.ndarray:
    """(T, 3, 3) matrices M with r_GCRS = M @ r_TEME."""
    from skyfield.sgp4lib import TEME

    rot = TEME.rotation_at(t)  # GCRS → TEME, shape (3, 3, T)
    rot = rot.reshape(3, 3, -1)
    return np.transpose(rot, (2, 1, 0))  # transpose of each matrix, time first


def propagate_gcrs_m(tles: list[TLE], t) -> tuple[np.ndarray, np.ndarray]:
    """Geocentric GCRS positions (N, T, 3) in metres and SGP4 error codes (N, T)."""
    err, r_km, _ = propagate_teme_km(tles, *utc_julian_dates(t))
    m = teme_to_gcrs_matrices(t)
    return np.einsum("tij,ntj->nti", m, r_km) * 1e3, err

"""Earth's shadow on an object: the conic model with penumbra (PHYSICS.md §3).

Montenbruck & Gill, *Satellite Orbits* §3.4.2 (compared with other models by
Hubaux et al. 2012). ν is the fraction of the solar disc visible from the
object: 1 in sunlight, 0 in umbra, in between in penumbra (and for annular
geometry). The Earth is a sphere of the WGS84 equatorial radius.
"""

from __future__ import annotations

import numpy as np

R_EARTH_M = 6_378_137.0
R_SUN_M = 695_700_000.0  # IAU 2015 nominal solar radius


def shadow_nu(rso_m: np.ndarray, sun_m: np.ndarray) -> np.ndarray:
    """Fraction of the Sun's disc seen from the object.

    Args:
        rso_m: (..., 3) geocentric object positions (m).
        sun_m: (..., 3) geocentric Sun positions (m), broadcastable.

    Returns:
        (...) ν in [0, 1]; NaN where a position is NaN.
    """
    r = np.asarray(rso_m, dtype=np.float64)
    to_sun = np.asarray(sun_m, dtype=np.float64) - r
    d_sun = np.linalg.norm(to_sun, axis=-1)
    d_r = np.linalg.norm(r, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.arcsin(np.clip(R_SUN_M / d_sun, -1, 1))  # apparent solar radius
        b = np.arcsin(np.clip(R_EARTH_M / d_r, -1, 1))  # apparent Earth radius
        cos_c = -np.sum(r * to_sun, axis=-1) / (d_r * d_sun)
        c = np.arccos(np.clip(cos_c, -1.0, 1.0))  # Sun–Earth angular separation
        x = (c * c + a * a - b * b) / (2 * c)
        y = np.sqrt(np.clip(a * a - x * x, 0, None))
        area = (
            a * a * np.arccos(np.clip(x / a, -1, 1))
            + b * b * np.arccos(np.clip((c - x) / b, -1, 1))
            - c * y
        )
        nu = 1.0 - area / (np.pi * a * a)
    out = np.where(c >= a + b, 1.0, np.where(c < b - a, 0.0, nu))
    # Sun smaller than Earth's disc but not overlapping its edge, fully behind (annulus
    # impossible for Earth/Sun seen from near Earth): handled by c < b − a above.
    out = np.where(np.isnan(c) | np.isnan(d_sun), np.nan, np.clip(out, 0.0, 1.0))
    return out

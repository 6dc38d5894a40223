"""Irradiance, flux and magnitudes (``PHYSICS.md`` §1-2, ARCHITECTURE light-curve table).

The facet kernel returns the radiant intensity per unit irradiance
``I/E`` (m² sr⁻¹). This module turns it into the observed flux and magnitude,
in float64 on the host so that tiny and huge ranges neither underflow nor
overflow:

    E    = C_sun,vis · (1 AU / r_sun)² · ν         (W m⁻²)
    F    = E · (I/E) / d²                           (W m⁻²)
    m    = M_sun − 2.5 log10(F / C_sun,vis)
"""

from __future__ import annotations

import numpy as np

#: Solar irradiance in the visible band at 1 AU (W/m²), as in the seed paper.
C_SUN_VIS_W_M2 = 1062.0
#: Apparent V magnitude of the Sun at 1 AU.
M_SUN_V = -26.74
#: Astronomical unit (m), IAU 2012.
AU_M = 149_597_870_700.0


def solar_irradiance_w_m2(sun_distance_m, shadow_nu=1.0):
    """Visible-band solar irradiance at the object.

    Args:
        sun_distance_m: (T,) object-Sun distance in metres.
        shadow_nu: (T,) Earth-shadow function, 1 sunlit … 0 umbra.

    Returns:
        (T,) irradiance in W/m², float64.
    """
    d = np.asarray(sun_distance_m, dtype=np.float64)
    return C_SUN_VIS_W_M2 * (AU_M / d) ** 2 * np.asarray(shadow_nu, dtype=np.float64)


def flux_w_m2(intensity_m2_sr, irradiance_w_m2, range_m):
    """Irradiance at the observer: ``F = E · (I/E) / d²`` (float64).

    Args:
        intensity_m2_sr: (T,) radiant intensity per unit irradiance, m² sr⁻¹.
        irradiance_w_m2: (T,) solar irradiance at the object, W/m².
        range_m: (T,) object-observer distance, m.
    """
    i = np.asarray(intensity_m2_sr, dtype=np.float64)
    e = np.asarray(irradiance_w_m2, dtype=np.float64)
    d = np.asarray(range_m, dtype=np.float64)
    # (I/E)·E/d² written as a product of ratios keeps 1e-30 … 1e30 ranges finite.
    return (i / d) * (e / d)


def magnitude(flux):
    """Apparent magnitude ``m = −26.74 − 2.5 log10(F / C_sun,vis)``.

    A zero flux (nothing lit and seen) gives ``+inf``, a NaN flux (row not
    rendered) gives NaN.
    """
    f = np.asarray(flux, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return M_SUN_V - 2.5 * np.log10(f / C_SUN_VIS_W_M2)


def flux_from_magnitude(mag):
    """Inverse of :func:`magnitude`: ``F = C_sun,vis · 10^(−0.4 (m − M_sun))``; NaN stays NaN."""
    m = np.asarray(mag, dtype=np.float64)
    return C_SUN_VIS_W_M2 * 10.0 ** (-0.4 * (m - M_SUN_V))

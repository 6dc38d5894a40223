"""Measurement noise of a light curve: photons, sky, read-out, scintillation.

For a sample of magnitude m, exposure t and zero point m₀ (the magnitude that
gives one photo-electron per second) the expected source signal is
S = t · 10^(−0.4 (m − m₀)) electrons, the sky B = b · t. The simulated,
sky-subtracted count is

    N = Poisson(S (1 + σ_sc z₁) + B) − B + σ_r z₂,     z₁, z₂ ~ N(0, 1)

with read noise σ_r (electrons) and the relative scintillation of Young
(1967), as written by Dravins et al. (1998, PASP 110, 610, eq. 10):

    σ_sc = 0.09 D^(−2/3) X^1.75 exp(−h / 8000 m) / √(2 t)     (D in cm)

for an aperture D, airmass X and site altitude h. The noisy flux is N times
the flux of one electron, and ``mag_err`` the expected 1σ magnitude error
2.5/ln 10 · √(S + B + σ_r² + (σ_sc S)²) / S. Noise-free values are kept
beside the noisy ones by the dataset writer.
"""

from __future__ import annotations

import math

import numpy as np

from jaxlc.rendering import photometry

#: Cap of the expected electrons per sample (numpy's Poisson sampler limit is ~9e18).
MAX_ELECTRONS = 1e15
#: Largest magnitude error given (mag): a signal too weak to measure, e.g. no
#: flux at all, gets this instead of +inf, so that errors stay finite numbers.
MAX_MAG_ERR = 100.0


def scintillation_rel(aperture_m: float, airmass, altitude_m: float, exposure_s: float):
    """Relative scintillation rms (Young 1967; Dravins et al. 1998 eq. 10).

    Args:
        aperture_m: telescope aperture diameter (m).
        airmass: (T,) or scalar airmass X ≥ 1.
        altitude_m: site altitude (m).
        exposure_s: exposure time (s), > 0.
    """
    d_cm = 100.0 * aperture_m
    x = np.asarray(airmass, dtype=np.float64)
    return (
        0.09
        * d_cm ** (-2.0 / 3.0)
        * x**1.75
        * math.exp(-altitude_m / 8000.0)
        / math.sqrt(2.0 * exposure_s)
    )


def airmass_from_elevation(elevation_deg):
    """Plane-parallel airmass 1/sin(h) of elevations (°), NaN at or below the horizon."""
    el = np.radians(np.asarray(elevation_deg, dtype=np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(el > 0, 1.0 / np.sin(el), np.nan)


def add_noise(
    flux_w_m2: np.ndarray,
    exposure_s: float,
    rng: np.random.Generator,
    zero_point_mag: float,
    sky_e_per_s: float = 0.0,
    read_noise_e: float = 0.0,
    scintillation=0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Noisy flux and the expected magnitude error of a light curve.

    Args:
        flux_w_m2: (T,) noise-free flux (NaN: sample not observed).
        exposure_s: exposure time (s), > 0.
        rng: the curve's noise stream (z₁, z₂ and the Poisson draws, in that order).
        zero_point_mag: magnitude giving 1 electron per second.
        sky_e_per_s: sky background in the aperture (electrons per second).
        read_noise_e: read noise (electrons rms per exposure).
        scintillation: (T,) or scalar relative scintillation rms.

    Returns:
        ``(flux_noisy_w_m2, mag_err)``, each (T,) float64; NaN where the
        input is NaN; the noisy flux may be ≤ 0 (then its magnitude is NaN);
        ``mag_err`` is at most ``MAX_MAG_ERR`` (also for a zero flux).
    """
    flux = np.asarray(flux_w_m2, dtype=np.float64)
    n = flux.shape[0]
    # Flux of one electron per exposure: F = k · S.
    per_e = (
        photometry.C_SUN_VIS_W_M2
        * 10.0 ** (-0.4 * (zero_point_mag - photometry.M_SUN_V))
        / exposure_s
    )
    z1 = rng.standard_normal(n)
    z2 = rng.standard_normal(n)
    ok = np.isfinite(flux)
    signal = np.where(ok, flux, 0.0) / per_e
    sky = sky_e_per_s * exposure_s
    scint = np.broadcast_to(np.asarray(scintillation, dtype=np.float64), (n,))
    scint = np.where(ok & np.isfinite(scint), scint, 0.0)
    expected = np.maximum(signal * (1.0 + scint * z1), 0.0) + sky
    counts = rng.poisson(np.minimum(expected, MAX_ELECTRONS)).astype(np.float64)
    noisy = (counts - sky + read_noise_e * z2) * per_e
    var = signal + sky + read_noise_e**2 + (scint * signal) ** 2
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        rel = np.where(signal > 0, np.sqrt(var) / signal, np.inf)
    mag_err = np.minimum(2.5 / math.log(10.0) * rel, MAX_MAG_ERR)
    return np.where(ok, noisy, np.nan), np.where(ok, mag_err, np.nan)


def magnitude_of(flux_w_m2: np.ndarray) -> np.ndarray:
    """Magnitudes of possibly non-positive fluxes: NaN where flux ≤ 0."""
    f = np.asarray(flux_w_m2, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(f > 0, photometry.magnitude(np.where(f > 0, f, 1.0)), np.nan)

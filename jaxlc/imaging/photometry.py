"""Aperture photometry: the seed's instrument magnitude, the CCD equation, the zero point.

- Instrument magnitude (seed Eq. 3): I = −2.5 log10((N_ap − A_ap S_sky) / t_exp),
  N_ap the aperture's sum, A_ap its area (pixels), S_sky the sky per pixel
  (3σ-clipped mean of an annulus, other sources masked: a median of
  integer ADU would be quantised by up to half an ADU per pixel), t_exp from the header.
- Its error (the CCD equation, with the sky's measured per-pixel scatter σ_sky
  standing for sky, dark and read noise): σ_N² = g N + A_ap (1 + A_ap/A_sky) (g σ_sky)²
  in electrons (g the gain), σ_I = 1.0857 σ_N / (g N), N = N_ap − A_ap S_sky.
- Zero point (seed Eq. 5, m₁ = m₂ + I₁ − I₂): each matched star gives
  ZP = m_cat − I; the frame's ZP is their 3σ-clipped weighted mean, its error
  that of the mean (scaled by the Birge ratio when the stars scatter more than
  their errors), and its scatter their standard deviation.

Points get circular apertures, streaks rectangles along the streak (photutils).
"""

from __future__ import annotations

import math

import numpy as np

#: 2.5 / ln 10: magnitudes per relative flux error.
MAG_PER_REL = 2.5 / math.log(10.0)


def _measure(image, apertures, annuli, mask, gain, exptime_s):
    from astropy.stats import SigmaClip
    from photutils.aperture import ApertureStats, aperture_photometry

    total = np.atleast_1d(np.asarray(aperture_photometry(image, apertures)["aperture_sum"]))
    stats = ApertureStats(image, annuli, mask=mask, sigma_clip=SigmaClip(sigma=3.0))
    sky = np.atleast_1d(np.asarray(stats.mean, dtype=float))
    sky_sd = np.atleast_1d(np.asarray(stats.std, dtype=float))
    n_sky = np.atleast_1d(np.asarray(getattr(stats.sum_aper_area, "value", stats.sum_aper_area)))
    area = np.atleast_1d(np.asarray(apertures.area, dtype=float))
    net = total - area * sky
    var_e = (
        gain * np.maximum(net, 0.0)
        + area * (1.0 + area / np.maximum(n_sky, 1.0)) * (gain * sky_sd) ** 2
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        inst = np.where(net > 0, -2.5 * np.log10(net / exptime_s), np.nan)
        err = np.where(net > 0, MAG_PER_REL * np.sqrt(var_e) / (gain * net), np.nan)
        snr = np.where(net > 0, gain * net / np.sqrt(var_e), 0.0)
    return inst, err, snr, net, sky


def point_photometry(image, xy, radius_px, gain, exptime_s, mask=None):
    """Instrument magnitudes of point sources.

    Args:
        image: (H, W) frame (ADU, bias included: the annulus removes it).
        xy: (N, 2) positions (pixels, 0-based).
        radius_px: aperture radius; the sky annulus spans 2–3.5 radii.
        gain: e⁻/ADU.
        exptime_s: exposure (s).
        mask: (H, W) bool, pixels the sky must not use (other sources).

    Returns:
        (inst_mag, inst_err, snr, net_adu, sky_adu), each (N,); NaN magnitudes
        where the net counts are not positive.
    """
    from photutils.aperture import CircularAnnulus, CircularAperture

    xy = np.atleast_2d(np.asarray(xy, dtype=float))
    ap = CircularAperture(xy, r=radius_px)
    ann = CircularAnnulus(xy, r_in=2.0 * radius_px, r_out=3.5 * radius_px)
    return _measure(image, ap, ann, mask, gain, exptime_s)


def streak_apertures(xy, length_px, angle_deg, radius_px):
    """Rectangular apertures ``radius_px`` beyond each streak all round, and their sky annuli."""
    from photutils.aperture import RectangularAnnulus, RectangularAperture

    out = []
    for (x, y), length, angle in zip(
        np.atleast_2d(xy), np.atleast_1d(length_px), np.atleast_1d(angle_deg), strict=True
    ):
        theta = math.radians(float(angle))
        w, h = float(length) + 2.0 * radius_px, 2.0 * radius_px
        ap = RectangularAperture((x, y), w=w, h=h, theta=theta)
        ann = RectangularAnnulus(
            (x, y), w_in=w + 2.0 * radius_px, w_out=w + 5.0 * radius_px,
            h_out=h + 5.0 * radius_px, h_in=h + 2.0 * radius_px, theta=theta,
        )  # fmt: skip
        out.append((ap, ann))
    return out


def isolated(apertures, labels: np.ndarray, own) -> np.ndarray:
    """(N,) whether each aperture holds no segment but its own (``labels`` 0 = sky)."""
    out = []
    for ap, label in zip(apertures, own, strict=True):
        cut = ap.to_mask(method="center").to_image(labels.shape)
        seen = np.unique(labels[(cut > 0) & (labels > 0)]) if cut is not None else []
        out.append(all(s == label for s in seen))
    return np.asarray(out, dtype=bool)


def streak_photometry(image, xy, length_px, angle_deg, radius_px, gain, exptime_s, mask=None):
    """Instrument magnitudes of streaks (rectangles ``radius_px`` beyond the streak all round).

    Args:
        xy: (N, 2) streak centres; length_px, angle_deg: (N,) lengths and
            angles from +x (degrees); the rest as :func:`point_photometry`.
    """
    out = [[] for _ in range(5)]
    for ap, ann in streak_apertures(xy, length_px, angle_deg, radius_px):
        for acc, value in zip(out, _measure(image, ap, ann, mask, gain, exptime_s), strict=True):
            acc.append(float(value[0]))
    return tuple(np.asarray(v) for v in out)


def zero_point(catalog_mag, inst_mag, inst_err):
    """The frame's zero point from matched stars (seed Eq. 5).

    Args:
        catalog_mag, inst_mag, inst_err: (N,) catalogue magnitudes, instrument
            magnitudes and their errors of the matched stars.

    Returns:
        (zp, zp_err, scatter, n_used): NaN and 0 stars when none is usable.
    """
    from astropy.stats import sigma_clip

    zp = np.asarray(catalog_mag, float) - np.asarray(inst_mag, float)
    err = np.asarray(inst_err, float)
    ok = np.isfinite(zp) & np.isfinite(err) & (err > 0)
    zp, err = zp[ok], err[ok]
    if len(zp) == 0:
        return math.nan, math.nan, math.nan, 0
    if len(zp) >= 3:
        keep = ~np.ma.getmaskarray(sigma_clip(zp, sigma=3.0, maxiters=5))
        zp, err = zp[keep], err[keep]
    w = 1.0 / err**2
    mean = float((w * zp).sum() / w.sum())
    sigma = math.sqrt(1.0 / w.sum())
    scatter = float(zp.std(ddof=1)) if len(zp) > 1 else math.nan
    if len(zp) > 1:
        birge = math.sqrt(float((w * (zp - mean) ** 2).sum()) / (len(zp) - 1))
        sigma *= max(birge, 1.0)
    return mean, sigma, scatter, len(zp)


def chord_fraction(centre, starts, ends, radius):
    """Fraction of each segment start → end (a streak, or a point when they coincide)
    that lies within ``radius`` of ``centre``.

    Args:
        centre: (2,) point; starts, ends: (N, 2) segment ends; radius: scalar.

    Returns:
        (N,) fractions in [0, 1].
    """
    a = np.asarray(starts, float) - np.asarray(centre, float)
    d = np.asarray(ends, float) - np.asarray(starts, float)
    dd = (d * d).sum(axis=-1)
    inside_point = ((a * a).sum(axis=-1) <= radius * radius).astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        b = (a * d).sum(axis=-1) / dd
        c = ((a * a).sum(axis=-1) - radius * radius) / dd
        root = np.sqrt(np.maximum(b * b - c, 0.0))
        t0 = np.clip(-b - root, 0.0, 1.0)
        t1 = np.clip(-b + root, 0.0, 1.0)
    frac = np.where(b * b - c > 0, t1 - t0, 0.0)
    return np.where(dd > 1e-12, frac, inside_point)

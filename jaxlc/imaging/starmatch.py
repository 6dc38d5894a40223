"""Catalogue stars in a frame: matching detections to them, and telling blends apart.

A rate-tracked frame has every star draw the same streak, so a detection is
one catalogue star's measurable streak only if it matches one star's
mid-exposure position (:func:`match_stars`), its aperture holds no other
source (:func:`isolated_sources`), it has the common length and direction
(:func:`like_common_streak`) and its ridge is uniform (``uniform`` of
:func:`~jaxlc.imaging.detect.detect_sources`). :func:`blend_mag` estimates the
catalogue starlight inside an object's aperture.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from jaxlc.imaging.catalog import stars_near
from jaxlc.imaging.fitsframe import Frame
from jaxlc.imaging.photometry import chord_fraction, isolated, streak_apertures


def catalogue_in_frame(frame: Frame, stars: pd.DataFrame, margin_px: float = 0.0):
    """Catalogue stars whose mid-exposure position falls in the frame: (stars, (N, 2) pixels)."""
    h, w = frame.data.shape
    centre = frame.wcs.pixel_to_world_values((w - 1) / 2.0, (h - 1) / 2.0)
    scale_deg = float(np.sqrt(abs(np.linalg.det(frame.wcs.pixel_scale_matrix))))
    near = stars_near(stars, float(centre[0]), float(centre[1]), 0.5 * math.hypot(w, h) * scale_deg)
    if len(near) == 0:
        return near, np.zeros((0, 2))
    x, y = frame.wcs.world_to_pixel_values(near["ra_deg"].to_numpy(), near["dec_deg"].to_numpy())
    inside = (x > -margin_px) & (x < w - 1 + margin_px) & (y > -margin_px) & (y < h - 1 + margin_px)
    return near[inside], np.stack([x[inside], y[inside]], axis=-1)


def match_stars(det: pd.DataFrame, star_xy: np.ndarray, match_px: float) -> np.ndarray:
    """Each detection's catalogue index (−1: none or ambiguous, two stars in reach)."""
    out = np.full(len(det), -1, dtype=int)
    if len(det) == 0 or len(star_xy) == 0:
        return out
    xy = det[["x_px", "y_px"]].to_numpy(float)
    dist = np.linalg.norm(xy[:, None, :] - star_xy[None, :, :], axis=-1)
    reach = match_px + 0.02 * det["length_px"].to_numpy(float)[:, None]
    close = dist <= reach
    single = close.sum(axis=1) == 1
    out[single] = np.argmin(dist[single], axis=1)
    taken, counts = np.unique(out[out >= 0], return_counts=True)
    out[np.isin(out, taken[counts > 1])] = -1  # two detections claim one star
    return out


def isolated_sources(det: pd.DataFrame, segm: np.ndarray, radius: float) -> np.ndarray:
    """(N,) whether each detection's aperture holds no other detected source (a blend)."""
    from photutils.aperture import CircularAperture

    out = np.ones(len(det), dtype=bool)
    if len(det) == 0:
        return out
    streak = (det["kind"] == "streak").to_numpy()
    point = (det["kind"] == "point").to_numpy()
    if streak.any():
        rows = det[streak]
        aps = [ap for ap, _ in streak_apertures(
            rows[["x_px", "y_px"]].to_numpy(), rows["length_px"].to_numpy(),
            rows["angle_deg"].to_numpy(), radius,
        )]  # fmt: skip
        out[streak] = isolated(aps, segm, rows["label"].to_numpy())
    if point.any():
        rows = det[point]
        aps = [CircularAperture(xy, r=radius) for xy in rows[["x_px", "y_px"]].to_numpy()]
        out[point] = isolated(aps, segm, rows["label"].to_numpy())
    return out


def like_common_streak(det: pd.DataFrame, streak_vec: np.ndarray) -> np.ndarray:
    """(N,) False for streaks whose length or direction differ from the common streak.

    Every star of a rate-tracked frame draws the same streak; a longer or
    turned one is two stars merged (or a star and an object) and is not measured.
    """
    length = float(np.hypot(*streak_vec))
    streak = (det["kind"] == "streak").to_numpy()
    if length == 0 or not streak.any():
        return np.ones(len(det), dtype=bool)
    turn = np.radians(det["angle_deg"].to_numpy(float)) - math.atan2(streak_vec[1], streak_vec[0])
    aligned = np.abs(np.sin(turn)) * length <= 3.0
    alike = np.abs(det["length_px"].to_numpy(float) - length) <= max(3.0, 0.05 * length)
    return ~streak | (aligned & alike)


def near_star(det: pd.DataFrame, star_xy: np.ndarray, match_px: float) -> np.ndarray:
    """(N,) whether a detection lies within ``match_px`` of any catalogue star."""
    if len(det) == 0 or len(star_xy) == 0:
        return np.zeros(len(det), dtype=bool)
    xy = det[["x_px", "y_px"]].to_numpy(float)
    return (np.linalg.norm(xy[:, None, :] - star_xy[None, :, :], axis=-1) <= match_px).any(axis=1)


def common_streak(det: pd.DataFrame, star_of: np.ndarray) -> np.ndarray:
    """The stars' streak (dx, dy) in pixels: the median of the uniform full streaks
    matched to catalogue stars and at least half as long as the brightest of them
    (a faint star's streak breaks into fragments near the threshold).

    In a rate-tracked frame every star moves alike.

    Returns:
        ((2,) vector, number of streaks behind it); ((0, 0), 0) when none is seen.
    """
    full = det[
        (det["kind"] == "streak").to_numpy() & det["uniform"].to_numpy(bool) & (star_of >= 0)
    ]
    if len(full):
        brightest = full["length_px"].to_numpy(float)[np.argmax(full["snr"].to_numpy(float))]
        full = full[full["length_px"].to_numpy(float) >= 0.5 * brightest]
    if len(full) == 0:
        return np.zeros(2), 0
    angle = np.radians(full["angle_deg"].to_numpy(float))
    # Orientation is defined modulo 180°: average the doubled angle.
    mean = 0.5 * np.arctan2(np.median(np.sin(2 * angle)), np.median(np.cos(2 * angle)))
    vec = float(np.median(full["length_px"])) * np.array([np.cos(mean), np.sin(mean)])
    return vec, len(full)


#: Offsets (PSF sigmas) and weights smoothing the aperture's edge in :func:`blend_mag`.
EDGE_OFFSETS = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])
EDGE_WEIGHTS = np.exp(-0.5 * EDGE_OFFSETS**2) / np.exp(-0.5 * EDGE_OFFSETS**2).sum()


def blend_mag(xy, inst_mag, near, star_xy, streak_vec, radius, sigma, zp):
    """How much catalogue starlight falls in each object's aperture (mag of excess).

    Each star's streak is its mid-exposure position ± half the common streak;
    the part of it within the aperture radius (edge smoothed by the PSF) times
    the star's flux from the catalogue and the frame's zero point.

    Returns:
        (N,) −2.5 log10(1 + contamination / object flux); 0 when nothing crosses.
    """
    out = np.zeros(len(xy))
    if len(xy) == 0 or len(star_xy) == 0 or not np.isfinite(zp):
        return out
    rate = 10.0 ** (-0.4 * (near["mag"].to_numpy(float) - zp))
    a, b = star_xy - 0.5 * streak_vec, star_xy + 0.5 * streak_vec
    for k, (centre, inst) in enumerate(zip(xy, inst_mag, strict=True)):
        frac = sum(
            w * chord_fraction(centre, a, b, max(radius + z * sigma, 0.0))
            for z, w in zip(EDGE_OFFSETS, EDGE_WEIGHTS, strict=True)
        )
        extra = float((frac * rate).sum())
        if extra > 0 and np.isfinite(inst):
            out[k] = -2.5 * math.log10(1.0 + extra / 10.0 ** (-0.4 * inst))
    return out
    rate = 10.0 ** (-0.4 * (near["mag"].to_numpy(float) - zp))
    for k, (centre, inst) in enumerate(zip(xy, inst_mag, strict=True)):
        frac = chord_fraction(
            centre, star_xy - 0.5 * streak_vec, star_xy + 0.5 * streak_vec, radius
        )
        extra = float((frac * rate).sum())
        if extra > 0 and np.isfinite(inst):
            out[k] = -2.5 * math.log10(1.0 + extra / 10.0 ** (-0.4 * inst))
    return out


#: Neighbouring frames further apart than this (s) do not predict the streak.
MAX_POINTING_GAP_S = 30.0


def pointing_streak(frame: Frame, times_s: np.ndarray, centres_deg: np.ndarray, k: int):
    """The stars' streak (dx, dy) in frame ``k``, from the pointing of its neighbours.

    A rate-tracking telescope's field centre follows the object, so the
    centres of the frames before and after, projected through this frame's
    WCS, give the pointing's motion; over the exposure the stars move by that
    rate times ``exptime_s`` (a streak's sign does not matter).

    Args:
        frame: frame ``k`` (its WCS and exposure).
        times_s: (N,) start times of all frames (s), in order.
        centres_deg: (N, 2) RA, Dec of every frame's centre.
        k: this frame's index.

    Returns:
        (2,) pixels, or None without a neighbour within :data:`MAX_POINTING_GAP_S`.
    """
    lo, hi = max(k - 1, 0), min(k + 1, len(times_s) - 1)
    if hi == lo or times_s[hi] - times_s[lo] > (hi - lo) * MAX_POINTING_GAP_S:
        return None
    px = np.asarray(
        frame.wcs.world_to_pixel_values(centres_deg[[lo, hi], 0], centres_deg[[lo, hi], 1])
    )
    rate = (px[:, 1] - px[:, 0]) / (times_s[hi] - times_s[lo])
    return rate * frame.exptime_s

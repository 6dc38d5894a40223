"""FITS frames → one light-curve table per tracked object (the seed's §3 pipeline).

Per frame (:func:`measure_frame`): background and matched-filter detection
(:mod:`~jaxlc.imaging.detect`); catalogue stars projected through the
header's WCS and matched to the full streaks (or points, for sidereal
tracking) whose centre lies within ``match_px`` of a star's mid-exposure
position; the zero point from them (:mod:`~jaxlc.imaging.photometry`); every
other point source is an object candidate, measured in a circular aperture.
Over frames (:func:`extract_lightcurves`), candidates are linked into tracks
(:mod:`~jaxlc.imaging.track`); each track seen in at least ``min_frames``
frames is an object with its own light curve, one row per frame (NaN and a
``note`` where it was not measured).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.errors import JaxlcError
from jaxlc.imaging.detect import DetectSettings, detect_sources
from jaxlc.imaging.fitsframe import Frame, frame_pointing, list_frames, read_frame
from jaxlc.imaging.photometry import point_photometry, streak_photometry, zero_point
from jaxlc.imaging.sensor import FWHM_PER_SIGMA, HeaderKeys
from jaxlc.imaging.starmatch import (
    blend_mag,
    catalogue_in_frame,
    common_streak,
    isolated_sources,
    like_common_streak,
    match_stars,
    near_star,
    pointing_streak,
)
from jaxlc.imaging.track import Tracker
from jaxlc.io.utc import format_utc
from jaxlc.rendering.photometry import flux_from_magnitude


@dataclasses.dataclass(frozen=True)
class ExtractSettings:
    """Knobs of the extraction.

    Attributes:
        fwhm_px: PSF FWHM when the header has none (pixels).
        aperture_fwhm: aperture radius in FWHM.
        match_px: largest catalogue-to-detection distance (pixels).
        gate_px: tracking gate (pixels).
        min_frames: a track seen in fewer frames is not reported (noise, cosmic rays).
        zero_point: a fixed zero point (mag) instead of one from stars.
        detect: :class:`~jaxlc.imaging.detect.DetectSettings`.
    """

    fwhm_px: float = 2.5
    aperture_fwhm: float = 2.0
    match_px: float = 4.0
    gate_px: float = 10.0
    min_frames: int = 3
    zero_point: float | None = None
    detect: DetectSettings = dataclasses.field(default_factory=DetectSettings)


def measure_frame(
    frame: Frame,
    stars: pd.DataFrame | None,
    settings: ExtractSettings,
    prior_streak: np.ndarray | None = None,
) -> dict:
    """Detections, zero point and object candidates of one frame (see module doc).

    ``prior_streak``, the stars' streak (dx, dy) expected from the pointing of
    the neighbouring frames (:func:`~jaxlc.imaging.starmatch.pointing_streak`),
    is the common streak when given: a lone catalogue match may be a fragment
    of a faint star's streak. Without it, the frame's own estimate
    (``result["streak"]``: vector, count) is used.
    """
    fwhm = frame.fwhm_px or settings.fwhm_px
    det, segm, _, _ = detect_sources(frame.data, fwhm, frame.saturation, settings.detect)
    radius = settings.aperture_fwhm * fwhm
    sigma = fwhm / FWHM_PER_SIGMA
    mask = segm > 0
    result = {"detections": det, "segments": segm, "n_catalog": 0}
    star_of = np.full(len(det), -1)
    near, star_xy = None, np.zeros((0, 2))  # no catalogue: no star is ever matched
    if stars is not None:
        near, star_xy = catalogue_in_frame(frame, stars, margin_px=0.5 * frame.data.shape[0])
        star_of = match_stars(det, star_xy, settings.match_px)
        result["n_catalog"] = len(near)
    det = det.assign(star=star_of)
    result["detections"] = det
    own, n_streaks = common_streak(det, star_of)
    result["streak"] = (own, n_streaks)
    streak_vec = own if prior_streak is None else np.asarray(prior_streak)
    usable = (star_of >= 0) & ~det["saturated"].to_numpy(bool) & ~det["edge"].to_numpy(bool)
    usable &= isolated_sources(det, segm, radius) & like_common_streak(det, streak_vec)
    usable &= det["uniform"].to_numpy(bool)
    cat_mag, inst, err = [], [], []
    streaks = det[usable & (det["kind"] == "streak").to_numpy()]
    if len(streaks):
        i, e, *_ = streak_photometry(
            frame.data, streaks[["x_px", "y_px"]].to_numpy(), streaks["length_px"].to_numpy(),
            streaks["angle_deg"].to_numpy(), radius, frame.gain, frame.exptime_s, mask,
        )  # fmt: skip
        cat_mag.append(near["mag"].to_numpy()[streaks["star"].to_numpy()])
        inst.append(i)
        err.append(e)
    # stars are points only when they barely move (sidereal tracking, a distant
    # object); in a streaking frame a point on a star's position is a fragment
    stars_are_points = float(np.hypot(*streak_vec)) < 1.5 * fwhm
    points = det[usable & (det["kind"] == "point").to_numpy() & stars_are_points]
    if len(points):
        i, e, *_ = point_photometry(
            frame.data, points[["x_px", "y_px"]].to_numpy(), radius, frame.gain,
            frame.exptime_s, mask,
        )  # fmt: skip
        cat_mag.append(near["mag"].to_numpy()[points["star"].to_numpy()])
        inst.append(i)
        err.append(e)
    if settings.zero_point is not None:
        result["zp"] = (float(settings.zero_point), 0.0, math.nan, 0)
    elif cat_mag:
        result["zp"] = zero_point(np.concatenate(cat_mag), np.concatenate(inst),
                                  np.concatenate(err))  # fmt: skip
    else:
        result["zp"] = (math.nan, math.nan, math.nan, 0)
    objects = det[
        (det["kind"] == "point").to_numpy()
        & (star_of < 0)
        & ~near_star(det, star_xy, settings.match_px)
    ]
    xy = objects[["x_px", "y_px"]].to_numpy(float)
    if len(objects):
        i, e, snr, *_ = point_photometry(frame.data, xy, radius, frame.gain, frame.exptime_s, mask)
    else:
        i = e = snr = np.zeros(0)
    result["objects"] = pd.DataFrame({
        "x_px": xy[:, 0], "y_px": xy[:, 1], "instrument_mag": i, "instrument_err": e,
        "snr": snr, "saturated": objects["saturated"].to_numpy(bool),
        "blend_mag": blend_mag(xy, i, near, star_xy, streak_vec, radius, sigma, result["zp"][0]),
    })  # fmt: skip
    return result


def frame_note(result: dict) -> str:
    """Why this frame gives no magnitude for any object ('' when it can)."""
    zp = result["zp"]
    if not np.isfinite(zp[0]):
        det = result["detections"]
        partial = int((det["kind"] == "partial").sum()) if len(det) else 0
        return (
            f"no zero point: no catalogue star measured ({result['n_catalog']} catalogue stars "
            f"in the field, {partial} partial streaks); give --zero-point or a deeper --catalog"
        )
    return ""


def magnitude_row(obj, zp) -> tuple[float, float, str]:
    """(mag, mag_err, note) of one measured object given the frame's zero point."""
    if obj["saturated"]:
        return math.nan, math.nan, "object saturated"
    if not np.isfinite(obj["instrument_mag"]):
        return math.nan, math.nan, "object not above the sky"
    if not np.isfinite(zp[0]):
        return math.nan, math.nan, "no zero point"
    err = math.hypot(obj["instrument_err"], zp[1])
    if abs(obj["blend_mag"]) > max(0.5 * err, BLEND_FLOOR_MAG):
        return (
            math.nan,
            math.nan,
            "a catalogue star falls in the aperture",
        )
    return obj["instrument_mag"] + zp[0], err, ""


def extract_lightcurves(
    frames: str | Path | list,
    stars: pd.DataFrame | None,
    settings: ExtractSettings | None = None,
    keys: HeaderKeys | None = None,
    progress: Callable[[int, int], None] | None = None,
):
    """Light curves of every tracked object in a sequence of frames.

    Args:
        frames: a folder of FITS files (or a list of paths).
        stars: catalogue (:func:`~jaxlc.imaging.catalog.load_catalog`), or
            None with ``settings.zero_point`` set.
        settings: :class:`ExtractSettings`.
        keys: :class:`~jaxlc.imaging.sensor.HeaderKeys`.
        progress: ``progress(done, total)``.

    Returns:
        (curves, log): a list of light-curve tables (most-detected object
        first; the project's columns plus ``mag_err, x_px, y_px, zero_point,
        zero_point_err, zero_point_scatter, n_stars, instrument_mag, snr,
        file, note``) and a per-frame log (file, utc, points, streaks,
        partial, n_stars, zero_point, note).
    """

    settings = settings or ExtractSettings()
    keys = keys or HeaderKeys()
    if stars is None and settings.zero_point is None:
        raise JaxlcError(
            "no star catalogue and no fixed zero point: give --catalog or --zero-point"
        )
    paths = list_frames(frames) if not isinstance(frames, list) else [Path(p) for p in frames]
    pointing = [frame_pointing(p, keys) for p in paths]
    starts = [start for start, _, _ in pointing]
    order = np.argsort(np.asarray([s.value for s in starts]), kind="stable")
    t0 = starts[order[0]]
    times = np.asarray([(starts[k] - t0).total_seconds() for k in order])
    centres = np.asarray([pointing[k][1:] for k in order])
    tracker = Tracker(settings.gate_px)
    rows, log, misses = [], [], {}
    for done, k in enumerate(order):
        frame = read_frame(paths[k], keys)
        t_s = times[done]
        expected = pointing_streak(frame, times, centres, done)
        res = measure_frame(frame, stars, settings, expected)
        predicted = tracker.predictions(t_s)
        objects = res["objects"]
        ids = tracker.update(done, t_s, objects[["x_px", "y_px"]].to_numpy())
        for tid, xy in predicted.items():
            if tid not in ids:
                misses[(tid, done)] = miss_note(res, xy)
        det = res["detections"]
        kinds = det["kind"].value_counts() if len(det) else {}
        zp = res["zp"]
        log.append((
            frame.path.name, frame.start, t_s, frame.exptime_s, kinds.get("point", 0),
            kinds.get("streak", 0), kinds.get("partial", 0), zp[3], zp[0], zp[1], zp[2],
            frame_note(res),
        ))  # fmt: skip
        for tid, (_, obj) in zip(ids, objects.iterrows(), strict=True):
            mag, err, why = magnitude_row(obj, zp)
            rows.append((
                tid, done, mag, err, obj["x_px"], obj["y_px"], obj["instrument_mag"],
                obj["snr"], why,
            ))  # fmt: skip
        if progress is not None:
            progress(done + 1, len(order))
    log = pd.DataFrame(log, columns=list(LOG_COLUMNS))
    return curves_from_tracks(rows, log, misses, settings.min_frames), log


#: Starlight in the aperture below this (mag) is ignored.
BLEND_FLOOR_MAG = 0.002

#: Columns of the per-frame log of :func:`extract_lightcurves`.
LOG_COLUMNS = (
    "file", "start", "t_s", "exposure_s", "points", "streaks", "partial", "n_stars",
    "zero_point", "zero_point_err", "zero_point_scatter", "note",
)  # fmt: skip
_ROW_COLUMNS = (
    "track", "frame", "mag", "mag_err", "x_px", "y_px", "instrument_mag", "snr", "note",
)  # fmt: skip


def miss_note(result: dict, xy) -> str:
    """Why a track's object is missing at its predicted position ``xy`` in this frame."""
    segm = result["segments"]
    x, y = round(xy[0]), round(xy[1])
    h, w = segm.shape
    if not (0 <= x < w and 0 <= y < h):
        return "predicted position outside the frame"
    label = segm[y, x]
    det = result["detections"]
    if label > 0 and len(det):
        kind = det.loc[det["label"] == label, "kind"]
        if len(kind) and kind.iloc[0] != "point":
            return "blended with a star streak"
    return "not detected (fainter than the threshold or eclipsed)"


def curves_from_tracks(rows, log: pd.DataFrame, misses: dict, min_frames: int):
    """One light-curve table per track seen in ≥ ``min_frames`` frames, a row per frame."""
    found = pd.DataFrame(rows, columns=list(_ROW_COLUMNS))
    counts = found["track"].value_counts()
    keep = [int(t) for t in counts.index if counts[t] >= min_frames]
    curves = []
    for tid in keep:
        mine = found[found["track"] == tid].drop_duplicates("frame").set_index("frame")
        lc = pd.DataFrame({
            "utc": format_utc(log["start"]),
            "t_s": log["t_s"].to_numpy(float),
        })  # fmt: skip
        for col in ("mag", "mag_err", "x_px", "y_px", "instrument_mag", "snr"):
            lc[col] = mine[col].reindex(range(len(log))).to_numpy(float)
        lc["flux_w_m2"] = flux_from_magnitude(lc["mag"].to_numpy())
        lc["phase_angle_deg"] = np.nan
        lc["range_m"] = np.nan
        lc["exposure_s"] = log["exposure_s"].to_numpy(float)
        lc["visible"] = np.isfinite(lc["mag"].to_numpy())
        for col in ("zero_point", "zero_point_err", "zero_point_scatter", "n_stars"):
            lc[col] = log[col].to_numpy()
        lc["file"] = log["file"].to_numpy()
        notes = mine["note"].reindex(range(len(log))).fillna("").to_numpy(object)
        for f in range(len(log)):
            if f not in mine.index:
                notes[f] = misses.get((tid, f), "before the object's first detection")
            if log["note"].iloc[f] and not np.isfinite(lc["mag"].iloc[f]):
                notes[f] = notes[f] or log["note"].iloc[f]
        lc["note"] = notes
        lc.attrs["object"] = f"track {len(curves) + 1}"
        curves.append(lc)
    return curves

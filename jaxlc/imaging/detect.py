"""Detection in a rate-tracked frame: background, FFT matched filter, segments, classes.

The seed detects objects and stars "using an FFT approach": here the
background-subtracted frame is correlated with the PSF in the Fourier domain
(the matched filter for a point source, which also brings out streaks), the
result divided by its own noise, thresholded and cut into connected segments
(photutils). Each segment is a ``point`` (round, PSF-sized), a ``streak``
(elongated, both ends in the frame; ``uniform`` when no pixel rises
well above the ridge a single star's streak would have) or a ``partial`` streak (touching a frame
edge, so one end or both lie outside); ``saturated`` marks a segment with
pixels at the saturation level.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
import pandas as pd
from scipy.signal import fftconvolve

from jaxlc.imaging.sensor import FWHM_PER_SIGMA

#: Segment columns of :func:`detect_sources`.
DETECTION_COLUMNS = (
    "label", "kind", "x_px", "y_px", "length_px", "angle_deg", "elongation", "area_px",
    "snr", "saturated", "edge", "uniform",
)  # fmt: skip
#: A streak whose brightest pixel exceeds this many times a uniform streak's
#: ridge is not one star's streak (a point source sits on it).
RIDGE_PEAK_RATIO = 2.0


@dataclasses.dataclass(frozen=True)
class DetectSettings:
    """Detection thresholds.

    Attributes:
        snr: threshold of the matched-filter signal-to-noise per pixel.
        min_pixels: smallest segment (pixels above threshold).
        box_px: background mesh box (pixels; smaller frames use a quarter of their side).
        point_elongation: a segment up to this axis ratio is a point (a streak of 2.5
            FWHM already has 2).
        edge_px: a segment within this of the border is cut by the edge.
    """

    snr: float = 5.0
    min_pixels: int = 5
    box_px: int = 64
    point_elongation: float = 1.6
    edge_px: int = 1


def background(image: np.ndarray, box_px: int = 64):
    """Sky level and its RMS per pixel (sigma-clipped medians in boxes, photutils).

    Returns:
        (background, rms) arrays of the image's shape (ADU).
    """
    from astropy.stats import SigmaClip
    from photutils.background import Background2D, MedianBackground

    box = int(min(box_px, max(8, min(image.shape) // 4)))
    bkg = Background2D(
        image, box, filter_size=3, sigma_clip=SigmaClip(sigma=3.0),
        bkg_estimator=MedianBackground(),
    )  # fmt: skip
    return np.asarray(bkg.background), np.asarray(bkg.background_rms)


def psf_kernel(fwhm_px: float) -> np.ndarray:
    """A normalised (sum 1) Gaussian PSF stamp of the given FWHM (pixels)."""
    sigma = fwhm_px / FWHM_PER_SIGMA
    half = max(2, math.ceil(4.0 * sigma))
    y, x = np.mgrid[-half : half + 1, -half : half + 1]
    k = np.exp(-0.5 * (x * x + y * y) / sigma**2)
    return k / k.sum()


def matched_filter_snr(residual: np.ndarray, rms: np.ndarray, fwhm_px: float) -> np.ndarray:
    """Signal-to-noise map of the PSF-matched filter, computed by FFT.

    Args:
        residual: background-subtracted image (ADU).
        rms: background RMS per pixel (ADU).
        fwhm_px: PSF FWHM (pixels).
    """
    kernel = psf_kernel(fwhm_px)
    filtered = fftconvolve(residual, kernel[::-1, ::-1], mode="same")
    return filtered / (np.maximum(rms, 1e-12) * math.sqrt(float((kernel**2).sum())))


def weighted_moments(x, y, weight):
    """Weighted centroid (x, y) and 2×2 covariance (pixels²) of pixel positions."""
    wsum = weight.sum()
    xc, yc = (weight * x).sum() / wsum, (weight * y).sum() / wsum
    dx, dy = x - xc, y - yc
    cxx, cyy, cxy = (weight * dx * dx).sum(), (weight * dy * dy).sum(), (weight * dx * dy).sum()
    return float(xc), float(yc), np.array([[cxx, cxy], [cxy, cyy]]) / wsum


def detect_sources(
    image: np.ndarray,
    fwhm_px: float,
    saturation_adu: float,
    settings: DetectSettings | None = None,
):
    """Find and classify the sources of one frame.

    Args:
        image: (H, W) frame in ADU (float or integer).
        fwhm_px: PSF FWHM (pixels).
        saturation_adu: the saturation level.
        settings: :class:`DetectSettings`.

    Returns:
        (detections, segments, background, rms): a DataFrame with
        :data:`DETECTION_COLUMNS` (one row per segment; ``length_px`` the
        streak length, 0 for points; ``angle_deg`` from +x towards +y),
        the (H, W) segment labels (0 = sky) and the background maps.
    """
    from photutils.segmentation import detect_sources as segment
    from photutils.utils.exceptions import NoDetectionsWarning
    from scipy.ndimage import find_objects

    settings = settings or DetectSettings()
    data = np.asarray(image, dtype=np.float64)
    sky, rms = background(data, settings.box_px)
    residual = data - sky
    snr = matched_filter_snr(residual, rms, fwhm_px)
    with warnings.catch_warnings():  # an empty frame is an answer, not a warning
        warnings.simplefilter("ignore", NoDetectionsWarning)
        segm = segment(snr, settings.snr, n_pixels=settings.min_pixels)
    if segm is None:
        empty = pd.DataFrame(columns=list(DETECTION_COLUMNS))
        return empty, np.zeros(data.shape, dtype=np.int32), sky, rms
    labels = np.asarray(segm.data)
    sigma = fwhm_px / FWHM_PER_SIGMA
    h, w = data.shape
    e = settings.edge_px
    rows = []
    for label, sl in enumerate(find_objects(labels), start=1):
        if sl is None:
            continue
        inside = labels[sl] == label
        ys, xs = np.nonzero(inside)
        weight = np.maximum(residual[sl][inside], 0.0)
        if weight.sum() <= 0:
            continue
        x_c, y_c, cov = weighted_moments(xs + sl[1].start, ys + sl[0].start, weight)
        evals, evecs = np.linalg.eigh(cov)
        a2, b2 = max(evals[1], 1e-12), max(evals[0], 1e-12)
        length = math.sqrt(max(12.0 * (a2 - sigma * sigma), 0.0))
        elongation = math.sqrt(a2 / b2)
        angle = math.degrees(math.atan2(evecs[1, 1], evecs[0, 1])) % 180.0
        edge = sl[1].start < e or sl[0].start < e or sl[1].stop > w - e or sl[0].stop > h - e
        saturated = bool((data[sl][inside] >= saturation_adu - 0.5).any())
        point = elongation <= settings.point_elongation  # round, however bright
        kind = "partial" if edge else ("point" if point else "streak")
        # a uniform streak's ridge: flux / length spread across by the PSF
        ridge = weight.sum() / max(length, 1.0) / (math.sqrt(2.0 * math.pi) * sigma)
        noise = float(np.median(rms[sl][inside]))
        uniform = point or weight.max() <= RIDGE_PEAK_RATIO * ridge + 5.0 * noise
        rows.append((
            label, kind, x_c, y_c, 0.0 if point else length, angle, elongation,
            float(inside.sum()), float(snr[sl][inside].max()), saturated, bool(edge),
            bool(uniform),
        ))  # fmt: skip
    detections = pd.DataFrame(rows, columns=list(DETECTION_COLUMNS))
    return detections, np.asarray(segm.data), sky, rms

"""Point sources and streaks drawn on a pixel grid (Gaussian PSF, sampled at pixel centres).

A streak is the PSF swept uniformly along a straight segment: across the
segment a Gaussian, along it the difference of two error functions, so its
total flux is exact for any length (down to a point). Pixel (i, j) has its
centre at x = j, y = i (0-based, as numpy indexes ``image[y, x]``).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import erf

#: PSF half-width drawn, in standard deviations.
EXTENT_SIGMA = 6.0


def _window(shape, xs, ys, pad):
    """Integer bounds [x0, x1) × [y0, y1) covering points ± pad, clipped to the frame."""
    h, w = shape
    x0 = max(math.floor(min(xs) - pad), 0)
    x1 = min(math.ceil(max(xs) + pad) + 1, w)
    y0 = max(math.floor(min(ys) - pad), 0)
    y1 = min(math.ceil(max(ys) + pad) + 1, h)
    return x0, x1, y0, y1


def add_streak(image: np.ndarray, x0, y0, x1, y1, flux: float, sigma_px: float) -> None:
    """Add (in place) ``flux`` spread uniformly along (x0, y0) → (x1, y1) with a Gaussian PSF.

    Args:
        image: (H, W) float array.
        x0, y0, x1, y1: segment ends (pixels, 0-based).
        flux: total counts of the streak (also what falls off the frame).
        sigma_px: PSF standard deviation (pixels).
    """
    pad = EXTENT_SIGMA * sigma_px
    bx0, bx1, by0, by1 = _window(image.shape, (x0, x1), (y0, y1), pad)
    if bx0 >= bx1 or by0 >= by1 or flux == 0:
        return
    yy, xx = np.mgrid[by0:by1, bx0:bx1].astype(np.float64)
    dx, dy = x1 - x0, y1 - y0
    length = math.hypot(dx, dy)
    norm = 1.0 / (2.0 * math.pi * sigma_px**2)
    if length < 1e-3 * sigma_px:
        r2 = (xx - 0.5 * (x0 + x1)) ** 2 + (yy - 0.5 * (y0 + y1)) ** 2
        image[by0:by1, bx0:bx1] += flux * norm * np.exp(-0.5 * r2 / sigma_px**2)
        return
    ux, uy = dx / length, dy / length
    along = (xx - x0) * ux + (yy - y0) * uy
    across = -(xx - x0) * uy + (yy - y0) * ux
    s = math.sqrt(2.0) * sigma_px
    profile = 0.5 * (erf(along / s) - erf((along - length) / s)) / length
    gauss = np.exp(-0.5 * (across / sigma_px) ** 2) / (math.sqrt(2.0 * math.pi) * sigma_px)
    image[by0:by1, bx0:bx1] += flux * profile * gauss


def add_path(image: np.ndarray, xs: np.ndarray, ys: np.ndarray, flux: float, sigma_px: float):
    """Add a source moving along the polyline (xs, ys) at uniform speed per segment.

    Each of the K segments gets ``flux / K`` (equal time steps).
    """
    k = len(xs) - 1
    if k < 1:
        add_streak(image, xs[0], ys[0], xs[0], ys[0], flux, sigma_px)
        return
    for i in range(k):
        add_streak(image, xs[i], ys[i], xs[i + 1], ys[i + 1], flux / k, sigma_px)

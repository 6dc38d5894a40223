"""Telescope frames from light curves, and light curves from frames (the seed's §3).

- :mod:`~jaxlc.imaging.sensor`: the rate-tracked sensor (pixels, PSF, sky,
  noise, zero point) and its celestial WCS.
- :mod:`~jaxlc.imaging.catalog`: the star catalogue (shipped Hipparcos to
  V = 8, or any ``ra_deg, dec_deg, mag`` table) and cone queries.
- :mod:`~jaxlc.imaging.draw`: point sources and streaks on a pixel grid.
- :mod:`~jaxlc.imaging.frames`: a light curve + geometry → one FITS per exposure.
- :mod:`~jaxlc.imaging.detect`: background, FFT matched filter, segments and
  their classes (point, streak, partial streak).
- :mod:`~jaxlc.imaging.starmatch`: detections matched to catalogue stars; blends.
- :mod:`~jaxlc.imaging.photometry`: apertures, the instrument magnitude
  (seed Eq. 3), the CCD equation and the zero point from stars (Eq. 5).
- :mod:`~jaxlc.imaging.track`: frame-to-frame linking of objects with prediction.
- :mod:`~jaxlc.imaging.fitsframe`: reading FITS frames (image, WCS, EXPTIME, DATE-OBS).
- :mod:`~jaxlc.imaging.extract`: FITS frames → one light-curve table per object.
- :mod:`~jaxlc.imaging.plots`: a frame with its detections; extracted vs injected.
"""

from jaxlc.imaging.catalog import load_catalog, stars_near
from jaxlc.imaging.extract import extract_lightcurves
from jaxlc.imaging.frames import simulate_frames
from jaxlc.imaging.sensor import HeaderKeys, Sensor

__all__ = [
    "HeaderKeys",
    "Sensor",
    "extract_lightcurves",
    "load_catalog",
    "simulate_frames",
    "stars_near",
]

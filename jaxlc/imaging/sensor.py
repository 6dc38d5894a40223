"""The rate-tracked sensor: pixels, PSF, sky, noise, zero point and WCS.

Magnitudes are the light-curve table's visual magnitudes. The zero point
``zero_point_mag`` is the magnitude of a source giving 1 photo-electron per
second in the whole PSF, so a source of magnitude m gives
``10**(-0.4 (m - zero_point_mag))`` e⁻/s.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from jaxlc.errors import JaxlcError

#: FWHM of a Gaussian over its standard deviation.
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


@dataclasses.dataclass(frozen=True)
class Sensor:
    """A camera on a rate-tracking telescope (defaults: a 10-cm wide-field sensor).

    Attributes:
        width_px, height_px: frame size (pixels).
        pixel_scale_arcsec: sky angle of one pixel (arcsec).
        psf_fwhm_px: Gaussian PSF full width at half maximum (pixels).
        sky_mag_arcsec2: sky brightness (mag per arcsec²).
        read_noise_e: read noise (e⁻ RMS per pixel).
        gain_e_per_adu: electrons per ADU.
        dark_e_per_s: dark current (e⁻/s per pixel).
        zero_point_mag: magnitude giving 1 e⁻/s.
        bias_adu: bias level (ADU).
        saturation_adu: the largest ADU (16-bit by default).
        readout_s: dead time after an exposure before the next can start (s).
    """

    width_px: int = 1024
    height_px: int = 1024
    pixel_scale_arcsec: float = 10.0
    psf_fwhm_px: float = 2.5
    sky_mag_arcsec2: float = 20.5
    read_noise_e: float = 8.0
    gain_e_per_adu: float = 2.0
    dark_e_per_s: float = 0.5
    zero_point_mag: float = 20.0
    bias_adu: float = 500.0
    saturation_adu: int = 65535
    readout_s: float = 0.0

    def __post_init__(self):
        positive = ("pixel_scale_arcsec", "psf_fwhm_px", "gain_e_per_adu")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise JaxlcError(f"sensor {name} = {value!r} must be a positive number")
        for name in ("read_noise_e", "dark_e_per_s", "bias_adu", "readout_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise JaxlcError(f"sensor {name} = {value!r} must be ≥ 0")
        for name in ("sky_mag_arcsec2", "zero_point_mag"):
            if not math.isfinite(getattr(self, name)):
                raise JaxlcError(f"sensor {name} = {getattr(self, name)!r} must be finite")
        for name in ("width_px", "height_px"):
            value = getattr(self, name)
            if int(value) != value or not 16 <= value <= 16384:
                raise JaxlcError(f"sensor {name} = {value!r} must be a whole number 16..16384")
        if not 0 < self.bias_adu < self.saturation_adu <= 65535:
            raise JaxlcError(
                f"sensor saturation_adu = {self.saturation_adu!r} must lie above the bias "
                f"({self.bias_adu}) and fit 16 bits (≤ 65535)"
            )

    @property
    def psf_sigma_px(self) -> float:
        """Gaussian PSF standard deviation (pixels)."""
        return self.psf_fwhm_px / FWHM_PER_SIGMA

    @property
    def pixel_scale_deg(self) -> float:
        return self.pixel_scale_arcsec / 3600.0

    @property
    def centre_px(self) -> tuple[float, float]:
        """Detector centre (x, y), 0-based pixels: where the tracked object sits."""
        return (self.width_px - 1) / 2.0, (self.height_px - 1) / 2.0

    @property
    def half_diagonal_deg(self) -> float:
        return 0.5 * math.hypot(self.width_px, self.height_px) * self.pixel_scale_deg

    def electron_rate(self, mag):
        """Photo-electrons per second of a source of visual magnitude ``mag``."""
        return 10.0 ** (-0.4 * (np.asarray(mag, dtype=np.float64) - self.zero_point_mag))

    @property
    def sky_e_per_s_px(self) -> float:
        """Sky photo-electrons per second per pixel."""
        return float(self.electron_rate(self.sky_mag_arcsec2)) * self.pixel_scale_arcsec**2


def tangent_wcs(sensor: Sensor, ra_deg: float, dec_deg: float):
    """A TAN WCS with (ra, dec) at the detector centre, north up, east left."""
    from astropy.wcs import WCS

    wcs = WCS(naxis=2)
    wcs.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    wcs.wcs.cunit = ["deg", "deg"]
    wcs.wcs.crval = [float(ra_deg) % 360.0, float(dec_deg)]
    wcs.wcs.crpix = [sensor.centre_px[0] + 1.0, sensor.centre_px[1] + 1.0]
    scale = sensor.pixel_scale_deg
    wcs.wcs.cd = np.array([[-scale, 0.0], [0.0, scale]])
    wcs.wcs.radesys = "ICRS"
    return wcs


@dataclasses.dataclass(frozen=True)
class HeaderKeys:
    """FITS header keywords ``jaxlc extract`` reads (configurable for other telescopes).

    ``gain`` and ``saturation`` are optional in a header; when absent the
    defaults ``default_gain`` and ``default_saturation`` are used.
    """

    exptime: str = "EXPTIME"
    date_obs: str = "DATE-OBS"
    gain: str = "GAIN"
    saturation: str = "SATURATE"
    fwhm: str = "PSF_FWHM"
    default_gain: float = 1.0
    default_saturation: float = 65535.0

"""Reading telescope frames (FITS): the image, its WCS, exposure, start time, gain.

Any FITS file with a 2-D image in some HDU and a celestial WCS in that HDU's
header works; the keywords read are :class:`~jaxlc.imaging.sensor.HeaderKeys`
(configurable for other telescopes). A missing or unreadable item is one
line naming the file, the keyword and the fix.
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.errors import JaxlcError
from jaxlc.imaging.sensor import HeaderKeys


@dataclasses.dataclass
class Frame:
    """One exposure: ``data`` (H, W) float ADU, ``wcs`` (celestial), ``exptime_s``,
    ``start`` (UTC Timestamp), ``gain`` (e⁻/ADU), ``saturation`` (ADU),
    ``fwhm_px`` (None when the header has none) and the header itself."""

    path: Path
    data: np.ndarray
    wcs: object
    exptime_s: float
    start: pd.Timestamp
    gain: float
    saturation: float
    fwhm_px: float | None
    header: object


def _image_hdu(hdul, path):
    for hdu in hdul:
        if hdu.data is not None and getattr(hdu.data, "ndim", 0) == 2:
            return hdu
    raise JaxlcError(f"{path}: no 2-D image in any HDU of this FITS file")


def frame_start(header, path, keys: HeaderKeys) -> pd.Timestamp:
    """The exposure's UTC start from ``keys.date_obs``."""
    from jaxlc.io.utc import utc_timestamp

    if keys.date_obs not in header:
        raise JaxlcError(
            f"{path}: no {keys.date_obs} keyword (UTC start of the exposure); "
            "name the right one with --date-key"
        )
    return utc_timestamp(str(header[keys.date_obs]), where=f"{path}: {keys.date_obs}")


def celestial_wcs(header, path):
    """The header's celestial WCS; a clear error when it has none."""
    from astropy.wcs import WCS, FITSFixedWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FITSFixedWarning)
        try:
            wcs = WCS(header).celestial
        except Exception as exc:
            raise JaxlcError(f"{path}: the header's WCS cannot be read ({exc})") from None
    if not wcs.has_celestial or wcs.naxis != 2:
        raise JaxlcError(
            f"{path}: no celestial WCS in the header (CTYPE1/2 = RA---TAN/DEC--TAN, CRVAL, "
            "CRPIX, CD or CDELT); plate-solve the frame first (e.g. astrometry.net)"
        )
    return wcs


def frame_pointing(path: str | Path, keys: HeaderKeys) -> tuple[pd.Timestamp, float, float]:
    """(UTC start, RA, Dec in degrees) of a frame's centre, from its header alone."""
    from astropy.io import fits

    try:
        with fits.open(path, memmap=True) as hdul:
            hdu = next((h for h in hdul if h.header.get("NAXIS", 0) == 2), None)
            if hdu is None:
                raise JaxlcError(f"{path}: no 2-D image in any HDU of this FITS file")
            header = hdu.header.copy()
    except JaxlcError:
        raise
    except Exception as exc:
        raise JaxlcError(f"{path}: not a readable FITS file ({type(exc).__name__})") from None
    wcs = celestial_wcs(header, path)
    ra, dec = wcs.pixel_to_world_values((header["NAXIS1"] - 1) / 2.0, (header["NAXIS2"] - 1) / 2.0)
    return frame_start(header, path, keys), float(ra), float(dec)


def read_frame(path: str | Path, keys: HeaderKeys | None = None) -> Frame:
    """Read one FITS frame; raises :class:`JaxlcError` for anything unusable."""
    from astropy.io import fits

    keys = keys or HeaderKeys()
    path = Path(path)
    if not path.is_file():
        raise JaxlcError(f"{path}: no such file")
    try:
        with fits.open(path, memmap=False) as hdul:
            hdu = _image_hdu(hdul, path)
            data = np.asarray(hdu.data, dtype=np.float64)
            header = hdu.header.copy()
    except JaxlcError:
        raise
    except Exception as exc:
        raise JaxlcError(
            f"{path}: not a readable FITS file ({type(exc).__name__}: {exc})"
        ) from None
    wcs = celestial_wcs(header, path)
    if keys.exptime not in header:
        raise JaxlcError(
            f"{path}: no {keys.exptime} keyword (exposure in seconds); "
            "name the right one with --exptime-key"
        )
    try:
        exptime = float(header[keys.exptime])
    except (TypeError, ValueError):
        exptime = float("nan")
    if not np.isfinite(exptime) or exptime <= 0:
        raise JaxlcError(
            f"{path}: {keys.exptime} = {header[keys.exptime]!r} is not a positive time"
        )
    if not np.isfinite(data).any():
        raise JaxlcError(f"{path}: the image has no finite pixel")
    gain = float(header.get(keys.gain, keys.default_gain))
    saturation = float(header.get(keys.saturation, keys.default_saturation))
    fwhm = header.get(keys.fwhm)
    return Frame(
        path, data, wcs, exptime, frame_start(header, path, keys), gain, saturation,
        None if fwhm is None else float(fwhm), header,
    )  # fmt: skip


def list_frames(folder: str | Path) -> list[Path]:
    """The FITS files of ``folder`` (``.fits``, ``.fit``, ``.fts``, gzipped too), by name."""
    folder = Path(folder)
    if folder.is_file():
        return [folder]
    if not folder.is_dir():
        raise JaxlcError(f"{folder}: no such folder of FITS frames")
    files = sorted(
        p for p in folder.iterdir()
        if p.is_file() and p.name.lower().endswith((".fits", ".fit", ".fts", ".fits.gz"))
    )  # fmt: skip
    if not files:
        raise JaxlcError(f"{folder}: holds no FITS file (.fits, .fit, .fts, .fits.gz)")
    return files

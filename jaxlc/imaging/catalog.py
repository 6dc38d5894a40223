"""Star catalogues: the shipped Hipparcos stars to V = 8, or any ``ra_deg, dec_deg, mag`` table.

The shipped file ``jaxlc/data/stars/hipparcos_v8.csv.gz`` (42,212 stars,
epoch 2024.0, ICRS, V magnitudes) is made by ``experiments/make_star_catalog.py``
from the Hipparcos main catalogue (ESA 1997) as bundled by the PyPI package
cedar-solve 0.5.1. Hipparcos has about one star per square degree, so a
sensor of ≳ 2° field is needed for a zero point from it; fainter tables
(UCAC4, Gaia exports) can be given as CSV.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.errors import JaxlcError

#: The catalogue shipped with jaxlc.
SHIPPED_CATALOG = Path(__file__).resolve().parents[1] / "data" / "stars" / "hipparcos_v8.csv.gz"
CATALOG_COLUMNS = ("ra_deg", "dec_deg", "mag")


def load_catalog(path: str | Path | None = None) -> pd.DataFrame:
    """Read a star catalogue (CSV, optionally gzipped, ``#`` comments allowed).

    Args:
        path: a table with columns ``ra_deg, dec_deg, mag`` (ICRS degrees,
            visual magnitudes); None for the shipped Hipparcos stars.

    Returns:
        DataFrame with at least ``ra_deg, dec_deg, mag`` and the unit vectors
        ``ux, uy, uz`` (ICRS).

    Raises:
        JaxlcError: a missing file, missing columns or values out of range.
    """
    path = SHIPPED_CATALOG if path is None else Path(path)
    if not path.is_file():
        raise JaxlcError(f"star catalogue {path}: no such file; give a CSV with ra_deg,dec_deg,mag")
    try:
        stars = pd.read_csv(path, comment="#")
    except Exception as exc:
        raise JaxlcError(f"star catalogue {path}: cannot read as CSV ({exc})") from None
    missing = [c for c in CATALOG_COLUMNS if c not in stars.columns]
    if missing:
        raise JaxlcError(
            f"star catalogue {path}: missing column(s) {', '.join(missing)} "
            f"(has {', '.join(map(str, stars.columns[:6]))}); it needs ra_deg, dec_deg, mag"
        )
    values = stars[list(CATALOG_COLUMNS)].apply(pd.to_numeric, errors="coerce")
    bad = ~np.isfinite(values.to_numpy()).all(axis=1) | (values["dec_deg"].abs() > 90).to_numpy()
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise JaxlcError(
            f"star catalogue {path}: row {row + 1} has a non-numeric or out-of-range "
            f"ra_deg/dec_deg/mag ({stars.iloc[row][list(CATALOG_COLUMNS)].tolist()})"
        )
    stars[list(CATALOG_COLUMNS)] = values
    ra, dec = np.radians(values["ra_deg"].to_numpy()), np.radians(values["dec_deg"].to_numpy())
    stars["ux"] = np.cos(dec) * np.cos(ra)
    stars["uy"] = np.cos(dec) * np.sin(ra)
    stars["uz"] = np.sin(dec)
    stars.attrs["source"] = str(path)
    return stars


def unit_vector(ra_deg, dec_deg) -> np.ndarray:
    """ICRS unit vector(s) (..., 3) of right ascension and declination (degrees)."""
    ra, dec = np.radians(ra_deg), np.radians(dec_deg)
    return np.stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)], axis=-1)


def stars_near(stars: pd.DataFrame, ra_deg: float, dec_deg: float, radius_deg: float):
    """The catalogue's stars within ``radius_deg`` of (ra, dec)."""
    centre = unit_vector(ra_deg, dec_deg)
    cosine = stars[["ux", "uy", "uz"]].to_numpy() @ centre
    return stars[cosine >= np.cos(np.radians(min(radius_deg, 180.0)))]

"""Ground sites: a small registry of named observatories, or any coordinates."""

from __future__ import annotations

import dataclasses
import math

from jaxlc.errors import JaxlcError


@dataclasses.dataclass(frozen=True)
class Site:
    """A sensor on the WGS84 ellipsoid.

    Attributes:
        name: short key, e.g. ``"mt-stromlo"``.
        lat_deg: geodetic latitude, north positive.
        lon_deg: longitude, east positive.
        alt_m: height above the WGS84 ellipsoid.
        description: what and where, with the source of the coordinates.
    """

    name: str
    lat_deg: float
    lon_deg: float
    alt_m: float
    description: str = ""

    def __post_init__(self):
        for key, value, lo, hi in (
            ("lat_deg", self.lat_deg, -90.0, 90.0),
            ("lon_deg", self.lon_deg, -180.0, 360.0),
            ("alt_m", self.alt_m, -500.0, 10_000.0),
        ):
            if not (math.isfinite(value) and lo <= value <= hi):
                raise JaxlcError(
                    f"site {self.name!r}: {key} = {value!r} must be in [{lo:g}, {hi:g}]"
                )

    def skyfield(self):
        """The site as a skyfield ``GeographicPosition`` (WGS84)."""
        from skyfield.api import wgs84

        return wgs84.latlon(self.lat_deg, self.lon_deg, elevation_m=self.alt_m)


SITES: dict[str, Site] = {
    s.name: s
    for s in (
        Site(
            "mt-stromlo",
            -35.3161,
            149.0099,
            805.0,
            "EOS/SERC satellite laser ranging station, Mount Stromlo, Canberra, Australia "
            "(ILRS 7825; the seed paper's site)",
        ),
        Site(
            "mmt-sao",
            43.6468,
            41.4405,
            2070.0,
            "Mini-MegaTORTORA, Special Astrophysical Observatory, Nizhny Arkhyz, Russia "
            "(coordinates of the BTA on the same grounds, ~1 km)",
        ),
        Site(
            "siding-spring",
            -31.2733,
            149.0644,
            1165.0,
            "Siding Spring Observatory, NSW, Australia",
        ),
        Site(
            "haleakala",
            20.7082,
            -156.2571,
            3055.0,
            "Haleakalā summit (AMOS), Maui, Hawaii",
        ),
    )
}


def get_site(name: str) -> Site:
    """A registered site by name (case-insensitive)."""
    key = name.strip().lower()
    if key not in SITES:
        raise JaxlcError(
            f"unknown site {name!r}; known sites: {', '.join(SITES)} "
            "(or give --lat-deg, --lon-deg and --alt-m)"
        )
    return SITES[key]


def site_from(name: str | None = None, lat_deg=None, lon_deg=None, alt_m=None) -> Site:
    """A site from a registry name or from coordinates (exactly one of the two)."""
    coords = (lat_deg, lon_deg, alt_m)
    if name is not None and any(c is not None for c in coords):
        raise JaxlcError("give either --site or --lat-deg/--lon-deg/--alt-m, not both")
    if name is not None:
        return get_site(name)
    if any(c is None for c in coords):
        raise JaxlcError(
            "no site given: use --site NAME (see `jaxlc sites`) or all of "
            "--lat-deg, --lon-deg and --alt-m"
        )
    return Site(
        f"lat{lat_deg:+.4f}_lon{lon_deg:+.4f}",
        float(lat_deg),
        float(lon_deg),
        float(alt_m),
        "user coordinates",
    )

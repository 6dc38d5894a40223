"""Observation geometry: tables of object, Sun and observer positions per sample.

From TLEs (:mod:`~jaxlc.geometry.tle` → :mod:`~jaxlc.geometry.orbit` (SGP4,
GCRS) → :mod:`~jaxlc.geometry.observe`, with the Sun from
:mod:`~jaxlc.geometry.ephemeris`, sites from :mod:`~jaxlc.geometry.sites` and
the conic Earth shadow from :mod:`~jaxlc.geometry.eclipse`), or without an
orbit (:mod:`~jaxlc.geometry.synthetic`: a fixed Sun, an observer sweeping a
range of phase angles) for analytic tests, demos and random-geometry data.
"""

from jaxlc.geometry.observe import Visibility, find_passes, geometry_table
from jaxlc.geometry.sites import get_site, site_from
from jaxlc.geometry.synthetic import synthetic_geometry
from jaxlc.geometry.tle import latest_before, read_tles, select_objects

__all__ = [
    "Visibility",
    "find_passes",
    "geometry_table",
    "get_site",
    "latest_before",
    "read_tles",
    "select_objects",
    "site_from",
    "synthetic_geometry",
]

"""Observation geometry: tables of object, Sun and observer positions per sample.

``synthetic`` makes tables without an orbit (a fixed Sun, an observer sweeping
a range of phase angles) for analytic tests, demos and random-geometry data.
"""

from jaxlc.geometry.synthetic import synthetic_geometry

__all__ = ["synthetic_geometry"]

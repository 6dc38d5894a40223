"""Per-row observation geometry: what the renderer needs from a geometry table.

For every row, in float64: unit vectors from the object to the Sun and to the
observer, the range, the solar irradiance at the object (1/r² and the Earth
shadow ν, :mod:`jaxlc.rendering.photometry`), the phase angle, the exposure
and whether the row is rendered (visible and ν > 0). Made from a validated
table (:func:`geometry_arrays`) or from position arrays
(:func:`geometry_from_positions`, e.g. a dataset's synthetic tracks).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from jaxlc.io.tables import read_geometry, validate_geometry
from jaxlc.rendering import photometry


@dataclasses.dataclass(frozen=True)
class GeometryArrays:
    """Per-row float64 quantities of a geometry table.

    Attributes:
        t_start_s: (T,) exposure start times, seconds from the first row.
        exposure_s: (T,) exposure times (the scene's where the table has none).
        sun_dir, obs_dir: (T, 3) unit vectors object→Sun, object→observer.
        range_m: (T,) object-observer distance.
        irradiance_w_m2: (T,) solar irradiance at the object (1/r² and shadow ν).
        phase_angle_deg: (T,) Sun-object-observer angle.
        visible: (T,) rows to render.
        origin_utc: UTC time of the first row (None for an empty table).
    """

    t_start_s: np.ndarray
    exposure_s: np.ndarray
    sun_dir: np.ndarray
    obs_dir: np.ndarray
    range_m: np.ndarray
    irradiance_w_m2: np.ndarray
    phase_angle_deg: np.ndarray
    visible: np.ndarray
    origin_utc: pd.Timestamp | None

    @property
    def t_mid_s(self) -> np.ndarray:
        """(T,) mid-exposure times, seconds from the first row."""
        return self.t_start_s + 0.5 * self.exposure_s

    @property
    def n_rows(self) -> int:
        return len(self.t_start_s)


def observation_directions(rso_m, sun_m, obs_m, shadow_nu):
    """Unit vectors object→Sun and object→observer (T, 3), range (T,) in m,
    solar irradiance (T,) in W/m² and phase angle (T,) in degrees, from
    float64 positions (T, 3) in m and the shadow function ν (T,)."""
    to_sun = sun_m - rso_m
    to_obs = obs_m - rso_m
    with np.errstate(invalid="ignore", divide="ignore"):
        sun_dist = row_norm(to_sun)
        range_m = row_norm(to_obs)
        s = to_sun / sun_dist[:, None]
        v = to_obs / range_m[:, None]
        # |s − v| = 2 sin(α/2), |s + v| = 2 cos(α/2): accurate at every angle
        phase = np.degrees(2.0 * np.arctan2(row_norm(s - v), row_norm(s + v)))
        irradiance = photometry.solar_irradiance_w_m2(sun_dist, shadow_nu)
    return s, v, range_m, irradiance, phase


def row_norm(x: np.ndarray) -> np.ndarray:
    """(T,) Euclidean norms of the rows of x (T, 3) (3× faster than ``np.linalg.norm``)."""
    return np.sqrt(np.einsum("ij,ij->i", x, x))


def geometry_from_positions(
    t_s,
    rso_m,
    sun_m,
    obs_m,
    shadow_nu=1.0,
    exposure_s=1.0,
    visible=True,
    origin_utc: pd.Timestamp | None = None,
) -> GeometryArrays:
    """:class:`GeometryArrays` from positions (T, 3) in m (GCRS or synthetic) and
    per-row (T,) or scalar shadow ν, exposure (s) and visibility.

    A row is rendered only where it is visible and ν > 0.
    """
    t = np.asarray(t_s, np.float64)
    n = len(t)
    nu = np.broadcast_to(np.asarray(shadow_nu, np.float64), (n,))
    s, v, range_m, irradiance, phase = observation_directions(
        np.asarray(rso_m, np.float64), np.asarray(sun_m, np.float64), obs_m, nu
    )
    with np.errstate(invalid="ignore"):
        vis = np.broadcast_to(np.asarray(visible, bool), (n,)) & (nu > 0)
    return GeometryArrays(
        t_start_s=t - t[0] if n else t,
        exposure_s=np.broadcast_to(np.asarray(exposure_s, np.float64), (n,)).copy(),
        sun_dir=s,
        obs_dir=v,
        range_m=range_m,
        irradiance_w_m2=irradiance,
        phase_angle_deg=phase,
        visible=vis,
        origin_utc=origin_utc,
    )


def geometry_arrays(table: pd.DataFrame, default_exposure_s: float = 1.0) -> GeometryArrays:
    """:class:`GeometryArrays` of a validated geometry table (rows without an
    ``exposure_s`` get ``default_exposure_s``, the scene's)."""
    pos = {
        b: table[[f"{b}_{c}_m" for c in "xyz"]].to_numpy(np.float64) for b in ("rso", "sun", "obs")
    }
    exposure = table["exposure_s"].to_numpy(np.float64).copy()
    exposure[np.isnan(exposure)] = default_exposure_s
    return geometry_from_positions(
        table["t_s"].to_numpy(np.float64),
        pos["rso"],
        pos["sun"],
        pos["obs"],
        table["shadow_nu"].to_numpy(np.float64),
        exposure,
        table["visible"].to_numpy(bool),
        pd.Timestamp(table["utc"].iloc[0]) if len(table) else None,
    )


def as_geometry(geometry, default_exposure_s: float) -> tuple[GeometryArrays, pd.DataFrame | None]:
    """Geometry arrays and the validated table of a path, DataFrame or GeometryArrays."""
    if isinstance(geometry, GeometryArrays):
        return geometry, None
    table = (
        validate_geometry(geometry)
        if isinstance(geometry, pd.DataFrame)
        else read_geometry(geometry)
    )
    return geometry_arrays(table, default_exposure_s), table

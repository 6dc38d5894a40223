"""The front door of rendering: scene + geometry table → light-curve table.

:func:`render` prepares the scene over the table
(:func:`jaxlc.rendering.prepare.prepare`: plan, object, exposures), evaluates
the kernel entry :func:`jaxlc.rendering.kernel.exposure_intensity` on the
visible rows (padded to a few bucket sizes to limit recompilation) and turns
I/E into flux and magnitudes in float64 (:mod:`jaxlc.rendering.photometry`).
Invisible rows keep their row with NaN values.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import numpy as np
import pandas as pd

from jaxlc.errors import JaxlcError
from jaxlc.io.provenance import jaxlc_version
from jaxlc.rendering import photometry
from jaxlc.rendering.kernel import exposure_intensity
from jaxlc.rendering.observation import GeometryArrays
from jaxlc.rendering.options import RenderOptions
from jaxlc.rendering.prepare import Prepared, adapt, prepare, probe_inputs
from jaxlc.scene import Scene
from jaxlc.xla import jit

_kernel = jit(exposure_intensity, static_argnames=("chunk",))


def intensity(prepared: Prepared) -> np.ndarray:
    """(T,) mean I/E (m² sr⁻¹) over each exposure of the geometry table; NaN on
    rows not rendered.

    Raises:
        JaxlcError: a rendered row came out non-finite (a bug: the message asks
            for a report).
    """
    out = np.full(prepared.geometry.n_rows, np.nan)
    rows = prepared.exposures.rows
    if len(rows) == 0:
        return out
    if prepared.refinement is not None:
        got = prepared.refinement.intensity
    else:
        with jax.enable_x64(prepared.precision == "float64"):
            got = np.asarray(_kernel(prepared.object, prepared.inputs), dtype=np.float64)
    got = got[: len(rows)]
    if not np.all(np.isfinite(got)):
        bad = int(np.count_nonzero(~np.isfinite(got)))
        raise JaxlcError(
            f"render: {bad} visible sample(s) gave a non-finite intensity for scene "
            f"{prepared.scene.source}; please report this with the scene and geometry files"
        )
    out[rows] = got
    return out


def evaluate_instants(requests) -> list[np.ndarray]:
    """I/E at every instant of each (prepared curve, probe) pair, one kernel call each
    (the evaluator of :func:`jaxlc.rendering.prepare.adapt` for single curves)."""
    out = []
    for prepared, probe in requests:
        m = len(probe.t_s)
        if m == 0:
            out.append(np.zeros(0))
            continue
        with jax.enable_x64(prepared.precision == "float64"):
            got = _kernel(prepared.object, probe_inputs(prepared, probe))
            out.append(np.asarray(got, np.float64)[:m])
    return out


def render(
    scene: Scene | str | Path,
    geometry: pd.DataFrame | str | Path,
    precision: str = "float32",
    options: RenderOptions | None = None,
    progress=None,
) -> pd.DataFrame:
    """Render a light curve.

    Args:
        scene: a :class:`~jaxlc.scene.Scene`, the path of a scene file, or a
            shipped scene's name (``"s4_falcon9"``, ``"S4"``).
        geometry: a geometry table (DataFrame) or its path (CSV/Parquet).
        precision: ``"float32"`` (default, fast) or ``"float64"``.
        options: shadows and motion blur (default: the scene's ``[render]`` table).
        progress: optional callable(done, total) while a shadow table is traced.

    Returns:
        Light-curve table: ``utc, t_s, mag, flux_w_m2, phase_angle_deg,
        range_m, exposure_s, visible``; invisible rows have NaN ``mag`` and
        ``flux_w_m2``; a visible row where no lit facet is seen has zero flux
        and ``mag = inf``. ``attrs["plan"]`` says what was done
        (:meth:`~jaxlc.rendering.plan.RenderPlan.explain`).

    Example:
        >>> lc = jaxlc.render("s4_falcon9", "geometry.csv")
        >>> lc[["t_s", "mag"]].head()
    """
    with jax.enable_x64(precision == "float64"):
        prepared = prepare(scene, geometry, options, precision, pad_rows=True, progress=progress)
        prepared = adapt([prepared], evaluate_instants, pad_rows=True)[0]
    out = lightcurve_table(prepared.table, prepared.geometry, intensity(prepared))
    plan = prepared.plan
    if prepared.refinement is not None:
        plan = dataclasses.replace(
            plan, blur_reason=f"{plan.blur_reason}: {prepared.refinement.describe()}"
        )
    out.attrs.update(
        {
            "frame": prepared.table.attrs.get("frame", "unknown"),
            "scene": prepared.scene.source,
            "precision": precision,
            "generator": f"jaxlc {jaxlc_version()}",
            "plan": " | ".join(line.split(None, 1)[1] for line in plan.explain().splitlines()),
        }
    )
    return out


def lightcurve_table(
    table: pd.DataFrame, geo: GeometryArrays, intensity_m2_sr: np.ndarray, **extra
) -> pd.DataFrame:
    """The light-curve table of a geometry table and per-row I/E (m² sr⁻¹, NaN: not rendered).

    ``extra`` columns (arrays of one value per row) follow the standard ones.
    """
    flux = photometry.flux_w_m2(intensity_m2_sr, geo.irradiance_w_m2, geo.range_m)
    return pd.DataFrame(
        {
            "utc": table["utc"],
            "t_s": table["t_s"],
            "mag": photometry.magnitude(flux),
            "flux_w_m2": flux,
            "phase_angle_deg": geo.phase_angle_deg,
            "range_m": geo.range_m,
            "exposure_s": geo.exposure_s,
            "visible": geo.visible,
            **extra,
        }
    )

"""Render bulk datasets: shards of curves, run in this process or on Dask.

A shard is a pure function of (config, shard index) (:func:`render_shard`):
its curves are drawn (:mod:`jaxlc.dataset.draw`), each prepared like any
render (:func:`jaxlc.rendering.prepare.prepare`) from its scene and geometry,
grouped by shape class and evaluated in batches (:mod:`jaxlc.dataset.bulk`),
their flux turned into magnitudes where light arrives (:func:`lit`: a stored
sample is visible only where the visibility rules pass *and* its flux is > 0)
and, with a noise model, noisy values (:mod:`jaxlc.dataset.noise`).
:func:`jaxlc.dataset.generate` renders the missing shards of a store
(:mod:`jaxlc.dataset.store`): in this process (``workers=0``), on a local Dask
cluster (worker processes, one thread each) or on a cluster given by its
scheduler address, with a progress bar.
"""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np
import pandas as pd

from jaxlc.dataset.bulk import render_class
from jaxlc.dataset.config import DatasetConfig, DatasetError, PassSource, SyntheticSource
from jaxlc.dataset.draw import curve_geometry, curve_rng, curve_scene, draw_curve
from jaxlc.rendering import photometry
from jaxlc.rendering.prepare import prepare
from jaxlc.scene import scene_from_dict

# ---------------------------------------------------------------------------
# One shard


@dataclasses.dataclass(frozen=True)
class Shard:
    """A rendered shard: rows ``start … start + len(labels)`` of every array.

    Attributes:
        index: shard number.
        start: first curve.
        arrays: name → (n, T) arrays in their store dtypes.
        labels: (n rows) the label columns of :data:`jaxlc.dataset.store.LABELS`.
    """

    index: int
    start: int
    arrays: dict
    labels: pd.DataFrame


def render_shard(config: DatasetConfig, shard: int, pool=None) -> Shard:
    """Render shard ``shard`` of a dataset (a pure function of its arguments).

    Args:
        config: the dataset config.
        shard: shard index, 0 … n_shards − 1.
        pool: the pass pool (:class:`jaxlc.geometry.pool.PassPool`) for real passes.
    """
    from jaxlc.dataset.noise import add_noise, magnitude_of, scintillation_rel

    rows = config.shard_rows(shard)
    if isinstance(config.geometry, PassSource) and pool is None:
        raise DatasetError("render_shard: real-pass geometry needs the pass pool")
    lengths = pool.length if pool is not None else None
    curves = [draw_curve(config, i, lengths) for i in rows]
    geos = [curve_geometry(config, c, pool) for c in curves]
    scenes = [curve_scene(config, c) for c in curves]
    prepared = [
        prepare(
            scene_from_dict(d, source=f"curve {c.index}"),
            g.arrays,
            plan_instants=False,
            candidate_cells=False,  # one table per class batch (bulk.stacked_objects)
        )
        for c, d, g in zip(curves, scenes, geos, strict=True)
    ]
    n, t_len = len(curves), config.samples
    intensity = np.full((n, t_len), np.nan)
    instants = np.zeros(n)  # per curve: instants per rendered exposure
    for class_id in sorted({c.class_id for c in curves}):
        idx = [j for j, c in enumerate(curves) if c.class_id == class_id]
        got = []
        cls = config.classes[class_id]
        intensity[idx] = render_class(config, cls, [prepared[j] for j in idx], got)
        instants[idx] = got

    arr = [g.arrays for g in geos]
    observed = np.stack([a.visible for a in arr])
    bad = observed & ~np.isfinite(intensity)
    if bad.any():
        j = int(np.flatnonzero(bad.any(axis=1))[0])
        raise DatasetError(
            f"shard {shard}: curve {curves[j].index} gave a non-finite intensity on "
            f"{int(bad[j].sum())} visible sample(s); please report this with the config"
        )
    flux = np.stack(
        [
            photometry.flux_w_m2(intensity[j], a.irradiance_w_m2, a.range_m)
            for j, a in enumerate(arr)
        ]
    )
    vis = observed & lit(flux)
    flux[~vis] = np.nan
    mag = photometry.magnitude(flux)
    arrays = {
        "mag": mag.astype(np.float32),
        "flux_w_m2": flux.astype(np.float32),
        "phase_angle_deg": np.stack([a.phase_angle_deg for a in arr]).astype(np.float32),
        "range_m": np.stack([a.range_m for a in arr]).astype(np.float32),
        "visible": vis,
    }
    if config.noise is not None:
        nm = config.noise
        noisy = np.full_like(flux, np.nan)
        err = np.full_like(flux, np.nan)
        for j, (c, g) in enumerate(zip(curves, geos, strict=True)):
            scint = 0.0
            if nm.aperture_m is not None:
                alt = (
                    nm.altitude_m
                    if nm.altitude_m is not None
                    else pool.site_alt_m[c.geometry["pass_id"]]
                )
                scint = scintillation_rel(nm.aperture_m, g.airmass, alt, config.exposure_s)
            noisy[j], err[j] = add_noise(
                flux[j],
                config.exposure_s,
                curve_rng(config.seed, c.index, stream=1),
                nm.zero_point_mag,
                nm.sky_e_per_s,
                nm.read_noise_e,
                scint,
            )
        arrays["mag_noisy"] = magnitude_of(noisy).astype(np.float32)
        arrays["flux_noisy_w_m2"] = noisy.astype(np.float32)
        arrays["mag_err"] = err.astype(np.float32)
    labels = _labels(config, curves, scenes, geos, prepared, instants, vis, pool)
    return Shard(shard, rows.start, arrays, labels)


def tumble_labels(spec) -> dict:
    """A tumble's labels (mode, excitation, both periods, moments; empty for a spin)
    from its scene ``[attitude]`` (:class:`jaxlc.scene_attitude.AttitudeSpec`)."""
    if spec.model != "tumble":
        return {}
    tumble = spec.tumble()
    body, precession = tumble.periods_s()
    return {
        "tumble_mode": tumble.mode(),
        "excitation": tumble.excitation(),
        "body_period_s": body,
        "precession_period_s": precession,
        **{f"inertia_{a}_kg_m2": float(x) for a, x in zip("xyz", spec.inertia_kg_m2, strict=True)},
    }


def lit(flux_w_m2: np.ndarray) -> np.ndarray:
    """Where a noise-free flux has a magnitude once stored: > 0 and finite in float32.

    A zero flux (no lit facet faces the observer) would be ``mag = +inf``, and
    one below float32's smallest number (≈ 1e-45 W/m², fainter than mag 90)
    would be stored as 0; such samples are not visible in a dataset.

    Args:
        flux_w_m2: (…) noise-free flux, W/m² (NaN: not rendered).

    Returns:
        (…) bool.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        f = np.asarray(flux_w_m2, dtype=np.float64).astype(np.float32)
    return np.isfinite(f) & (f > 0)


def _labels(config, curves, scenes, geos, prepared, instants, visible, pool) -> pd.DataFrame:
    out = []
    for c, d, g, p, m, v in zip(curves, scenes, geos, prepared, instants, visible, strict=True):
        cls = config.classes[c.class_id]
        a = g.arrays
        any_v = bool(v.any())
        axis = cls.body_axis if cls.body_axis is not None else (np.nan,) * 3
        row = {
            "class": cls.name,
            "class_id": c.class_id,
            "mesh": str(cls.mesh_path),
            "scale": cls.mesh_scale * c.scale,
            "materials": json.dumps(list(c.materials)),
            "attitude": json.dumps(d["attitude"]),
            "body_axis_x": axis[0],
            "body_axis_y": axis[1],
            "body_axis_z": axis[2],
            **tumble_labels(p.scene.attitude),
            "pole_ra_deg": c.pole_ra_deg,
            "pole_dec_deg": c.pole_dec_deg,
            "period_s": c.period_s,
            "phase_deg": c.phase_deg,
            "subsamples": p.plan.subsamples if a.visible.any() else 0,
            "instants_per_exposure": float(m),
            "shadows": p.plan.shadow is not None,
            "utc_start": g.utc_start,
            "visible_samples": int(v.sum()),
            "phase_mean_deg": float(a.phase_angle_deg[v].mean()) if any_v else np.nan,
            "phase_min_deg": float(a.phase_angle_deg[v].min()) if any_v else np.nan,
            "phase_max_deg": float(a.phase_angle_deg[v].max()) if any_v else np.nan,
            "range_mean_m": float(a.range_m[v].mean()) if any_v else np.nan,
        }
        if isinstance(config.geometry, SyntheticSource):
            row.update(
                geometry="synthetic", pass_id=-1, pass_offset=-1, norad_id=-1, site="", **c.geometry
            )
        else:
            p = c.geometry["pass_id"]
            row.update(
                geometry="pass",
                pass_id=p,
                pass_offset=c.geometry["offset"],
                norad_id=int(pool.norad_id[p]),
                site=str(pool.site[p]),
            )
        out.append(row)
    from jaxlc.dataset.store import LABELS

    # column by column in numpy (pandas' where/astype per column took ~0.2 ms a curve)
    columns = {}
    for name, (dtype, fill, _) in LABELS.items():
        values = [_or_fill(row.get(name), fill) for row in out]  # a spin's tumble labels
        columns[name] = np.array(values, dtype=object if dtype == "str" else dtype)
    return pd.DataFrame(columns)


def _or_fill(value, fill):
    """``value``, or ``fill`` where it is missing (None or NaN)."""
    if value is None or (isinstance(value, float | np.floating) and np.isnan(value)):
        return fill
    return value


_POOLS: dict = {}
#: Set in local workers' environment: where their JAX compilation cache lives.
WORKER_CACHE_ENV = "JAXLC_WORKER_XLA_CACHE"


def _use_compilation_cache() -> None:
    """In a local worker: turn on JAX's persistent compilation cache (once).

    Done here rather than by JAX's own environment variable because the
    worker may have imported JAX before its environment was set.
    """
    from jaxlc.xla import enable_persistent_cache

    path = os.environ.get(WORKER_CACHE_ENV)
    if path:
        enable_persistent_cache(path)


def run_shard(config: DatasetConfig, shard: int, store: str) -> tuple[int, int]:
    """Render shard ``shard`` and write it into ``store`` (the unit of work on a worker).

    Returns:
        (shard, number of curves).
    """
    from jaxlc.dataset.store import read_pool, write_shard

    _use_compilation_cache()
    pool = None
    if isinstance(config.geometry, PassSource):
        if store not in _POOLS:
            _POOLS[store] = read_pool(store)
        pool = _POOLS[store]
    data = render_shard(config, shard, pool)
    write_shard(store, shard, data.start, data.arrays, data.labels)
    return shard, len(data.labels)

"""Render bulk datasets: shards of curves, batched in JAX, run in-process or on Dask.

A shard is a pure function of (config, shard index) (:func:`render_shard`):
its curves are drawn (:func:`jaxlc.dataset.draw_curve`), grouped by shape
class, and rendered in batches. Within a class every curve shares the mesh,
the facet order and — for a non-convex mesh — one shadow table, so a batch
is the class's facet model stacked along a leading axis:

* the sub-exposures of every curve (as many as :func:`jaxlc.plan.make_plan`
  would choose for that curve: its own spin rate, geometry and materials)
  are separate *renders* of T samples; renders are cut into batches of
  ``batch_size`` (the last one padded), so each class compiles once per
  process and a curve's result never depends on its batch neighbours;
* unshadowed classes ``jax.vmap`` over the batch; shadowed ones loop over it
  inside the jitted call (``lax.map``): vmapping the shadow lookup was 1.7×
  (S4) and 3.5× (S6) slower on the 2-core reference machine;
* the mesh is rendered at the class's own scale and I/E multiplied by the
  curve's size factor squared (uniform scaling keeps the shadow table).

:func:`generate` runs the missing shards of a store: in this process
(``workers=0``), on a local Dask cluster (processes, one thread each) or on
a cluster given by its scheduler address, with a progress bar.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc import photometry
from jaxlc.dataset import (
    Curve,
    DatasetConfig,
    DatasetError,
    PassSource,
    SyntheticSource,
    curve_rng,
    draw_curve,
    load_config,
)
from jaxlc.photometry import AU_M

#: Direction given to rows that are not rendered (their result is discarded).
_PARKED = np.array([0.0, 0.0, 1.0])


# ---------------------------------------------------------------------------
# Geometry of one curve (float64, host)


@dataclasses.dataclass(frozen=True)
class CurveGeometry:
    """Per-sample geometry of one curve, as :func:`jaxlc.render.geometry_arrays` derives it.

    Arrays are (T,) or (T, 3), float64: ``t_start_s``, ``sun_dir``, ``obs_dir``
    (unit vectors from the object), ``range_m``, ``irradiance_w_m2``,
    ``phase_angle_deg``, ``visible``; ``airmass`` (T,) for the noise model;
    ``utc_start`` the first sample's UTC.
    """

    t_start_s: np.ndarray
    sun_dir: np.ndarray
    obs_dir: np.ndarray
    range_m: np.ndarray
    irradiance_w_m2: np.ndarray
    phase_angle_deg: np.ndarray
    visible: np.ndarray
    airmass: np.ndarray
    utc_start: str


def _directions(rso, sun, obs, shadow_nu):
    """The same float64 steps as :func:`jaxlc.render.geometry_arrays`."""
    to_sun = sun - rso
    to_obs = obs - rso
    with np.errstate(invalid="ignore", divide="ignore"):
        sun_dist = np.linalg.norm(to_sun, axis=1)
        range_m = np.linalg.norm(to_obs, axis=1)
        s = to_sun / sun_dist[:, None]
        v = to_obs / range_m[:, None]
        phase = np.degrees(
            np.arctan2(np.linalg.norm(np.cross(s, v), axis=1), np.sum(s * v, axis=1))
        )
        irradiance = photometry.solar_irradiance_w_m2(sun_dist, shadow_nu)
    return s, v, range_m, irradiance, phase


def curve_geometry(config: DatasetConfig, curve: Curve, pool=None) -> CurveGeometry:
    """Geometry of a curve: its synthetic track, or its rows of the pass pool."""
    n, cadence = config.samples, config.cadence_s
    t = np.arange(n) * cadence
    g = curve.geometry
    if isinstance(config.geometry, SyntheticSource):
        # jaxlc.geometry.synthetic_geometry, step for step, without building a table.
        frac = t / t[-1] if n > 1 else np.zeros(1)
        alpha = np.radians(
            g["phase_start_deg"] + (g["phase_end_deg"] - g["phase_start_deg"]) * frac
        )
        rng = g["range_start_m"] + (g["range_end_m"] - g["range_start_m"]) * frac
        ra, dec = math.radians(g["sun_ra_deg"]), math.radians(g["sun_dec_deg"])
        s = np.array([math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra), math.sin(dec)])
        q = np.array([-math.sin(ra), math.cos(ra), 0.0])
        tilt = math.radians(g["tilt_deg"])
        e = math.cos(tilt) * q + math.sin(tilt) * np.cross(s, q)
        obs = rng[:, None] * (np.cos(alpha)[:, None] * s + np.sin(alpha)[:, None] * e)
        sun = np.broadcast_to(AU_M * s, (n, 3))
        nu = np.ones(n)
        s_dir, v_dir, range_m, irr, phase = _directions(np.zeros((n, 3)), sun, obs, nu)
        visible = np.ones(n, bool)
        airmass = np.full(n, config.noise.airmass if config.noise is not None else 1.0)
        utc = config.geometry.start_utc
    else:
        rows = pool.rows(g["pass_id"], g["offset"], n)
        nu = rows["shadow_nu"]
        s_dir, v_dir, range_m, irr, phase = _directions(
            rows["rso_m"], rows["sun_m"], rows["obs_m"], nu
        )
        with np.errstate(invalid="ignore"):
            visible = rows["visible"] & (nu > 0)
        from jaxlc.noise import airmass_from_elevation

        airmass = airmass_from_elevation(rows["elevation_deg"])
        start = pd.Timestamp(pool.utc_start[g["pass_id"]]) + pd.Timedelta(
            seconds=g["offset"] * pool.cadence_s
        )
        utc = start.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
    return CurveGeometry(t, s_dir, v_dir, range_m, irr, phase, visible, airmass, utc)


# ---------------------------------------------------------------------------
# What every curve of a class shares (per process)


@dataclasses.dataclass(frozen=True)
class ClassKit:
    """Facets (in render order), shadow table and static flags of a shape class.

    Attributes:
        facets: the mesh's facets at the class scale (original order).
        ordered: the same facets in render order (unshadowable first).
        part_names: the mesh's parts.
        shadow: the shadow table (device arrays), or None.
        free: number of leading facets that cannot be shadowed.
        plan_shadowed: whether a render plan would use shadows (for the blur scale).
        flags: the class's static facet-model flags (the union over its priors).
        part: (F,) part index of each facet in render order.
        area: (F,) float32 facet areas (m²) in render order.
        frame: ``normals``, ``tangent_u``, ``tangent_w`` (F, 3) float32 (the
            tangents follow the class's fixed material tangents).
    """

    facets: object
    ordered: object
    part_names: tuple[str, ...]
    shadow: object
    free: int
    plan_shadowed: bool
    flags: dict
    part: np.ndarray
    area: np.ndarray
    frame: dict


_KITS: dict = {}


def class_kit(cls) -> ClassKit:
    """The :class:`ClassKit` of a shape class, built once per process.

    The shadow table comes from jaxlc.shadow's disk cache (traced on a miss).
    """
    from jaxlc.brdf import BRDFS
    from jaxlc.mesh import facets_from_mesh, load_mesh
    from jaxlc.shadow import shadow_data, shadow_table

    key = (str(cls.mesh_path), cls.mesh_scale, repr(cls.render), cls.materials)
    if key in _KITS:
        return _KITS[key]
    import jax.numpy as jnp

    mesh = load_mesh(cls.mesh_path, cls.mesh_scale)
    facets = facets_from_mesh(mesh)
    plan_shadowed = not facets.convex and cls.render.shadows != "off"
    data = shadow_data(mesh, facets, cls.render.shadow) if plan_shadowed else None
    if data is None:
        order, free, table = np.arange(facets.n_facets), 0, None
    else:
        free_ids = np.flatnonzero(~facets.can_shadow)
        order, free = np.concatenate([free_ids, data.facet_ids]), len(free_ids)
        table = shadow_table(data, jnp.float32)
    kinds = [BRDFS[m.brdf] for m in cls.materials]
    flags = {
        "use_lambert": any(k.has_lambert for k in kinds),
        "use_as_diffuse": any(k.has_as_diffuse for k in kinds),
        "use_specular": any(k.has_specular for k in kinds),
        "anisotropic": any(
            m.nv is not None and (m.nv != m.nu or m.nv[0] != m.nv[1]) for m in cls.materials
        ),
    }
    ordered = facets.subset(order)
    # Normals and tangents do not depend on drawn values: one facet model gives them.
    from jaxlc.brdf import facet_model

    model = facet_model(ordered, _probe_materials(cls, ordered.part_names), dtype=jnp.float32)
    frame = {k: np.asarray(getattr(model, k)) for k in ("normals", "tangent_u", "tangent_w")}
    kit = ClassKit(
        facets,
        ordered,
        tuple(facets.part_names),
        table,
        free,
        plan_shadowed,
        flags,
        np.asarray(ordered.part),
        np.asarray(ordered.areas_m2, dtype=np.float32),
        frame,
    )
    _KITS[key] = kit
    return kit


def _brdf(entry: dict):
    """The material of one scene ``[[material]]`` dict (as jaxlc.scene reads it)."""
    from jaxlc.brdf import BRDFS

    kind = BRDFS[entry["brdf"]]
    if entry["brdf"] == "lambert":
        return kind(rd=float(entry["rd"]))
    return kind(
        rd=float(entry["rd"]),
        rs=float(entry["rs"]),
        nu=float(entry["nu"]),
        nv=float(entry["nv"]),
        tangent=tuple(float(x) for x in entry["tangent"]),
    )


def _materials_from(entries, part_names) -> list:
    """One material per part, as :meth:`jaxlc.scene.Scene.materials_for` assigns them."""
    by_part = {e["part"]: _brdf(e) for e in entries}
    return [by_part.get(p, by_part.get("*")) for p in part_names]


def _probe_materials(cls, part_names) -> list:
    """The class's materials at the low end of every range (for its fixed tangent frames)."""
    entries = []
    for m in cls.materials:
        e = {"part": m.part, "brdf": m.brdf, "rd": m.rd[0]}
        if m.brdf != "lambert":
            e.update(rs=m.rs[0], nu=m.nu[0], nv=(m.nv or m.nu)[0], tangent=list(m.tangent))
        entries.append(e)
    return _materials_from(entries, part_names)


def _coefficients(kit: ClassKit, materials) -> dict:
    """Per-facet material coefficients (float32), as :func:`jaxlc.brdf.facet_model` makes them.

    The same float32 steps (per-part values, gathered by part, times the facet
    area) without a JAX dispatch per array: ~100× faster for one curve.
    """
    coef = [m.coefficients() for m in materials]
    out = {}
    for k in ("kl", "kd", "ks", "fa", "fb", "nu", "nv"):
        per_part = np.array([np.asarray(c[k], dtype=np.float32) for c in coef], dtype=np.float32)
        out[k] = per_part[kit.part]
    for k in ("kl", "kd", "ks"):
        out[k] = out[k] * kit.area
    return out


def subsamples_for(
    cls, kit: ClassKit, materials, period_s: float, geo: CurveGeometry, exposure_s: float
) -> int:
    """Sub-exposures of one curve: :func:`jaxlc.plan.make_plan`'s choice for it."""
    from jaxlc.blur import choose_subsamples, direction_rate_rad_s, feature_scale_rad

    opts = cls.render
    if opts.subsamples is not None:
        return int(opts.subsamples)
    if opts.blur == "off":
        return 1
    scale, feature = feature_scale_rad(materials, kit.facets, shadowed=kit.plan_shadowed)
    idx = np.flatnonzero(geo.visible)
    t = geo.t_start_s[idx] + 0.5 * exposure_s
    geo_rate = max(
        direction_rate_rad_s(geo.sun_dir[idx], t), direction_rate_rad_s(geo.obs_dir[idx], t)
    )
    exposure = exposure_s if len(idx) else 0.0
    rate = 2.0 * math.pi / period_s + geo_rate
    return choose_subsamples(exposure, rate, scale, feature, opts.max_subsamples).subsamples


# ---------------------------------------------------------------------------
# The batched kernel


#: Samples per time chunk for shadowed classes: the shadow lookup runs ~15 % faster
#: in chunks of 32 than with the default (128 for S4's 1,205 facets; the same bits,
#: measured on the 2-core reference machine). None: jaxlc.render.time_chunk.
SHADOW_CHUNK = 32


def _one(model, attitude, shadow, times, sun, obs, free, chunk):
    from jaxlc.render import SpaceObject, light_curve_intensity

    obj = SpaceObject(model, attitude, shadow, free)
    return light_curve_intensity(obj, times, sun, obs, chunk=chunk)


@functools.cache
def batch_kernel(sequential: bool):
    """Jitted (B, T) I/E of B renders of one class (static: free-facet count, chunk).

    ``sequential`` loops over the batch inside the call (shadowed classes);
    otherwise the batch is vmapped.
    """
    import jax

    from jaxlc.render import compiler_options

    if sequential:

        def f(models, attitudes, shadow, times, sun, obs, free, chunk):
            return jax.lax.map(
                lambda a: _one(a[0], a[1], shadow, a[2], a[3], a[4], free, chunk),
                (models, attitudes, times, sun, obs),
            )

    else:
        f = jax.vmap(_one, in_axes=(0, 0, None, 0, 0, 0, None, None))
    return jax.jit(f, static_argnums=(6, 7), compiler_options=compiler_options())


def _render_class(config, cls, kit: ClassKit, curves, geos):
    """(C, T) mean I/E over sub-exposures (float64) and (C,) sub-exposure counts."""
    import jax
    import jax.numpy as jnp

    from jaxlc.attitude import Spin, SpinTimes
    from jaxlc.brdf import FacetModel

    t_len, exposure = config.samples, config.exposure_s
    models, attitudes, subs = [], [], []
    for c, g in zip(curves, geos, strict=True):
        mats = _materials_from(c.materials, kit.part_names)
        models.append(_coefficients(kit, mats))
        spin = Spin.from_degrees(
            cls.body_axis,
            c.pole_ra_deg,
            c.pole_dec_deg,
            c.period_s,
            c.phase_deg % 360.0,
            jnp.float32,
        )
        attitudes.append(
            {f.name: np.asarray(getattr(spin, f.name)) for f in dataclasses.fields(spin)}
        )
        subs.append(
            subsamples_for(cls, kit, mats, c.period_s, g, exposure) if g.visible.any() else 0
        )
    model_np = {k: np.stack([m[k] for m in models]) for k in models[0]}
    att_np = {k: np.stack([a[k] for a in attitudes]) for k in attitudes[0]}
    vis = np.stack([g.visible for g in geos])
    sun = np.where(vis[..., None], np.stack([g.sun_dir for g in geos]), _PARKED).astype(np.float32)
    obs = np.where(vis[..., None], np.stack([g.obs_dir for g in geos]), _PARKED).astype(np.float32)
    t_start = np.stack([g.t_start_s for g in geos])
    period = np.array([c.period_s for c in curves])

    jobs = [(j, k) for j, n in enumerate(subs) for k in range(n)]
    sums = np.zeros((len(curves), t_len))
    kernel = batch_kernel(kit.shadow is not None)
    size = config.batch_size
    for b0 in range(0, len(jobs), size):
        batch = jobs[b0 : b0 + size]
        real = len(batch)
        batch = batch + [batch[0]] * (size - real)  # pad: one shape per class
        ci = np.array([j for j, _ in batch])
        frac = np.array([(k + 0.5) / subs[j] for j, k in batch])
        # jaxlc.blur.subexposure_times and Spin.times, element for element (float64).
        t = t_start[ci] + exposure * frac[:, None]
        p = period[ci][:, None]
        turns = np.floor(t / p)
        # Cast on the host (a device-side cast would compile a kernel per shape).
        times = SpinTimes(
            turns=jnp.asarray(turns.astype(np.float32)),
            remainder_s=jnp.asarray((t - turns * p).astype(np.float32)),
            period_ref_s=jnp.asarray(np.broadcast_to(p, t.shape).astype(np.float32)),
        )
        model = FacetModel(
            **{k: jnp.asarray(v[ci]) for k, v in model_np.items()},
            **{k: jnp.asarray(np.broadcast_to(v, (size, *v.shape))) for k, v in kit.frame.items()},
            **kit.flags,
        )
        attitude = Spin(**{k: jnp.asarray(v[ci]) for k, v in att_np.items()})
        out = kernel(
            model,
            attitude,
            kit.shadow,
            times,
            jnp.asarray(sun[ci]),
            jnp.asarray(obs[ci]),
            kit.free,
            None if kit.shadow is None else SHADOW_CHUNK,
        )
        out = np.asarray(jax.device_get(out), dtype=np.float64)
        for r in range(real):  # sub-exposures of a curve in order: a fixed summation order
            sums[ci[r]] += out[r]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = sums / np.asarray(subs, dtype=np.float64)[:, None]
    return mean, np.asarray(subs)


# ---------------------------------------------------------------------------
# One shard


@dataclasses.dataclass(frozen=True)
class Shard:
    """A rendered shard: rows ``start … start + len(labels)`` of every array.

    Attributes:
        index: shard number.
        start: first curve.
        arrays: name → (n, T) arrays in their store dtypes.
        labels: (n rows) the label columns of :data:`jaxlc.datastore.LABELS`.
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
    from jaxlc.noise import add_noise, magnitude_of, scintillation_rel

    rows = config.shard_rows(shard)
    if isinstance(config.geometry, PassSource) and pool is None:
        raise DatasetError("render_shard: real-pass geometry needs the pass pool")
    lengths = pool.length if pool is not None else None
    curves = [draw_curve(config, i, lengths) for i in rows]
    geos = [curve_geometry(config, c, pool) for c in curves]
    n, t_len = len(curves), config.samples
    intensity = np.full((n, t_len), np.nan)
    subs = np.zeros(n, dtype=np.int64)
    shadows = np.zeros(n, dtype=bool)
    for class_id in sorted({c.class_id for c in curves}):
        idx = [j for j, c in enumerate(curves) if c.class_id == class_id]
        cls = config.classes[class_id]
        kit = class_kit(cls)
        mean, s = _render_class(config, cls, kit, [curves[j] for j in idx], [geos[j] for j in idx])
        intensity[idx], subs[idx], shadows[idx] = mean, s, kit.shadow is not None

    vis = np.stack([g.visible for g in geos])
    bad = vis & ~np.isfinite(intensity)
    if bad.any():
        j = int(np.flatnonzero(bad.any(axis=1))[0])
        raise DatasetError(
            f"shard {shard}: curve {curves[j].index} gave a non-finite intensity on "
            f"{int(bad[j].sum())} visible sample(s); please report this with the config"
        )
    factor = np.array([c.scale for c in curves]) ** 2
    flux = np.stack(
        [
            photometry.flux_w_m2(intensity[j] * factor[j], g.irradiance_w_m2, g.range_m)
            for j, g in enumerate(geos)
        ]
    )
    flux[~vis] = np.nan
    mag = photometry.magnitude(flux)
    arrays = {
        "mag": mag.astype(np.float32),
        "flux_w_m2": flux.astype(np.float32),
        "phase_angle_deg": np.stack([g.phase_angle_deg for g in geos]).astype(np.float32),
        "range_m": np.stack([g.range_m for g in geos]).astype(np.float32),
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
    return Shard(shard, rows.start, arrays, _labels(config, curves, geos, subs, shadows, pool))


def _labels(config, curves, geos, subs, shadows, pool) -> pd.DataFrame:
    out = []
    for c, g, s, sh in zip(curves, geos, subs, shadows, strict=True):
        cls = config.classes[c.class_id]
        v = g.visible
        any_v = bool(v.any())
        row = {
            "class": cls.name,
            "class_id": c.class_id,
            "mesh": str(cls.mesh_path),
            "scale": cls.mesh_scale * c.scale,
            "materials": json.dumps(list(c.materials)),
            "body_axis_x": cls.body_axis[0],
            "body_axis_y": cls.body_axis[1],
            "body_axis_z": cls.body_axis[2],
            "pole_ra_deg": c.pole_ra_deg,
            "pole_dec_deg": c.pole_dec_deg,
            "period_s": c.period_s,
            "phase_deg": c.phase_deg,
            "subsamples": int(s),
            "shadows": bool(sh),
            "utc_start": g.utc_start,
            "visible_samples": int(v.sum()),
            "phase_mean_deg": float(g.phase_angle_deg[v].mean()) if any_v else np.nan,
            "phase_min_deg": float(g.phase_angle_deg[v].min()) if any_v else np.nan,
            "phase_max_deg": float(g.phase_angle_deg[v].max()) if any_v else np.nan,
            "range_mean_m": float(g.range_m[v].mean()) if any_v else np.nan,
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
    from jaxlc.datastore import LABELS

    df = pd.DataFrame(out)
    for name, (dtype, fill, _) in LABELS.items():
        if name not in df:
            df[name] = fill
        if dtype != "str":
            df[name] = df[name].astype(dtype)
    return df[list(LABELS)]


_POOLS: dict = {}
#: Set in local workers' environment: where their JAX compilation cache lives.
_CACHE_ENV = "JAXLC_WORKER_XLA_CACHE"


def _use_compilation_cache() -> None:
    """In a local worker: turn on JAX's persistent compilation cache (once).

    Done here rather than by JAX's own environment variable because the
    worker may have imported JAX before its environment was set.
    """
    path = os.environ.get(_CACHE_ENV)
    if not path:
        return
    import jax

    if jax.config.jax_compilation_cache_dir is None:
        jax.config.update("jax_compilation_cache_dir", path)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)


def run_shard(config: DatasetConfig, shard: int, store: str) -> tuple[int, int]:
    """Render shard ``shard`` and write it into ``store`` (the unit of work on a worker).

    Returns:
        (shard, number of curves).
    """
    from jaxlc.datastore import read_pool, write_shard

    _use_compilation_cache()
    pool = None
    if isinstance(config.geometry, PassSource):
        if store not in _POOLS:
            _POOLS[store] = read_pool(store)
        pool = _POOLS[store]
    data = render_shard(config, shard, pool)
    write_shard(store, shard, data.start, data.arrays, data.labels)
    return shard, len(data.labels)


# ---------------------------------------------------------------------------
# Running a dataset


def _progress_bar(enabled: bool):
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        ProgressColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )
    from rich.text import Text

    class Rate(ProgressColumn):
        def render(self, task):
            speed = task.finished_speed or task.speed
            unit = task.fields.get("unit", "curves")
            return Text("–" if speed is None else f"{speed:,.1f} {unit}/s")

    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        Rate(),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
        console=Console(stderr=True),
        disable=not enabled,
        transient=False,
    )


def _worker_env(n_workers: int) -> dict:
    """Environment of local worker processes.

    * One XLA thread each when the workers fill the cores: XLA's CPU thread
      pool would otherwise make every worker use every core, and the workers
      slow each other down.
    * JAX's persistent compilation cache (unless ``JAX_COMPILATION_CACHE_DIR``
      is set already): every worker, and every later run, loads the class
      kernels instead of compiling them (~5 s per worker process saved).
    """
    from jaxlc.shadow import cache_dir

    env = {}
    if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
        env[_CACHE_ENV] = str(cache_dir() / "xla")
    if n_workers >= (os.cpu_count() or 1):
        flags = os.environ.get("XLA_FLAGS", "")
        if "xla_cpu_multi_thread_eigen" not in flags:
            flags = (flags + " --xla_cpu_multi_thread_eigen=false").strip()
        env.update(XLA_FLAGS=flags, OMP_NUM_THREADS="1")
    return env


def generate(
    config: DatasetConfig | str | Path,
    out_path: str | Path,
    workers: int | None = None,
    scheduler: str | None = None,
    count: int | None = None,
    seed: int | None = None,
    progress: bool = True,
    on_shard=None,
):
    """Render a dataset into a Zarr store, or finish one a killed run left behind.

    Args:
        config: a :class:`~jaxlc.dataset.DatasetConfig` or the path of its TOML file.
        out_path: the store (a ``.zarr`` folder). If it exists it must come from
            the same config (and count, seed, meshes): its missing shards are rendered.
        workers: None: a local Dask cluster with one worker process per core;
            N > 0: N worker processes; 0: render in this process (no Dask).
        scheduler: address of a running Dask scheduler (e.g. ``tcp://host:8786``)
            instead of a local cluster; the workers must see ``out_path``.
        count, seed: override the config's ``count`` and ``seed``.
        progress: show a progress bar (rate and ETA) on stderr.
        on_shard: optional callable(shard) after each shard is written (in
            completion order); an exception from it stops the run (the shards
            written so far stay done).

    Returns:
        The finished :class:`~jaxlc.datastore.Dataset`.

    The arrays do not depend on ``workers`` or on the order shards finish in:
    same config, count and seed give the same bytes (on the same platform).
    """
    from jaxlc.datastore import check_store, create_store, done_shards, open_dataset

    if not isinstance(config, DatasetConfig):
        config = load_config(config)
    if count is not None:
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            raise DatasetError(f"count = {count!r} must be a whole number ≥ 1")
        config = dataclasses.replace(config, count=count)
    if seed is not None:
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise DatasetError(f"seed = {seed!r} must be a whole number ≥ 0")
        config = dataclasses.replace(config, seed=seed)
    if config.noise is not None and config.exposure_s <= 0:
        raise DatasetError(f"{config.source}: a [noise] model needs exposure_s > 0")
    if workers is not None and scheduler is not None:
        raise DatasetError("give either workers or a scheduler address, not both")
    if workers is not None and (isinstance(workers, bool) or workers < 0):
        raise DatasetError(f"workers = {workers!r} must be ≥ 0 (0: in this process)")
    if workers != 0:
        _require_dask()

    out = Path(out_path).resolve()
    bar = _progress_bar(progress)
    with bar:
        if out.exists():
            check_store(out, config)
        else:
            pool = None
            if isinstance(config.geometry, PassSource):
                pool = _build_pool(config, bar)
            _warm_shadow_tables(config, bar)
            create_store(out, config, pool)
            check_store(out, config)
        done = done_shards(out)
        todo = [k for k in range(config.n_shards) if not done[k]]
        done_curves = sum(len(config.shard_rows(k)) for k in np.flatnonzero(done))
        task = bar.add_task(f"{out.name}", total=config.count, completed=done_curves)

        def finished(k, n):
            bar.update(task, advance=n)
            if on_shard is not None:
                on_shard(k)

        if todo and workers == 0:
            for k in todo:
                finished(*run_shard(config, k, str(out)))
        elif todo:
            _run_dask(config, out, todo, workers, scheduler, finished)
    return open_dataset(out)


def _require_dask():
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise DatasetError(
            "running shards on workers needs dask and distributed: pip install 'jaxlc[dask]' "
            "(or use workers = 0 / --workers 0 to render in this process)"
        ) from None


def _build_pool(config, bar):
    from jaxlc.geometry.pool import build_pool

    g = config.geometry
    task = bar.add_task("pass pool", total=None, unit="passes")
    pool = build_pool(
        g.tle_paths,
        g.sites,
        g.start_utc,
        g.days,
        config.samples,
        config.cadence_s,
        config.exposure_s,
        norad=g.norad,
        search_step_s=g.search_step_s,
        rules=g.rules,
        min_pass_s=g.min_pass_s,
        max_passes=g.max_passes,
        progress=lambda d, n: bar.update(task, completed=d, total=n),
    )
    bar.update(task, description=f"pass pool: {len(pool)} passes")
    return pool


def _warm_shadow_tables(config, bar):
    """Trace missing shadow tables once here, so workers load them from the disk cache."""
    from jaxlc.mesh import facets_from_mesh, load_mesh
    from jaxlc.shadow import shadow_data

    for cls in config.classes:
        if cls.render.shadows == "off":
            continue
        mesh = load_mesh(cls.mesh_path, cls.mesh_scale)
        facets = facets_from_mesh(mesh)
        if facets.convex:
            continue
        task = bar.add_task(f"shadow table {cls.mesh_path.name}", total=None, unit="directions")
        shadow_data(
            mesh,
            facets,
            cls.render.shadow,
            progress=lambda d, n, t=task: bar.update(t, completed=d, total=n),
        )
        bar.remove_task(task)


def _run_dask(config, out: Path, todo, workers, scheduler, finished):
    import logging

    from distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="20s")
        except OSError as exc:
            raise DatasetError(f"cannot reach the Dask scheduler {scheduler!r}: {exc}") from None
    else:
        n = workers or min(os.cpu_count() or 1, len(todo))
        cluster = LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",  # any free port (8787 may be taken)
            silence_logs=logging.ERROR,
            env=_worker_env(n),
        )
        client = Client(cluster)
    futures = []
    try:
        tag = config.fingerprint()[:8]
        futures = [
            client.submit(run_shard, config, k, str(out), key=f"jaxlc-shard-{tag}-{k}", pure=False)
            for k in todo
        ]
        for fut in as_completed(futures):
            finished(*fut.result())
    finally:
        for fut in futures:
            fut.cancel()
        client.close()
        if cluster is not None:
            cluster.close()

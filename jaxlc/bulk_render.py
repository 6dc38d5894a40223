"""Batched rendering of many curves of one shape class (the inside of a dataset shard).

Within a class every curve shares the mesh, the facet order and — for a
non-convex mesh — one shadow table (:class:`ClassKit`, built once per
process), so a batch is the class's facet model stacked along a leading axis:

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

Every step repeats what :func:`jaxlc.render.render` does for one curve
(geometry, sub-exposure times, spin phase, material coefficients), so a
curve re-rendered from its labels agrees to float32 rounding
(``tests/test_dataset.py``).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from jaxlc.attitude import Spin, SpinTimes
from jaxlc.blur import choose_subsamples, direction_rate_rad_s, feature_scale_rad
from jaxlc.brdf import BRDFS, FacetModel, facet_model
from jaxlc.dataset import Curve, DatasetConfig, SyntheticSource
from jaxlc.mesh import facets_from_mesh, load_mesh
from jaxlc.noise import airmass_from_elevation
from jaxlc.photometry import AU_M
from jaxlc.render import (
    SpaceObject,
    compiler_options,
    light_curve_intensity,
    observation_directions,
)
from jaxlc.shadow import shadow_data, shadow_table

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
        s_dir, v_dir, range_m, irr, phase = observation_directions(np.zeros((n, 3)), sun, obs, nu)
        visible = np.ones(n, bool)
        airmass = np.full(n, config.noise.airmass if config.noise is not None else 1.0)
        utc = config.geometry.start_utc
    else:
        rows = pool.rows(g["pass_id"], g["offset"], n)
        nu = rows["shadow_nu"]
        s_dir, v_dir, range_m, irr, phase = observation_directions(
            rows["rso_m"], rows["sun_m"], rows["obs_m"], nu
        )
        with np.errstate(invalid="ignore"):
            visible = rows["visible"] & (nu > 0)
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
    key = (str(cls.mesh_path), cls.mesh_scale, repr(cls.render), cls.materials)
    if key in _KITS:
        return _KITS[key]
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
    obj = SpaceObject(model, attitude, shadow, free)
    return light_curve_intensity(obj, times, sun, obs, chunk=chunk)


@functools.cache
def batch_kernel(sequential: bool):
    """Jitted (B, T) I/E of B renders of one class (static: free-facet count, chunk).

    ``sequential`` loops over the batch inside the call (shadowed classes);
    otherwise the batch is vmapped.
    """
    if sequential:

        def f(models, attitudes, shadow, times, sun, obs, free, chunk):
            return jax.lax.map(
                lambda a: _one(a[0], a[1], shadow, a[2], a[3], a[4], free, chunk),
                (models, attitudes, times, sun, obs),
            )

    else:
        f = jax.vmap(_one, in_axes=(0, 0, None, 0, 0, 0, None, None))
    return jax.jit(f, static_argnums=(6, 7), compiler_options=compiler_options())


def render_class(config, cls, kit: ClassKit, curves, geos):
    """Render C curves of one class: (C, T) mean I/E over sub-exposures and (C,) counts.

    Args:
        config: the dataset config (samples, exposure, batch size).
        cls: the curves' shape class; ``kit``: its :func:`class_kit`.
        curves: the drawn curves; ``geos``: their :func:`curve_geometry`.

    Returns:
        ``(intensity_m2_sr, subsamples)``: (C, T) float64 I/E at the class's
        own scale (NaN-free on visible rows; meaningless elsewhere) and (C,)
        sub-exposures per exposure (0 for a curve with no visible row).
    """
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

"""Render light curves: scene + geometry table → light-curve table.

Two layers:

* :func:`light_curve_intensity` — pure, jittable, differentiable and
  ``vmap``-able over objects: a :class:`SpaceObject` (facets + materials +
  attitude) and per-sample times and inertial unit vectors give I/E per sample.
  The time axis is processed in chunks so the (chunk × facets) temporaries stay
  in cache; everything per facet-sample is one fused XLA loop.
* :func:`render` — the host front door: validates the table, converts
  positions to directions, ranges and irradiance in float64, renders only the
  visible rows (padded to a few bucket sizes to limit recompilation), and
  returns the light-curve table with NaN on invisible rows.

The attitude is evaluated at the middle of each exposure (``t_s +
exposure_s/2``); positions are those of the table row.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
from jaxtyping import Array, Float, PyTree

from jaxlc import photometry
from jaxlc.attitude import AbstractAttitude
from jaxlc.blur import subexposure_times
from jaxlc.brdf import FacetModel, facet_intensity, facet_model
from jaxlc.errors import JaxlcError
from jaxlc.mesh import Facets, load_mesh
from jaxlc.plan import RenderOptions, RenderPlan, make_plan
from jaxlc.scene import Scene, load_scene
from jaxlc.shadow import ShadowSettings, ShadowTable, lit_seen_fraction, shadow_data, shadow_table
from jaxlc.tables import read_geometry, validate_geometry

PRECISIONS = {"float32": jnp.float32, "float64": jnp.float64}
#: Target size of one (time chunk × facets) block, in elements (~1 MB of float32).
CHUNK_ELEMENTS = 1 << 18


class SpaceObject(eqx.Module):
    """Everything about the object that the renderer traces.

    Attributes:
        model: all facets. With shadows, those that cannot be shadowed come
            first and the ``shadow`` table's facets follow, in its order.
        attitude: body → inertial rotation over time.
        shadow: visibility table of the facets that can be shadowed
            (:mod:`jaxlc.shadow`), or None (no shadow work).
        free: number of leading facets that cannot be shadowed (static).
    """

    model: FacetModel
    attitude: AbstractAttitude
    shadow: ShadowTable | None = None
    free: int = eqx.field(static=True, default=0)

    @property
    def n_facets(self) -> int:
        return self.model.n_facets


def time_chunk(n_facets: int) -> int:
    """Samples per chunk so that a chunk × facets block is about CHUNK_ELEMENTS."""
    c = CHUNK_ELEMENTS // max(n_facets, 1)
    return int(min(1024, max(8, 1 << max(3, c.bit_length() - 1))))


def body_intensity(
    obj: SpaceObject, sun_b: Float[Array, "T 3"], obs_b: Float[Array, "T 3"]
) -> Float[Array, " T"]:
    """I/E (m² sr⁻¹) for body-frame Sun and observer directions (no attitude).

    Facets that can be shadowed are weighted by their lit-and-seen fraction.
    """
    if obj.shadow is None:
        return facet_intensity(obj.model, sun_b, obs_b)
    return _weighted_intensity(obj, sun_b, obs_b, lit_seen_fraction(obj.shadow, sun_b, obs_b))


def _weighted_intensity(obj: SpaceObject, sun_b, obs_b, frac):
    """The facet sum with the shadowable facets weighted by ``frac`` (T, F_s)."""
    n_t, n_pad = frac.shape[0], obj.model.n_facets - obj.free - frac.shape[1]
    # Weight exactly 1 for facets that cannot be shadowed (and for padding).
    ones = lambda n: jnp.ones((n_t, n), frac.dtype)  # noqa: E731
    weights = jnp.concatenate([ones(obj.free), frac, ones(n_pad)], axis=1)
    return facet_intensity(obj.model, sun_b, obs_b, weights=weights)


def light_curve_intensity(
    obj: SpaceObject,
    times: PyTree,
    sun_dir: Float[Array, "T 3"],
    obs_dir: Float[Array, "T 3"],
    chunk: int | None = None,
) -> Float[Array, " T"]:
    """I/E (m² sr⁻¹) of one object at T samples.

    Args:
        obj: facets, materials and attitude.
        times: (T,) seconds from the attitude's time origin, or better
            ``obj.attitude.times(t_s)`` made on the host from float64 seconds
            (keeps fast spins precise in float32).
        sun_dir: (T, 3) unit vectors object→Sun, inertial frame.
        obs_dir: (T, 3) unit vectors object→observer, inertial frame.
        chunk: samples per chunk (static); default from the facet count.

    Returns:
        (T,) radiant intensity per unit irradiance. Flux = I/E · E / d².

    Example:
        >>> batched = jax.vmap(light_curve_intensity, in_axes=(0, 0, None, None))
    """
    n_t = sun_dir.shape[0]
    chunk = chunk or time_chunk(obj.n_facets)
    chunk = min(chunk, max(n_t, 1))
    n_chunks = -(-n_t // chunk)
    pad = n_chunks * chunk - n_t

    def blocks(x):
        # Zero directions light no facet; padded samples are cut off below.
        x = jnp.pad(x, ((0, pad),) + ((0, 0),) * (x.ndim - 1)) if pad else x
        return x.reshape(n_chunks, chunk, *x.shape[1:])

    def to_body(args):
        t, s, v = args
        r = obj.attitude.rotation(t)  # (chunk, 3, 3) body → inertial
        return jnp.einsum("tji,tj->ti", r, s), jnp.einsum("tji,tj->ti", r, v)

    args = jax.tree_util.tree_map(blocks, (times, sun_dir, obs_dir))
    if obj.shadow is None:
        out = jax.lax.map(lambda a: facet_intensity(obj.model, *to_body(a)), args)
        return out.reshape(-1)[:n_t]

    # Two passes: in one loop XLA fuses the bit counting into the facet sum,
    # which then runs 2-3× slower (measured); the fractions are small to keep.
    def lit_seen(a):
        s_b, v_b = to_body(a)
        return s_b, v_b, lit_seen_fraction(obj.shadow, s_b, v_b)

    per_chunk = jax.lax.map(lit_seen, args)
    out = jax.lax.map(lambda a: _weighted_intensity(obj, *a), per_chunk)
    return out.reshape(-1)[:n_t]


#: XLA:CPU hands row reductions to YNNPACK, which splits the facet sum into
#: several (samples × facets) arrays in memory; with that off it is one fused,
#: vectorised loop (about 1.4× faster on the 2-core reference machine, see
#: experiments/bench_render.py). Only ever applied on the CPU backend.
CPU_COMPILER_OPTIONS = {"xla_cpu_experimental_ynn_fusion_type": ""}


@functools.cache
def compiler_options() -> dict | None:
    """Per-compilation XLA options for the facet kernels on this backend (or None).

    Use them when jitting your own functions around :func:`light_curve_intensity`:
    ``jax.jit(f, compiler_options=jaxlc.render.compiler_options())``.
    """
    if jax.default_backend() != "cpu":
        return None
    try:  # an XLA that no longer knows the option: plain compilation
        jax.jit(lambda x: x + 1, compiler_options=CPU_COMPILER_OPTIONS)(1.0)
    except Exception:
        return None
    return dict(CPU_COMPILER_OPTIONS)


def filter_jit(fn):
    """``eqx.filter_jit`` with :func:`compiler_options` (fixed on the first call).

    For functions of pytrees that hold a facet model (fit models, log-posteriors):
    on the CPU the facet sum and its derivatives run 1.4-2.4× faster compiled this
    way (measured on S4 in the spin fit).
    """
    jitted = None

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        nonlocal jitted
        if jitted is None:
            jitted = eqx.filter_jit(fn, compiler_options=compiler_options())
        return jitted(*args, **kwargs)

    return wrapper


@functools.cache
def _intensity_jit():
    return jax.jit(
        light_curve_intensity, static_argnames=("chunk",), compiler_options=compiler_options()
    )


def stack_objects(objects: list[SpaceObject]) -> SpaceObject:
    """Stack objects along a new leading axis for ``jax.vmap``, padding facets.

    Objects with fewer facets get zero-coefficient facets (which contribute
    nothing). All attitudes must be of the same type; objects with shadows must
    share one mesh (and so one shadow-table layout).
    """
    if not objects:
        raise JaxlcError("stack_objects: no objects given")
    kinds = {type(o.attitude) for o in objects}
    if len(kinds) > 1:
        raise JaxlcError(
            f"stack_objects: attitudes must share one type, got {sorted(k.__name__ for k in kinds)}"
        )
    shadowed = {o.shadow is not None for o in objects}
    if len(shadowed) > 1:
        raise JaxlcError(
            "stack_objects: mix of objects with and without shadows; render them apart"
        )
    if True in shadowed:
        layouts = {(o.shadow.bits.shape, o.shadow.groups, o.free) for o in objects}
        if len(layouts) > 1:
            raise JaxlcError(
                "stack_objects: shadowed objects must share one mesh (one table layout)"
            )
    models = _pad_models([o.model for o in objects])
    padded = [
        SpaceObject(m, o.attitude, o.shadow, o.free) for m, o in zip(models, objects, strict=True)
    ]
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *padded)


def _pad_models(models: list[FacetModel]) -> list[FacetModel]:
    """Models padded with inert facets to one facet count and one set of flags."""
    n_max = max(m.n_facets for m in models)
    flags = {
        f: any(getattr(m, f) for m in models)
        for f in ("use_lambert", "use_as_diffuse", "use_specular", "anisotropic")
    }
    out = []
    for m in models:
        extra = n_max - m.n_facets
        arrays = {}
        for field in dataclasses.fields(m):
            if field.metadata.get("static"):
                continue
            x = getattr(m, field.name)
            if extra:
                if x.ndim == 2:
                    fill = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 1.0], x.dtype), (extra, 3))
                else:
                    fill = jnp.full((extra,), 1.0 if field.name in ("nu", "nv") else 0.0, x.dtype)
                x = jnp.concatenate([x, fill])
            arrays[field.name] = x
        out.append(FacetModel(**arrays, **flags))
    return out


# ---------------------------------------------------------------------------
# Host side


@dataclasses.dataclass(frozen=True)
class GeometryArrays:
    """Per-row float64 quantities derived from a geometry table.

    Attributes:
        t_start_s: (T,) exposure start times, seconds from the first row.
        t_eval_s: (T,) mid-exposure times (where one sub-exposure samples).
        sun_dir, obs_dir: (T, 3) unit vectors object→Sun, object→observer.
        range_m: (T,) object-observer distance.
        irradiance_w_m2: (T,) solar irradiance at the object (1/r² and shadow ν).
        phase_angle_deg: (T,) Sun-object-observer angle.
        exposure_s: (T,) exposure times (the scene's where the table has none).
        visible: (T,) rows to render.
        origin_utc: UTC time of the first row (the attitude's time origin).
    """

    t_start_s: np.ndarray
    t_eval_s: np.ndarray
    sun_dir: np.ndarray
    obs_dir: np.ndarray
    range_m: np.ndarray
    irradiance_w_m2: np.ndarray
    phase_angle_deg: np.ndarray
    exposure_s: np.ndarray
    visible: np.ndarray
    origin_utc: pd.Timestamp | None


def observation_directions(rso_m, sun_m, obs_m, shadow_nu):
    """Unit vectors object→Sun and object→observer (T, 3), range (T,) in m,
    solar irradiance (T,) in W/m² and phase angle (T,) in degrees, from
    float64 positions (T, 3) in m and the shadow function ν (T,)."""
    to_sun = sun_m - rso_m
    to_obs = obs_m - rso_m
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


def geometry_arrays(table: pd.DataFrame, default_exposure_s: float = 1.0) -> GeometryArrays:
    """Directions, ranges, irradiance and phase angles of a validated geometry table."""
    pos = {
        b: table[[f"{b}_{c}_m" for c in "xyz"]].to_numpy(np.float64) for b in ("rso", "sun", "obs")
    }
    s, v, range_m, irradiance, phase = observation_directions(
        pos["rso"], pos["sun"], pos["obs"], table["shadow_nu"].to_numpy()
    )
    exposure = table["exposure_s"].to_numpy(np.float64).copy()
    exposure[np.isnan(exposure)] = default_exposure_s
    t = table["t_s"].to_numpy(np.float64)
    t_rel = t - t[0] if len(t) else t
    origin = pd.Timestamp(table["utc"].iloc[0]) if len(table) else None
    visible = table["visible"].to_numpy(bool) & (table["shadow_nu"].to_numpy() > 0)
    return GeometryArrays(
        t_start_s=t_rel,
        t_eval_s=t_rel + 0.5 * exposure,
        sun_dir=s,
        obs_dir=v,
        range_m=range_m,
        irradiance_w_m2=irradiance,
        phase_angle_deg=phase,
        exposure_s=exposure,
        visible=visible,
        origin_utc=origin,
    )


def bucket_size(n: int) -> int:
    """Pad n samples up to one of a few sizes per octave (≤ 12.5 % waste)."""
    if n <= 64:
        return 64
    step = 1 << (n.bit_length() - 4)
    return -(-n // step) * step


def space_object(
    scene: Scene,
    origin_utc: pd.Timestamp | None,
    dtype=jnp.float32,
    shadow: ShadowSettings | None = None,
    progress=None,
    facets: Facets | None = None,
) -> SpaceObject:
    """The traced object of a scene, its attitude referred to ``origin_utc``.

    Args:
        scene: the scene.
        origin_utc: time origin of the attitude (the geometry table's first row).
        dtype: float32 or float64.
        shadow: shadow resolution, or None for no self-shadowing. A convex mesh
            never gets shadow data.
        progress: optional callable(done, total) while a shadow table is traced.
        facets: facets to use instead of the scene's (e.g. a coarsened set
            whose ``triangle_facet`` maps the mesh's triangles onto them).
    """
    facets = scene.facets if facets is None else facets
    materials = scene.materials_for(facets.part_names)
    attitude = scene.attitude.build(origin_utc, dtype)
    data = None
    if shadow is not None and not facets.convex:
        data = shadow_data(
            load_mesh(scene.mesh_path, scene.scale), facets, shadow, progress=progress
        )
    if data is None:
        return SpaceObject(model=facet_model(facets, materials, dtype=dtype), attitude=attitude)
    free = np.flatnonzero(~facets.can_shadow)
    order = np.concatenate([free, data.facet_ids])
    return SpaceObject(
        model=facet_model(facets.subset(order), materials, dtype=dtype),
        attitude=attitude,
        shadow=shadow_table(data, dtype),
        free=len(free),
    )


def render(
    scene: Scene | str | Path,
    geometry: pd.DataFrame | str | Path,
    precision: str = "float32",
    options: RenderOptions | None = None,
    progress=None,
) -> pd.DataFrame:
    """Render a light curve.

    Args:
        scene: a :class:`~jaxlc.scene.Scene` or the path of a scene file.
        geometry: a geometry table (DataFrame) or its path (CSV/Parquet).
        precision: ``"float32"`` (default, fast) or ``"float64"``.
        options: shadows and motion blur (default: the scene's ``[render]`` table).
        progress: optional callable(done, total) while a shadow table is traced.

    Returns:
        Light-curve table: ``utc, t_s, mag, flux_w_m2, phase_angle_deg,
        range_m, exposure_s, visible``; invisible rows have NaN ``mag`` and
        ``flux_w_m2``; a visible row where no lit facet is seen has zero flux
        and ``mag = inf``. ``attrs["plan"]`` says what was done
        (:meth:`~jaxlc.plan.RenderPlan.explain`).

    Example:
        >>> lc = jaxlc.render("experiments/scenes/s4_falcon9.toml", "geometry.csv")
        >>> lc[["t_s", "mag"]].head()
    """
    if precision not in PRECISIONS:
        raise JaxlcError(f"precision = {precision!r} must be 'float32' or 'float64'")
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    table = (
        read_geometry(geometry)
        if not isinstance(geometry, pd.DataFrame)
        else validate_geometry(geometry)
    )
    geo = geometry_arrays(table, scene.exposure_s)
    plan = make_plan(scene, geo, options or scene.render)

    intensity = np.full(len(table), np.nan)
    idx = np.flatnonzero(geo.visible)
    if len(idx):
        intensity[idx] = _render_rows(scene, geo, idx, precision, plan, progress)

    out = lightcurve_table(table, geo, intensity)
    out.attrs.update(
        {
            "frame": table.attrs.get("frame", "unknown"),
            "scene": scene.source,
            "precision": precision,
            "generator": f"jaxlc {_version()}",
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


def _render_rows(
    scene: Scene, geo: GeometryArrays, idx: np.ndarray, precision: str, plan: RenderPlan, progress
) -> np.ndarray:
    """Mean I/E over each visible row's sub-exposures (padded to a bucket size)."""
    dtype = PRECISIONS[precision]
    n = len(idx)
    take = np.concatenate([idx, np.full(bucket_size(n) - n, idx[-1])])
    sub = plan.subsamples
    t = subexposure_times(geo.t_start_s[take], geo.exposure_s[take], sub)
    with jax.enable_x64(precision == "float64"):
        obj = space_object(scene, geo.origin_utc, dtype, plan.shadow, progress)
        times = obj.attitude.times(t, **scene.attitude.exact_parameters())
        s = jnp.asarray(np.repeat(geo.sun_dir[take], sub, axis=0), dtype=dtype)
        v = jnp.asarray(np.repeat(geo.obs_dir[take], sub, axis=0), dtype=dtype)
        flat = np.asarray(_intensity_jit()(obj, times, s, v), dtype=np.float64)
    result = flat.reshape(-1, sub).mean(axis=1)[:n]
    if not np.all(np.isfinite(result)):
        bad = int(np.count_nonzero(~np.isfinite(result)))
        raise JaxlcError(
            f"render: {bad} visible sample(s) gave a non-finite intensity for scene "
            f"{scene.source}; please report this with the scene and geometry files"
        )
    return result


def _version() -> str:
    from jaxlc import __version__

    return __version__


def magnitudes(
    obj: SpaceObject,
    times: PyTree,
    sun_dir: Float[Array, "T 3"],
    obs_dir: Float[Array, "T 3"],
    irradiance_w_m2: Float[Array, " T"],
    range_m: Float[Array, " T"],
) -> Float[Array, " T"]:
    """Differentiable magnitudes (for fits): :func:`light_curve_intensity` → mag."""
    i = light_curve_intensity(obj, times, sun_dir, obs_dir)
    return photometry.magnitude_jax(i, irradiance_w_m2, range_m)


__all__ = [
    "GeometryArrays",
    "SpaceObject",
    "body_intensity",
    "bucket_size",
    "geometry_arrays",
    "light_curve_intensity",
    "magnitudes",
    "render",
    "space_object",
    "stack_objects",
    "time_chunk",
]

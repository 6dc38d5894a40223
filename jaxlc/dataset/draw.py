"""One curve of a dataset: its draws, its scene and its geometry.

Every curve is a pure function of (config, seed, curve index): curve i draws
its shape class, size, materials, spin and geometry from
``numpy.random.SeedSequence(seed, spawn_key=(i,))`` (the i-th child of
``SeedSequence(seed).spawn``). Its scene (:func:`curve_scene`, a scene-file
dict) and geometry (:func:`curve_geometry`) are what it is rendered from, by
the same preparation as :func:`jaxlc.render`; the store keeps them as labels
so that :meth:`jaxlc.dataset.store.Dataset.scene` and ``.geometry`` give them back.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pandas as pd

from jaxlc.dataset.config import DatasetConfig, DatasetError, SyntheticSource
from jaxlc.dataset.noise import airmass_from_elevation
from jaxlc.geometry.synthetic import synthetic_positions
from jaxlc.io.utc import format_utc_time, utc_timestamp
from jaxlc.rendering.observation import GeometryArrays, geometry_from_positions


@dataclasses.dataclass(frozen=True)
class Curve:
    """The drawn parameters of one light curve.

    Attributes:
        index: curve number in the dataset.
        class_id: index into ``config.classes``.
        scale: size factor drawn from the class (× the class's ``mesh_scale``).
        period_s, pole_ra_deg, pole_dec_deg, phase_deg: the spin; the phase is
            at the curve's first sample (t_s = 0).
        materials: one scene ``[[material]]`` dict per class material entry.
        geometry: synthetic: the :func:`jaxlc.synthetic_geometry` keyword
            arguments; passes: ``{"pass_id": p, "offset": k}`` (rows of the pool).
        tumble: a tumbling class's draws (:func:`draw_tumble`), None for a spin;
            then ``period_s`` is the precession period, the pole L's direction and
            the phase the rotation about L at the first sample.
    """

    index: int
    class_id: int
    scale: float
    period_s: float
    pole_ra_deg: float
    pole_dec_deg: float
    phase_deg: float
    materials: tuple[dict, ...]
    geometry: dict
    tumble: dict | None = None


def _uniform(rng, r):
    u = rng.random()
    return r[0] if r[0] == r[1] else r[0] + (r[1] - r[0]) * u


def _log_uniform(rng, r):
    u = rng.random()
    if r[0] == r[1]:
        return r[0]
    if r[0] <= 0.0:
        return r[0] + (r[1] - r[0]) * u
    return math.exp(math.log(r[0]) + (math.log(r[1]) - math.log(r[0])) * u)


def curve_rng(seed: int, index: int, stream: int = 0) -> np.random.Generator:
    """The random stream of curve ``index``: 0 for its parameters, 1 for its noise.

    Stream 0 is ``SeedSequence(seed).spawn(index + 1)[index]``; stream 1 is
    that sequence's first child.
    """
    key = (index,) if stream == 0 else (index, stream - 1)
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


def draw_curve(config: DatasetConfig, index: int, pass_lengths: np.ndarray | None = None) -> Curve:
    """Draw curve ``index`` (a pure function of the config, its seed and ``index``).

    Args:
        config: the dataset config.
        index: curve number, 0 … count − 1.
        pass_lengths: (P,) samples per pass of the pool (real passes only).

    Order of the draws (fixed; a fixed value still takes its draw, so changing
    a range never shifts the others): class, scale, period, pole (z, RA),
    phase, materials (rd, rs, nu, nv per entry), geometry, and for a tumbling
    class :func:`draw_tumble`'s.
    """
    rng = curve_rng(config.seed, index)
    weights = np.array([c.weight for c in config.classes])
    cum = np.cumsum(weights) / weights.sum()
    class_id = min(int(np.searchsorted(cum, rng.random(), side="right")), len(cum) - 1)
    cls = config.classes[class_id]
    scale = _uniform(rng, cls.scale)
    period = _log_uniform(rng, cls.period_s)
    z = 2.0 * rng.random() - 1.0
    ra = 360.0 * rng.random()
    phase = 360.0 * rng.random()
    materials = [
        _material(m, lambda r, log: _log_uniform(rng, r) if log else _uniform(rng, r))
        for m in cls.materials
    ]
    g = config.geometry
    if isinstance(g, SyntheticSource):
        start_m = _log_uniform(rng, g.range_start_m)
        end_m = _log_uniform(rng, g.range_end_m if g.range_end_m is not None else g.range_start_m)
        geometry = dict(
            phase_start_deg=_uniform(rng, g.phase_start_deg),
            phase_end_deg=_uniform(rng, g.phase_end_deg),
            range_start_m=start_m,
            range_end_m=end_m if g.range_end_m is not None else start_m,
            sun_ra_deg=360.0 * rng.random(),
            sun_dec_deg=_uniform(rng, g.sun_dec_deg),
            tilt_deg=_uniform(rng, g.tilt_deg),
        )
    else:
        if pass_lengths is None or len(pass_lengths) == 0:
            raise DatasetError("draw_curve: real-pass geometry needs the pool's pass lengths")
        p = int(rng.integers(len(pass_lengths)))
        spare = max(0, int(pass_lengths[p]) - config.samples)
        geometry = dict(pass_id=p, offset=int(rng.integers(spare + 1)))
    tumble = None if cls.tumble is None else draw_tumble(cls.tumble, rng)
    return Curve(
        index=index,
        class_id=class_id,
        scale=scale,
        period_s=period,
        pole_ra_deg=ra,
        pole_dec_deg=math.degrees(math.asin(z)),
        phase_deg=phase,
        materials=tuple(materials),
        geometry=geometry,
        tumble=tumble,
    )


def draw_tumble(prior, rng: np.random.Generator) -> dict:
    """A tumbling curve's own draws, in this order: the moments along body x, y, z
    (log-uniform), the mode (``"any"``: SAM or LAM, ½ each), the excitation
    (uniform), the polhode phase and the sense (the arguments of
    :func:`jaxlc.body.tumble.tumble_from_invariants` that the spin's draws do not give)."""
    inertia = [_log_uniform(rng, r) for r in prior.inertia_kg_m2]
    u = rng.random()
    mode = prior.mode if prior.mode != "any" else ("SAM" if u < 0.5 else "LAM")
    return {
        "inertia_kg_m2": inertia,
        "mode": mode,
        "excitation": _uniform(rng, prior.excitation),
        "polhode_phase": float(rng.random()),
        "sense": 1 if rng.random() < 0.5 else -1,
    }


def curve_attitude(curve: Curve) -> dict:
    """The scene ``[attitude]`` table of a drawn curve, at its first sample (no epoch)."""
    if curve.tumble is None:
        raise DatasetError("curve_attitude: a spinning curve's attitude needs its body axis")
    from jaxlc.body.tumble import tumble_from_invariants

    d = curve.tumble
    tumble = tumble_from_invariants(
        d["inertia_kg_m2"],
        d["mode"],
        d["excitation"],
        curve.period_s,
        curve.pole_ra_deg,
        curve.pole_dec_deg,
        curve.phase_deg,
        d["polhode_phase"],
        d["sense"],
    )
    return {
        "model": "tumble",
        "inertia_kg_m2": [float(x) for x in d["inertia_kg_m2"]],
        "omega_body_rad_s": [float(x) for x in np.asarray(tumble.omega_body_rad_s)],
        "quaternion": [float(x) for x in np.asarray(tumble.quaternion)],
    }


def spin_attitude(body_axis, pole_ra_deg, pole_dec_deg, period_s, phase_deg) -> dict:
    """A spin's scene ``[attitude]`` table, its phase at the first sample (no epoch)."""
    return {
        "model": "spin",
        "body_axis": [float(x) for x in body_axis],
        "pole_ra_deg": float(pole_ra_deg),
        "pole_dec_deg": float(pole_dec_deg),
        "period_s": float(period_s),
        "phase_deg": float(phase_deg),
    }


def _material(prior, pick) -> dict:
    """A scene ``[[material]]`` dict from a prior; ``pick(range, log_uniform)`` gives each
    value, in the order rd, rs, nu, nv (nv is picked even when it equals nu)."""
    entry = {"part": prior.part, "brdf": prior.brdf, "rd": pick(prior.rd, False)}
    if prior.brdf != "lambert":
        entry["rs"] = pick(prior.rs, False)
        entry["nu"] = pick(prior.nu, True)
        nv = pick(prior.nv if prior.nv is not None else prior.nu, True)
        entry["nv"] = nv if prior.nv is not None else entry["nu"]
        entry["tangent"] = list(prior.tangent)
    return entry


def check_extremes(config: DatasetConfig) -> None:
    """Refuse priors whose extreme curves the renderer would refuse, before any work.

    For each class, the scenes at the low and at the high ends of all its
    ranges (size, period, reflectances, exponents) must be valid scenes, and
    the largest object must be far enough away for the facet model's
    parallel rays (:data:`jaxlc.rendering.prepare.FAR_FIELD_RADII`) at the
    closest synthetic range.

    Raises:
        DatasetError: naming the class, the range and the fix.
    """
    from jaxlc.errors import JaxlcError
    from jaxlc.rendering.prepare import FAR_FIELD_RADII
    from jaxlc.scene import scene_from_dict

    g = config.geometry
    for class_id, cls in enumerate(config.classes):
        where = f"{config.source}: [[class]] {cls.name!r}"
        t = cls.tumble
        modes = [None] if t is None else (["SAM", "LAM"] if t.mode == "any" else [t.mode])
        for (end, k), mode in itertools.product((("low", 0), ("high", 1)), modes):
            tumble = None
            if t is not None:
                tumble = {
                    "inertia_kg_m2": [r[k] for r in t.inertia_kg_m2],
                    "mode": mode,
                    "excitation": t.excitation[k],
                    "polhode_phase": 0.0,
                    "sense": 1,
                }
            curve = Curve(
                index=-1,
                class_id=class_id,
                scale=cls.scale[k],
                period_s=cls.period_s[k],
                pole_ra_deg=0.0,
                pole_dec_deg=90.0,
                phase_deg=0.0,
                materials=tuple(_material(m, lambda r, log, k=k: r[k]) for m in cls.materials),
                geometry={},
                tumble=tumble,
            )
            source = f"{where} at the {end} ends of its ranges" + (f" ({mode})" if mode else "")
            try:
                scene = scene_from_dict(curve_scene(config, curve), source=source)
            except (JaxlcError, ValueError) as exc:
                raise DatasetError(str(exc)) from None
        if not isinstance(g, SyntheticSource):
            continue
        # ``scene`` is the high ends' (the largest object).
        radius_m = scene.radius_m
        closest_m = min(g.range_start_m[0], (g.range_end_m or g.range_start_m)[0])
        if closest_m < FAR_FIELD_RADII * radius_m:
            raise DatasetError(
                f"{config.source}: [geometry] range_start_m/range_end_m: the closest range "
                f"{closest_m:g} m is within {FAR_FIELD_RADII:g} × the radius of the largest "
                f"{cls.name!r} ({radius_m:.3g} m; the facet model assumes a distant observer); "
                f"raise the ranges' low ends to ≥ {FAR_FIELD_RADII * radius_m:.3g} m"
            )


def scene_dict(mesh: str, scale: float, materials, attitude: dict, exposure_s: float, render):
    """A curve's scene as a scene-file dict (:func:`jaxlc.scene_from_dict`); its
    ``attitude`` table (:func:`spin_attitude`, :func:`curve_attitude`) is at the
    curve's first sample (no epoch)."""
    return {
        "object": {"mesh": str(mesh), "scale": float(scale)},
        "material": [dict(m) for m in materials],
        "attitude": dict(attitude),
        "sensor": {"exposure_s": float(exposure_s)},
        "render": dict(render),
    }


def curve_scene(config: DatasetConfig, curve: Curve) -> dict:
    """The scene of a drawn curve (a scene-file dict)."""
    cls = config.classes[curve.class_id]
    if curve.tumble is None:
        attitude = spin_attitude(
            cls.body_axis, curve.pole_ra_deg, curve.pole_dec_deg, curve.period_s, curve.phase_deg
        )
    else:
        attitude = curve_attitude(curve)
    return scene_dict(
        cls.mesh_path,
        cls.mesh_scale * curve.scale,
        curve.materials,
        attitude,
        config.exposure_s,
        cls.render.as_table(),
    )


@dataclasses.dataclass(frozen=True)
class CurveGeometry:
    """The geometry of one curve: per-row arrays, airmass (T,) for the noise model,
    and the UTC of the first sample."""

    arrays: GeometryArrays
    airmass: np.ndarray
    utc_start: str


def curve_geometry(config: DatasetConfig, curve: Curve, pool=None) -> CurveGeometry:
    """Geometry of a curve: its synthetic track, or its rows of the pass pool."""
    n, cadence, g = config.samples, config.cadence_s, curve.geometry
    if isinstance(config.geometry, SyntheticSource):
        t, rso, sun, obs = synthetic_positions(
            n,
            cadence,
            g["phase_start_deg"],
            g["phase_end_deg"],
            g["range_start_m"],
            g["range_end_m"],
            g["sun_ra_deg"],
            g["sun_dec_deg"],
            g["tilt_deg"],
        )
        start = utc_timestamp(config.geometry.start_utc)
        nu, visible = 1.0, True
        airmass = np.full(n, config.noise.airmass if config.noise is not None else 1.0)
    else:
        rows = pool.rows(g["pass_id"], g["offset"], n)
        t = np.arange(n) * cadence
        rso, sun, obs = rows["rso_m"], rows["sun_m"], rows["obs_m"]
        nu, visible = rows["shadow_nu"], rows["visible"]
        airmass = airmass_from_elevation(rows["elevation_deg"])
        start = utc_timestamp(pool.utc_start[g["pass_id"]]) + pd.Timedelta(
            seconds=g["offset"] * pool.cadence_s
        )
    arrays = geometry_from_positions(
        t, rso, sun, obs, nu, config.exposure_s, visible, origin_utc=start
    )
    return CurveGeometry(arrays, airmass, format_utc_time(start))

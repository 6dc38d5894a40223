"""The dataset config file (TOML): shape classes, geometry, noise — parsed strictly.

Unknown keys, missing values and bad ranges are :class:`DatasetError`\\ s that
name the file, the table, the key and the value, raised before any work (the
meshes are loaded to check part names). A range is a number (fixed) or
``[low, high]``; reflectances, sizes, phase angles, Sun declinations and tilts
are drawn uniformly, periods, exponents and ranges log-uniformly (see
:func:`jaxlc.dataset.draw_curve`)::

    [dataset]
    count = 200                   # light curves
    samples = 1800                # per light curve
    cadence_s = 1.0               # time between samples
    exposure_s = 1.0              # default: cadence_s
    shard_size = 50               # curves per shard (the unit of work and of resuming)
    seed = 1

    [[class]]                     # shape classes, drawn in proportion to weight
    name = "rocket_body"
    scene = "../scenes/s4_falcon9.toml"  # mesh, materials, [render] and body axis of a scene
    # mesh = "meshes/x.obj"       # … or a mesh with [[class.material]] and body_axis
    weight = 1.0
    scale = [0.8, 1.2]            # size factor (uniform), × the scene's own scale
    period_s = [20.0, 200.0]      # spin period (log-uniform); pole isotropic, phase uniform
    [[class.material]]            # optional with a scene (then replaces its materials)
    part = "*"
    brdf = "ashikhmin-shirley"
    rd = [0.4, 0.7]               # a number or [low, high]: uniform
    rs = 0.1
    nu = [10, 300]                # exponents: log-uniform; nv defaults to nu
    [class.render]                # optional, as a scene's [render] table
    max_subsamples = 64

    [geometry]
    source = "synthetic"          # fixed Sun, observer sweeping phase angle
    phase_start_deg = [10, 90]
    phase_end_deg = [30, 150]
    range_start_m = [5e5, 3e6]    # log-uniform (phases: uniform)
    range_end_m = [5e5, 3e6]      # default: constant range
    # source = "passes"           # or real passes: a pool of pass geometry tables,
    # tle = ["data/tle/falcon9_rb.tle"]   # one drawn per curve
    # sites = ["mt-stromlo"]
    # start_utc = "2020-08-09T00:00:00Z"
    # days = 3

    [noise]                       # optional: noisy values kept beside noise-free ones
    zero_point_mag = 21.0         # magnitude giving 1 photo-electron per second
    sky_e_per_s = 200.0
    read_noise_e = 8.0
    aperture_m = 0.5              # scintillation (Young 1967); omit for none
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.brdf import BRDFS
from jaxlc.errors import JaxlcError
from jaxlc.geometry.observe import Visibility
from jaxlc.mesh import load_mesh
from jaxlc.plan import RenderOptions
from jaxlc.scene import (
    SHIPPED_MESHES,
    MaterialSpec,
    Scene,
    _parse_render,
    _Section,
    load_scene,
)


class DatasetError(JaxlcError):
    """A dataset config or store is malformed, incomplete or inconsistent."""


#: Largest number of curves of one dataset.
MAX_COUNT = 1_000_000_000


# ---------------------------------------------------------------------------
# Strict TOML tables


class _Table(_Section):
    """A scene-style TOML table reader (:class:`jaxlc.scene._Section`) raising
    :class:`DatasetError`, with ranges, integer and string-list kinds."""

    error = DatasetError

    def has(self, key) -> bool:
        self.used.add(key)
        return key in self.data

    def get(self, key, kind, *, default=..., check=None, what=""):
        self.used.add(key)
        hint = f" ({what})" if what else ""
        if key not in self.data:
            if default is ...:
                raise DatasetError(f"{self.where}: missing required key {key!r}{hint}")
            return default
        value = self.data[key]
        if kind is float:
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise DatasetError(f"{self.where}: {key} = {value!r} must be a number{hint}")
            value = float(value)
            if not math.isfinite(value):
                raise DatasetError(f"{self.where}: {key} = {value!r} must be finite")
        elif kind is int:
            if isinstance(value, bool) or not isinstance(value, int):
                raise DatasetError(f"{self.where}: {key} = {value!r} must be a whole number{hint}")
        elif kind == "vec3":
            ok = (
                isinstance(value, list)
                and len(value) == 3
                and all(isinstance(x, int | float) and not isinstance(x, bool) for x in value)
                and all(math.isfinite(x) for x in value)
            )
            if not ok or not any(value):
                raise DatasetError(
                    f"{self.where}: {key} = {value!r} must be a list of 3 finite numbers, "
                    "not all zero"
                )
            value = tuple(float(x) for x in value)
        elif kind == "strings":
            if isinstance(value, str):
                value = [value]
            if not (isinstance(value, list) and value and all(isinstance(x, str) for x in value)):
                raise DatasetError(
                    f"{self.where}: {key} = {value!r} must be a string or a list of strings"
                )
            value = tuple(value)
        elif kind == "ints":
            if not (
                isinstance(value, list)
                and value
                and all(isinstance(x, int) and not isinstance(x, bool) for x in value)
            ):
                raise DatasetError(f"{self.where}: {key} = {value!r} must be a list of integers")
            value = tuple(value)
        elif not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
            raise DatasetError(f"{self.where}: {key} = {value!r} must be of type {kind.__name__}")
        if check is not None:
            problem = check(value)
            if problem:
                raise DatasetError(f"{self.where}: {key} = {value!r} {problem}{hint}")
        return value

    def range(self, key, lo, hi, *, default=..., positive=False, what=""):
        """A number (fixed) or ``[low, high]`` inside [lo, hi] → (low, high)."""
        self.used.add(key)
        if key not in self.data:
            if default is ...:
                hint = f" ({what})" if what else ""
                raise DatasetError(
                    f"{self.where}: missing required key {key!r}{hint}: a number or [low, high]"
                )
            return default
        value = self.data[key]

        def number(x):
            return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)

        if number(value):
            pair = (float(value), float(value))
        elif isinstance(value, list) and len(value) == 2 and all(number(x) for x in value):
            pair = (float(value[0]), float(value[1]))
        else:
            raise DatasetError(
                f"{self.where}: {key} = {value!r} must be a number or [low, high] (two numbers)"
            )
        if pair[0] > pair[1]:
            raise DatasetError(
                f"{self.where}: {key} = {value!r} is not a range: low {pair[0]:g} > high "
                f"{pair[1]:g}; write [low, high]"
            )
        if pair[0] < lo or pair[1] > hi or (positive and pair[0] <= 0):
            bound = f"({lo:g}, {hi:g}]" if positive else f"[{lo:g}, {hi:g}]"
            raise DatasetError(f"{self.where}: {key} = {value!r} must lie in {bound}")
        return pair


def _whole(lo, hi):
    return lambda x: None if lo <= x <= hi else f"must be in [{lo:,}, {hi:,}]"


def _positive(x):
    return None if x > 0 else "must be > 0"


def _resolve(path: str, base_dir: Path | None, where: str, key: str) -> Path:
    """A file relative to the config, the working directory or the checkout."""
    p = Path(path)
    candidates = [p] if p.is_absolute() else []
    if not p.is_absolute():
        if base_dir is not None:
            candidates.append(base_dir / p)
        candidates += [Path.cwd() / p, SHIPPED_MESHES.parent / p, SHIPPED_MESHES / p]
    for c in candidates:
        if c.is_file():
            return c.resolve()
    tried = ", ".join(str(c) for c in dict.fromkeys(candidates))
    raise DatasetError(f"{where}: {key} = {path!r} not found (looked in: {tried})")


# ---------------------------------------------------------------------------
# The config


@dataclasses.dataclass(frozen=True)
class MaterialPrior:
    """One ``[[class.material]]`` entry: a BRDF with a range per parameter.

    ``rd``/``rs`` are drawn uniformly, ``nu``/``nv`` log-uniformly (uniformly
    when the range includes 0); ``nv = None`` means nv = nu (isotropic).
    """

    part: str
    brdf: str
    rd: tuple[float, float]
    rs: tuple[float, float] | None = None
    nu: tuple[float, float] | None = None
    nv: tuple[float, float] | None = None
    tangent: tuple[float, float, float] = (0.0, 0.0, 1.0)


@dataclasses.dataclass(frozen=True)
class ShapeClass:
    """A shape class: mesh, material priors, size and spin priors, render options.

    Attributes:
        name: label of the class.
        mesh_path: the mesh file.
        mesh_scale: the scene's ``[object] scale`` (file units → m; 1 for a bare mesh).
        weight: relative frequency.
        scale: (low, high) size factor on top of ``mesh_scale`` (uniform).
        period_s: (low, high) spin period (log-uniform).
        body_axis: spin axis in the body frame (unit).
        materials: material priors, one per part or ``"*"``.
        render: shadows and blur options (a scene's ``[render]`` table).
    """

    name: str
    mesh_path: Path
    mesh_scale: float
    weight: float
    scale: tuple[float, float]
    period_s: tuple[float, float]
    body_axis: tuple[float, float, float]
    materials: tuple[MaterialPrior, ...]
    render: RenderOptions


@dataclasses.dataclass(frozen=True)
class SyntheticSource:
    """Synthetic phase-angle tracks (:func:`jaxlc.synthetic_geometry`), ranges per curve."""

    phase_start_deg: tuple[float, float]
    phase_end_deg: tuple[float, float]
    range_start_m: tuple[float, float]
    range_end_m: tuple[float, float] | None
    sun_dec_deg: tuple[float, float] = (-23.44, 23.44)
    tilt_deg: tuple[float, float] = (-90.0, 90.0)
    start_utc: str = "2019-07-07T12:00:00Z"


@dataclasses.dataclass(frozen=True)
class PassSource:
    """Real passes: objects of TLE files seen from sites over a window.

    A pool of pass geometry tables is computed once per run (stored in the
    dataset); each curve draws a pass and a start offset within it.
    """

    tle_paths: tuple[Path, ...]
    norad: tuple[int, ...] | None
    sites: tuple[str, ...]
    start_utc: str
    days: float
    search_step_s: float = 10.0
    rules: Visibility = dataclasses.field(default_factory=Visibility)
    min_pass_s: float = 60.0
    max_passes: int = 500


@dataclasses.dataclass(frozen=True)
class NoiseModel:
    """Photon, sky, read and scintillation noise (see :mod:`jaxlc.noise`)."""

    zero_point_mag: float
    sky_e_per_s: float = 0.0
    read_noise_e: float = 0.0
    aperture_m: float | None = None
    altitude_m: float | None = None
    airmass: float | None = None


@dataclasses.dataclass(frozen=True)
class DatasetConfig:
    """A parsed dataset config (see the module docstring for the file format)."""

    count: int
    samples: int
    cadence_s: float
    exposure_s: float
    shard_size: int
    seed: int
    batch_size: int
    classes: tuple[ShapeClass, ...]
    geometry: SyntheticSource | PassSource
    noise: NoiseModel | None
    text: str = ""
    source: str = "<config>"

    @property
    def n_shards(self) -> int:
        return -(-self.count // self.shard_size)

    def shard_rows(self, shard: int) -> range:
        """Curve indices of shard ``shard``."""
        if not 0 <= shard < self.n_shards:
            raise DatasetError(f"shard {shard} does not exist (0 … {self.n_shards - 1})")
        return range(shard * self.shard_size, min((shard + 1) * self.shard_size, self.count))

    def fingerprint(self) -> str:
        """Hash of everything the arrays depend on (the parsed config and the mesh files)."""

        def plain(x):
            if dataclasses.is_dataclass(x):
                return {f.name: plain(getattr(x, f.name)) for f in dataclasses.fields(x)}
            if isinstance(x, tuple | list):
                return [plain(v) for v in x]
            if isinstance(x, Path):
                return str(x)
            return x

        data = plain(dataclasses.replace(self, text="", source=""))
        h = hashlib.sha256(json.dumps(data, sort_keys=True, default=repr).encode())
        for c in self.classes:
            h.update(hashlib.sha256(c.mesh_path.read_bytes()).digest())
        return h.hexdigest()[:32]


def load_config(path: str | Path) -> DatasetConfig:
    """Read and validate a dataset config file.

    Raises:
        DatasetError: naming the file, table, key and value of the first problem.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"dataset config {str(path)!r} does not exist")
    try:
        text = path.read_text(encoding="utf-8")
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise DatasetError(f"{path}: not valid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{path}: not a UTF-8 text file ({exc.reason})") from exc
    return config_from_dict(data, source=str(path), base_dir=path.parent, text=text)


def config_from_dict(
    data: dict, source: str = "<dict>", base_dir: Path | None = None, text: str = ""
) -> DatasetConfig:
    """Validate a dataset config given as a dict (the TOML document's structure).

    Meshes are loaded to check part names, so a wrong part fails here, before
    any rendering.
    """
    top = _Table(data, source)
    ds = _Table(top.get("dataset", dict, what="the [dataset] table"), f"{source}: [dataset]")
    count = ds.get("count", int, check=_whole(1, MAX_COUNT), what="number of light curves")
    samples = ds.get("samples", int, check=_whole(1, 1_000_000), what="samples per light curve")
    cadence = ds.get("cadence_s", float, default=1.0, check=_positive, what="seconds")
    exposure = ds.get("exposure_s", float, default=cadence, what="seconds")
    if not 0 <= exposure <= 3600:
        raise DatasetError(f"{source}: [dataset]: exposure_s = {exposure:g} must be in [0, 3600]")
    shard_size = ds.get("shard_size", int, default=100, check=_whole(1, 1_000_000))
    seed = ds.get("seed", int, check=_whole(0, 2**63 - 1), what="a whole number ≥ 0")
    batch = ds.get("batch_size", int, default=16, check=_whole(1, 4096), what="renders per call")
    ds.finish()

    entries = top.get("class", list, what="at least one [[class]] table")
    if not entries:
        raise DatasetError(f"{source}: needs at least one [[class]] table")
    classes = []
    for i, entry in enumerate(entries, 1):
        name = entry.get("name", f"#{i}") if isinstance(entry, dict) else f"#{i}"
        classes.append(_parse_class(entry, f"{source}: [[class]] #{i} ({name})", base_dir))
    names = [c.name for c in classes]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise DatasetError(f"{source}: [[class]] name = {dup[0]!r} is given twice")

    geo_table = top.get("geometry", dict, what="the [geometry] table")
    geometry = _parse_geometry(geo_table, f"{source}: [geometry]", base_dir)
    noise = None
    if top.has("noise"):
        noise = _parse_noise(top.get("noise", dict), f"{source}: [noise]", geometry)
    top.finish()
    return DatasetConfig(
        count=count,
        samples=samples,
        cadence_s=cadence,
        exposure_s=exposure,
        shard_size=shard_size,
        seed=seed,
        batch_size=batch,
        classes=tuple(classes),
        geometry=geometry,
        noise=noise,
        text=text,
        source=source,
    )


def _parse_class(entry, where: str, base_dir) -> ShapeClass:
    sec = _Table(entry, where)
    name = sec.get("name", str, what="label of the class")
    has_scene, has_mesh = sec.has("scene"), sec.has("mesh")
    if has_scene == has_mesh:
        raise DatasetError(f"{where}: give exactly one of 'scene' (a scene file) or 'mesh'")
    scene = None
    if has_scene:
        scene_path = _resolve(sec.get("scene", str), base_dir, where, "scene")
        scene = load_scene(scene_path)
        mesh_path, mesh_scale = scene.mesh_path, scene.scale
    else:
        mesh_path = _resolve(sec.get("mesh", str), base_dir, where, "mesh")
        mesh_scale = 1.0
    weight = sec.get("weight", float, default=1.0, check=_positive, what="relative frequency")
    scale = sec.range("scale", 0.0, 1e6, default=(1.0, 1.0), positive=True, what="size factor")
    period = sec.range("period_s", 0.0, 1e7, positive=True, what="spin period range, seconds")
    scene_axis = None
    if scene is not None and scene.attitude.model == "spin":
        scene_axis = scene.attitude.body_axis
    axis = sec.get(
        "body_axis",
        "vec3",
        default=... if scene_axis is None else scene_axis,
        what="spin axis in the body frame",
    )
    axis = tuple(float(x) for x in np.asarray(axis) / np.linalg.norm(axis))

    if sec.has("material"):
        items = sec.get("material", list)
        if not items:
            raise DatasetError(f"{where}: [[class.material]] is empty")
        materials = [
            _parse_material(m, f"{where}: [[class.material]] #{j}") for j, m in enumerate(items, 1)
        ]
        parts = [m.part for m in materials]
        dup = sorted({p for p in parts if parts.count(p) > 1})
        if dup:
            raise DatasetError(f"{where}: [[class.material]] part {dup[0]!r} is given twice")
    elif scene is not None:
        materials = [_prior_from_spec(m) for m in scene.materials]
    else:
        raise DatasetError(f"{where}: a class with 'mesh' needs [[class.material]] tables")

    if sec.has("render"):
        render = _parse_render(sec.get("render", dict), f"{where}: [render]")
    else:
        render = scene.render if scene is not None else RenderOptions()
    sec.finish()

    # Every part must get a material; every named part must exist.
    probe = Scene(
        mesh_path=mesh_path,
        materials=tuple(MaterialSpec(m.part, None) for m in materials),
        attitude=None,
        scale=mesh_scale,
        source=where,
    )
    try:
        probe.materials_for(load_mesh(mesh_path, mesh_scale).part_names)
    except JaxlcError as exc:
        raise DatasetError(str(exc)) from None
    return ShapeClass(
        name=name,
        mesh_path=mesh_path,
        mesh_scale=mesh_scale,
        weight=weight,
        scale=scale,
        period_s=period,
        body_axis=axis,
        materials=tuple(materials),
        render=render,
    )


def _parse_material(entry, where) -> MaterialPrior:
    sec = _Table(entry, where)
    part = sec.get("part", str, default="*")
    brdf = sec.get("brdf", str, what=f"one of {', '.join(BRDFS)}")
    if brdf not in BRDFS:
        raise DatasetError(f"{where}: brdf = {brdf!r} is not one of {', '.join(BRDFS)}")
    rd = sec.range("rd", 0.0, 1.0, what="reflectance, 0 … 1")
    rs = nu = nv = None
    tangent = (0.0, 0.0, 1.0)
    if brdf != "lambert":
        rs = sec.range("rs", 0.0, 1.0, what="reflectance, 0 … 1")
        nu = sec.range("nu", 0.0, 1e6, what="AS exponent, 0 … 1e6")
        nv = sec.range("nv", 0.0, 1e6, default=None, what="AS exponent, 0 … 1e6")
        tangent = sec.get("tangent", "vec3", default=tangent, what="body-frame u tangent")
    sec.finish()
    return MaterialPrior(part=part, brdf=brdf, rd=rd, rs=rs, nu=nu, nv=nv, tangent=tangent)


def _prior_from_spec(spec: MaterialSpec) -> MaterialPrior:
    """A fixed prior from a scene's material."""
    b = spec.brdf
    name = next(k for k, v in BRDFS.items() if type(b) is v)
    fixed = lambda x: (float(x), float(x))  # noqa: E731
    if name == "lambert":
        return MaterialPrior(spec.part, name, fixed(b.rd))
    nv = None if float(b.nv) == float(b.nu) else fixed(b.nv)
    return MaterialPrior(
        spec.part, name, fixed(b.rd), fixed(b.rs), fixed(b.nu), nv, tuple(b.tangent)
    )


def _parse_geometry(table, where, base_dir):
    sec = _Table(table, where)
    source = sec.get("source", str, what="'synthetic' or 'passes'")
    if source == "synthetic":
        geo = SyntheticSource(
            phase_start_deg=sec.range("phase_start_deg", 0.0, 180.0, what="degrees"),
            phase_end_deg=sec.range("phase_end_deg", 0.0, 180.0, what="degrees"),
            range_start_m=sec.range("range_start_m", 0.0, 1e12, positive=True, what="metres"),
            range_end_m=sec.range("range_end_m", 0.0, 1e12, default=None, positive=True),
            sun_dec_deg=sec.range("sun_dec_deg", -90.0, 90.0, default=(-23.44, 23.44)),
            tilt_deg=sec.range("tilt_deg", -180.0, 180.0, default=(-90.0, 90.0)),
            start_utc=_utc(sec.get("start_utc", str, default="2019-07-07T12:00:00Z"), where),
        )
    elif source == "passes":
        from jaxlc.geometry.sites import get_site

        tles = sec.get("tle", "strings", what="TLE file(s)")
        paths = tuple(_resolve(t, base_dir, where, "tle") for t in tles)
        norad = sec.get("norad", "ints", default=None, what="catalogue numbers")
        sites = sec.get("sites", "strings", what="registered site names (jaxlc sites)")
        for s in sites:
            try:
                get_site(s)
            except JaxlcError as exc:
                raise DatasetError(f"{where}: sites: {exc}") from None
        rules = dict(
            min_elevation_deg=sec.get("min_elevation_deg", float, default=15.0),
            max_sun_elevation_deg=sec.get("max_sun_elevation_deg", float, default=-6.0),
            min_shadow_nu=sec.get("min_shadow_nu", float, default=0.0),
        )
        try:
            visibility = Visibility(**rules)
        except JaxlcError as exc:
            raise DatasetError(f"{where}: {exc}") from None
        geo = PassSource(
            tle_paths=paths,
            norad=norad,
            sites=tuple(s.strip().lower() for s in sites),
            start_utc=_utc(sec.get("start_utc", str, what="window start, ISO 8601"), where),
            days=sec.get(
                "days",
                float,
                check=lambda x: None if 0 < x <= 60 else "must be in (0, 60]",
                what="window length",
            ),
            search_step_s=sec.get("search_step_s", float, default=10.0, check=_positive),
            rules=visibility,
            min_pass_s=sec.get(
                "min_pass_s", float, default=60.0, check=lambda x: None if x >= 0 else "must be ≥ 0"
            ),
            max_passes=sec.get("max_passes", int, default=500, check=_whole(1, 100_000)),
        )
    else:
        raise DatasetError(f"{where}: source = {source!r} must be 'synthetic' or 'passes'")
    sec.finish()
    return geo


def _utc(text: str, where: str) -> str:
    try:
        ts = pd.Timestamp(text)
    except (ValueError, TypeError):
        raise DatasetError(
            f"{where}: start_utc = {text!r} is not an ISO 8601 time like 2020-08-09T00:00:00Z"
        ) from None
    ts = ts.tz_localize("UTC") if ts.tzinfo is None else ts.tz_convert("UTC")
    return ts.strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _parse_noise(table, where, geometry) -> NoiseModel:
    sec = _Table(table, where)
    zp = sec.get(
        "zero_point_mag",
        float,
        check=lambda x: None if -10 <= x <= 40 else "must be in [-10, 40]",
        what="magnitude giving 1 photo-electron per second",
    )
    nonneg = lambda x: None if x >= 0 else "must be ≥ 0"  # noqa: E731
    sky = sec.get("sky_e_per_s", float, default=0.0, check=nonneg, what="electrons per second")
    read = sec.get("read_noise_e", float, default=0.0, check=nonneg, what="electrons rms")
    aperture = sec.get("aperture_m", float, default=None, check=_positive, what="metres")
    synthetic = isinstance(geometry, SyntheticSource)
    altitude = airmass = None
    if sec.has("altitude_m") or sec.has("airmass"):
        if not synthetic:
            key = "altitude_m" if "altitude_m" in sec.data else "airmass"
            raise DatasetError(
                f"{where}: {key} applies to synthetic geometry only; real passes use the "
                "site's altitude and the object's elevation"
            )
        altitude = sec.get("altitude_m", float, default=0.0, what="site altitude, metres")
        airmass = sec.get(
            "airmass",
            float,
            default=1.0,
            check=lambda x: None if 1 <= x <= 40 else "must be in [1, 40]",
        )
    sec.finish()
    if synthetic:
        altitude = 0.0 if altitude is None else altitude
        airmass = 1.0 if airmass is None else airmass
    return NoiseModel(zp, sky, read, aperture, altitude, airmass)

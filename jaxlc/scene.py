"""Scene files (TOML): mesh, materials per part, attitude, sensor — parsed strictly.

Unknown keys, missing values and out-of-range numbers are errors that name the
file, the key and the allowed range (ARCHITECTURE.md, "Scene file")::

    [object]
    mesh = "meshes/falcon9_upper_stage.obj"   # any trimesh-readable file
    scale = 1.0                               # optional multiplier (file units → m)
    [[material]]
    part = "*"                                # part name, "*" = every other part
    brdf = "ashikhmin-shirley"                # | "lambert" | "as-glossy"
    rd = 0.5
    rs = 0.1
    nu = 100
    nv = 100                                  # optional, default nu (isotropic)
    [attitude]
    model = "spin"                            # | "fixed"
    body_axis = [0, 0, 1]
    pole_ra_deg = 30.0
    pole_dec_deg = 60.0
    period_s = 82.6
    phase_deg = 0.0                           # optional, default 0
    epoch_utc = "2019-07-07T12:00:00Z"        # optional, default: first table row
    [sensor]
    exposure_s = 1.0                          # used when the table has no exposure_s
    [render]                                  # optional; these are the defaults
    shadows = "auto"                          # | "off": self-shadowing where the mesh can
    shadow_grid = 32                          # direction grid side (32² directions)
    shadow_spacing = 0.005                    # sub-point spacing × object size
    shadow_max_subpoints = 512                # per facet
    shadow_interpolation = "bilinear"         # | "nearest"
    blur = "auto"                             # | "off": sub-exposures as the motion needs
    max_subsamples = 64                       # cap of the automatic choice
    # subsamples = 16                         # or a fixed number per exposure
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc import attitude as att
from jaxlc.brdf import BRDFS, AbstractBRDF
from jaxlc.errors import JaxlcError, SceneError
from jaxlc.mesh import Facets, facets_from_mesh, load_mesh
from jaxlc.plan import RenderOptions
from jaxlc.shadow import ShadowSettings

#: Where shipped meshes live (``meshes/`` beside the package in a checkout).
SHIPPED_MESHES = Path(__file__).resolve().parent.parent / "meshes"


class _Section:
    """Typed access to one TOML table that remembers which keys were used.

    ``error`` is the exception raised for bad input (subclasses for other
    file kinds, e.g. dataset configs, set their own).
    """

    error: type[Exception] = SceneError

    def __init__(self, data: dict, where: str):
        if not isinstance(data, dict):
            raise self.error(f"{where} must be a table, got {data!r}")
        self.data, self.where, self.used = data, where, set()

    def get(self, key, kind, *, default=..., check=None, what=""):
        self.used.add(key)
        if key not in self.data:
            if default is ...:
                hint = f" ({what})" if what else ""
                raise SceneError(f"{self.where}: missing required key {key!r}{hint}")
            return default
        value = self.data[key]
        if kind is float:
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise SceneError(f"{self.where}: {key} = {value!r} must be a number")
            value = float(value)
            if not math.isfinite(value):
                raise SceneError(f"{self.where}: {key} = {value!r} must be finite")
        elif kind == "vec3" or kind == "vec4":
            size = 3 if kind == "vec3" else 4
            ok = (
                isinstance(value, list)
                and len(value) == size
                and all(isinstance(x, int | float) and not isinstance(x, bool) for x in value)
            )
            if not ok or not all(math.isfinite(x) for x in value):
                raise SceneError(
                    f"{self.where}: {key} = {value!r} must be a list of {size} finite numbers"
                )
            value = np.asarray(value, dtype=np.float64)
        elif not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
            raise SceneError(f"{self.where}: {key} = {value!r} must be of type {kind.__name__}")
        if check is not None:
            problem = check(value)
            if problem:
                hint = f" ({what})" if what else ""
                raise SceneError(f"{self.where}: {key} = {_show(value)} {problem}{hint}")
        return value

    def finish(self):
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            key = unknown[0]
            close = difflib.get_close_matches(key, sorted(self.used), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            allowed = ", ".join(sorted(self.used))
            raise self.error(f"{self.where}: unknown key {key!r}{hint} (allowed here: {allowed})")


def _show(value):
    return np.array2string(value, separator=", ") if isinstance(value, np.ndarray) else repr(value)


def _in_range(lo, hi):
    return lambda x: None if lo <= x <= hi else f"is outside [{lo:g}, {hi:g}]"


def _positive(x):
    return None if x > 0 else "must be > 0"


def _nonzero_vector(x):
    return None if np.linalg.norm(x) > 1e-12 else "must not be the zero vector"


@dataclasses.dataclass(frozen=True)
class MaterialSpec:
    """One ``[[material]]`` entry: the part it applies to and its BRDF."""

    part: str
    brdf: AbstractBRDF


@dataclasses.dataclass(frozen=True)
class AttitudeSpec:
    """The ``[attitude]`` table in scene units (degrees, UTC)."""

    model: str
    quaternion: tuple[float, ...] | None = None
    body_axis: tuple[float, ...] | None = None
    pole_ra_deg: float | None = None
    pole_dec_deg: float | None = None
    period_s: float | None = None
    phase_deg: float = 0.0
    epoch_utc: pd.Timestamp | None = None

    def rate_rad_s(self) -> float:
        """Rotation rate of the attitude (rad/s): 2π/period for a spin, 0 when fixed."""
        return 2.0 * math.pi / self.period_s if self.model == "spin" else 0.0

    def exact_parameters(self) -> dict:
        """Float64 parameters to pass to ``attitude.times`` (keeps float32 models exact)."""
        return {"period_s": self.period_s} if self.model == "spin" else {}

    def build(self, origin_utc: pd.Timestamp | None, dtype) -> att.AbstractAttitude:
        """The attitude model with its time origin at ``origin_utc`` (float64 phase transfer)."""
        import jax.numpy as jnp

        if self.model == "fixed":
            return att.Fixed(quaternion=jnp.asarray(self.quaternion, dtype=dtype))
        offset = 0.0
        if self.epoch_utc is not None and origin_utc is not None:
            offset = (origin_utc - self.epoch_utc).total_seconds()
        phase = att.phase_at_offset_deg(self.phase_deg, self.period_s, offset)
        return att.Spin.from_degrees(
            self.body_axis, self.pole_ra_deg, self.pole_dec_deg, self.period_s, phase, dtype
        )


@dataclasses.dataclass(frozen=True)
class Scene:
    """A parsed scene: what to render, independent of the observing geometry."""

    mesh_path: Path
    materials: tuple[MaterialSpec, ...]
    attitude: AttitudeSpec
    scale: float = 1.0
    exposure_s: float = 1.0
    source: str = "<scene>"
    render: RenderOptions = dataclasses.field(default_factory=RenderOptions)

    @functools.cached_property
    def facets(self) -> Facets:
        """Facets of the mesh (loaded and merged once per scene object)."""
        return facets_from_mesh(load_mesh(self.mesh_path, self.scale))

    def materials_for(self, part_names) -> list[AbstractBRDF]:
        """One material per part: an exact ``part`` match, else the ``"*"`` entry."""
        by_part = {m.part: m.brdf for m in self.materials}
        unknown = [p for p in by_part if p != "*" and p not in part_names]
        if unknown:
            raise SceneError(
                f"{self.source}: [[material]] part = {unknown[0]!r} is not a part of "
                f"{self.mesh_path.name} (parts: {', '.join(part_names)})"
            )
        out = []
        for name in part_names:
            if name in by_part:
                out.append(by_part[name])
            elif "*" in by_part:
                out.append(by_part["*"])
            else:
                raise SceneError(
                    f"{self.source}: part {name!r} of {self.mesh_path.name} has no material; "
                    "add a [[material]] with part = "
                    f'{name!r} or part = "*"'
                )
        return out


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file.

    Raises:
        SceneError: naming the file, table and key of the first problem found.
    """
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"scene file {str(path)!r} does not exist")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise SceneError(f"{path}: not a UTF-8 text file ({exc.reason})") from exc
    return scene_from_dict(data, source=str(path), base_dir=path.parent)


def scene_from_dict(data: dict, source: str = "<dict>", base_dir: Path | None = None) -> Scene:
    """Validate a scene given as a dict (the TOML document's structure)."""
    top = _Section(data, source)
    obj = _Section(
        top.get("object", dict, what="the [object] table with the mesh"), f"{source}: [object]"
    )
    mesh = obj.get("mesh", str, what="path of a mesh file")
    scale = obj.get("scale", float, default=1.0, check=_positive)
    obj.finish()
    mesh_path = _resolve_mesh(mesh, base_dir, source)

    entries = top.get("material", list, what="at least one [[material]] table")
    if not entries:
        raise SceneError(f"{source}: needs at least one [[material]] table")
    materials, seen = [], set()
    for i, entry in enumerate(entries, 1):
        m = _parse_material(entry, f"{source}: [[material]] #{i}")
        if m.part in seen:
            raise SceneError(f"{source}: [[material]] #{i}: part {m.part!r} is given twice")
        seen.add(m.part)
        materials.append(m)

    attitude = _parse_attitude(top.get("attitude", dict, what="the [attitude] table"), source)
    sensor = _Section(top.get("sensor", dict, default={}), f"{source}: [sensor]")
    exposure = sensor.get("exposure_s", float, default=1.0, check=_positive, what="seconds")
    sensor.finish()
    render = _parse_render(top.get("render", dict, default={}), f"{source}: [render]")
    top.finish()
    return Scene(
        mesh_path=mesh_path,
        materials=tuple(materials),
        attitude=attitude,
        scale=scale,
        exposure_s=exposure,
        source=source,
        render=render,
    )


def _choice(*allowed):
    return lambda x: None if x in allowed else f"must be one of {', '.join(map(repr, allowed))}"


def _whole(lo, hi):
    return lambda x: (
        None
        if float(x).is_integer() and lo <= x <= hi
        else f"must be a whole number in [{lo}, {hi}]"
    )


def _parse_render(table, where) -> RenderOptions:
    """The optional ``[render]`` table: shadow and motion-blur choices."""
    sec = _Section(table, where)
    shadows = sec.get("shadows", str, default="auto", check=_choice("auto", "off"))
    grid = sec.get(
        "shadow_grid", float, default=32.0, check=_whole(4, 512), what="directions per side"
    )
    spacing = sec.get(
        "shadow_spacing", float, default=0.005, check=_in_range(1e-4, 1.0), what="× object size"
    )
    max_sub = sec.get("shadow_max_subpoints", float, default=512.0, check=_whole(32, 4096))
    interp = sec.get(
        "shadow_interpolation", str, default="bilinear", check=_choice("bilinear", "nearest")
    )
    blur = sec.get("blur", str, default="auto", check=_choice("auto", "off"))
    subsamples = sec.get("subsamples", float, default=None, check=_whole(1, 4096))
    max_subsamples = sec.get("max_subsamples", float, default=64.0, check=_whole(1, 4096))
    sec.finish()
    try:
        shadow = ShadowSettings(int(grid), float(spacing), int(max_sub), interp)
    except JaxlcError as exc:
        raise SceneError(f"{where}: {exc}") from None
    return RenderOptions(
        shadows=shadows,
        shadow=shadow,
        blur=blur,
        subsamples=None if subsamples is None else int(subsamples),
        max_subsamples=int(max_subsamples),
    )


def _resolve_mesh(mesh: str, base_dir: Path | None, source: str) -> Path:
    candidates = []
    p = Path(mesh)
    if p.is_absolute():
        candidates.append(p)
    else:
        if base_dir is not None:
            candidates.append(base_dir / p)
        candidates.append(Path.cwd() / p)
        candidates.append(SHIPPED_MESHES.parent / p)
        candidates.append(SHIPPED_MESHES / p)
    for c in candidates:
        if c.is_file():
            return c.resolve()
    tried = ", ".join(str(c) for c in dict.fromkeys(candidates))
    raise SceneError(f"{source}: [object] mesh = {mesh!r} not found (looked in: {tried})")


_ALBEDO = "reflectance, 0 … 1"
_EXPONENT = "AS exponent, 0 … 1e6"


def _parse_material(entry, where) -> MaterialSpec:
    sec = _Section(entry, where)
    part = sec.get("part", str, default="*")
    name = sec.get("brdf", str, what=f"one of {', '.join(BRDFS)}")
    if name not in BRDFS:
        raise SceneError(f"{where}: brdf = {name!r} is not one of {', '.join(BRDFS)}")
    rd = sec.get("rd", float, check=_in_range(0.0, 1.0), what=_ALBEDO)
    if name == "lambert":
        brdf = BRDFS[name](rd=rd)
    else:
        rs = sec.get("rs", float, check=_in_range(0.0, 1.0), what=_ALBEDO)
        nu = sec.get("nu", float, check=_in_range(0.0, 1e6), what=_EXPONENT)
        nv = sec.get("nv", float, default=nu, check=_in_range(0.0, 1e6), what=_EXPONENT)
        tangent = sec.get(
            "tangent",
            "vec3",
            default=np.array([0.0, 0.0, 1.0]),
            check=_nonzero_vector,
            what="body-frame direction of the u tangent",
        )
        brdf = BRDFS[name](rd=rd, rs=rs, nu=nu, nv=nv, tangent=tuple(float(x) for x in tangent))
    sec.finish()
    return MaterialSpec(part=part, brdf=brdf)


def _parse_utc(value: str, where: str, key: str) -> pd.Timestamp:
    try:
        ts = pd.Timestamp(value)
    except (ValueError, TypeError) as exc:
        raise SceneError(
            f"{where}: {key} = {value!r} is not an ISO 8601 time like 2019-07-07T12:00:00Z"
        ) from exc
    return ts.tz_localize("UTC") if ts.tzinfo is None else ts.tz_convert("UTC")


def _parse_attitude(table, source) -> AttitudeSpec:
    where = f"{source}: [attitude]"
    sec = _Section(table, where)
    model = sec.get("model", str, what="'spin' or 'fixed'")
    if model == "fixed":
        q = sec.get(
            "quaternion", "vec4", check=_nonzero_vector, what="[w, x, y, z], body → inertial"
        )
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > 1e-3:
            raise SceneError(
                f"{where}: quaternion = {_show(q)} has norm {norm:.6g}; give a unit quaternion "
                f"[w, x, y, z] (e.g. {_show(q / norm)})"
            )
        spec = AttitudeSpec(model="fixed", quaternion=tuple(float(x) for x in q / norm))
    elif model == "spin":
        axis = sec.get(
            "body_axis", "vec3", check=_nonzero_vector, what="spin axis in the body frame"
        )
        ra = sec.get("pole_ra_deg", float, check=_in_range(-360.0, 360.0), what="degrees")
        dec = sec.get("pole_dec_deg", float, check=_in_range(-90.0, 90.0), what="degrees")
        period = sec.get("period_s", float, check=_positive, what="spin period in seconds")
        phase = sec.get("phase_deg", float, default=0.0, what="degrees")
        epoch = sec.get("epoch_utc", str, default=None, what="ISO 8601 UTC")
        spec = AttitudeSpec(
            model="spin",
            body_axis=tuple(float(x) for x in axis / np.linalg.norm(axis)),
            pole_ra_deg=ra,
            pole_dec_deg=dec,
            period_s=period,
            phase_deg=phase,
            epoch_utc=None if epoch is None else _parse_utc(epoch, where, "epoch_utc"),
        )
    elif model == "tumble":
        raise SceneError(
            f"{where}: model = 'tumble' (torque-free tumbling) is not implemented yet; "
            "use 'spin' or 'fixed'"
        )
    else:
        raise SceneError(f"{where}: model = {model!r} must be 'spin' or 'fixed'")
    sec.finish()
    return spec

"""Scene files (TOML): mesh, materials per part, attitude, sensor — parsed strictly.

Unknown keys, missing values and out-of-range numbers are errors that name the
file, the key and the allowed range (ARCHITECTURE.md, "Scene file")::

    [object]
    mesh = "../meshes/falcon9_upper_stage.obj"  # relative to this file (or a shipped mesh's name)
    scale = 1.0                               # optional multiplier (file units → m)
    [[material]]
    part = "*"                                # part name, "*" = every other part
    brdf = "ashikhmin-shirley"                # | "lambert" | "as-glossy"
    rd = 0.5
    rs = 0.1
    nu = 100
    nv = 100                                  # optional, default nu (isotropic)
    [attitude]
    model = "spin"                            # | "fixed" | "tumble" (jaxlc.scene_attitude)
    body_axis = [0, 0, 1]
    pole_ra_deg = 30.0
    pole_dec_deg = 60.0
    period_s = 82.6
    phase_deg = 0.0                           # optional, default 0
    epoch_utc = "2019-07-07T12:00:00Z"        # optional, default: first table row
    [sensor]
    exposure_s = 1.0                          # used when the table has no exposure_s
    [render]                                  # optional: shadows and blur
                                              # (jaxlc.rendering.options)

The standard scenes S1–S6 ship with the package (:data:`SHIPPED_SCENES`,
:func:`scene_path`): ``jaxlc render s4_falcon9 geometry.csv`` works anywhere; so do
the test shapes ``s7_antenna_box`` and ``s8_boom_panel``, by name.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.body.brdf import BRDFS, AbstractBRDF
from jaxlc.body.mesh import Facets, TriangleMesh, load_body
from jaxlc.errors import SceneError
from jaxlc.io.toml import Section, in_range, nonzero_vector, read_toml
from jaxlc.memo import identity_memo, remember
from jaxlc.rendering.options import RenderOptions, render_options_from_table
from jaxlc.scene_attitude import AttitudeSpec, parse_attitude

#: Package data: the standard scenes and their meshes.
DATA = Path(__file__).resolve().parent / "data"
#: The standard scenes of BENCHMARKS.md by id.
SHIPPED_SCENES = {
    "S1": "s1_plate",
    "S2": "s2_sphere",
    "S3": "s3_cylinder",
    "S4": "s4_falcon9",
    "S5": "s5_cubesat",
    "S6": "s6_boxwing",
}


@identity_memo()
def _radius_m(mesh: TriangleMesh) -> float:
    """Largest distance of a finite vertex from the body origin (mesh units; once per mesh)."""
    return float(np.nanmax(np.linalg.norm(mesh.vertices_m, axis=1)))


def scene_path(name: str | Path) -> Path:
    """A scene file: an existing path, or a shipped scene by id or name.

    ``"S4"``, ``"s4_falcon9"`` and ``"s4_falcon9.toml"`` all name the shipped
    Falcon 9 stage; any existing file is returned as it is.

    Raises:
        SceneError: neither a file nor a shipped scene (the shipped ones are listed).
    """
    path = Path(name)
    if path.is_file():
        return path
    stem = SHIPPED_SCENES.get(str(name).upper(), path.stem)
    shipped = DATA / "scenes" / f"{stem}.toml"
    if path.parent == Path(".") and shipped.is_file():
        return shipped
    known = ", ".join(f"{k} ({v})" for k, v in SHIPPED_SCENES.items())
    raise SceneError(f"scene file {str(name)!r} does not exist (shipped scenes: {known})")


@dataclasses.dataclass(frozen=True)
class MaterialSpec:
    """One ``[[material]]`` entry: the part it applies to and its BRDF."""

    part: str
    brdf: AbstractBRDF


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

    @property
    def body(self) -> tuple[TriangleMesh, Facets]:
        """The mesh and its facets in the file's units (derived once per file and process)."""
        return load_body(self.mesh_path)

    @functools.cached_property
    def mesh(self) -> TriangleMesh:
        """The mesh at the scene's scale (metres)."""
        return self.body[0].scaled(self.scale)

    @functools.cached_property
    def radius_m(self) -> float:
        """The object's radius about its body origin (m, at the scene's scale; finite vertices)."""
        return self.scale * _radius_m(self.body[0])

    @functools.cached_property
    def facets(self) -> Facets:
        """The facets at the scene's scale (metres, m²)."""
        return self.body[1].scaled(self.scale)

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

    def with_spin(
        self,
        period_s: float,
        pole_ra_deg: float = 0.0,
        pole_dec_deg: float = 90.0,
        phase_deg: float = 0.0,
        epoch_utc: pd.Timestamp | None = None,
    ) -> Scene:
        """The scene spinning about its ``body_axis`` (body z for a fixed attitude).

        Raises:
            SceneError: for a tumble, which has no single spin axis (the spin fit
                models a uniform spin).
        """
        if self.attitude.model == "tumble":
            raise SceneError(
                f"{self.source}: [attitude] model = 'tumble' has no single spin axis, and the "
                "spin fit models a uniform spin; fit it with --attitude tumble, or give a "
                "scene with model = 'spin' (its body_axis) or 'fixed' (body z)"
            )
        axis = self.attitude.body_axis if self.attitude.model == "spin" else (0.0, 0.0, 1.0)
        spin = AttitudeSpec(
            model="spin",
            body_axis=tuple(axis),
            pole_ra_deg=float(pole_ra_deg),
            pole_dec_deg=float(pole_dec_deg),
            period_s=float(period_s),
            phase_deg=float(phase_deg),
            epoch_utc=epoch_utc,
        )
        return dataclasses.replace(self, attitude=spin)

    def with_tumble(
        self, inertia_kg_m2, omega_body_rad_s, quaternion, epoch_utc: pd.Timestamp | None = None
    ) -> Scene:
        """The scene tumbling torque-free from a state (moments along body x, y, z,
        body-frame ω and body → inertial quaternion at ``epoch_utc``)."""
        tumble = AttitudeSpec(
            model="tumble",
            inertia_kg_m2=tuple(map(float, inertia_kg_m2)),
            omega_body_rad_s=tuple(map(float, omega_body_rad_s)),
            quaternion=tuple(map(float, quaternion)),
            epoch_utc=epoch_utc,
        )
        return dataclasses.replace(self, attitude=tumble)


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file (a path, or a shipped scene's id or name).

    Raises:
        SceneError: naming the file, table and key of the first problem found.
    """
    path = scene_path(path)
    data, _ = read_toml(path, SceneError)
    return scene_from_dict(data, source=str(path), base_dir=path.resolve().parent)


def scene_from_dict(data: dict, source: str = "<dict>", base_dir: Path | None = None) -> Scene:
    """Validate a scene given as a dict (the TOML document's structure).

    A relative mesh path is taken relative to ``base_dir`` (the scene file's
    folder), or as given when there is none; a bare file name may also name a
    shipped mesh.
    """
    top = Section(data, source, SceneError)
    obj = Section(
        top.get("object", dict, what="the [object] table with the mesh"),
        f"{source}: [object]",
        SceneError,
    )
    mesh = obj.get("mesh", str, what="path of a mesh file")
    scale = obj.get(
        "scale", float, default=1.0, check=in_range(1e-6, 1e6), what="file units → m, 1e-6 … 1e6"
    )
    obj.finish()
    mesh_path = resolve_file(mesh, base_dir, f"{source}: [object] mesh", SceneError, "meshes")

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

    attitude = parse_attitude(top.get("attitude", dict, what="the [attitude] table"), source)
    sensor = Section(top.get("sensor", dict, default={}), f"{source}: [sensor]", SceneError)
    exposure = sensor.get(
        "exposure_s", float, default=1.0, check=in_range(*EXPOSURE_RANGE_S), what="seconds"
    )
    sensor.finish()
    render_table = top.get("render", dict, default={})
    render = render_options_from_table(Section(render_table, f"{source}: [render]", SceneError))
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


def resolve_file(
    name: str, base_dir: Path | None, where: str, error=SceneError, shipped: str | None = None
) -> Path:
    """A file named in a scene or config: absolute, relative to ``base_dir`` (the
    referring file's folder; as given without one), or a file of the package
    data folder ``shipped`` (``"meshes"``, ``"scenes"``) by its bare name.

    Never looked up in the working directory or the checkout.
    """
    p = Path(name)
    candidates = [p if p.is_absolute() or base_dir is None else base_dir / p]
    if shipped is not None and p.parent == Path("."):
        candidates.append(DATA / shipped / p)
        if shipped == "scenes" and p.suffix == "":
            candidates.append(DATA / shipped / f"{SHIPPED_SCENES.get(name.upper(), name)}.toml")
    for c in candidates:
        if c.is_file():
            return c.resolve()
    tried = ", ".join(str(c) for c in dict.fromkeys(candidates))
    raise error(f"{where} = {name!r} not found (looked in: {tried})")


#: Exposure times a scene may give (s): 1 µs to one hour.
EXPOSURE_RANGE_S = (1e-6, 3600.0)
_ALBEDO = "reflectance, 0 … 1"
_EXPONENT = "AS exponent, 0 … 1e6"


#: Materials parsed from valid [[material]] tables, by their content (a dataset's curves
#: repeat a few: ~30 µs each saved a curve); at most :data:`MATERIAL_MEMO` kept.
_MATERIALS: dict = {}
MATERIAL_MEMO = 256


def _entry_key(entry):
    """A hashable key of a [[material]] table's content (types included), or None."""
    if not isinstance(entry, dict):
        return None
    items = []
    for k, v in sorted(entry.items(), key=lambda kv: str(kv[0])):
        if isinstance(v, list):
            v = tuple((type(x).__name__, x) for x in v)
        items.append((k, type(v).__name__, v))
    key = tuple(items)
    try:
        hash(key)
    except TypeError:
        return None
    return key


def _parse_material(entry, where) -> MaterialSpec:
    key = _entry_key(entry)
    spec = _MATERIALS.get(key) if key is not None else None
    if spec is None:
        spec = _parse_material_table(entry, where)  # an invalid table raises: never kept
        if key is not None:
            remember(_MATERIALS, key, spec, MATERIAL_MEMO)
    return spec


def _parse_material_table(entry, where) -> MaterialSpec:
    sec = Section(entry, where, SceneError)
    part = sec.get("part", str, default="*")
    name = sec.get("brdf", str, what=f"one of {', '.join(BRDFS)}")
    if name not in BRDFS:
        raise SceneError(f"{where}: brdf = {name!r} is not one of {', '.join(BRDFS)}")
    rd = sec.get("rd", float, check=in_range(0.0, 1.0), what=_ALBEDO)
    if name == "lambert":
        brdf = BRDFS[name](rd=rd)
    else:
        rs = sec.get("rs", float, check=in_range(0.0, 1.0), what=_ALBEDO)
        nu = sec.get("nu", float, check=in_range(0.0, 1e6), what=_EXPONENT)
        nv = sec.get("nv", float, default=nu, check=in_range(0.0, 1e6), what=_EXPONENT)
        tangent = sec.get(
            "tangent",
            "vec3",
            default=np.array([0.0, 0.0, 1.0]),
            check=nonzero_vector,
            what="body-frame direction of the u tangent",
        )
        if name == "as-glossy" and rd + rs > 1.0:
            raise SceneError(
                f"{where}: rd + rs = {rd:g} + {rs:g} > 1 reflects more light than it receives "
                "(as-glossy adds a Lambert term rd and a lobe of albedo ≤ rs); lower them so "
                "that rd + rs ≤ 1"
            )
        brdf = BRDFS[name](rd=rd, rs=rs, nu=nu, nv=nv, tangent=tuple(float(x) for x in tangent))
    sec.finish()
    return MaterialSpec(part=part, brdf=brdf)

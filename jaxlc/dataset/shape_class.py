"""The ``[[class]]`` tables of a dataset config: mesh, materials, size, spin or tumble.

Parsed strictly (:class:`~jaxlc.dataset.config.DatasetError` naming the
table, key and value), the meshes loaded to check part names. A class spins
about its ``body_axis`` (a scene's by default) with an isotropic pole, or, with
a ``[class.tumble]`` table, tumbles torque-free::

    [[class]]
    name = "rocket_body_tumbling"
    scene = "s4_falcon9"
    period_s = [20.0, 200.0]      # a tumble's precession period (mean rotation about L)
    [class.tumble]
    inertia_kg_m2 = [[9e4, 1e5], 1e5, [1.5e4, 2.5e4]]   # body x, y, z: number or [low, high]
    mode = "any"                  # "SAM", "LAM" or "any"
    excitation = [0.05, 0.9]      # 0: principal-axis spin … 1: the separatrix

The moments default to the scene's when its attitude is a tumble.
"""

from __future__ import annotations

import math

import numpy as np

from jaxlc.body.brdf import BRDFS
from jaxlc.body.tumble import TUMBLE_MODES
from jaxlc.dataset.config import DatasetError, MaterialPrior, ShapeClass, TumblePrior
from jaxlc.errors import JaxlcError
from jaxlc.io.toml import Section, in_range, nonzero_vector
from jaxlc.rendering.options import RenderOptions, render_options_from_table
from jaxlc.scene import MaterialSpec, Scene, load_scene, resolve_file
from jaxlc.scene_attitude import PERIOD_RANGE_S, principal_moments_problem

#: Largest excitation a prior may reach: the separatrix itself has no period.
MAX_EXCITATION = 0.999


def parse_class(entry, where: str, base_dir) -> ShapeClass:
    """One ``[[class]]`` table of a dataset config, checked (``where`` names it in errors;
    relative files are looked up from ``base_dir``)."""
    sec = Section(entry, where, DatasetError)
    name = sec.get("name", str, what="label of the class")
    has_scene, has_mesh = sec.has("scene"), sec.has("mesh")
    if has_scene == has_mesh:
        raise DatasetError(f"{where}: give exactly one of 'scene' (a scene file) or 'mesh'")
    scene = None
    if has_scene:
        scene_path = resolve_file(
            sec.get("scene", str), base_dir, f"{where}: scene", DatasetError, "scenes"
        )
        scene = load_scene(scene_path)
        mesh_path, mesh_scale = scene.mesh_path, scene.scale
    else:
        mesh_path = resolve_file(
            sec.get("mesh", str), base_dir, f"{where}: mesh", DatasetError, "meshes"
        )
        mesh_scale = 1.0
    weight = sec.get(
        "weight", float, default=1.0, check=in_range(1e-6, 1e6), what="relative frequency"
    )
    scale = sec.range("scale", 0.0, 1e6, default=(1.0, 1.0), positive=True, what="size factor")
    tumble = None
    if sec.has("tumble"):
        tumble = _parse_tumble(sec.get("tumble", dict), f"{where}: [class.tumble]", scene)
    what = "precession period range (the mean rotation about L), seconds"
    period = sec.range(
        "period_s", *PERIOD_RANGE_S, what=what if tumble else "spin period range, seconds"
    )
    axis = None
    if tumble is None:
        scene_axis = None
        if scene is not None and scene.attitude.model == "spin":
            scene_axis = scene.attitude.body_axis
        axis = sec.get(
            "body_axis",
            "vec3",
            default=... if scene_axis is None else np.asarray(scene_axis),
            check=nonzero_vector,
            what="spin axis in the body frame (or a [class.tumble] table)",
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
        render = render_options_from_table(
            Section(sec.get("render", dict), f"{where}: [render]", DatasetError)
        )
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
        probe.materials_for(probe.body[1].part_names)
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
        tumble=tumble,
    )


def _parse_material(entry, where) -> MaterialPrior:
    sec = Section(entry, where, DatasetError)
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
        tangent = sec.get(
            "tangent", "vec3", default=tangent, check=nonzero_vector, what="body-frame u tangent"
        )
        tangent = tuple(float(x) for x in tangent)
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


def _parse_tumble(table, where: str, scene) -> TumblePrior:
    sec = Section(table, where, DatasetError)
    default = ...
    if scene is not None and scene.attitude.model == "tumble":
        default = [float(x) for x in scene.attitude.inertia_kg_m2]
    value = sec.get("inertia_kg_m2", list, default=default, what=_INERTIA)
    inertia = tuple(_moment_range(v, f"{where}: inertia_kg_m2", value) for v in value)
    if len(inertia) != 3:
        raise DatasetError(f"{where}: inertia_kg_m2 = {value!r} must have 3 entries ({_INERTIA})")
    modes = (*TUMBLE_MODES, "any")
    mode = sec.get("mode", str, default="any", what=" or ".join(map(repr, modes)))
    if mode not in modes:
        raise DatasetError(f"{where}: mode = {mode!r} must be one of {', '.join(map(repr, modes))}")
    excitation = sec.range(
        "excitation",
        0.0,
        MAX_EXCITATION,
        default=(0.0, 0.9),
        what="0 (principal-axis spin) … 1 (the separatrix)",
    )
    sec.finish()
    prior = TumblePrior(inertia_kg_m2=inertia, mode=mode, excitation=excitation)
    for corner in prior.corners():
        problem = principal_moments_problem(np.asarray(corner))
        if problem:
            raise DatasetError(
                f"{where}: inertia_kg_m2 = {value!r}: the draw {list(corner)} {problem}; "
                "narrow the ranges so that every combination of their ends is a rigid body"
            )
    return prior


_INERTIA = "principal moments along body x, y, z: each a number or [low, high]"


def _moment_range(v, where: str, value) -> tuple[float, float]:
    def number(x):
        return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)

    if number(v):
        pair = (float(v), float(v))
    elif isinstance(v, list) and len(v) == 2 and all(number(x) for x in v):
        pair = (float(v[0]), float(v[1]))
    else:
        raise DatasetError(f"{where} = {value!r}: entry {v!r} must be a number or [low, high]")
    if not 0 < pair[0] <= pair[1]:
        raise DatasetError(
            f"{where} = {value!r}: entry {v!r} must be > 0, written [low, high] (log-uniform)"
        )
    return pair

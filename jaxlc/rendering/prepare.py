"""One preparation for every path: (scene, geometry, options) → what the kernel needs.

:func:`prepare` is the only place where a light-curve model is set up;
:func:`jaxlc.render`, dataset generation (:mod:`jaxlc.dataset.bulk`), the spin
fit's forward model (:mod:`jaxlc.inference.model`), the Blender job writer
(:mod:`calibrate.render`) and the experiments all call it (or its stages), and
evaluate the result with the one kernel entry
:func:`jaxlc.rendering.kernel.exposure_intensity`. Its stages, all on the host
in float64 until the arrays the kernel takes:

1. geometry — :mod:`jaxlc.rendering.observation` (from a table or from
   position arrays): per row, unit vectors to the Sun
   and the observer, range, solar irradiance (1/r² and Earth shadow), phase
   angle, exposure, visibility;
2. plan — :func:`jaxlc.rendering.plan.make_plan`: shadows, sub-exposures per
   exposure, rows to render;
3. object — :func:`space_object`: facets in render order (those that can be
   shadowed first, in the shadow table's order), material coefficients (the
   scene's ``scale`` as an area factor), attitude referred to the time origin,
   shadow table;
4. exposures — :mod:`jaxlc.rendering.exposures`: the instants of every
   exposure with their quadrature weights and directions;
5. kernel inputs — :func:`kernel_inputs`: the instants in the attitude's time
   representation and the kernel's precision.

The attitude is evaluated at the instants of each exposure (its midpoints by
default, so one sub-exposure means mid-exposure); positions are those of the
table row.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import numpy as np
import pandas as pd

from jaxlc.body.facet_model import facet_model
from jaxlc.body.lobe_cells import cells_for
from jaxlc.body.mesh import Facets
from jaxlc.body.shadow import ShadowSettings, shadow_data, table_order
from jaxlc.body.shadow_lookup import shadow_table
from jaxlc.errors import JaxlcError
from jaxlc.rendering.adaptive import (
    Curve,
    Refinement,
    max_level_for,
    refine,
    start_levels,
)
from jaxlc.rendering.exact_glints import kit_for
from jaxlc.rendering.exposures import Exposures, exposure_instants
from jaxlc.rendering.glint_bound import lobe_bound
from jaxlc.rendering.kernel import KernelInputs, SpaceObject
from jaxlc.rendering.observation import GeometryArrays, as_geometry
from jaxlc.rendering.options import RenderOptions
from jaxlc.rendering.plan import RenderPlan, make_plan
from jaxlc.scene import Scene, load_scene

PRECISIONS = ("float32", "float64")


# ---------------------------------------------------------------------------
# The object


def space_object(
    scene: Scene,
    origin_utc: pd.Timestamp | None,
    dtype="float32",
    shadow: ShadowSettings | None = None,
    progress=None,
    facets: Facets | None = None,
    exact_glints: bool = False,
    candidate_cells: bool = True,
) -> SpaceObject:
    """The traced object of a scene, its attitude referred to ``origin_utc``.

    Args:
        scene: the scene.
        origin_utc: time origin of the attitude (the geometry table's first row).
        dtype: ``"float32"`` or ``"float64"`` (or the numpy/JAX dtype).
        shadow: shadow resolution, or None for no self-shadowing. A convex mesh
            never gets shadow data.
        progress: optional callable(done, total) while a shadow table is traced.
        facets: facets in the mesh file's units to use instead of the mesh's
            own (e.g. a coarsened set whose ``triangle_facet`` maps the mesh's
            triangles onto them).
        exact_glints: with shadows, clip the lit-and-seen fraction of bright shadowed
            terms exactly (:mod:`jaxlc.rendering.exact_glints`).
        candidate_cells: give a large glossy mesh its specular candidate cells
            (:func:`~jaxlc.body.lobe_cells.cells_for`); False leaves them to a caller that
            makes one table for many curves (dataset generation).

    The mesh, its facets and its shadow table are derived once per mesh file
    and process (at the file's scale: the scene's ``scale`` multiplies the
    areas, so every size of one shape shares them).
    """
    dtype = np.dtype(dtype)
    mesh, own = scene.body
    facets = own if facets is None else facets
    materials = scene.materials_for(facets.part_names)
    attitude = scene.attitude.build(origin_utc, dtype)
    area_scale = scene.scale**2
    data = None
    if shadow is not None and not facets.convex:
        data = shadow_data(mesh, facets, shadow, progress=progress)
    ordered = facets if data is None else table_order(facets, data.facet_ids)
    model = facet_model(ordered, materials, dtype, area_scale, lane_facets(ordered.n_facets))
    return SpaceObject(
        model=model,
        attitude=attitude,
        shadow=None if data is None else shadow_table(data, dtype),
        exact=kit_for(data, mesh, facets, dtype) if data is not None and exact_glints else None,
        lobes=cells_for(model) if candidate_cells else None,
    )


#: Objects with fewer facets than this get inert facets up to a multiple of
#: FACET_LANES: XLA:CPU vectorises the facet axis in lanes of 8 float32, and a
#: 6-facet CubeSat then renders 3× faster (5.5 vs 16.5 ms for 60,000 instants,
#: an 18-facet box-wing 2.5×; no gain from 64 facets up, measured on the 2-core
#: reference machine).
PAD_BELOW_FACETS = 64
FACET_LANES = 8


def lane_facets(n: int) -> int | None:
    """The facet count an object of ``n`` facets is padded to (None: as it is)."""
    if n >= PAD_BELOW_FACETS or n % FACET_LANES == 0:
        return None
    return -(-n // FACET_LANES) * FACET_LANES


# ---------------------------------------------------------------------------
# Kernel inputs


def kernel_inputs(
    attitude, exposures: Exposures, dtype="float32", exact: dict | None = None, pad_rows: int = 0
) -> KernelInputs:
    """The kernel's view of ``exposures`` (host arrays in ``dtype``; JAX moves them).

    Args:
        attitude: the attitude model whose :meth:`times` represents the instants.
        exposures: the instants.
        dtype: the kernel's precision.
        exact: float64 attitude parameters for ``attitude.times`` (e.g. the
            scene's period, :meth:`~jaxlc.scene.AttitudeSpec.exact_parameters`).
        pad_rows: total rows to pad to (copies of the last row, discarded by the
            caller) so that a few padded sizes share one compilation.
    """
    dtype = np.dtype(dtype)
    e, s, n_rows = exposures, exposures.subsamples, exposures.n_rows
    arrays = [e.t_s, e.sun_dir, e.obs_dir, e.weight]
    row = e.row.astype(np.int32)
    if pad_rows > n_rows and n_rows:
        extra = pad_rows - n_rows
        k = s or 1  # variable counts: each padding row is one copy of the last instant
        arrays = [
            np.concatenate([a, np.tile(a[-k:], (extra,) + (1,) * (a.ndim - 1))]) for a in arrays
        ]
        if s is None:
            arrays[3][len(e.weight) :] = 1.0
        row = np.concatenate([row, np.repeat(np.arange(n_rows, pad_rows, dtype=np.int32), k)])
        n_rows = pad_rows
    if s is None and len(row):  # variable counts: instants padded to a bucket size too
        extra = bucket_size(len(row)) - len(row)
        arrays = [np.concatenate([a, np.repeat(a[-1:], extra, axis=0)]) for a in arrays]
        arrays[3][len(row) :] = 0.0  # zero weight: no contribution
        row = np.concatenate([row, np.full(extra, row[-1], np.int32)])
    t_s, sun, obs, weight = arrays
    # the class's method called directly: an eqx.Module wraps each method it hands out in a
    # pytree of its own, ~20 µs to make (785 of them a shard of the standard mix)
    return KernelInputs(
        times=type(attitude).times(attitude, t_s, **(exact or {})),
        sun_dir=sun.astype(dtype),
        obs_dir=obs.astype(dtype),
        weight=weight.astype(dtype),
        row=row,
        n_rows=n_rows,
        subsamples=s,
    )


def bucket_size(n: int) -> int:
    """Pad n rows up to one of a few sizes per octave (≤ 12.5 % waste)."""
    if n <= 64:
        return 64
    step = 1 << (n.bit_length() - 4)
    return -(-n // step) * step


# ---------------------------------------------------------------------------
# All stages: prepare


@dataclasses.dataclass(frozen=True)
class Prepared:
    """What :func:`prepare` made: everything the kernel needs, and how it was decided.

    Attributes:
        scene: the scene.
        geometry: per-row geometry of the whole table.
        plan: shadows, sub-exposures and rows (:meth:`RenderPlan.explain`).
        object: the traced object (facets, materials, attitude, shadow table).
        exposures: the rendered rows' instants (host, float64).
        inputs: the same instants as the kernel takes them.
        precision: ``"float32"`` or ``"float64"``.
        table: the validated geometry table (None when given as arrays).
        options: the render options used.
        t0_s: the attitude's time origin, seconds after the geometry's first row.
        refinement: the adaptive quadrature's result when :func:`adapt` chose
            the instants (their mean I/E included), else None.
    """

    scene: Scene
    geometry: GeometryArrays
    plan: RenderPlan
    object: SpaceObject
    exposures: Exposures
    inputs: KernelInputs
    precision: str
    table: pd.DataFrame | None = None
    options: RenderOptions | None = None
    t0_s: float = 0.0
    refinement: Refinement | None = None

    @property
    def adaptive(self) -> bool:
        """Whether the plan asks for adaptive sub-exposures (and the instants are not fixed)."""
        return self.plan.blur.adaptive and self.exposures.quadrature == "midpoint"


def prepare(
    scene: Scene | str | Path,
    geometry,
    options: RenderOptions | None = None,
    precision: str = "float32",
    *,
    rows=None,
    origin_utc: pd.Timestamp | None = None,
    subsamples: int | None = None,
    quadrature: str = "midpoint",
    facets: Facets | None = None,
    pad_rows: bool = False,
    progress=None,
    plan_instants: bool = True,
    candidate_cells: bool = True,
) -> Prepared:
    """Prepare a scene over a geometry for the kernel (the module docstring's stages).

    Args:
        scene: a :class:`~jaxlc.scene.Scene` or the path of a scene file.
        geometry: a geometry table (DataFrame), its path, or :class:`GeometryArrays`.
        options: shadows and motion blur (default: the scene's ``[render]`` table).
        precision: ``"float32"`` or ``"float64"``.
        rows: rows to render (default: every visible row; the plan is made for
            the visible rows either way).
        origin_utc: the attitude's time origin (default: the first row's UTC).
        subsamples: instants per exposure instead of the plan's.
        quadrature: ``"midpoint"`` or ``"endpoints"`` (:class:`Exposures`).
        facets: facets (file units) instead of the mesh's own (:func:`space_object`).
        pad_rows: pad the kernel inputs to :func:`bucket_size` rows.
        progress: optional callable(done, total) while a shadow table is traced.
        plan_instants: False: an adaptive plan's exposures are only their midpoints,
            where :func:`adapt` starts, not the plan's worst-case count: for callers
            that always adapt and keep only the refined means (dataset generation;
            S5: ~3 ms a curve saved). Fixed plans keep their instants either way.
        candidate_cells: False: no specular candidate cells in the object (for callers
            that make one table for a batch of curves, :func:`jaxlc.dataset.bulk.
            stacked_objects`: a table per curve of drawn exponents cost ~40 ms, S4).

    Example:
        >>> p = prepare("scene.toml", "geometry.csv")
        >>> p.plan.explain()
    """
    if precision not in PRECISIONS:
        raise JaxlcError(f"precision = {precision!r} must be 'float32' or 'float64'")
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    geo, table = as_geometry(geometry, scene.exposure_s)
    check_far_field(scene, geo, "geometry" if table is None else table.attrs.get("source", ""))
    # The plan is the whole light curve's (its visible rows), whatever subset
    # is rendered: a fit of some of the rows samples them as a render of all does.
    plan = make_plan(scene, geo, options or scene.render, facets=facets)
    if rows is None:
        rows = np.flatnonzero(geo.visible)
    else:
        rows = np.asarray(rows, np.int64)
        plan = dataclasses.replace(plan, rows_rendered=len(rows))
    origin = geo.origin_utc if origin_utc is None else origin_utc
    t0 = (
        0.0
        if origin is None or geo.origin_utc is None
        else (origin - geo.origin_utc).total_seconds()
    )
    with jax.enable_x64(precision == "float64"):
        obj = space_object(
            scene,
            origin,
            precision,
            plan.shadow,
            progress,
            facets,
            plan.exact_glints,
            candidate_cells,
        )
    if subsamples is not None and plan.blur.adaptive:
        plan = dataclasses.replace(plan, blur=dataclasses.replace(plan.blur, adaptive=False))
    count = subsamples or plan.subsamples
    if plan.blur.adaptive and not plan_instants:
        count = 1  # the refinement replaces them (its first probe is the midpoint)
    exposures = exposure_instants(geo, rows, count, quadrature, t0)
    inputs = kernel_inputs(
        obj.attitude,
        exposures,
        precision,
        scene.attitude.exact_parameters(),
        bucket_size(len(rows)) if pad_rows else 0,
    )
    return Prepared(
        scene, geo, plan, obj, exposures, inputs, precision, table, options or scene.render, t0
    )


#: The facet model takes one direction to the Sun and one to the observer for the
#: whole body (parallel rays): the observer must be this many object radii away.
FAR_FIELD_RADII = 100.0


def check_far_field(scene: Scene, geo: GeometryArrays, where: str = "geometry") -> None:
    """Refuse visible rows whose observer is too close for parallel rays (``FAR_FIELD_RADII``)."""
    if not np.any(geo.visible):
        return
    radius_m = scene.radius_m
    near = geo.visible & ~(geo.range_m >= FAR_FIELD_RADII * radius_m)
    if np.any(near):
        row = int(np.flatnonzero(near)[0])
        raise JaxlcError(
            f"{where or 'geometry'}: row {row}: the observer is {geo.range_m[row]:.3g} m from "
            "the object, "
            f"within {FAR_FIELD_RADII:g} × its radius ({radius_m:.3g} m) — the facet model "
            f"assumes a distant observer (parallel rays); check the obs_*_m columns' units "
            f"({int(np.count_nonzero(near))} row(s) affected)"
        )


def with_exposures(prepared: Prepared, exposures: Exposures, pad_rows: bool = False) -> Prepared:
    """``prepared`` with other instants (e.g. an adaptive quadrature's), kernel inputs remade."""
    inputs = kernel_inputs(
        prepared.object.attitude,
        exposures,
        prepared.precision,
        prepared.scene.attitude.exact_parameters(),
        bucket_size(exposures.n_rows) if pad_rows else 0,
    )
    return dataclasses.replace(prepared, exposures=exposures, inputs=inputs)


def probe_inputs(prepared: Prepared, probe: Exposures, pad: bool = True) -> KernelInputs:
    """Kernel inputs that give I/E at each instant of ``probe`` (one instant per row),
    padded to a :func:`bucket_size` (``pad``) so that a few sizes share one compilation;
    ``prepared.inputs`` where ``probe`` is ``prepared.exposures`` (the midpoints that
    :func:`prepare` made without ``plan_instants``, :func:`adapt`'s first probe) padded alike."""
    if probe is prepared.exposures and prepared.inputs.n_rows == (
        bucket_size(probe.n_rows) if pad else probe.n_rows
    ):
        return prepared.inputs
    return kernel_inputs(
        prepared.object.attitude,
        probe,
        prepared.precision,
        prepared.scene.attitude.exact_parameters(),
        bucket_size(probe.n_rows) if pad else 0,
    )


def adapt(
    prepared: list[Prepared],
    evaluate,
    pad_rows: bool = False,
    least_levels: bool = False,
    instants: bool = True,
) -> list[Prepared]:
    """The adaptive sub-exposures (:mod:`jaxlc.rendering.adaptive`) of curves whose plan asks
    for them; the others are returned as they are.

    Args:
        prepared: curves from :func:`prepare`.
        evaluate: callable(list of (Prepared, probe :class:`Exposures`)) → list of
            (M,) I/E at the probes' instants (see :func:`probe_inputs`).
        pad_rows: pad the new kernel inputs to :func:`bucket_size` rows.
        least_levels: refine from one level finer than usual, then give each exposure
            its least level within tolerance (``refine``'s option; a fit's model).
        instants: give each refined curve its final instants and kernel inputs; False
            attaches only the :class:`~jaxlc.rendering.adaptive.Refinement` (its
            intensity per exposure), the exposures and inputs staying the plan's:
            for callers that use nothing else (dataset generation).
    """
    todo = [i for i, p in enumerate(prepared) if p.adaptive and p.exposures.n_rows]
    if not todo:
        return list(prepared)
    options = [prepared[i].options or RenderOptions() for i in todo]
    tol = {o.blur_tolerance_mag for o in options}
    level = {max_level_for(o.max_subsamples) for o in options}
    if len(tol) > 1 or len(level) > 1:
        raise JaxlcError("adapt: curves refined together must share blur options")
    last = next(iter(level))
    curves = []
    for i in todo:
        p = prepared[i]
        (first, resolved), plain = start_levels(p.plan.blur, last, least_levels)
        bound = None
        if plain[0] < first:  # a lobe sets a later start: where can it glint?
            period = p.scene.attitude.exact_parameters().get("period_s")
            obj, rows = p.object, p.exposures.rows
            bound = lobe_bound(obj.model, obj.attitude, p.geometry, rows, p.t0_s, period)
        e = p.exposures  # its midpoints (prepare without plan_instants): the first probe
        mid = e if e.subsamples == 1 and e.quadrature == "midpoint" else None
        curves.append(Curve(p.geometry, e.rows, p.t0_s, first, resolved, bound, plain, mid))
    found = refine(
        curves,
        lambda probes: evaluate([(prepared[i], p) for i, p in zip(todo, probes, strict=True)]),
        next(iter(tol)),
        last,
        least_levels,
    )
    out = list(prepared)
    for i, r in zip(todo, found, strict=True):
        own = with_exposures(prepared[i], r.exposures, pad_rows) if instants else prepared[i]
        out[i] = dataclasses.replace(own, refinement=r)
    return out


def rotation_matrices(prepared: Prepared) -> np.ndarray:
    """(M, 3, 3) body → inertial rotations at the prepared instants (float64; for
    renderers that pose the body themselves, like the Blender job)."""
    with jax.enable_x64(True):
        r = prepared.object.attitude.rotation(prepared.inputs.times)
        return np.asarray(r, dtype=np.float64)

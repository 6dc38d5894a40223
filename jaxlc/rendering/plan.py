"""What a render will do, decided before it runs: skip what the scene does not need.

* facets: coplanar triangles of a part merged (exact without shadows);
* shadows: a convex object gets no shadow work at all; otherwise only facets
  that can be shadowed get sub-points and a visibility table (:mod:`jaxlc.body.shadow`);
* motion blur: sub-exposures only as many as the attitude's motion during an
  exposure needs (:mod:`jaxlc.rendering.blur`);
* rows: invisible rows are not rendered.

The plan also says which attitude turns the body (a tumble's mode and its two
periods), since its rotation rate sets the blur.

``jaxlc render --explain`` prints :meth:`RenderPlan.explain`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxlc.body.shadow import ShadowSettings, reduced_resolution
from jaxlc.body.shadow_rays import RAY_POINTS
from jaxlc.rendering.blur import (
    BlurChoice,
    choose_subsamples,
    feature_scale_rad,
)
from jaxlc.rendering.options import RenderOptions


@dataclasses.dataclass(frozen=True)
class RenderPlan:
    """The decisions for one scene and one geometry table."""

    mesh: str
    triangles: int
    masked: int
    facets: int
    convex: bool
    shadowable: int
    shadow: ShadowSettings | None
    shadow_reason: str
    blur: BlurChoice
    blur_reason: str
    rows: int
    rows_rendered: int
    attitude: str = ""
    exact_glints: bool = False

    @property
    def subsamples(self) -> int:
        return self.blur.subsamples

    def explain(self) -> str:
        """A few lines a person can read before a long render."""
        lines = [
            f"mesh       {self.mesh}: {self.triangles} triangles"
            + (f" ({self.masked} degenerate masked)" if self.masked else "")
            + f" → {self.facets} facets after merging coplanar triangles",
            f"convex     {'yes: the object cannot shadow itself' if self.convex else 'no'}",
            f"shadows    {self.shadow_reason}",
            f"blur       {self.blur_reason}",
            f"rows       {self.rows_rendered} of {self.rows} rendered"
            + (
                f" ({self.rows - self.rows_rendered} invisible, skipped)"
                if self.rows_rendered < self.rows
                else ""
            ),
        ]
        if self.attitude:
            lines.append(f"attitude   {self.attitude}")
        return "\n".join(lines)


def make_plan(scene, geo, options: RenderOptions | None = None, facets=None) -> RenderPlan:
    """Decide shadows, sub-exposures and rows for ``scene`` over ``geo``
    (:class:`~jaxlc.rendering.prepare.GeometryArrays`).

    Args:
        scene: the scene (its materials, mesh and attitude's rotation rate).
        geo: the geometry.
        options: shadows and blur (default :class:`RenderOptions`).
        facets: facets to plan for instead of the mesh's own (a coarse model).
    """
    options = options or RenderOptions()
    own_facets = facets
    # the mesh file's units: nothing planned from the facets depends on the scene's scale
    facets = scene.body[1] if facets is None else facets
    materials = scene.materials_for(facets.part_names)
    shadowable = int(np.count_nonzero(facets.can_shadow))
    if facets.convex:
        shadow, why = None, "none needed (convex)"
    elif options.shadows == "off":
        shadow, why = None, f"off (requested; {shadowable} facets could be shadowed)"
    else:
        s = options.shadow
        why = (
            f"approximate, {shadowable} of {facets.n_facets} facets can be shadowed: "
            f"{s.grid}×{s.grid} direction grid, sub-points every {s.spacing:g} × object size "
            f"(≤ {s.max_subpoints} per facet), {s.interpolation}"
        )
        mesh, own = scene.body  # a large mesh's table is coarser: say so
        why += reduced_resolution(mesh, own if own_facets is None else own_facets, s)
        if options.shadow_exact == "glints":
            why += (
                "; glints of partly shadowed facets clipped exactly (counted on "
                f"up to {RAY_POINTS} rays where a facet has too many occluders to clip)"
            )
        shadow = s
    idx = np.flatnonzero(geo.visible)
    blur, blur_reason = choose_blur(
        options, materials, facets, shadow is not None, scene.attitude.rate_rad_s(), geo, idx
    )
    return RenderPlan(
        mesh=scene.mesh_path.name,
        triangles=facets.n_triangles,
        masked=facets.n_masked,
        facets=facets.n_facets,
        convex=facets.convex,
        shadowable=shadowable,
        shadow=shadow,
        shadow_reason=why,
        blur=blur,
        blur_reason=blur_reason,
        rows=len(geo.visible),
        rows_rendered=len(idx),
        attitude=scene.attitude.describe(),
        exact_glints=shadow is not None and options.shadow_exact == "glints",
    )


def choose_blur(
    options: RenderOptions, materials, facets, shadowed: bool, attitude_rate_rad_s: float, geo, rows
) -> tuple[BlurChoice, str]:
    """Sub-exposures per exposure for ``rows`` of ``geo``, and why (:mod:`jaxlc.rendering.blur`).

    Within an exposure the kernel holds the row's Sun and observer directions
    (positions are per row): only the attitude turns the body, so its rotation
    rate alone sets the sweep. A body that does not turn needs one instant per
    exposure whatever the table's rows do (rows of random geometries included).
    """
    scale, feature = feature_scale_rad(materials, facets, shadowed=shadowed)
    exposure = float(np.max(geo.exposure_s[rows])) if len(rows) else 0.0
    auto = choose_subsamples(exposure, attitude_rate_rad_s, scale, feature, options.max_subsamples)
    auto = dataclasses.replace(auto, start_scale_rad=feature_scale_rad(materials)[0])
    if options.subsamples is not None:
        blur = dataclasses.replace(auto, subsamples=options.subsamples, capped=False)
        reason = f"{options.subsamples} per exposure (fixed; automatic: {auto.subsamples})"
    elif options.blur == "off":
        blur = dataclasses.replace(auto, subsamples=1, capped=False)
        reason = f"off (requested; automatic: {auto.subsamples}), attitude at mid-exposure"
    elif auto.negligible or options.max_subsamples < 3:
        blur, reason = auto, auto.describe()
    else:
        blur = dataclasses.replace(auto, adaptive=True)
        reason = blur.describe() + f", ≤ {options.blur_tolerance_mag:g} mag per exposure"
    if exposure == 0.0 and len(rows):
        reason = "1 per exposure (zero exposure time)"
    return blur, reason

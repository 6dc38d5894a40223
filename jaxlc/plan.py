"""What a render will do, decided before it runs: skip what the scene does not need.

* facets: coplanar triangles of a part merged (exact without shadows);
* shadows: a convex object gets no shadow work at all; otherwise only facets
  that can be shadowed get sub-points and a visibility table (:mod:`jaxlc.shadow`);
* motion blur: sub-exposures only as many as the attitude's motion during an
  exposure needs (:mod:`jaxlc.blur`);
* rows: invisible rows are not rendered.

``jaxlc render --explain`` prints :meth:`RenderPlan.explain`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxlc.blur import BlurChoice, choose_subsamples, direction_rate_rad_s, feature_scale_rad
from jaxlc.errors import JaxlcError
from jaxlc.shadow import ShadowSettings


@dataclasses.dataclass(frozen=True)
class RenderOptions:
    """How to render (scene ``[render]`` table, CLI flags).

    Attributes:
        shadows: ``"auto"`` (approximate self-shadowing where the mesh can
            shadow itself) or ``"off"``.
        shadow: resolution of the shadow approximation.
        blur: ``"auto"`` (sub-exposures as needed) or ``"off"`` (one, at mid-exposure).
        subsamples: a fixed number of sub-exposures instead of the automatic choice.
        max_subsamples: cap of the automatic choice.
    """

    shadows: str = "auto"
    shadow: ShadowSettings = dataclasses.field(default_factory=ShadowSettings)
    blur: str = "auto"
    subsamples: int | None = None
    max_subsamples: int = 64

    def __post_init__(self):
        if self.shadows not in ("auto", "off"):
            raise JaxlcError(f"shadows = {self.shadows!r} must be 'auto' or 'off'")
        if self.blur not in ("auto", "off"):
            raise JaxlcError(f"blur = {self.blur!r} must be 'auto' or 'off'")
        if self.subsamples is not None and not (
            isinstance(self.subsamples, int) and 1 <= self.subsamples <= 4096
        ):
            raise JaxlcError(f"subsamples = {self.subsamples!r} must be an integer in [1, 4096]")
        if not (isinstance(self.max_subsamples, int) and 1 <= self.max_subsamples <= 4096):
            raise JaxlcError(f"max_subsamples = {self.max_subsamples!r} must be in [1, 4096]")


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
        return "\n".join(lines)


def make_plan(scene, geo, options: RenderOptions | None = None) -> RenderPlan:
    """Decide shadows, sub-exposures and rows for ``scene`` over ``geo``
    (:class:`~jaxlc.render.GeometryArrays`)."""
    options = options or RenderOptions()
    facets = scene.facets
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
        shadow = s

    vis = geo.visible
    rows, rendered = len(vis), int(np.count_nonzero(vis))
    scale, feature = feature_scale_rad(materials, facets, shadowed=shadow is not None)
    attitude_rate = scene.attitude.rate_rad_s()
    idx = np.flatnonzero(vis)
    t = geo.t_eval_s[idx]
    geo_rate = max(
        direction_rate_rad_s(geo.sun_dir[idx], t), direction_rate_rad_s(geo.obs_dir[idx], t)
    )
    exposure = float(np.max(geo.exposure_s[idx])) if rendered else 0.0
    auto = choose_subsamples(
        exposure, attitude_rate + geo_rate, scale, feature, options.max_subsamples
    )
    if options.subsamples is not None:
        blur = dataclasses.replace(auto, subsamples=options.subsamples, capped=False)
        blur_reason = f"{options.subsamples} per exposure (fixed; automatic: {auto.subsamples})"
    elif options.blur == "off":
        blur = dataclasses.replace(auto, subsamples=1, capped=False)
        blur_reason = f"off (requested; automatic: {auto.subsamples}), attitude at mid-exposure"
    else:
        blur, blur_reason = auto, auto.describe()
    if exposure == 0.0 and rendered:
        blur_reason = "1 per exposure (zero exposure time)"
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
        rows=rows,
        rows_rendered=rendered,
    )

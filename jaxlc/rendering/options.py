"""How to render: shadows and motion blur (a scene's ``[render]`` table, CLI flags).

::

    [render]                                  # optional; these are the defaults
    shadows = "auto"                          # | "off": self-shadowing where the mesh can
    shadow_grid = 64                          # direction grid side (64² directions)
    shadow_spacing = 0.005                    # sub-point spacing × object size
    shadow_max_subpoints = 512                # per facet
    shadow_interpolation = "triangle"         # | "bilinear" (4 corners) | "nearest"
    shadow_exact = "off"                      # | "glints": bright shadowed terms clipped exactly
    blur = "auto"                             # | "off": sub-exposures where the motion needs them
    blur_tolerance_mag = 0.001                # error allowed per exposure (adaptive quadrature)
    max_subsamples = 64                       # cap of the automatic choice (81 adaptive: 3⁴)
    # subsamples = 16                         # or a fixed number per exposure
"""

from __future__ import annotations

import dataclasses

from jaxlc.body.shadow import INTERPOLATIONS, ShadowSettings
from jaxlc.errors import JaxlcError
from jaxlc.io.toml import Section, choice, in_range, whole

#: Values of ``shadow_exact``.
SHADOW_EXACT = ("off", "glints")


@dataclasses.dataclass(frozen=True)
class RenderOptions:
    """How to render.

    Attributes:
        shadows: ``"auto"`` (approximate self-shadowing where the mesh can
            shadow itself) or ``"off"``.
        shadow: resolution of the shadow approximation.
        shadow_exact: ``"glints"``: the brightest shadowable terms of each instant get
            their lit-and-seen fraction clipped exactly instead of looked up, or
            counted on 512 rays where a facet has too many occluders to clip
            (:mod:`jaxlc.rendering.exact_glints`; ~2 ms per S6 instant, ~4 ms per S4
            instant on a CPU core; a fit refuses it: :func:`jaxlc.inference.model.check_fittable`);
            ``"off"``: the table alone.
        blur: ``"auto"`` (sub-exposures per exposure as its own motion needs,
            :mod:`jaxlc.rendering.adaptive`) or ``"off"`` (one, at mid-exposure).
        blur_tolerance_mag: the error allowed per exposure by the adaptive quadrature.
        subsamples: a fixed number of sub-exposures instead of the automatic choice.
        max_subsamples: cap of the automatic choice.
    """

    shadows: str = "auto"
    shadow: ShadowSettings = dataclasses.field(default_factory=ShadowSettings)
    shadow_exact: str = "off"
    blur: str = "auto"
    blur_tolerance_mag: float = 1e-3
    subsamples: int | None = None
    max_subsamples: int = 64

    def __post_init__(self):
        if self.shadows not in ("auto", "off"):
            raise JaxlcError(f"shadows = {self.shadows!r} must be 'auto' or 'off'")
        if self.blur not in ("auto", "off"):
            raise JaxlcError(f"blur = {self.blur!r} must be 'auto' or 'off'")
        tol = self.blur_tolerance_mag
        if not (isinstance(tol, (int, float)) and 1e-6 <= tol <= 1.0):
            raise JaxlcError(f"blur_tolerance_mag = {tol!r} must be in [1e-6, 1] mag")
        if self.subsamples is not None and not (
            isinstance(self.subsamples, int) and 1 <= self.subsamples <= 4096
        ):
            raise JaxlcError(f"subsamples = {self.subsamples!r} must be an integer in [1, 4096]")
        if self.shadow_exact not in SHADOW_EXACT:
            raise JaxlcError(
                f"shadow_exact = {self.shadow_exact!r} must be one of {', '.join(SHADOW_EXACT)}"
            )
        if not (isinstance(self.max_subsamples, int) and 1 <= self.max_subsamples <= 4096):
            raise JaxlcError(f"max_subsamples = {self.max_subsamples!r} must be in [1, 4096]")

    def as_table(self) -> dict:
        """The ``[render]`` table that gives these options (for scene dicts and stores)."""
        s = self.shadow
        out = {
            "shadows": self.shadows,
            "shadow_grid": s.grid,
            "shadow_spacing": s.spacing,
            "shadow_max_subpoints": s.max_subpoints,
            "shadow_interpolation": s.interpolation,
            "shadow_exact": self.shadow_exact,
            "blur": self.blur,
            "blur_tolerance_mag": self.blur_tolerance_mag,
            "max_subsamples": self.max_subsamples,
        }
        if self.subsamples is not None:
            out["subsamples"] = self.subsamples
        return out


def render_options_from_table(sec: Section) -> RenderOptions:
    """The ``[render]`` table of a scene or dataset class (see the module docstring)."""
    shadows = sec.get("shadows", str, default="auto", check=choice("auto", "off"))
    grid = sec.get(
        "shadow_grid",
        float,
        default=float(ShadowSettings().grid),
        check=whole(4, 512),
        what="directions per side",
    )
    spacing = sec.get(
        "shadow_spacing", float, default=0.005, check=in_range(1e-4, 1.0), what="× object size"
    )
    max_sub = sec.get("shadow_max_subpoints", float, default=512.0, check=whole(32, 4096))
    interp = sec.get("shadow_interpolation", str, default="triangle", check=choice(*INTERPOLATIONS))
    exact = sec.get("shadow_exact", str, default="off", check=choice(*SHADOW_EXACT))
    blur = sec.get("blur", str, default="auto", check=choice("auto", "off"))
    tol = sec.get("blur_tolerance_mag", float, default=1e-3, check=in_range(1e-6, 1.0), what="mag")
    subsamples = sec.get("subsamples", float, default=None, check=whole(1, 4096))
    max_subsamples = sec.get("max_subsamples", float, default=64.0, check=whole(1, 4096))
    sec.finish()
    try:
        shadow = ShadowSettings(int(grid), float(spacing), int(max_sub), interp)
        return RenderOptions(
            shadows=shadows,
            shadow=shadow,
            shadow_exact=exact,
            blur=blur,
            blur_tolerance_mag=float(tol),
            subsamples=None if subsamples is None else int(subsamples),
            max_subsamples=int(max_subsamples),
        )
    except JaxlcError as exc:
        raise sec.error(f"{sec.where}: {exc}") from None

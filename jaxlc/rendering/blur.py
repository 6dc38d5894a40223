"""Motion blur: how fast the body turns against the sharpest feature of the scene.

During an exposure of e seconds the body turns by Δθ = ω e, with ω the
attitude's rotation rate (the kernel holds each row's Sun and observer
directions through its exposure, so only the attitude moves the body frame).
The light curve changes on the angular scale σ of the sharpest feature of the
scene:

* a specular lobe of exponent n: σ = 1/√n ((n·h)^n ≈ exp(−n θ²/2));
* a shadow edge crossing a facet: σ ≈ √(facet area) / object size;
* otherwise (diffuse facets turning towards or away): σ = 0.25 rad.

When Δθ < σ/10 blur is negligible: one instant, mid-exposure. Otherwise the
sub-exposures are chosen per exposure by the adaptive quadrature of
:mod:`jaxlc.rendering.adaptive`, which starts at the least level whose instants
are no farther apart than the sharpest lobe (or diffuse) scale — a glint can
hide between coarser instants, a shadow edge cannot
(:attr:`BlurChoice.start_scale_rad`). This module's per-curve rule,
n = ⌈k Δθ/σ⌉ midpoints (at most ``max_subsamples``; k = 2.5 for lobes and
diffuse turn-on, 0.8 for shadow edges), is the fixed count. That rule alone
(a fixed count, ``[render] subsamples``, or what the search model of the spin
fit uses) bounds the error only on average: over the demo pass its p99 error
was 2.4 mag for S3 (dark end-on samples) and 0.06 mag for S4
(``experiments/results/blur_adaptive.csv``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from jaxlc.errors import JaxlcError
from jaxlc.memo import identity_memo

#: Angular scale (rad) of diffuse-only brightness changes (facet turn-on kinks).
DIFFUSE_SCALE_RAD = 0.25
#: Sub-samples per angular scale σ, by the feature that set σ (module docstring).
SAMPLES_PER_SCALE = {"specular lobe": 2.5, "diffuse": 2.5, "shadow edge": 0.8}
#: No blur when the exposure moves less than this fraction of σ.
NEGLIGIBLE_FRACTION = 0.1


@dataclasses.dataclass(frozen=True)
class BlurChoice:
    """The number of sub-exposures and why.

    Attributes:
        subsamples: per exposure (1: no blur work).
        rate_rad_s: body-frame angular rate used.
        sweep_rad: angle swept during the longest exposure.
        scale_rad: angular scale σ of the sharpest feature.
        feature: what set σ.
        capped: whether ``max_subsamples`` limited the count.
        adaptive: the count is refined per exposure (:mod:`jaxlc.rendering.adaptive`);
            ``subsamples`` is then the rule's estimate for the fastest motion.
        start_scale_rad: the angular scale of the sharpest feature that coarse instants
            can miss entirely — a specular lobe, or diffuse turn-on, but not a shadow
            edge (:func:`feature_scale_rad` without shadows); it sets the adaptive
            quadrature's first level. None: ``scale_rad``.
    """

    subsamples: int
    rate_rad_s: float
    sweep_rad: float
    scale_rad: float
    feature: str
    capped: bool = False
    adaptive: bool = False
    start_scale_rad: float | None = None

    @property
    def start_scale(self) -> float:
        """:attr:`start_scale_rad`, or :attr:`scale_rad` when it is not set (rad)."""
        return self.scale_rad if self.start_scale_rad is None else self.start_scale_rad

    @property
    def negligible(self) -> bool:
        """Whether the exposures move less than a tenth of the sharpest feature."""
        return self.sweep_rad < NEGLIGIBLE_FRACTION * self.scale_rad

    def describe(self) -> str:
        if self.subsamples == 1:
            return (
                f"1 per exposure (sweep {math.degrees(self.sweep_rad):.3g}° ≪ "
                f"{self.feature} scale {math.degrees(self.scale_rad):.3g}°)"
            )
        cap = ", capped" if self.capped else ""
        if self.adaptive:
            return (
                f"adaptive per exposure (sweep {math.degrees(self.sweep_rad):.3g}° at "
                f"{math.degrees(self.rate_rad_s):.3g}°/s, {self.feature} scale "
                f"{math.degrees(self.scale_rad):.3g}°; the fixed rule would take {self.subsamples})"
            )
        return (
            f"{self.subsamples} per exposure{cap} (sweep {math.degrees(self.sweep_rad):.3g}° "
            f"at {math.degrees(self.rate_rad_s):.3g}°/s over the {self.feature} scale "
            f"{math.degrees(self.scale_rad):.3g}°)"
        )


def feature_scale_rad(materials, facets=None, shadowed: bool = False) -> tuple[float, str]:
    """Angular scale σ (rad) of the sharpest brightness feature, and its name."""
    scale, feature = DIFFUSE_SCALE_RAD, "diffuse"
    for m in materials:
        if m.has_specular:
            n = max(float(np.asarray(m.nu)), float(np.asarray(m.nv)), 1.0)
            if 1.0 / math.sqrt(n) < scale:
                scale, feature = 1.0 / math.sqrt(n), f"specular lobe (n = {n:g})"
    if shadowed and facets is not None and np.any(facets.can_shadow):
        edge = shadow_edge_rad(facets)
        if edge < scale:
            scale, feature = edge, "shadow edge"
    return scale, feature


@identity_memo()
def shadow_edge_rad(facets) -> float:
    """Angular scale (rad) of a shadow edge on facets that can be shadowed: their median
    size over the object's size (scale-free; once per facets)."""
    size = float(np.sqrt(np.median(facets.areas_m2[facets.can_shadow])))
    diag = float(np.linalg.norm(np.ptp(facets.centroids_m, axis=0))) or 1.0
    return float(np.clip(size / diag, 0.02, DIFFUSE_SCALE_RAD))


def direction_rate_rad_s(directions: np.ndarray, t_s: np.ndarray) -> float:
    """Largest angular rate (rad/s) of a sequence of unit vectors (T, 3) sampled at t_s."""
    if len(t_s) < 2:
        return 0.0
    dt = np.diff(t_s)
    cos = np.clip(np.sum(directions[1:] * directions[:-1], axis=1), -1.0, 1.0)
    ok = (dt > 0) & np.isfinite(cos)
    if not np.any(ok):
        return 0.0
    return float(np.max(np.arccos(cos[ok]) / dt[ok]))


def choose_subsamples(
    exposure_s: float, rate_rad_s: float, scale_rad: float, feature: str, max_subsamples: int = 64
) -> BlurChoice:
    """n sub-exposures for an exposure of ``exposure_s`` (see the module docstring)."""
    if not (isinstance(max_subsamples, int) and 1 <= max_subsamples <= 4096):
        raise JaxlcError(f"max_subsamples = {max_subsamples!r} must be an integer in [1, 4096]")
    sweep = float(rate_rad_s) * float(exposure_s)
    if sweep < NEGLIGIBLE_FRACTION * scale_rad:
        return BlurChoice(1, rate_rad_s, sweep, scale_rad, feature)
    k = next((v for name, v in SAMPLES_PER_SCALE.items() if feature.startswith(name)), 2.5)
    n = math.ceil(k * sweep / scale_rad)
    return BlurChoice(
        min(n, max_subsamples), rate_rad_s, sweep, scale_rad, feature, n > max_subsamples
    )

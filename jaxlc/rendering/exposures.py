"""Exposures: the instants at which the kernel samples each exposure, with weights.

An exposure of e seconds starting at t is the mean of the flux over
[t, t + e]; the kernel evaluates it by a quadrature over S instants
(:func:`exposure_instants`): midpoints t + e (k + ½)/S with equal weights (the
default; S = 1 is mid-exposure), or the end points t + e k/(S − 1) with
trapezoid weights (for renderers that keyframe the exposure's ends, like the
Blender job). How many instants an exposure needs is the render plan's
decision (:mod:`jaxlc.rendering.blur`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxlc.errors import JaxlcError
from jaxlc.rendering.observation import GeometryArrays
from jaxlc.rendering.patterson import level_counts, level_rule

QUADRATURES = ("midpoint", "endpoints")


@dataclasses.dataclass(frozen=True)
class Exposures:
    """The instants at which the kernel samples each rendered exposure (host, float64).

    Attributes:
        rows: (N,) geometry rows rendered, in order.
        t_s: (M,) instants, seconds from the attitude's time origin.
        row: (M,) index into ``rows`` of each instant, non-decreasing.
        weight: (M,) quadrature weights; those of one exposure sum to 1.
        sun_dir, obs_dir: (M, 3) inertial unit vectors at each instant.
        subsamples: instants per exposure when it is the same for every row;
            None when exposures have their own counts (adaptive quadrature,
            :mod:`jaxlc.rendering.adaptive`): ``row`` says which exposure owns
            each instant.
        quadrature: ``"midpoint"`` (instants t + e (k + ½)/S, equal weights) or
            ``"endpoints"`` (t + e k/(S − 1), trapezoid weights: what a renderer
            that keyframes the exposure's ends needs). Adaptive exposures keep
            ``"midpoint"``: they start from the mid-exposure instant and their
            instants and weights are the nested rule's (:func:`nested_instants`).
    """

    rows: np.ndarray
    t_s: np.ndarray
    row: np.ndarray
    weight: np.ndarray
    sun_dir: np.ndarray
    obs_dir: np.ndarray
    subsamples: int | None
    quadrature: str = "midpoint"

    @property
    def n_rows(self) -> int:
        return len(self.rows)


def quadrature_nodes(subsamples: int, quadrature: str = "midpoint"):
    """Fractions of the exposure (S,) and their weights (S,) (see :class:`Exposures`)."""
    n = int(subsamples)
    if quadrature not in QUADRATURES:
        raise JaxlcError(f"quadrature = {quadrature!r} must be one of {', '.join(QUADRATURES)}")
    if n < 1:
        raise JaxlcError(f"subsamples = {subsamples!r} must be ≥ 1")
    if quadrature == "midpoint" or n == 1:
        return (np.arange(n) + 0.5) / n, np.full(n, 1.0 / n)
    weight = np.full(n, 1.0 / (n - 1))
    weight[[0, -1]] *= 0.5
    return np.arange(n) / (n - 1), weight


def exposure_instants(
    geo: GeometryArrays,
    rows,
    subsamples: int,
    quadrature: str = "midpoint",
    t0_s: float = 0.0,
) -> Exposures:
    """The sub-exposure instants of ``rows`` (indices into ``geo``).

    Args:
        geo: the geometry.
        rows: (N,) rows to render.
        subsamples: instants per exposure.
        quadrature: ``"midpoint"`` or ``"endpoints"`` (:class:`Exposures`).
        t0_s: the attitude's time origin, seconds after the first row.
    """
    rows = np.asarray(rows, np.int64)
    frac, w = quadrature_nodes(subsamples, quadrature)
    n, s = len(rows), len(frac)
    start = geo.t_start_s[rows] - t0_s
    t = (start[:, None] + geo.exposure_s[rows][:, None] * frac[None, :]).ravel()
    owner = rows if s == 1 else np.repeat(rows, s)
    return Exposures(
        rows=rows,
        t_s=t,
        row=np.repeat(np.arange(n), s),
        weight=np.tile(w, n),
        sun_dir=np.take(geo.sun_dir, owner, axis=0),  # np.take: 3× faster than [owner]
        obs_dir=np.take(geo.obs_dir, owner, axis=0),
        subsamples=s,
        quadrature=quadrature,
    )


def probe_instants(geo: GeometryArrays, rows, fractions, t0_s: float = 0.0) -> Exposures:
    """Instants at the same ``fractions`` of each exposure of ``rows``, each instant
    its own output row (weight 1): what evaluating the kernel instant by instant needs."""
    rows = np.asarray(rows, np.int64)
    f = np.asarray(fractions, np.float64)
    start = geo.t_start_s[rows] - t0_s
    t = (start[:, None] + geo.exposure_s[rows][:, None] * f[None, :]).ravel()
    m = len(t)
    owner = np.repeat(rows, len(f))
    return Exposures(
        rows=owner,
        t_s=t,
        row=np.arange(m),
        weight=np.ones(m),
        sun_dir=np.take(geo.sun_dir, owner, axis=0),
        obs_dir=np.take(geo.obs_dir, owner, axis=0),
        subsamples=1,
    )


def nested_instants(geo: GeometryArrays, rows, levels, t0_s: float = 0.0) -> Exposures:
    """The instants and weights of the adaptive quadrature's rule of level ``levels[i]``
    (:func:`jaxlc.rendering.patterson.level_rule`) for exposure ``rows[i]``
    (:attr:`Exposures.subsamples` None unless all levels are equal)."""
    rows = np.asarray(rows, np.int64)
    levels = np.asarray(levels, np.int64)
    n = len(rows)
    counts = level_counts(levels)
    owner = np.repeat(np.arange(n), counts)
    # position of each instant within its exposure, then the rule's node of that level
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    j = np.arange(len(owner)) - np.repeat(start, counts)
    lv = levels[owner]
    frac = np.empty(len(owner))
    weight = np.empty(len(owner))
    for k in np.unique(levels):
        at = lv == k
        f, w = level_rule(int(k))
        frac[at], weight[at] = f[j[at]], w[j[at]]
    r = rows[owner]
    same = n > 0 and np.all(levels == levels[0])
    return Exposures(
        rows=rows,
        t_s=geo.t_start_s[r] - t0_s + geo.exposure_s[r] * frac,
        row=owner,
        weight=weight,
        sun_dir=np.take(geo.sun_dir, r, axis=0),
        obs_dir=np.take(geo.obs_dir, r, axis=0),
        subsamples=len(level_rule(int(levels[0]))[0]) if same else None,
    )

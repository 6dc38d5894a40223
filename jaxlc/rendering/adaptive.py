"""Sub-exposures where they are needed: adaptive, nested Gauss–Patterson quadrature per exposure.

The mean flux of an exposure is the integral of I/E over it. Level k of the
nested rule (:mod:`jaxlc.rendering.patterson`) is the midpoint (k = 0), then the
Gauss–Patterson rules of 3, 7, 15, 31 and 63 points, each keeping every instant
of the level below; finer levels are compound 63-point rules (126, 252, …). The error of
Q_k, the level's estimate, is taken from its change:

    ε_k = |Q_k − Q_{k−1}| / D_k,   D_k = (n_k / n_{k−1})² − 1

(:func:`~jaxlc.rendering.patterson.error_divisor`: the error falling as n⁻² with
the instants n, as across a kink — a shadow's interpolated edge — for any rule;
a smooth integrand converges far faster, and the estimate is then conservative)
once the level's instants resolve the sharpest specular lobe, and D_k = 1
before (:func:`divisor`: a glint between coarse instants converges erratically).
Nor may it fall faster than (n_{k−1}/n_k)⁴ from the level below's own estimate
(:data:`CARRY_POWER`): where a facet turns off mid-exposure, the midpoint may
see nothing, and the 3- and 7-point rules then agree to 1e-5 while both are 2 %
off (S3 and S6, one exposure each in 1,000 curves of the standard mix: 16 and 21
mmag against 256 sub-exposures; 6.3 and 4.2 mmag with the carry, for 2–7 % more
instants; the n⁻² law of a kink, p = 2, took 11–29 % more).

Each exposure is refined on its own, level by level, until ε_k ≤ tol · max(Q_k,
floor) with tol = tolerance_mag / 1.0857 (a relative flux error: that many
magnitudes) and floor a fraction :data:`FLOOR_FRACTION` of the curve's median
flux (a sample 10 mag fainter than the curve's median gets the absolute error
of one at that level). So a body that does not move during its exposures costs
one instant per exposure whatever the table's rows do, a slow spinner mostly
three, and a glint or a shadow edge as many as it needs, up to the last level
(reported when reached). Against the nested midpoints used before (3ᴸ
instants, D = 8, the first level set by shadow edges too), over 10 random spins
per class of the standard mix at 1 mmag (``experiments/quadrature_study.py``,
against 729 midpoints; rerun with the carry): instants per exposure S3 8.4 → 5.7,
S4 11.1 → 7.1, S5 66 → 54, S6 9.6 → 10.4; mean p95 error 0.67 → 0.11, 0.59 →
0.09, 0.69 → 0.14, 1.00 → 0.40 mmag; curves with an exposure off by > 10 mmag 3 →
0 of 40 (worst 1.09 mag → 5.9 mmag).

The first level guards against a glint that every coarse instant misses, so a
curve's sharpest lobe sets it for all its exposures — yet most exposures of a
spinning box meet no lobe at all. Where a closed-form bound on what the lobes add
to an exposure (:func:`jaxlc.rendering.glint_bound.lobe_bound`, for a
:class:`~jaxlc.body.attitude.Spin`) is within :data:`GLINT_SHARE` of its
tolerance, the exposure starts from the diffuse terms' levels instead
(:func:`start_levels`, :func:`exposure_levels`). The standard mix's CubeSats
(800 curves of the mix, against 256 sub-exposures): 41.5 → 18.2 instants per
exposure, the worst curve's p95 and max unchanged (0.83 and 4.0 mmag); the mix
6 % faster on one core.

The refinement is host logic around any evaluator of instants
(:func:`refine`): :func:`jaxlc.render` evaluates one object, the dataset
path a batch of curves, the spin fit its model at a mode's spin. Its result is
an :class:`~jaxlc.rendering.exposures.Exposures` with per-exposure instants and
weights, which the one kernel entry evaluates like any other.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from jaxlc.rendering.blur import DIFFUSE_SCALE_RAD
from jaxlc.rendering.exposures import Exposures, nested_instants, probe_instants
from jaxlc.rendering.observation import GeometryArrays
from jaxlc.rendering.patterson import (
    NESTED_LEVELS,
    added_fractions,
    error_divisor,
    largest_gap,
    level_count,
    level_counts,
    stacked_weights,
)

#: Fraction of a curve's median flux below which errors are held absolute (10 mag).
FLOOR_FRACTION = 1e-4
#: A level's estimated error is at least the level below's own estimate × (n_{k−1}/n_k)^p:
#: two levels that agree by chance right after a large change are not trusted.
CARRY_POWER = 4
#: Share of the tolerance within which a coarser level must match the refined mean
#: (:func:`least_level`).
LEAST_LEVEL_MARGIN = 0.7
#: Share of the tolerance below which an exposure's lobe bound lets it start from the
#: diffuse terms' levels (:func:`exposure_levels`).
GLINT_SHARE = 0.1
#: The angular scale (rad) that sets an exposure's start where no lobe can glint: half
#: the diffuse scale (the whole one left 5 of 400 CubeSat curves over 10 mmag).
PLAIN_SCALE_RAD = 0.5 * DIFFUSE_SCALE_RAD
#: … and such an exposure's first level at least this: where a face turns on or off
#: between the instants, the midpoint and the 3-point rule can agree while both are off
#: (the CubeSat, 41 s spin at phase 104°: 0.8 of a 1 mmag tolerance apart, 10.6 mmag off).
PLAIN_MIN_LEVEL = 2
#: Relative flux error per magnitude of error (d mag = 1.0857 dF/F).
MAG_PER_REL = 2.5 / math.log(10.0)


@dataclasses.dataclass(frozen=True)
class Curve:
    """One light curve to refine: its geometry, the exposures to integrate, the first level.

    Attributes:
        geo: the geometry.
        rows: (N,) exposures (rows of ``geo``).
        t0_s: the attitude's time origin, seconds after the first row.
        first_level: level of the first error estimate (0: one instant and no
            refinement; 1: the usual start; see :func:`first_level_for`).
        resolved_level: the first level whose instants resolve the sharpest lobe (gaps
            within half its scale, :func:`first_level_for`): from there on the error
            law's divisor applies (:func:`divisor`), below it ε = |Q_k − Q_{k−1}|.
        lobe_bound: (N,) a bound of what the specular lobes add to each exposure's I/E
            (:func:`jaxlc.rendering.glint_bound.lobe_bound`), or None.
        plain_levels: (first, resolved) levels from the diffuse terms' scale alone: those
            of an exposure whose lobe bound is within :data:`GLINT_SHARE` of its
            tolerance (no glint to miss between coarse instants).
        midpoints: the level-0 probe when the caller already has it (equal to
            :func:`~jaxlc.rendering.exposures.probe_instants` of ``rows`` at ½): an
            evaluator may then reuse what it made for it (:func:`jaxlc.rendering.prepare.
            probe_inputs`), or None.
    """

    geo: GeometryArrays
    rows: np.ndarray
    t0_s: float = 0.0
    first_level: int = 1
    resolved_level: int = 1
    lobe_bound: np.ndarray | None = None
    plain_levels: tuple[int, int] = (1, 1)
    midpoints: Exposures | None = None


@dataclasses.dataclass(frozen=True)
class Refinement:
    """What :func:`refine` found for one curve.

    Attributes:
        curve: the curve refined.
        intensity: (N,) mean I/E over each exposure at its final level (m² sr⁻¹).
        level: (N,) final level (:func:`~jaxlc.rendering.patterson.level_count` instants).
        error: (N,) estimated error of ``intensity`` (m² sr⁻¹; 0 at level 0).
        capped: exposures that reached the last level without meeting the tolerance.
        glint_free: exposures started below the curve's first level, no lobe within
            reach (:func:`exposure_levels`).
    """

    curve: Curve
    intensity: np.ndarray
    level: np.ndarray
    error: np.ndarray
    capped: int
    glint_free: int = 0

    @functools.cached_property
    def exposures(self) -> Exposures:
        """The final instants (level ``level[i]`` for exposure i), made when first asked
        for: dataset generation keeps only the intensity (S5: 5.4 ms a curve saved)."""
        c = self.curve
        return nested_instants(c.geo, c.rows, self.level, c.t0_s)

    @property
    def instants(self) -> int:
        return int(level_counts(self.level).sum())

    def describe(self) -> str:
        n = max(len(self.level), 1)
        counts = np.bincount(self.level, minlength=1)
        parts = ", ".join(f"{level_count(k)}: {c}" for k, c in enumerate(counts) if c)
        cap = f"; {self.capped} at the cap" if self.capped else ""
        free = (
            f"; {self.glint_free} started from the diffuse scale, no lobe within reach"
            if self.glint_free
            else ""
        )
        return (
            f"{self.instants / n:.2f} instants per exposure "
            f"(instants: exposures — {parts}{cap}{free})"
        )


def refine(
    curves: list[Curve],
    evaluate,
    tolerance_mag: float = 1e-3,
    max_level: int = 4,
    least_levels: bool = False,
):
    """Refine every exposure of every curve until its estimated error is within tolerance.

    Args:
        curves: the curves.
        evaluate: callable(list of :class:`Exposures`, one per curve, each
            instant its own row) → list of (M_c,) I/E at those instants.
        tolerance_mag: the magnitude error allowed per exposure.
        max_level: the last level (:func:`max_level_for`).
        least_levels: then give each exposure the least level (down to one
            instant) whose mean is within tolerance of the refined one
            (:func:`least_level`): for a model evaluated many times at nearly
            one state (a fit's mode), where this one-off work pays.

    Returns:
        One :class:`Refinement` per curve.
    """
    tol = tolerance_mag / MAG_PER_REL
    probes = [
        probe_instants(c.geo, c.rows, [0.5], c.t0_s) if c.midpoints is None else c.midpoints
        for c in curves
    ]
    mean = [np.array(v, np.float64) for v in evaluate(probes)]  # own, writable copies
    # the values at the nested levels' instants (in evaluation order) of the exposures
    # still refined: row j is exposure todo[j] of the level (the active set only shrinks)
    values = [m[:, None].copy() for m in mean]
    # every level's means (NaN until reached), kept only for the least-level choice
    by_level = []
    if least_levels:
        by_level = [np.column_stack([m, np.full((len(m), max_level), np.nan)]) for m in mean]
    level = [np.zeros(len(c.rows), np.int64) for c in curves]
    error = [np.zeros(len(c.rows)) for c in curves]
    own = [np.zeros(len(c.rows)) for c in curves]  # each level's estimate from its own change
    floor = []
    for m in mean:
        pos = m[m > 0]
        floor.append(FLOOR_FRACTION * float(np.median(pos)) if len(pos) else 0.0)
    first, resolved = exposure_levels(curves, mean, floor, tol)
    active = [f > 0 for f in first]
    for k in range(1, max_level + 1):
        todo = [np.flatnonzero(a) for a in active]
        if not any(len(t) for t in todo):
            break
        frac = added_fractions(k)
        probes = [
            probe_instants(c.geo, c.rows[t], frac, c.t0_s)
            for c, t in zip(curves, todo, strict=True)
        ]
        new = evaluate(probes)
        for i, (t, v) in enumerate(zip(todo, new, strict=True)):
            if not len(t):
                continue
            got = np.asarray(v, np.float64).reshape(len(t), len(frac))
            if k <= NESTED_LEVELS:  # kept: the next nested level reuses these instants
                got = values[i] = np.concatenate([values[i], got], axis=1)
            m = got @ stacked_weights(k)
            change = np.abs(m - mean[i][t]) / divisor(k, resolved[i][t])
            carried = own[i][t] * (level_count(k - 1) / level_count(k)) ** CARRY_POWER
            err, own[i][t] = np.maximum(change, carried), change
            mean[i][t], level[i][t], error[i][t] = m, k, err
            if least_levels:
                by_level[i][t, k] = m
            done = (k >= first[i][t]) & (err <= tol * np.maximum(m, floor[i]))
            active[i][t[done]] = False
            if k < NESTED_LEVELS:
                values[i] = values[i][~done]
    if least_levels:
        for i, a in enumerate(active):
            done = np.flatnonzero(~a & (level[i] > 0))
            lv, m, e = least_level(
                by_level[i][done], level[i][done], error[i][done], tol, floor[i],
                resolved[i][done],
            )  # fmt: skip
            level[i][done], mean[i][done], error[i][done] = lv, m, e
    out = []
    for c, m, lv, e, a, f in zip(curves, mean, level, error, active, first, strict=True):
        out.append(
            Refinement(
                curve=c,
                intensity=m,
                level=lv,
                error=e,
                capped=int(np.count_nonzero(a)),
                glint_free=int(np.count_nonzero(f < c.first_level)),
            )
        )
    return out


def exposure_levels(curves: list[Curve], mean: list, floor: list, tol: float):
    """Each exposure's (first, resolved) levels: the curve's, or its
    :attr:`Curve.plain_levels` where its :attr:`Curve.lobe_bound` is at most
    :data:`GLINT_SHARE` × tol × max(level-0 mean, floor) (the lobes then add less than
    that share of the tolerance, however the instants fall).

    Returns:
        Two lists of (N,) int arrays, one per curve.
    """
    first, resolved = [], []
    for c, m, fl in zip(curves, mean, floor, strict=True):
        f, r = np.full(len(c.rows), c.first_level), np.full(len(c.rows), c.resolved_level)
        if c.lobe_bound is not None:
            free = c.lobe_bound <= GLINT_SHARE * tol * np.maximum(m, fl)
            f = np.where(free, c.plain_levels[0], f)
            r = np.where(free, c.plain_levels[1], r)
        first.append(f)
        resolved.append(r)
    return first, resolved


def least_level(
    by_level: np.ndarray,
    level: np.ndarray,
    error: np.ndarray,
    tol: float,
    floor,
    resolved_level: int = 1,
):
    """The least level of each exposure that is resolved and close to its refined mean.

    Level l qualifies when (a) the usual estimate calls it resolved, |M_l − M_{l−1}|
    divided by :func:`divisor` within tolerance (level 0: |M_1 − M_0|), and (b) it is within
    :data:`LEAST_LEVEL_MARGIN` of the tolerance of the last level's mean, counting that
    mean's own estimated error. (a) keeps a glint that a coarse level straddles by
    chance, level with the refined mean at the mode only, at its refined level (the
    CubeSat: 6.8 mmag at states 0.06° off the mode without it, 0.6 with it); the
    margin keeps states near the mode within tolerance (S4: 3.4 mmag at margin 1).

    Args:
        by_level: (N, L) means of each exposure at levels 0 … L − 1
            (NaN above the exposure's last level).
        level: (N,) the last level, where the estimated error met the tolerance.
        error: (N,) that estimated error (I/E).
        tol: relative tolerance; floor: the absolute floor of its scale (I/E).
        resolved_level: (N,) each exposure's resolved level (or one for all).

    Returns:
        (N,) levels, (N,) their means and (N,) error bounds |M_l − M_last| + error.
    """
    rows = np.arange(len(level))
    ref = by_level[rows, level]
    bound = np.abs(by_level - ref[:, None]) + error[:, None]
    scale = tol * np.maximum(ref, floor)[:, None]
    est = np.full_like(by_level, np.inf)
    resolved = np.broadcast_to(resolved_level, level.shape)
    for k in range(1, by_level.shape[1]):
        est[:, k] = np.abs(by_level[:, k] - by_level[:, k - 1]) / divisor(k, resolved)
    if by_level.shape[1] > 1:
        est[:, 0] = np.abs(by_level[:, 1] - by_level[:, 0])
    ok = (bound <= LEAST_LEVEL_MARGIN * scale) & (est <= scale)  # NaN compares False
    ok[rows, level] = True
    least = np.argmax(ok, axis=1)
    return least, by_level[rows, least], bound[rows, least]


def divisor(level: int, resolved_level):
    """The error law's divisor at ``level``: D_k (:func:`~jaxlc.rendering.patterson.
    error_divisor`) once the level's instants resolve the sharpest lobe, else 1. A glint
    between coarse instants does not converge as n⁻²: two unresolved levels can agree
    to within D_k × the tolerance and both be off (the CubeSat, 43 s spin: 19.8 mmag
    at a 1 mmag tolerance with D_k throughout, 1.4 mmag this way;
    ``experiments/quadrature_study.py``). ``resolved_level`` may be an array (one per
    exposure): the divisors are then an array of its shape."""
    return np.where(level >= np.asarray(resolved_level), error_divisor(level), 1.0)


def start_levels(blur, last: int, least_levels: bool = False):
    """The (first, resolved) levels of a curve whose motion is ``blur``
    (:class:`~jaxlc.rendering.blur.BlurChoice`): :func:`first_level_for` its sweep over
    the start scale and over half of it (``least_levels``: the first one finer), at
    most ``last``; and the same over :data:`PLAIN_SCALE_RAD`, the first at least
    :data:`PLAIN_MIN_LEVEL` — the levels of an exposure that no lobe can glint in
    (:func:`exposure_levels`), never above the curve's own."""
    levels = []
    for scale in (blur.start_scale, PLAIN_SCALE_RAD):
        first = min(last, first_level_for(blur.sweep_rad, scale) + int(least_levels))
        levels.append((first, first_level_for(blur.sweep_rad, scale / 2)))
    (first, resolved), (p_first, p_resolved) = levels
    plain = (
        min(first, max(PLAIN_MIN_LEVEL, p_first)),
        min(resolved, max(PLAIN_MIN_LEVEL, p_resolved)),
    )
    return (first, resolved), plain


def first_level_for(sweep_rad: float, scale_rad: float) -> int:
    """The first level of the error estimate for exposures that sweep at most ``sweep_rad``
    (the curve's fastest motion, :class:`jaxlc.rendering.blur.BlurChoice`) over the
    sharpest feature a coarse level can miss entirely, of angular scale ``scale_rad``
    (a specular lobe: :attr:`~jaxlc.rendering.blur.BlurChoice.start_scale`): the
    least level whose largest gap between instants (:func:`~jaxlc.rendering.patterson.
    largest_gap`) is within that scale, at least 1. A start coarser than a glint can
    miss it in every one of its instants; two coarse levels then agree by chance
    (midpoints started one level below the fixed rule's count left the CubeSat — lobe
    1.8°, a 57 s spin — 24 mmag off 256 sub-exposures at a 1 mmag tolerance, SBC case 3).
    A shadow edge cannot hide that way (it moves every later instant's value): it does
    not set the start (S4 over 10 spins: 6.3 instants per exposure, worst exposure
    2.4 mmag; nested midpoints started at its edge scale took 11.1 and 2.0 mmag;
    ``experiments/quadrature_study.py``)."""
    if not (sweep_rad > 0 and scale_rad > 0):
        return 1
    k = 1
    while largest_gap(k) * sweep_rad > scale_rad and k < 12:
        k += 1
    return k


def max_level_for(max_subsamples: int) -> int:
    """The last level whose instant count is at most 3 × ``max_subsamples`` (≥ 1): 126
    for the default 64, 504 for 243 (as the nested midpoints' 3ᴸ ≤ 3 × the cap)."""
    k = 1
    while level_count(k + 1) <= 3 * max_subsamples:
        k += 1
    return k

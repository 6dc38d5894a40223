"""Where the spin search starts and which of its optima it keeps.

:func:`start_points` spreads starts over isotropic poles, the seed periods and
phases; :func:`reversed_starts` starts again about good optima (reversed pole,
same pole, phases spread); :func:`distinct_modes` clusters optima;
:func:`refinement_set` picks those refined on the exact model (and the bases of
the reversed solve): the best, and the best of each other period;
:func:`match_offset` sets a start's Δm and :func:`better_half_turn` picks a start
or its twin half a turn on.
"""

from __future__ import annotations

import jax
import numpy as np

from jaxlc.inference.data import FitData, soft_clip
from jaxlc.inference.model import SpinModel
from jaxlc.xla import filter_jit


def start_points(
    seeds_period_s, n_starts: int, rng: np.random.Generator, period_jitter: float = 0.002
) -> np.ndarray:
    """(n_starts, 6) LM starts: isotropic poles, the seed periods in turn, uniform phases.

    Δm starts at 0 and is set by :func:`match_offset` before solving.
    """
    seeds = np.asarray(seeds_period_s, np.float64)
    pole = rng.normal(size=(n_starts, 3))
    per = seeds[np.arange(n_starts) % len(seeds)] * np.exp(
        period_jitter * rng.standard_normal(n_starts)
    )
    phase = rng.uniform(0, 2 * np.pi, n_starts)
    return np.column_stack([pole, np.log(per), phase, np.zeros(n_starts)])


def reversed_starts(thetas, n_starts: int, rng: np.random.Generator) -> np.ndarray:
    """(n_starts, 6) starts about the poles of ``thetas`` (LM coordinates): half at the
    reversed poles −u, half at the poles u themselves, each jittered by ~3°, with the
    same period and phases spread uniformly (a body symmetric about its spin axis has
    optima half a turn apart that a start must reach in phase)."""
    base = np.asarray(thetas, np.float64)[np.arange(n_starts) % len(thetas)]
    out = base.copy()
    u = base[:, :3] / np.linalg.norm(base[:, :3], axis=1, keepdims=True)
    sign = np.where(np.arange(n_starts) < (n_starts + 1) // 2, -1.0, 1.0)[:, None]
    out[:, :3] = sign * u + 0.05 * rng.standard_normal((n_starts, 3))
    out[:, 4] = rng.uniform(0, 2 * np.pi, n_starts)
    out[:, 5] = 0.0
    return out


def greedy_clusters(
    theta: np.ndarray,
    cost: np.ndarray,
    directions: np.ndarray,
    ln_periods: np.ndarray,
    direction_tol_deg: float,
    period_tol: float,
    max_clusters: int,
) -> list[tuple[np.ndarray, float, int]]:
    """Greedy clustering of optima ``theta`` (K, P), best (lowest ``cost``) first: the
    cluster's best optimum, its cost and its members per cluster.

    Each optimum joins the first cluster whose best has its direction (K, 3; a pole or an
    angular momentum, any length) within ``direction_tol_deg`` and every log period
    (K, J) within ``period_tol``; otherwise it starts a new one (at most
    ``max_clusters``, later ones are dropped). Optima of non-finite cost or log
    period are left out. One array comparison per optimum against all clusters.
    """
    cost = np.asarray(cost, np.float64)
    ln_p = np.asarray(ln_periods, np.float64).reshape(len(cost), -1)
    u = np.asarray(directions, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):  # a zero vector: left out below
        u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    cos_tol = np.cos(np.radians(direction_tol_deg))
    ok = np.isfinite(cost) & np.all(np.isfinite(ln_p), axis=1) & np.all(np.isfinite(u), axis=1)
    heads: list[int] = []
    members: list[int] = []
    for k in np.argsort(np.where(ok, cost, np.inf), kind="stable"):
        if not ok[k]:
            break
        if heads:
            near = (u[heads] @ u[k] > cos_tol) & np.all(
                np.abs(ln_p[heads] - ln_p[k]) < period_tol, axis=1
            )
            if near.any():
                members[int(np.argmax(near))] += 1
                continue
        if len(heads) < max_clusters:
            heads.append(int(k))
            members.append(1)
    return [(theta[k], float(cost[k]), n) for k, n in zip(heads, members, strict=True)]


def distinct_modes(
    theta: np.ndarray,
    cost: np.ndarray,
    pole_tol_deg: float = 10.0,
    period_tol: float = 0.01,
    max_modes: int = 8,
) -> list[tuple[np.ndarray, float, int]]:
    """Greedy clustering of optima: (theta, cost, members) per mode, best first.

    Two optima belong together when their poles are within ``pole_tol_deg`` and
    their periods within a fraction ``period_tol`` (:func:`greedy_clusters`); failed
    solves (infinite cost) are left out.
    """
    return greedy_clusters(
        theta, cost, theta[:, :3], theta[:, 3], pole_tol_deg, period_tol, max_modes
    )


#: Distinct search optima kept for :func:`refinement_set`, per mode refined.
CANDIDATE_FACTOR = 4
#: Optima of other periods refined besides the ``max_modes`` best (their best each).
EXTRA_PERIODS = 4


def refinement_set(candidates: list, best: int, extra: int, period_tol: float = 0.01) -> list:
    """Search optima (theta, cost, members; best first) to refine on the exact model or
    to start the reversed solve from: the ``best`` best, and the best optimum of each
    period (within ``period_tol`` in ln P) not among them, at most ``extra`` of those;
    best first.

    The coarse search model can rank many optima of one wrong period (a third of the
    spin, with its symmetric twins) above every optimum of the true period: in SBC
    case 43 the reversed solve started only from P/3 optima, eight P/3 optima were
    refined, and the fit answered P/3 with weight 1, where the truth fits better by
    Δχ² 48. The reversed pole of the best 3P optimum leads to the truth. Taking those
    slots from the best optima instead lost the true pole of cases 23 and 25 (a
    lower-ranked optimum of the best period).
    """
    chosen = list(candidates[:best])
    periods = [c[0][3] for c in chosen]
    for c in candidates[best:]:
        if extra and all(abs(c[0][3] - p) >= period_tol for p in periods):
            periods.append(c[0][3])
            chosen.append(c)
            extra -= 1
    return sorted(chosen, key=lambda c: c[1])


@filter_jit
def batch_magnitudes(model: SpinModel, thetas):
    """(K, N) magnitudes of ``model`` at (K, P) device coordinates (any fit model)."""
    return jax.vmap(model.magnitudes)(thetas)


def match_offset(model: SpinModel, data: FitData, starts: np.ndarray) -> np.ndarray:
    """Set each start's Δm (LM coordinate ``model.dmag_index``) to the median offset
    between data and model (any fit model: :class:`SpinModel`, the tumble's)."""
    m = np.asarray(batch_magnitudes(model, model.to_device(starts)), np.float64)
    out = starts.copy()
    out[:, model.dmag_index] = np.median(soft_clip(data.mag, data.limit_mag)[None, :] - m, axis=1)
    return out


def better_half_turn(thetas: np.ndarray, chi2) -> np.ndarray:
    """Each start (K, 6) or its twin half a turn on (phase + π), whichever fits better
    by ``chi2``: callable((K, 6) starts) → (K,) χ² on the exact model.

    A body symmetric about its spin axis but for details that only the exact model
    has (shadows, an anisotropic panel: the search model merges facets and drops
    shadows) has optima half a turn apart that the search cannot tell apart; the
    refinement does not cross from one to the other (S6: the wrong twin fitted
    13 mmag rms where the right one fits 0.1 mmag, and won no weight).
    """
    twins = thetas.copy()
    twins[:, 4] += np.pi
    take_twin = chi2(twins) < chi2(thetas)
    return np.where(take_twin[:, None], twins, thetas)

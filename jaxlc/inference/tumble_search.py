"""Multi-start MAP search for a tumbling body, seeded by the light curve's two periods.

A torque-free tumbler's brightness is a Fourier series in two fundamental
frequencies, f_ψ = 1/P_ψ (the mean rotation about L) and f_ω = 1/T_ω (ω's
period in the body): its periodogram shows combinations j f_ψ + k f_ω
(:mod:`jaxlc.inference.two_periods`). The two periods ``jaxlc period``
reports are two of those combinations, and photometry does not say which:

1. :func:`frequency_hypotheses`: every (f_ψ, f_ω) for which the two observed
   frequencies are small combinations (|j| ≤ 2, |k| ≤ 4), simplest first,
   or, with one observed period, each small combination it may be (f_ω free);
2. :func:`tumble_starts`: per hypothesis, bodies drawn with moments from a
   log-uniform box of second-moment ratios (:mod:`jaxlc.inference.tumble_model`)
   and ω in a uniform direction, kept when their T_ω/P_ψ is the hypothesis's
   (within 2 %), scaled to its periods, in a uniform attitude;
3. :func:`tumble_multistart`: one batched Levenberg–Marquardt solve
   (:func:`jaxlc.inference.batched_solve.least_squares`) on the coarse model, the
   distinct optima (periods within 1 %, L within 10°) refined on the exact one.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc.body.attitude import matrix_to_quaternion, quaternion_to_matrix
from jaxlc.errors import JaxlcError
from jaxlc.inference.batched_solve import SolveReport, least_squares
from jaxlc.inference.data import FitData
from jaxlc.inference.harmonics import HarmonicModel, bic, median_step_s
from jaxlc.inference.mcmc import unit_vectors
from jaxlc.inference.search import search_subsamples
from jaxlc.inference.search_starts import greedy_clusters, match_offset
from jaxlc.inference.tumble_model import (
    N_TUMBLE_LM,
    angular_momentum_radec_deg,
    moments_from_ratios,
    motion_invariants,
    state_of,
    theta_of,
    tumble_model,
)
from jaxlc.scene import Scene

#: Box of ln(S_x/S_z), ln(S_y/S_z) the starts are drawn from (second-moment ratios
#: 1/50 … 50: plates, rods and everything between).
LN_MOMENT_RATIO_BOX = (-4.0, 4.0)
#: Largest |j|, |k| of the combinations j f_ψ + k f_ω an observed frequency may be.
MAX_J, MAX_K = 2, 4
#: Relative tolerance of a drawn body's T_ω/P_ψ against a hypothesis's.
RATIO_TOLERANCE = 0.02
#: What one observed frequency may be, j f_ψ + k f_ω: a mirror-symmetric body shows
#: twice its frequencies (a tumbling cylinder over 10 minutes: 2 f_ψ − 2 f_ω alone).
ONE_PERIOD_COMBINATIONS = ((1, 0), (2, 0), (1, -1), (2, -2), (1, 1), (2, 2), (0, 1), (0, 2))
#: Best search optima whose mirror twins (:func:`mirror_twins`) are refined too.
MIRRORED = 2
#: Hypotheses for (f_ψ, f_ω) the starts are spread over (:func:`rank_hypotheses`).
RANKED = 6


@dataclasses.dataclass(frozen=True)
class TumbleMode:
    """A distinct optimum of the tumble fit: LM coordinates, χ², members and what they mean."""

    theta_lm: np.ndarray
    chi2: float
    starts: int
    noise_mag: float
    rate_ref_rad_s: float

    def invariants(self) -> dict:
        inertia, omega, q = state_of(self.theta_lm, self.rate_ref_rad_s)
        inv = {k: v[0] for k, v in motion_invariants(inertia[None], omega[None]).items()}
        ra, dec = angular_momentum_radec_deg(inertia, omega, q)
        return {
            "tumble_mode": "SAM" if inv["sam"] else "LAM",
            "precession_period_s": float(inv["precession_period_s"]),
            "body_period_s": float(inv["body_period_s"]),
            "excitation": float(inv["excitation"]),
            "l_ra_deg": float(ra),
            "l_dec_deg": float(dec),
            "inertia_ratios": (inertia / inertia[2]).tolist(),
            "omega_body_rad_s": omega.tolist(),
            "quaternion": q.tolist(),
        }

    def describe(self, best_chi2: float) -> dict:
        return {
            **self.invariants(),
            "dmag": float(self.theta_lm[9]),
            "chi2": self.chi2,
            "delta_chi2": self.chi2 - best_chi2,
            "noise_mag": self.noise_mag,
            "starts": self.starts,
        }


def frequency_hypotheses(
    f1_hz: float, f2_hz: float | None = None, max_j: int = MAX_J, max_k: int = MAX_K
) -> list[tuple[float, float]]:
    """(f_ψ, f_ω) pairs (Hz) under which the observed frequencies are combinations
    j f_ψ + k f_ω (|j| ≤ ``max_j``, |k| ≤ ``max_k``), simplest first, distinct
    within 1 %.

    With one observed frequency f₁ the second is unknown: (f₁, NaN, j, k) for each
    combination f₁ = j f_ψ + k f_ω of :data:`ONE_PERIOD_COMBINATIONS` (the starts draw
    T_ω/P_ψ and solve for both).
    """
    if f2_hz is None or not math.isfinite(f2_hz):
        return [(f1_hz, math.nan, j, k) for j, k in ONE_PERIOD_COMBINATIONS]
    rows = [
        (j, k)
        for j in range(0, max_j + 1)
        for k in range(-max_k, max_k + 1)
        if (j, k) != (0, 0) and not (j == 0 and k < 0)
    ]
    found = []
    for (j1, k1), (j2, k2) in itertools.permutations(rows, 2):
        det = j1 * k2 - j2 * k1
        if det == 0:
            continue
        f_psi = (f1_hz * k2 - f2_hz * k1) / det
        f_omega = (j1 * f2_hz - j2 * f1_hz) / det
        if f_psi > 0 and f_omega > 0:
            found.append((abs(j1) + abs(k1) + abs(j2) + abs(k2), f_psi, f_omega))
    return [(a, b) for a, b, _c in distinct_pairs([(a, b, c) for c, a, b in sorted(found)], 0.01)]


def distinct_pairs(pairs, tol: float) -> list[tuple[float, float, float]]:
    """(f_ψ, f_ω, score) triples in order, each kept unless both frequencies are within a
    fraction ``tol`` of one kept before."""
    out: list[tuple[float, float, float]] = []
    for a, b, c in pairs:
        if all(abs(math.log(a / x)) > tol or abs(math.log(b / y)) > tol for x, y, _ in out):
            out.append((a, b, c))
    return out


def lattice_frequencies(
    f_psi_hz: float, f_omega_hz: float, lo_hz: float, hi_hz: float, max_j: int = 3, max_k: int = 4
) -> np.ndarray:
    """The positive combinations j f_ψ + k f_ω (0 ≤ j ≤ ``max_j``, |k| ≤ ``max_k``)
    within [lo_hz, hi_hz], each once."""
    j, k = np.meshgrid(np.arange(max_j + 1), np.arange(-max_k, max_k + 1))
    f = (j * f_psi_hz + k * f_omega_hz).ravel()
    f = np.unique(np.round(f[(f >= lo_hz) & (f <= hi_hz)] / (1e-6 * f_omega_hz)))
    return f * 1e-6 * f_omega_hz


def rank_hypotheses(
    t_s: np.ndarray, mag: np.ndarray, weight: np.ndarray, hypotheses, keep: int = RANKED
) -> list[tuple[float, float, float]]:
    """The ``keep`` hypotheses (f_ψ, f_ω) whose two-frequency Fourier series (a quadratic
    trend + :func:`lattice_frequencies`) fits the curve best by BIC, each refined
    (Nelder–Mead on ln f_ψ, ln f_ω) and distinct within 0.5 %: (f_ψ, f_ω, ΔBIC to the
    best) per hypothesis, best first. Hypotheses without f_ω are returned as they are.

    A tumbler's light curve has power only at the lattice of its own two frequencies;
    the lattice of a wrong basis that contains both observed periods misses or adds
    combinations (the shipped SAM tumbler: the truth ranks 4th of 245 before refining).
    """
    from scipy.optimize import minimize

    if any(not math.isfinite(h[1]) for h in hypotheses):
        return list(hypotheses)
    model = HarmonicModel(t_s, mag, weight, [np.arange(len(t_s))], 2)
    span, step = float(np.ptp(t_s)), median_step_s(t_s)
    lo, hi = 1.0 / span, 0.5 / step

    def score(ln_f) -> float:
        fs = lattice_frequencies(math.exp(ln_f[0]), math.exp(ln_f[1]), lo, hi)
        n_params = model.k_trend + 2 * len(fs)
        if n_params > model.n // 3:
            return math.inf
        r = model.residuals_at(fs)
        return bic(float(r @ r), model.n, n_params, model.n)

    start = [np.log(h) for h in hypotheses]
    first = sorted(zip(map(score, start), range(len(start)), strict=True))[: 3 * keep]
    refined = []
    for _s, i in first:
        simplex = start[i] + np.array([[0.0, 0.0], [0.003, 0.0], [0.0, 0.003]])
        options = {"xatol": 1e-4, "fatol": 0.1, "maxiter": 80, "initial_simplex": simplex}
        res = minimize(score, start[i], method="Nelder-Mead", options=options)
        refined.append((*np.exp(res.x), float(res.fun)))
    out = distinct_pairs(sorted(refined, key=lambda r: r[2]), 0.005)
    best = out[0][2]
    return [(a, b, s - best) for a, b, s in out[:keep]]


def body_pool(n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``n`` random tumbling bodies at |ω| = 1 rad/s: moments from
    :data:`LN_MOMENT_RATIO_BOX`, ω in a uniform direction; with their T_ω/P_ψ."""
    ln_s = rng.uniform(*LN_MOMENT_RATIO_BOX, size=(n, 2))
    inertia = moments_from_ratios(ln_s)
    omega = rng.normal(size=(n, 3))
    omega /= np.linalg.norm(omega, axis=1, keepdims=True)
    inv = motion_invariants(inertia, omega)
    ratio = inv["body_period_s"] / inv["precession_period_s"]
    ok = np.isfinite(ratio) & (ratio > 0)
    return {
        "inertia": inertia[ok],
        "omega": omega[ok],
        "body_period_s": inv["body_period_s"][ok],
        "ln_ratio": np.log(ratio[ok]),
    }


def tumble_starts(
    hypotheses, n_starts: int, rng: np.random.Generator, rate_ref_rad_s: float
) -> np.ndarray:
    """(≤ n_starts, 10) LM starts: the hypotheses (f_ψ, f_ω, …) in turn, each a drawn
    body with the hypothesis's T_ω/P_ψ (or, when f_ω is free, any, with both periods
    solved from f₁ = j f_ψ + k f_ω), scaled to its periods, in a uniform attitude; Δm 0."""
    pool = body_pool(max(20 * n_starts, 20000), rng)
    order = np.argsort(pool["ln_ratio"])
    sorted_ratio = pool["ln_ratio"][order]
    starts = []
    for h in np.arange(8 * n_starts) % len(hypotheses):
        if len(starts) == n_starts:
            break
        f_psi, f_omega = hypotheses[h][:2]
        if math.isfinite(f_omega):
            target = math.log(f_psi / f_omega)  # T_ω / P_ψ
            lo, hi = np.searchsorted(sorted_ratio, target + np.array([-1, 1]) * RATIO_TOLERANCE)
            if hi <= lo:
                continue
            k = order[rng.integers(lo, hi)]
        else:  # f₁ = j f_ψ + k f_ω with T_ω/P_ψ = f_ψ/f_ω of a drawn body
            j, kk = hypotheses[h][2:4]
            k = int(rng.integers(len(sorted_ratio)))
            ratio = math.exp(pool["ln_ratio"][k])
            if j + kk / ratio <= 0:
                continue
            f_psi = hypotheses[h][0] / (j + kk / ratio)
            f_omega = f_psi / ratio
        omega = pool["omega"][k] * pool["body_period_s"][k] * f_omega
        q = rng.normal(size=4)
        starts.append(theta_of(pool["inertia"][k], omega, q / np.linalg.norm(q), rate_ref_rad_s))
    if not starts:
        raise JaxlcError(
            "tumble fit: no body with moments in the search box has the periods' ratio "
            "(every hypothesis for the two periods needs a more extreme shape)"
        )
    return np.stack(starts)


def mirror_twins(theta: np.ndarray, data: FitData, rate_ref_rad_s: float) -> np.ndarray:
    """(3K, 10) the mirror images of K states through the Sun–observer plane at the
    middle fitted sample, one per body axis b: R' = M R B (M, B the reflections through
    that plane and through the body plane normal to b), ω' = −B ω (a pseudovector).

    A body mirror-symmetric about a principal plane gives the same light curve in
    both while the Sun–observer plane stays put (a tumbling cylinder over 10 minutes:
    the best mode was the true state's twin, its L 0.1° from the mirror image of the
    true L); these starts put both into the modes, as the spin fit's reversed poles do.
    """
    mid = data.rows[data.n // 2]
    n = np.cross(data.geometry.sun_dir[mid], data.geometry.obs_dir[mid])
    n = n / np.linalg.norm(n)
    m = np.eye(3) - 2.0 * np.outer(n, n)
    inertia, omega, q = state_of(theta, rate_ref_rad_s)
    with jax.enable_x64(True):
        rot = np.asarray(quaternion_to_matrix(jnp.asarray(q, jnp.float64)))
    out = []
    for b in np.eye(3):
        body = np.eye(3) - 2.0 * np.outer(b, b)
        twin = m[None] @ rot @ body[None]
        q_twin = matrix_to_quaternion(twin)
        out.append(theta_of(inertia, -omega @ body.T, q_twin, rate_ref_rad_s, theta[:, 9]))
    return np.concatenate(out)


def distinct_tumbles(
    theta: np.ndarray,
    cost: np.ndarray,
    rate_ref_rad_s: float,
    period_tol: float = 0.01,
    l_tol_deg: float = 10.0,
    max_modes: int = 8,
) -> list[tuple[np.ndarray, float, int]]:
    """Greedy clustering of optima (theta, cost, members), best first: two belong
    together when both periods agree within ``period_tol`` and L within ``l_tol_deg``."""
    inertia, omega, q = state_of(theta, rate_ref_rad_s)
    inv = motion_invariants(inertia, omega)
    ln_p = np.log(np.stack([inv["body_period_s"], inv["precession_period_s"]], axis=1))
    ell = unit_vectors(*angular_momentum_radec_deg(inertia, omega, q))
    return greedy_clusters(theta, cost, ell, ln_p, l_tol_deg, period_tol, max_modes)


def tumble_multistart(
    scene: Scene,
    data: FitData,
    hypotheses,
    rate_ref_rad_s: float,
    n_starts: int = 1024,
    search_samples: int = 256,
    search_steps: int = 20,
    refine_steps: int = 50,
    max_modes: int = 8,
    rng: np.random.Generator | None = None,
    log=None,
) -> tuple[list[TumbleMode], list[SolveReport]]:
    """Coarse-model LM from :func:`tumble_starts`, exact-model refinement of the
    ``max_modes`` best distinct optima (module docstring).

    Returns:
        Distinct modes on the exact model, best (lowest χ²) first, and the solver
        reports of both stages.
    """
    rng = rng or np.random.default_rng(0)
    log = log or (lambda msg: None)
    starts = tumble_starts(hypotheses, n_starts, rng, rate_ref_rad_s)
    fastest = starts[np.argmax(np.linalg.norm(starts[:, 2:5], axis=1))]
    sub = data.stratified_subset(search_samples, rng)
    coarse = tumble_model(
        scene, sub, fastest, rate_ref_rad_s, exact=False, max_subsamples=search_subsamples(scene)
    )
    starts = match_offset(coarse, sub, starts)
    theta, cost, r1 = least_squares(coarse, sub, starts, search_steps, "search")
    log(r1.describe())
    candidates = distinct_tumbles(theta, cost, rate_ref_rad_s, max_modes=max_modes)
    if not candidates:
        raise JaxlcError(
            f"tumble fit: no search solve gave a finite fit ({r1.describe()}); check the "
            "light curve and geometry"
        )
    init = np.stack([c[0] for c in candidates])
    members = [c[2] for c in candidates]
    twins = mirror_twins(init[:MIRRORED], data, rate_ref_rad_s)
    init = np.concatenate([init, twins])
    members += [0] * len(twins)  # started from no search solve
    plan = init[np.argmax(np.linalg.norm(init[:, 2:5], axis=1))]
    exact = tumble_model(scene, data, plan, rate_ref_rad_s, exact=True)
    refined, rcost, r2 = least_squares(exact, data, init, refine_steps, "refine")
    log(r2.describe())
    no_errors = np.all(data.mag_err == 0)
    # Refinement can land two starts (a state and its twin) on one optimum: merge again.
    merged = distinct_tumbles(refined, rcost, rate_ref_rad_s, max_modes=max_modes + MIRRORED)
    starts_of = {th.tobytes(): k for th, k in zip(refined, members, strict=True)}
    modes = [
        TumbleMode(
            theta_lm=th,
            chi2=float(c),
            starts=starts_of[th.tobytes()],
            noise_mag=math.sqrt(c / max(data.n - N_TUMBLE_LM, 1)) if no_errors else 0.0,
            rate_ref_rad_s=rate_ref_rad_s,
        )
        for th, c, _n in merged
    ]
    if not modes:
        raise JaxlcError(f"tumble fit: every refined solve failed ({r2.describe()})")
    return sorted(modes, key=lambda m: m.chi2), [r1, r2]

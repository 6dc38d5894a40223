"""A second period: the two frequencies of a tumbling body's light curve, or "one period".

A body tumbling torque-free turns about its angular momentum with one period
and nutates with another (:mod:`jaxlc.body.tumble`): its brightness is a
two-dimensional Fourier series in two fundamental frequencies f₁, f₂, with
power at the combinations j f₁ + k f₂ (Kaasalainen 2001; Pravec et al. 2005).
After the one-period analysis (:func:`jaxlc.inference.period.analyse_period`)
found its best frequency f₁ (reported or not), :func:`second_period`

1. builds the one-period models a second period must beat: f₁'s series with as
   many harmonics as BIC takes (a glinting body's aliased high harmonics are
   one period), the periods 2–4 × 1/f₁ likewise, f₁'s series with coefficients
   drifting linearly over the span (a shape that changes with the phase
   angle), and the trend alone when f₁ was not significant;
2. takes the periodogram of the first model's residuals; each strong peak f_r
   at least :data:`SEPARATION`/T from every harmonic of f₁ and its alias gives
   the candidates f₂ = f_r and f_r / 2 (two maxima per turn), kept if p f₁ and
   q f₂ (p, q ≤ 4) stay that far apart and the span holds
   :data:`MIN_CYCLES` cycles of 1/f₂;
3. fits the trend + the series of combinations {j f₁ : 1 ≤ j ≤ H₁} ∪
   {j f₁ + k f₂ : 1 ≤ k ≤ K, |j| ≤ J} (K, J by BIC; f₂, and f₁ when it was not
   significant, refined);
4. reports f₂ when the best pair beats every one-period model by ΔBIC >
   ``bic_threshold`` (the samples its residuals are worth), the residual
   periodogram's peak is unlikely under block-shuffled residuals (FAP <
   ``fap_threshold``), and it explains at least :data:`MIN_EXPLAINED` of what
   the best one-period model leaves.

The pair (f₁, f₂) is one basis of the lattice of combination frequencies;
(f₁, f₂ − f₁) is another, and a body with two maxima per turn shows 2 f where
the motion has f. Photometry alone does not say which basis is the precession
and the rotation: the two strongest (the periodogram's, then its residuals')
are reported as found; a simulated SAM tumbler gave P_ψ and T_ω / 2.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from jaxlc.inference import periodogram
from jaxlc.inference.harmonics import (
    MAX_HARMONICS,
    HarmonicModel,
    bic,
    effective_samples,
    median_step_s,
)

#: (K, J) of the combination series tried: harmonics of f₂ up to K, each with
#: sidebands j f₁ for |j| ≤ J.
TERM_SETS = ((1, 0), (2, 0), (3, 0), (1, 1), (2, 1), (2, 2), (4, 2))
#: Residual periodogram peaks tried.
N_PEAKS = 5
#: Largest p, q of a ratio p/q of f₂ to f₁ that counts as one period.
MAX_RATIO = 4
#: Resolution elements 1/T by which a second frequency must stand apart from the
#: first's harmonics, their aliases and p/q multiples (a light curve whose shape
#: changes over a pass has sidebands within about 2/T).
SEPARATION = 3.0
#: Least share of the best one-period model's residual sum of squares that a second
#: period must explain: a tumble's second period carries much of the light curve, while
#: a weak second frequency is more often a shape changing over the pass, a glint the
#: series misses or red noise (real tracks MMT calls periodic: 8 % and 28 %; a
#: simulated SAM tumbler: 98 %).
MIN_EXPLAINED = 0.5
#: Cycles of each period the span must hold (a slow change of shape over a pass
#: looks like one or two cycles of a long period).
MIN_CYCLES = 4.0
NAN = float("nan")


@dataclasses.dataclass(frozen=True)
class SecondPeriod:
    """The outcome of :func:`second_period` (NaN period: none found)."""

    first_period_s: float
    period_s: float
    best_period_s: float
    delta_bic: float
    false_alarm_probability: float
    n_frequencies: int
    n_effective: float
    decision: str


def combination_frequencies(f1_hz: float, h1: int, f2_hz: float, k: int, j: int) -> np.ndarray:
    """The series' frequencies (Hz): j f₁ for 1 ≤ j ≤ h1, and j f₁ + k f₂ for
    1 ≤ k' ≤ k, |j'| ≤ j, the positive ones, each once (to a millionth of f₂)."""
    out = [jj * f1_hz for jj in range(1, h1 + 1)]
    for kk in range(1, k + 1):
        out += [jj * f1_hz + kk * f2_hz for jj in range(-j, j + 1)]
    out = np.asarray(sorted(f for f in out if f > 1e-6 * f2_hz))
    keep = np.r_[True, np.diff(out) > 1e-6 * f2_hz]
    return out[keep]


def lattice_combination(
    f_hz: float, f1_hz: float, f2_hz: float, tol_hz: float, order: int = 6
) -> tuple[int, int] | None:
    """Which combination j f₁ + k f₂ a frequency is: the (j, k) of smallest |j| + |k|
    (≤ ``order`` each, not both 0) within ``tol_hz`` (e.g. the resolution 1/T), or None.

    Example:
        >>> lattice_combination(1 / 67.48, 1 / 47.98, 1 / 166.06, 1 / 1200)  # (1, -1)
    """
    pairs = sorted(
        (abs(j) + abs(k), j, k)
        for j in range(-order, order + 1)
        for k in range(-order, order + 1)
        if j or k
    )
    near = (jk for _, *jk in pairs if abs(jk[0] * f1_hz + jk[1] * f2_hz - f_hz) <= tol_hz)
    found = next(near, None)
    return None if found is None else (int(found[0]), int(found[1]))


def _degenerate(f1: float, f2: float, resolution_hz: float) -> bool:
    """Whether q f₂ ≈ p f₁ (p, q ≤ :data:`MAX_RATIO`) within the resolution 1/T: then
    the pair is one period (or two the span cannot tell apart)."""
    return any(
        abs(q * f2 - p * f1) < resolution_hz
        for p in range(1, MAX_RATIO + 1)
        for q in range(1, MAX_RATIO + 1)
    )


def second_period(
    model: HarmonicModel,
    grid: periodogram.Grid,
    t_s: np.ndarray,
    dy,
    weight: np.ndarray,
    f1_hz: float,
    periodic: bool,
    p_min_s: float,
    p_max_s: float,
    bic_threshold: float,
    fap_threshold: float,
    n_permutations: int,
    rng: np.random.Generator,
) -> SecondPeriod:
    """Two fundamental periods of a light curve, or "one period" (module docstring).

    Args:
        model: the analysis's trend + series model; grid: its periodogram grid.
        t_s, dy, weight: its (N,) samples' times, errors (or None) and weights.
        f1_hz: the one-period analysis's best frequency.
        periodic: whether that analysis reported it (else f₁ is refined too, and
            two periods must beat the trend alone as well).
        p_min_s, p_max_s: the periods searched (s).
        bic_threshold, fap_threshold: the evidence a second period needs.
        n_permutations, rng: the block shuffles of the false-alarm probability.
    """
    df, resolution = grid.df_hz, 1.0 / grid.span_s
    lo, hi = max(1.0 / p_max_s, MIN_CYCLES * resolution), 1.0 / p_min_s
    cap = min(model.max_harmonics(), MAX_HARMONICS)

    def fit(f1, h1, f2, k, j):
        """(residuals, parameters) of the combination series, or None if too big."""
        fs = combination_frequencies(f1, h1, f2, k, j)
        n_params = model.k_trend + len(model.groups) * 2 * len(fs)
        if n_params > model.n // 3:
            return None
        return model.residuals_at(fs), n_params

    def score(f1, h1, f2, k, j):  # BIC with every sample counted (rescored below)
        got = fit(f1, h1, f2, k, j)
        return math.inf if got is None else bic(float(got[0] @ got[0]), model.n, got[1], model.n)

    # The one-period models to beat: f₁ with as many harmonics as BIC takes (aliased
    # high harmonics of a glinting body are one period, not two); the periods 2–4 × 1/f₁
    # likewise (their harmonics are the p/q multiples of f₁); and f₁'s series with
    # coefficients drifting over the span (the sidebands of a shape that changes with
    # the phase angle).
    def one(f, hs):
        return min((bic(model.rss(f, h), model.n, model.n_params(h), model.n), h) for h in hs)

    h1 = one(f1_hz, range(1, cap + 1))[1]
    resid_one = model.residuals(f1_hz, h1)
    baselines = [(float(resid_one @ resid_one), model.n_params(h1))]
    for m in range(2, MAX_RATIO + 1):
        if m <= cap:
            h = one(f1_hz / m, range(m, cap + 1))[1]
            baselines.append((model.rss(f1_hz / m, h), model.n_params(h)))
    drift = model.residuals_at(f1_hz * np.arange(1, h1 + 1), modulated=True)
    baselines.append((float(drift @ drift), model.n_params(2 * h1)))
    if not periodic:
        baselines.append((model.rss_trend, model.k_trend))
    resid_mag = resid_one / np.sqrt(weight)
    pw = periodogram.power(t_s, resid_mag, dy, grid)
    sampling_hz = 1.0 / median_step_s(t_s)
    harmonics_hz = [abs(m * f1_hz - n * sampling_hz) for m in range(1, h1 + 2) for n in (0, 1)]
    best = (math.inf, None)
    for f_r in grid.frequency_hz[periodogram.local_peaks(pw, N_PEAKS, 10)]:
        if min(abs(f_r - e) for e in harmonics_hz) < SEPARATION * resolution:
            continue  # a harmonic of f₁, its alias or a sideband of either
        for f2 in (f_r, f_r / 2):
            if not lo <= f2 <= hi or _degenerate(f1_hz, f2, SEPARATION * resolution):
                continue
            f1 = f1_hz
            f2 = _refine(lambda f, f1=f1: score(f1, h1, f, 2, 1), f2, df)
            if not periodic:
                f1 = _refine(lambda f, f2=f2: score(f, h1, f2, 2, 1), f1, df)
            for k, j in TERM_SETS:
                s = score(f1, h1, f2, k, j)
                if s < best[0]:
                    best = (s, (f1, f2, k, j))
    if best[1] is None:
        return SecondPeriod(NAN, NAN, NAN, 0.0, 1.0, 0, NAN, "no second period to try")
    f1, f2, k, j = best[1]
    resid, n_params = fit(f1, h1, f2, k, j)
    # both models judged with the samples the two-period residuals are worth
    n_eff, _ = effective_samples(resid, t_s, model.groups, median_step_s(t_s))
    delta = min(bic(rss, model.n, kk, n_eff) for rss, kk in baselines) - bic(
        float(resid @ resid), model.n, n_params, n_eff
    )
    # the share of what the best one-period model leaves that the second period explains
    explained = min(1.0 - float(resid @ resid) / rss for rss, _ in baselines)
    fap = 1.0  # the shuffles only where the rest of the evidence holds (they cost most)
    if delta > bic_threshold and explained >= MIN_EXPLAINED:
        fap, _, _ = periodogram.permutation_fap(
            t_s, resid_mag, dy, grid, n_permutations, rng=rng, decide_at=fap_threshold
        )
    p1, p2 = 1.0 / f1, 1.0 / f2
    n_f = len(combination_frequencies(f1, h1, f2, k, j))
    found = delta > bic_threshold and fap < fap_threshold and explained >= MIN_EXPLAINED
    evidence = (
        f"ΔBIC {delta:.1f} over one period, {100 * max(explained, 0):.0f} % of the one-period "
        "residuals explained" + (f", FAP {fap:.2g}" if fap < 1.0 else "")
    )
    if found:
        text = (
            f"two periods: {p1:.6g} s and {p2:.6g} s ({evidence}; {n_f} frequencies "
            "j/P₁ + k/P₂), as a tumbling body's"
        )
    else:
        text = (
            f"no second period (best pair {p1:.5g} s and {p2:.5g} s: {evidence}; needs "
            f"ΔBIC > {bic_threshold:g}, FAP < {fap_threshold:g} and ≥ "
            f"{100 * MIN_EXPLAINED:.0f} %)"
        )
    return SecondPeriod(
        first_period_s=p1,
        period_s=p2 if found else NAN,
        best_period_s=p2,
        delta_bic=float(delta),
        false_alarm_probability=float(fap),
        n_frequencies=n_f,
        n_effective=float(n_eff),
        decision=text,
    )


def _refine(cost, f0: float, df: float) -> float:
    """Frequency of least ``cost`` within ±df of f0: a 9-point scan, then golden section."""
    grid = np.linspace(f0 - df, f0 + df, 9)
    grid = grid[grid > 0]
    k = int(np.argmin([cost(f) for f in grid]))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    g = (math.sqrt(5) - 1) / 2
    for _ in range(12):
        c, d = b - g * (b - a), a + g * (b - a)
        if cost(c) < cost(d):
            b = d
        else:
            a = c
    return 0.5 * (a + b)

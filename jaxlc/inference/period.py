"""Period analysis: a spin period that holds on real data, or "no period".

Steps (:func:`analyse_period`):

1. **Trend.** A slow polynomial in time (per sample group) is removed:
   phase-angle and range changes over a pass are not rotation.
2. **Periodogram.** Lomb–Scargle of the detrended magnitudes on a bounded
   grid (:mod:`jaxlc.inference.periodogram`), shortest period 2.5 sampling
   steps, longest half the span (at least two cycles seen).
3. **Candidates.** A body with m maxima per turn puts the periodogram peak
   at P/m; glinting bodies need m up to 4. The spin-period candidates are
   1–4 × each of the strongest peaks (aliases included), each refined and
   scored by a trend + Fourier-series fit (:mod:`jaxlc.inference.harmonics`)
   with its number of harmonics chosen by BIC, the sample count replaced by
   an effective one for red noise. A multiple m > 1 must beat the others by
   ΔBIC > :data:`BIC_THRESHOLD`: two identical halves (a symmetric body)
   cannot be told from one, and the simpler answer is kept — with the
   double as ``alternative_period_s``.
4. **Significance.** A period is reported only when the best candidate
   beats the trend-only model by ΔBIC > :data:`BIC_THRESHOLD` *and* the
   periodogram maximum is unlikely under block-shuffled residuals
   (:func:`jaxlc.inference.periodogram.permutation_fap` <
   :data:`FAP_THRESHOLD`). Otherwise ``period_s`` is NaN (``null`` in
   JSON) and ``verdict`` says whether the curve varies at all (von Neumann
   test of the residuals against white noise).
5. **A second period.** With a period found, its residuals are searched for a
   second fundamental frequency by the same evidence
   (:mod:`jaxlc.inference.two_periods`): a tumbling body's light curve has
   two; ``second_period_s`` is NaN when it shows one.

Example:
    >>> result = analyse_period(t_s, mag)
    >>> result.verdict, result.period_s, result.alternative_period_s
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from jaxlc.errors import JaxlcError
from jaxlc.inference import periodogram
from jaxlc.inference.harmonics import (
    Candidate,
    HarmonicModel,
    bic,
    effective_samples,
    median_step_s,
    spin_candidates,
    von_neumann_p,
)
from jaxlc.inference.period_result import NAN, PeriodResult, format_p
from jaxlc.inference.two_periods import second_period

#: ΔBIC (effective samples) a period must gain over the trend, and a multiple over the peak.
BIC_THRESHOLD = 10.0
#: Largest block-permutation false-alarm probability of a reported period.
FAP_THRESHOLD = 0.01
#: p-value of the von Neumann test below which a curve counts as variable.
VARIABLE_P_THRESHOLD = 1e-3
#: Residual scatter (mag) below which a curve is constant (noise-free or flat).
CONSTANT_MAG = 1e-6
#: Most samples analysed: longer curves are analysed on a random subset this large
#: (sorted in time), which keeps time and memory bounded whatever the input.
MAX_SAMPLES = 20_000
#: Periodogram peaks whose multiples are candidates.
N_PEAKS = 5


def _clean(t_s, mag, mag_err):
    t = np.asarray(t_s, dtype=np.float64)
    y = np.asarray(mag, dtype=np.float64)
    if t.shape != y.shape or t.ndim != 1:
        raise JaxlcError(f"t_s and mag must be 1-D of one length, got {t.shape} and {y.shape}")
    ok = np.isfinite(t) & np.isfinite(y)
    dy = None
    if mag_err is not None:
        dy = np.asarray(mag_err, dtype=np.float64)
        if dy.shape != t.shape:
            raise JaxlcError(f"mag_err must have the shape of mag {t.shape}, got {dy.shape}")
        ok &= np.isfinite(dy) & (dy > 0)
    if np.count_nonzero(ok) < 10:
        bad_err = "" if dy is None else f" ({int(np.sum(~(np.isfinite(dy) & (dy > 0))))} with "
        bad_err += "" if dy is None else "a non-finite or non-positive mag_err)"
        raise JaxlcError(
            f"period analysis needs at least 10 finite samples, got {np.count_nonzero(ok)}"
            + bad_err
        )
    order = np.argsort(t[ok], kind="stable")
    t, y = t[ok][order], y[ok][order]
    dy = None if dy is None else dy[ok][order]
    step = median_step_s(t)
    if step <= 0:
        raise JaxlcError("period analysis: all samples at one time")
    return t, y, dy, step


def _score(c: Candidate, n: int, n_eff: float) -> float:
    return bic(c.rss, n, c.n_params, n_eff) + (BIC_THRESHOLD if c.multiple > 1 else 0.0)


def analyse_period(
    t_s,
    mag,
    mag_err=None,
    min_period_s: float | None = None,
    max_period_s: float | None = None,
    detrend_degree: int = 2,
    samples_per_peak: float = 10.0,
    n_permutations: int = 300,
    seed: int = 0,
    catalogue_period_s: float = NAN,
    two_periods: bool = True,
) -> PeriodResult:
    """Spin period with its evidence, or "no period" when the data do not support one.

    Args:
        t_s: (N,) sample times in seconds (visible samples only).
        mag: (N,) magnitudes.
        mag_err: (N,) 1σ errors in mag, or None (equal weights; the noise
            level is profiled out either way, the errors only weight).
        min_period_s: shortest period searched (default: 2.5 × the median
            sampling step, never below Nyquist).
        max_period_s: longest periodogram period (default and ceiling: half
            the span, or of the longest run when the span is cut into runs).
        detrend_degree: degree of the polynomial trend in time (0 or −1: the mean only).
        samples_per_peak: periodogram oversampling.
        n_permutations: most block shuffles for the false-alarm probability (≥ 30;
            fewer are run when the answer is clear 10× either side of the threshold).
        seed: random seed of the shuffles.
        catalogue_period_s: a period from elsewhere (e.g. the MMT header),
            only carried into the result for comparison.
        two_periods: when a period is found, look for a second one in its
            residuals (a tumbling body's; :mod:`jaxlc.inference.two_periods`).

    Returns:
        A :class:`PeriodResult`.
    """
    t, y, dy, step = _clean(t_s, mag, mag_err)
    n_all = len(t)
    if n_all > MAX_SAMPLES:
        pick = np.sort(np.random.default_rng(seed).choice(n_all, MAX_SAMPLES, replace=False))
        t, y = t[pick], y[pick]
        dy = None if dy is None else dy[pick]
    # neighbours for the red-noise and variability statistics: the analysed samples' step
    near_s = median_step_s(t)
    if n_permutations < periodogram.MIN_PERMUTATIONS:
        raise JaxlcError(
            f"n_permutations = {n_permutations}: at least {periodogram.MIN_PERMUTATIONS} "
            "shuffles are needed for a false-alarm probability"
        )
    if detrend_degree < -1:
        raise JaxlcError(f"detrend_degree = {detrend_degree} must be ≥ −1 (−1 or 0: the mean)")
    span = float(t[-1] - t[0])
    p_min = 2.5 * step if min_period_s is None else float(min_period_s)
    grid = periodogram.plan_grid(t, p_min, max_period_s, samples_per_peak)
    p_max_spin = grid.span_s / 2  # at least two cycles of any spin period
    p_max = min(p_max_spin, max_period_s or p_max_spin)
    keep = np.concatenate(grid.groups)
    groups = _reindex(grid.groups)
    t, y = t[keep], y[keep]
    dy = None if dy is None else dy[keep]
    grid = dataclasses.replace(grid, groups=tuple(groups))
    w = np.ones_like(t) if dy is None else 1.0 / dy**2
    model = HarmonicModel(t, y, w, groups, max(detrend_degree, 0))
    r0 = model.residuals(0.0, 0)
    scatter = float(np.std(r0 / np.sqrt(w)))
    common = dict(
        n_samples=len(t),
        subsampled_from=n_all if n_all > MAX_SAMPLES else 0,
        span_s=span,
        min_period_s=p_min,
        max_period_s=p_max,
        n_groups=len(groups),
        catalogue_period_s=float(catalogue_period_s),
    )
    if scatter < CONSTANT_MAG:
        return _no_period(
            "not variable",
            f"constant: the residual scatter after the trend is {scatter:.1e} mag",
            **common,
        )
    resid_mag = r0 / np.sqrt(w)
    freq = grid.frequency_hz
    pw = periodogram.power(t, resid_mag, dy, grid)
    peaks = periodogram.local_peaks(pw, N_PEAKS, max(int(samples_per_peak), 1))
    peaks_hz = freq[peaks]
    cands = spin_candidates(model, peaks_hz, grid.df_hz, p_min, p_max)
    if not cands:
        var_p = von_neumann_p(r0, t, groups, near_s)
        return _no_period(
            "aperiodic" if var_p < VARIABLE_P_THRESHOLD else "not variable",
            "too few samples for any candidate period (a third of each run's samples "
            "must outnumber the series' parameters)",
            variability_p=var_p,
            **common,
        )
    raw_best = min(cands, key=lambda c: _score(c, model.n, model.n))
    n_eff, rho = effective_samples(
        model.residuals(raw_best.frequency_hz, raw_best.n_harmonics), t, groups, near_s
    )
    ranked = sorted(cands, key=lambda c: _score(c, model.n, n_eff))
    best = ranked[0]
    bic0 = bic(model.rss_trend, model.n, model.k_trend, n_eff)
    delta_bic = bic0 - bic(best.rss, model.n, best.n_params, n_eff)
    fap, fap_emp, n_shuffles = periodogram.permutation_fap(
        t,
        resid_mag,
        dy,
        grid,
        n_permutations,
        rng=np.random.default_rng(seed),
        decide_at=FAP_THRESHOLD,
    )
    fap_white = periodogram.baluev_fap(t, resid_mag, dy, grid, float(np.max(pw)))
    var_p = von_neumann_p(r0, t, groups, near_s)
    periodic = delta_bic > BIC_THRESHOLD and fap < FAP_THRESHOLD
    variable = periodic or var_p < VARIABLE_P_THRESHOLD
    f_err = model.frequency_error(best.frequency_hz, best.n_harmonics, n_eff)
    alternative = next(
        (c.period_s for c in ranked if abs(c.period_s / best.period_s - 1) > 0.01), float("nan")
    )
    fitted = model.fitted(best.frequency_hz, best.n_harmonics)
    trend = model.fitted(0.0, 0)
    decision = _decision(best, periodic, variable, delta_bic, fap, var_p, alternative)
    verdict = "periodic" if periodic else ("aperiodic" if variable else "not variable")
    period_s = best.period_s if periodic else NAN
    second = {}
    if variable and two_periods:
        found = second_period(
            model, grid, t, dy, w, best.frequency_hz, periodic, p_min, p_max,
            BIC_THRESHOLD, FAP_THRESHOLD, n_permutations, np.random.default_rng(seed + 1),
        )  # fmt: skip
        if math.isfinite(found.period_s):
            verdict, decision, period_s = "two periods", found.decision, found.first_period_s
        elif periodic:
            decision += f"; {found.decision}"
        second = dict(
            second_period_s=found.period_s,
            second_best_period_s=found.best_period_s,
            second_delta_bic=found.delta_bic,
            second_false_alarm_probability=found.false_alarm_probability,
        )
    s_best = _score(best, model.n, n_eff)
    return PeriodResult(
        verdict=verdict,
        variable=bool(variable),
        period_s=period_s,
        period_err_s=f_err / best.frequency_hz**2 if periodic else float("nan"),
        best_period_s=best.period_s,
        harmonic_factor=best.multiple,
        n_harmonics=best.n_harmonics,
        alternative_period_s=alternative,
        ls_period_s=float(1.0 / freq[peaks[0]]),
        ls_power=float(pw[peaks[0]]),
        false_alarm_probability=fap,
        false_alarm_probability_empirical=fap_emp,
        false_alarm_probability_white=fap_white,
        shuffles=n_shuffles,
        delta_bic=float(delta_bic),
        variability_p=var_p,
        effective_samples=n_eff,
        red_noise_rho=rho,
        cycles=float(grid.span_s / best.period_s),
        amplitude_mag=float(np.ptp(fitted - trend)),
        decision=decision,
        candidates=tuple(
            {
                "period_s": c.period_s,
                "multiple": c.multiple,
                "peak_period_s": c.peak_period_s,
                "n_harmonics": c.n_harmonics,
                "delta_score": _score(c, model.n, n_eff) - s_best,
            }
            for c in ranked[:8]
        ),
        frequency_hz=freq,
        power=pw,
        sample_t_s=t,
        sample_mag=y,
        model_mag=fitted,
        trend_mag=trend,
        **second,
        **common,
    )


def _reindex(groups) -> list[np.ndarray]:
    """The groups' indices after the dropped samples are removed (kept in order)."""
    out, pos = [], 0
    for g in groups:
        out.append(np.arange(pos, pos + len(g)))
        pos += len(g)
    return out


def _no_period(verdict: str, why: str, **common) -> PeriodResult:
    return PeriodResult(
        verdict=verdict,
        variable=verdict != "not variable",
        decision=f"no period: {why}",
        frequency_hz=np.zeros(0),
        power=np.zeros(0),
        **common,
    )


def _decision(best, periodic, variable, delta_bic, fap, var_p, alternative) -> str:
    evidence = f"ΔBIC {delta_bic:.1f} over the trend, block-shuffle FAP {format_p(fap)}"
    if periodic:
        how = (
            "the periodogram peak"
            if best.multiple == 1
            else f"{best.multiple} × the periodogram peak {best.peak_period_s:.5g} s"
        )
        text = (
            f"spin period {best.period_s:.6g} s = {how} ({evidence}; {best.n_harmonics} "
            f"harmonic{'s' if best.n_harmonics > 1 else ''})"
        )
        if math.isfinite(alternative):
            text += f"; next best {alternative:.5g} s"
        if best.multiple == 1:
            text += (
                f" — a body with two identical maxima per turn would spin in "
                f"{2 * best.period_s:.5g} s"
            )
        return text
    if variable:
        return (
            f"no period: the curve varies (von Neumann p = {format_p(var_p)}) but no period "
            f"is significant (best {best.period_s:.5g} s: {evidence}; needs ΔBIC > "
            f"{BIC_THRESHOLD:g} and FAP < {FAP_THRESHOLD:g})"
        )
    return (
        f"no period: not variable beyond noise and trend (von Neumann p = {format_p(var_p)}; "
        f"best {best.period_s:.5g} s: {evidence})"
    )

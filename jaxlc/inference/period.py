"""Period analysis: Lomb–Scargle, false-alarm probability and the P vs 2P decision.

A rotating body usually shows two maxima per turn (its cross-section peaks
twice), so the periodogram peaks at *half* the spin period. The decision
between the periodogram period P_ls and 2 P_ls is made from the data:

* **odd harmonics** — a Fourier series with the fundamental 1/(2 P_ls) and
  its harmonics against one with the harmonics of 1/P_ls only; the odd
  harmonics are what distinguishes the two halves of a turn. Compared by BIC
  (ΔBIC = BIC(P_ls) − BIC(2 P_ls); > 10 is strong evidence for 2 P_ls) and an
  F-test p-value.
* **halves** — the curve folded at 2 P_ls, binned in phase; the first half
  against the second (χ² of the bin differences per degree of freedom and
  its p-value).

``alternative_period_s`` is the other candidate (2 P_ls when the
decision is P_ls, P_ls when it is 2 P_ls). ``harmonic_factor`` is 2 when
both say the halves differ (ΔBIC > 10 and the halves' p < 0.01), 1
otherwise — then the object may still turn in 2 P_ls with two identical
halves, which photometry cannot tell apart, and the summary says so.

Example:
    >>> result = analyse_period(t_s, mag)
    >>> result.period_s, result.harmonic_factor
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from jaxlc.errors import JaxlcError

#: ΔBIC above which the odd harmonics (a 2 P_ls period) count as detected.
BIC_THRESHOLD = 10.0
#: p-value below which the two halves of the 2 P_ls fold count as different.
HALVES_P_THRESHOLD = 0.01


@dataclasses.dataclass(frozen=True)
class PeriodResult:
    """The outcome of :func:`analyse_period` (seconds, magnitudes; ``min_period_s`` and
    ``max_period_s``: the range searched)."""

    period_s: float
    ls_period_s: float
    ls_period_err_s: float
    false_alarm_probability: float
    harmonic_factor: int
    ls_power: float
    delta_bic: float
    odd_harmonics_p: float
    halves_chi2_per_dof: float
    halves_p: float
    amplitude_mag: float
    n_samples: int
    span_s: float
    min_period_s: float
    max_period_s: float
    decision: str
    alternative_period_s: float
    frequency_hz: np.ndarray = dataclasses.field(repr=False)
    power: np.ndarray = dataclasses.field(repr=False)
    catalogue_period_s: float = float("nan")

    def summary(self) -> dict:
        """JSON-ready dict (arrays left out)."""
        d = {
            k: v for k, v in dataclasses.asdict(self).items() if k not in ("frequency_hz", "power")
        }
        for k, v in d.items():
            if isinstance(v, float) and not math.isfinite(v):
                d[k] = None
        return d


def _detrend(t: np.ndarray, y: np.ndarray, degree: int) -> np.ndarray:
    """Remove a slow polynomial trend in time (phase-angle and range changes)."""
    if degree < 0:
        return y - np.mean(y)
    x = (t - t.mean()) / max(np.ptp(t), 1e-9)
    coef = np.polynomial.polynomial.polyfit(x, y, degree)
    return y - np.polynomial.polynomial.polyval(x, coef)


def fourier_design(t: np.ndarray, frequency_hz: float, harmonics) -> np.ndarray:
    """Design matrix (N, 1 + 2 K): a constant, cos and sin of each harmonic k·f."""
    cols = [np.ones_like(t)]
    for k in harmonics:
        w = 2 * np.pi * k * frequency_hz * t
        cols += [np.cos(w), np.sin(w)]
    return np.stack(cols, axis=1)


def _fit(a: np.ndarray, y: np.ndarray, w: np.ndarray) -> float:
    """Weighted residual sum of squares of a linear least-squares fit."""
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(a * sw[:, None], y * sw, rcond=None)
    r = (y - a @ coef) * sw
    return float(r @ r)


def odd_harmonic_test(t, y, w, ls_period_s: float, n_harmonics: int = 4) -> tuple[float, float]:
    """(ΔBIC, F-test p) for odd harmonics of 1/(2 P_ls) beyond the harmonics of 1/P_ls.

    The null model has harmonics 1..K of 1/P_ls (i.e. 2, 4, .., 2K of
    1/(2 P_ls)); the alternative adds the odd ones 1, 3, .., 2K − 1.
    """
    n = len(t)
    f2 = 0.5 / ls_period_s
    even = [2 * k for k in range(1, n_harmonics + 1)]
    both = list(range(1, 2 * n_harmonics + 1))
    rss0 = _fit(fourier_design(t, f2, even), y, w)
    rss1 = _fit(fourier_design(t, f2, both), y, w)
    k0, k1 = 1 + 2 * len(even), 1 + 2 * len(both)
    rss1 = max(rss1, 1e-300)
    # Gaussian likelihood with the noise level profiled out.
    bic0 = n * math.log(rss0 / n) + k0 * math.log(n)
    bic1 = n * math.log(rss1 / n) + k1 * math.log(n)
    dof = n - k1
    f_stat = ((rss0 - rss1) / (k1 - k0)) / (rss1 / dof) if dof > 0 else 0.0
    from scipy import stats  # here, not at import: it costs ~0.4 s of `import jaxlc`

    p = float(stats.f.sf(f_stat, k1 - k0, dof)) if dof > 0 else 1.0
    return bic0 - bic1, p


def halves_test(t, y, sigma, period_s: float, bins: int = 20) -> tuple[float, float]:
    """(χ²/dof, p) of the difference between the two halves of a fold at ``period_s``."""
    phase = np.mod(t / period_s, 1.0)
    half = bins // 2
    idx = np.minimum((phase * bins).astype(int), bins - 1)
    mean = np.full(bins, np.nan)
    err = np.full(bins, np.nan)
    for b in range(bins):
        m = idx == b
        if np.count_nonzero(m) >= 2:
            mean[b] = np.mean(y[m])
            # scatter within the bin includes the curve's own slope: a conservative error
            err[b] = max(np.std(y[m], ddof=1), np.median(sigma[m])) / math.sqrt(np.count_nonzero(m))
    d = mean[:half] - mean[half:]
    e2 = err[:half] ** 2 + err[half:] ** 2
    ok = np.isfinite(d) & np.isfinite(e2) & (e2 > 0)
    if np.count_nonzero(ok) < 3:
        return float("nan"), float("nan")
    chi2 = float(np.sum(d[ok] ** 2 / e2[ok]))
    dof = int(np.count_nonzero(ok))
    from scipy import stats

    return chi2 / dof, float(stats.chi2.sf(chi2, dof))


def analyse_period(
    t_s,
    mag,
    mag_err=None,
    min_period_s: float | None = None,
    max_period_s: float | None = None,
    detrend_degree: int = 2,
    samples_per_peak: int = 20,
    catalogue_period_s: float = float("nan"),
) -> PeriodResult:
    """Lomb–Scargle period with its false-alarm probability and the P vs 2P decision.

    Args:
        t_s: (N,) sample times in seconds (visible samples only).
        mag: (N,) magnitudes.
        mag_err: (N,) 1σ errors in mag, or None (then equal weights and the
            noise is estimated from the fit residuals).
        min_period_s: shortest period searched (default: 2.5 × the median
            sampling step, i.e. below Nyquist is never tried).
        max_period_s: longest period searched (default: the span / 2, so at
            least two cycles are seen).
        detrend_degree: polynomial degree of a slow trend removed first
            (−1: only the mean).
        samples_per_peak: periodogram oversampling.
        catalogue_period_s: a period from elsewhere (e.g. the MMT header),
            only carried into the result for comparison.

    Returns:
        A :class:`PeriodResult`.
    """
    from astropy.timeseries import LombScargle

    t = np.asarray(t_s, dtype=np.float64)
    y = np.asarray(mag, dtype=np.float64)
    if t.shape != y.shape or t.ndim != 1:
        raise JaxlcError(f"t_s and mag must be 1-D of one length, got {t.shape} and {y.shape}")
    ok = np.isfinite(t) & np.isfinite(y)
    if mag_err is not None:
        dy_all = np.asarray(mag_err, dtype=np.float64)
        ok &= np.isfinite(dy_all) & (dy_all > 0)
    t, y = t[ok], y[ok]
    dy = None if mag_err is None else dy_all[ok]
    if len(t) < 10:
        raise JaxlcError(f"period analysis needs at least 10 finite samples, got {len(t)}")
    order = np.argsort(t)
    t, y = t[order], y[order]
    dy = None if dy is None else dy[order]
    span = float(t[-1] - t[0])
    steps = np.diff(t)
    step = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 0.0
    if span <= 0 or step <= 0:
        raise JaxlcError("period analysis: all samples at one time")
    p_min = min_period_s or 2.5 * step
    p_max = max_period_s or span / 2
    if not 0 < p_min < p_max:
        raise JaxlcError(
            f"period search range [{p_min:g}, {p_max:g}] s is empty: the light curve spans "
            f"{span:g} s at {step:g} s steps; widen --min-period-s/--max-period-s"
        )
    y_d = _detrend(t, y, detrend_degree)
    ls = LombScargle(t, y_d, dy)
    f_min, f_max = 1.0 / p_max, 1.0 / p_min
    freq, power = ls.autopower(
        minimum_frequency=f_min, maximum_frequency=f_max, samples_per_peak=samples_per_peak
    )
    k = int(np.argmax(power))
    # Zoom on the peak: a fine grid ±1 coarse step around it.
    df = freq[1] - freq[0] if len(freq) > 1 else f_min
    fine = np.linspace(max(freq[k] - df, f_min), min(freq[k] + df, f_max), 201)
    p_fine = ls.power(fine)
    f_best = float(fine[int(np.argmax(p_fine))])
    p_best = float(np.max(p_fine))
    fap = float(
        ls.false_alarm_probability(
            p_best, method="baluev", minimum_frequency=f_min, maximum_frequency=f_max
        )
    )
    ls_period = 1.0 / f_best

    w = np.ones_like(t) if dy is None else 1.0 / dy**2
    sigma = np.full_like(t, np.nan) if dy is None else dy
    if dy is None:
        # noise from the residuals of a 4-harmonic fit at 2 P_ls
        a = fourier_design(t, 0.5 * f_best, range(1, 9))
        coef, *_ = np.linalg.lstsq(a, y_d, rcond=None)
        sigma = np.full_like(t, float(np.std(y_d - a @ coef, ddof=a.shape[1])))
    delta_bic, p_odd = odd_harmonic_test(t, y_d, w, ls_period)
    chi2_dof, p_halves = halves_test(t, y_d, sigma, 2 * ls_period)
    factor = 2 if (delta_bic > BIC_THRESHOLD and p_halves < HALVES_P_THRESHOLD) else 1
    if factor == 2:
        decision = (
            f"spin period = 2 × periodogram period: the two halves of a turn differ "
            f"(ΔBIC {delta_bic:.1f} > {BIC_THRESHOLD:g} for odd harmonics, halves p = "
            f"{p_halves:.2g})"
        )
    else:
        decision = (
            "spin period = periodogram period; the halves of a 2P fold do not differ "
            f"significantly (ΔBIC {delta_bic:.1f}, halves p = {p_halves:.2g}): a body with "
            "two identical maxima per turn would spin in 2 × this period"
        )
    # 1σ period error from the peak width (Kovacs / VanderPlas): σ_f ≈ √(2/(N P)) / (π T A/σ)
    a1 = fourier_design(t, f_best, [1])
    coef, *_ = np.linalg.lstsq(a1, y_d, rcond=None)
    amp = float(np.hypot(coef[1], coef[2]))
    noise = float(np.median(sigma)) if np.all(np.isfinite(sigma)) else float(np.std(y_d))
    sigma_f = math.sqrt(2.0 / len(t)) * noise / (math.pi * span * max(amp, 1e-12))
    period_err = sigma_f / f_best**2
    full = fourier_design(t, 0.5 * f_best, range(1, 9))
    c_full, *_ = np.linalg.lstsq(full, y_d, rcond=None)
    model = full @ c_full
    return PeriodResult(
        period_s=factor * ls_period,
        ls_period_s=ls_period,
        ls_period_err_s=float(period_err),
        false_alarm_probability=fap,
        harmonic_factor=factor,
        ls_power=p_best,
        delta_bic=float(delta_bic),
        odd_harmonics_p=float(p_odd),
        halves_chi2_per_dof=float(chi2_dof),
        halves_p=float(p_halves),
        amplitude_mag=float(np.ptp(model)),
        n_samples=len(t),
        span_s=span,
        min_period_s=p_min,
        max_period_s=p_max,
        decision=decision,
        alternative_period_s=(2 if factor == 1 else 1) * ls_period,
        frequency_hz=np.asarray(freq),
        power=np.asarray(power),
        catalogue_period_s=float(catalogue_period_s),
    )


def fold_phase(t_s, period_s: float) -> np.ndarray:
    """Rotational phase in [0, 1) of each sample for a period (s)."""
    return np.mod(np.asarray(t_s, dtype=np.float64) / period_s, 1.0)


def candidate_periods(
    t_s,
    mag,
    min_period_s: float,
    max_period_s: float,
    n_terms: int = 6,
    n_peaks: int = 3,
    samples_per_peak: int = 10,
) -> list[float]:
    """The ``n_peaks`` best distinct periods of a multi-harmonic periodogram.

    A light curve with sharp glints puts little power in any single sinusoid
    (the one-term periodogram's peak can then be an alias or noise); an
    ``n_terms``-harmonic Lomb–Scargle model (astropy, ``nterms``) follows the
    whole folded shape. Its peaks at P and at multiples of P are equally good
    (a series at 2P contains the harmonics of P): seed both.

    Args:
        t_s, mag: (N,) sample times (s) and magnitudes.
        min_period_s, max_period_s: search range.

    Returns:
        Periods (s), best first, each > 1 % from the others.
    """
    from astropy.timeseries import LombScargle

    t = np.asarray(t_s, np.float64)
    y = _detrend(t, np.asarray(mag, np.float64), 2)
    ls = LombScargle(t, y, nterms=n_terms)
    freq, power = ls.autopower(
        minimum_frequency=1.0 / max_period_s,
        maximum_frequency=1.0 / min_period_s,
        samples_per_peak=samples_per_peak,
    )
    # local maxima, strongest first
    is_peak = np.r_[False, (power[1:-1] >= power[:-2]) & (power[1:-1] >= power[2:]), False]
    order = np.flatnonzero(is_peak)[np.argsort(-power[is_peak])]
    return distinct_periods(1.0 / freq[order], limit=n_peaks)


def distinct_periods(periods, tol: float = 0.01, limit: int | None = None) -> list[float]:
    """The periods, in order, each more than a fraction ``tol`` from those before it
    (the first ``limit`` of them)."""
    out: list[float] = []
    for p in periods:
        if len(out) == limit:
            break
        if all(abs(p / q - 1) > tol for q in out):
            out.append(float(p))
    return out

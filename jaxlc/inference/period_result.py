"""What a period analysis found (:class:`PeriodResult`) and the small rules about periods
that its users share: agreement with a reference, probabilities for people, folding,
distinct periods.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

NAN = float("nan")


@dataclasses.dataclass(frozen=True)
class PeriodResult:
    """The outcome of :func:`analyse_period` (seconds, magnitudes).

    ``period_s`` is NaN unless ``verdict == "periodic"``; ``best_period_s``
    is the best candidate either way (for plots and fit seeds).
    """

    verdict: str  # "periodic", "two periods", "aperiodic" (varies, no period), "not variable"
    variable: bool
    decision: str
    n_samples: int
    subsampled_from: int  # 0, or the number of usable samples when more than MAX_SAMPLES
    span_s: float
    min_period_s: float
    max_period_s: float
    n_groups: int
    period_s: float = NAN
    period_err_s: float = NAN
    best_period_s: float = NAN
    harmonic_factor: int = 1
    n_harmonics: int = 0
    alternative_period_s: float = NAN
    ls_period_s: float = NAN
    ls_power: float = NAN
    false_alarm_probability: float = 1.0
    false_alarm_probability_empirical: float = 1.0
    false_alarm_probability_white: float = NAN
    shuffles: int = 0
    delta_bic: float = 0.0
    variability_p: float = 1.0
    effective_samples: float = NAN
    red_noise_rho: float = NAN
    cycles: float = NAN
    amplitude_mag: float = 0.0
    candidates: tuple = ()
    frequency_hz: np.ndarray = dataclasses.field(repr=False, default=None)
    power: np.ndarray = dataclasses.field(repr=False, default=None)
    sample_t_s: np.ndarray = dataclasses.field(repr=False, default=None)
    sample_mag: np.ndarray = dataclasses.field(repr=False, default=None)
    model_mag: np.ndarray = dataclasses.field(repr=False, default=None)
    trend_mag: np.ndarray = dataclasses.field(repr=False, default=None)
    catalogue_period_s: float = NAN
    second_period_s: float = NAN  # a tumbler's second fundamental period (two_periods)
    second_best_period_s: float = NAN
    second_delta_bic: float = NAN
    second_false_alarm_probability: float = NAN

    @property
    def periodic(self) -> bool:
        """True when a period is reported (one, or the first of two)."""
        return self.verdict in ("periodic", "two periods")

    @property
    def two_periods(self) -> bool:
        """True when a second period is reported too (a tumbling body's)."""
        return math.isfinite(self.second_period_s)

    def summary(self) -> dict:
        """JSON-ready dict (arrays left out, NaN as None)."""
        d = {
            k: v
            for k, v in dataclasses.asdict(self).items()
            if k
            not in ("frequency_hz", "power", "sample_t_s", "sample_mag", "model_mag", "trend_mag")
        }
        d["candidates"] = [dict(c) for c in self.candidates]
        for k, v in d.items():
            if isinstance(v, float) and not math.isfinite(v):
                d[k] = None
        return d


def period_agrees(found_s: float, true_s: float, span_s: float) -> bool:
    """Whether a period matches a reference spin period: it, or exactly half or double
    it, within max(1 %, ¼ of the periodogram resolution P²/T) of the reference P (T:
    the span, s). NaN never agrees."""
    tol = max(0.01 * true_s, 0.25 * true_s**2 / span_s)
    return any(abs(k * found_s - true_s) <= tol for k in (0.5, 1.0, 2.0))


def format_p(p: float) -> str:
    """A probability for people: '< 1e-300' instead of 0, two significant digits."""
    if not math.isfinite(p):
        return "—"
    if p < 1e-300:
        return "< 1e-300"
    return f"{p:.2g}"


def fold_phase(t_s, period_s: float) -> np.ndarray:
    """Rotational phase in [0, 1) of each sample for a period (s)."""
    return np.mod(np.asarray(t_s, dtype=np.float64) / period_s, 1.0)


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

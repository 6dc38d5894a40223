"""Trend + Fourier-series least squares: the model by which periods are judged.

A light curve folded at period P is described by a slow trend (a polynomial
in time per sample group, see :mod:`jaxlc.inference.periodogram`) plus H
harmonics of 1/P. :class:`HarmonicModel` projects the trend out once (QR per
group) so that each trial frequency costs one small least-squares solve.
Candidates are compared by BIC with the noise level profiled out and the
sample count replaced by an effective one (:func:`effective_samples`): red
noise makes neighbouring residuals alike, and a BIC that counts them as
independent evidence finds "periods" in every track.

Example:
    >>> m = HarmonicModel(t_s, mag, np.ones_like(t_s), [np.arange(len(t_s))], degree=2)
    >>> f = m.refine(1 / 12.0, n_harmonics=4, half_width_hz=1e-3)
    >>> m.rss(f, 4), m.n_params(4)
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

#: Golden-section iterations after the scan in :meth:`HarmonicModel.refine`.
REFINE_ITERATIONS = 16
#: Multiples of a periodogram peak tried as the spin period (glinting bodies need 4).
MULTIPLES = (1, 2, 3, 4)
#: Most harmonics of the peak frequency in a candidate's series, and in total.
MAX_PEAK_HARMONICS = 8
MAX_HARMONICS = 48
#: Most elements of one design matrix (bounds memory for long light curves).
MAX_DESIGN_ELEMENTS = 2 * 10**7


def fourier_design(t: np.ndarray, frequency_hz: float, harmonics) -> np.ndarray:
    """Design matrix (N, 1 + 2 K): a constant, cos and sin of each harmonic k·f."""
    cols = [np.ones_like(t)]
    for k in harmonics:
        w = 2 * np.pi * k * frequency_hz * t
        cols += [np.cos(w), np.sin(w)]
    return np.stack(cols, axis=1)


class HarmonicModel:
    """Weighted least squares of magnitudes on a per-group trend plus a Fourier series.

    Args:
        t_s: (N,) sorted times (s).
        mag: (N,) magnitudes.
        weight: (N,) weights (1/σ², or ones).
        groups: index arrays (each group gets its own trend and, when there is
            more than one group, its own Fourier coefficients).
        degree: polynomial degree of each group's trend in time.
    """

    def __init__(self, t_s, mag, weight, groups, degree: int):
        self.groups = [np.asarray(g) for g in groups]
        self.degree = degree
        self.n = int(sum(len(g) for g in self.groups))
        self._t, self._sw, self._q, self._y, self._mag = [], [], [], [], []
        for g in self.groups:
            t = np.asarray(t_s, np.float64)[g]
            sw = np.sqrt(np.asarray(weight, np.float64)[g])
            x = (t - t.mean()) / max(float(np.ptp(t)), 1e-9)
            trend = np.stack([x**k for k in range(degree + 1)], axis=1) * sw[:, None]
            q, _ = np.linalg.qr(trend)
            y = np.asarray(mag, np.float64)[g] * sw
            self._t.append(t - float(t_s[0]))
            self._sw.append(sw)
            self._q.append(q)
            self._y.append(y - q @ (q.T @ y))
            self._mag.append(np.asarray(mag, np.float64)[g])
        self.rss_trend = float(sum(y @ y for y in self._y))
        self.k_trend = len(self.groups) * (degree + 1)

    def n_params(self, n_harmonics: int) -> int:
        """Free parameters of the trend + ``n_harmonics``-harmonic model."""
        return self.k_trend + len(self.groups) * 2 * n_harmonics

    def max_harmonics(self) -> int:
        """Most harmonics every group can afford (≤ a third of its samples as parameters)."""
        fit = min((len(g) // 3 - self.degree - 1) // 2 for g in self.groups)
        return min(fit, MAX_DESIGN_ELEMENTS // (2 * max(len(g) for g in self.groups)))

    def _solve(self, i: int, frequency_hz: float, n_harmonics: int) -> np.ndarray:
        t, sw, q, y = self._t[i], self._sw[i], self._q[i], self._y[i]
        # harmonics by complex powers (one exp per sample, not one cos and sin per harmonic)
        z = np.exp(2j * np.pi * frequency_hz * t)
        zk = np.cumprod(np.broadcast_to(z[:, None], (len(t), n_harmonics)), axis=1)
        f = np.concatenate([zk.real, zk.imag], axis=1) * sw[:, None]
        f -= q @ (q.T @ f)
        # normal equations (2H × 2H), the residual formed explicitly (no cancellation)
        gram = f.T @ f
        gram[np.diag_indices_from(gram)] *= 1 + 1e-12
        try:
            coef = np.linalg.solve(gram, f.T @ y)
        except np.linalg.LinAlgError:
            coef, *_ = np.linalg.lstsq(f, y, rcond=None)
        return y - f @ coef

    def residuals_at(self, frequencies_hz, modulated: bool = False) -> np.ndarray:
        """(N,) weighted residuals of the trend + a cos and sin at each of the (K,)
        frequencies (Hz), fitted per group: the series of any set of frequencies
        (two periods' combinations), as :meth:`residuals` for harmonics.
        ``modulated``: each coefficient also changes linearly in time (a light curve
        whose shape drifts over the span; 4 K columns instead of 2 K)."""
        freqs = np.asarray(frequencies_hz, np.float64)
        out = []
        for t, sw, q, y in zip(self._t, self._sw, self._q, self._y, strict=True):
            w = 2 * np.pi * t[:, None] * freqs[None, :]
            f = np.concatenate([np.cos(w), np.sin(w)], axis=1)
            if modulated:
                x = (t - t.mean()) / max(float(np.ptp(t)), 1e-9)
                f = np.concatenate([f, f * x[:, None]], axis=1)
            f = f * sw[:, None]
            f -= q @ (q.T @ f)
            coef, *_ = np.linalg.lstsq(f, y, rcond=None)
            out.append(y - f @ coef)
        return np.concatenate(out)

    def residuals(self, frequency_hz: float, n_harmonics: int) -> np.ndarray:
        """(N,) weighted residuals, group after group (0 harmonics: the trend's)."""
        if n_harmonics == 0:
            return np.concatenate(self._y)
        return np.concatenate(
            [self._solve(i, frequency_hz, n_harmonics) for i in range(len(self.groups))]
        )

    def fitted(self, frequency_hz: float, n_harmonics: int) -> np.ndarray:
        """(N,) model magnitudes (trend + series), group after group."""
        r = self.residuals(frequency_hz, n_harmonics)
        return np.concatenate(self._mag) - r / np.concatenate(self._sw)

    def rss(self, frequency_hz: float, n_harmonics: int) -> float:
        """Weighted residual sum of squares."""
        r = self.residuals(frequency_hz, n_harmonics)
        return float(r @ r)

    def refine(self, frequency_hz: float, n_harmonics: int, half_width_hz: float) -> float:
        """Frequency (Hz) of least RSS within ±``half_width_hz``: a scan, then golden section."""
        grid = np.linspace(frequency_hz - half_width_hz, frequency_hz + half_width_hz, 17)
        grid = grid[grid > 0]
        cost = np.array([self.rss(f, n_harmonics) for f in grid])
        k = int(np.argmin(cost))
        a, b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
        g = (math.sqrt(5) - 1) / 2
        c, d = b - g * (b - a), a + g * (b - a)
        fc, fd = self.rss(c, n_harmonics), self.rss(d, n_harmonics)
        for _ in range(REFINE_ITERATIONS):
            if fc < fd:
                b, d, fd = d, c, fc
                c = b - g * (b - a)
                fc = self.rss(c, n_harmonics)
            else:
                a, c, fc = c, d, fd
                d = a + g * (b - a)
                fd = self.rss(d, n_harmonics)
        best = c if fc < fd else d
        return float(best if min(fc, fd) <= cost[k] else grid[k])

    def frequency_error(self, frequency_hz: float, n_harmonics: int, n_eff: float) -> float:
        """1σ error (Hz) from the RSS curvature, the noise profiled, inflated by √(N/N_eff)."""
        span = max(float(np.ptp(t)) for t in self._t) or 1.0
        h = 1e-3 / (span * max(n_harmonics, 1))
        r0 = self.rss(frequency_hz, n_harmonics)
        up, down = self.rss(frequency_hz + h, n_harmonics), self.rss(frequency_hz - h, n_harmonics)
        curv = (up + down - 2 * r0) / h**2
        s2 = r0 / max(self.n - self.n_params(n_harmonics), 1)
        if curv <= 0:
            return float("inf")
        return math.sqrt(s2 / curv * self.n / max(n_eff, 1.0))


def bic(rss: float, n: int, n_params: int, n_eff: float) -> float:
    """BIC with the noise profiled out: N_eff ln(RSS/N) + k ln N_eff."""
    return n_eff * math.log(max(rss, 1e-300) / n) + n_params * math.log(n_eff)


def median_step_s(t_s) -> float:
    """Median positive spacing of sorted sample times (s); 0 when all are equal."""
    steps = np.diff(np.asarray(t_s, np.float64))
    return float(np.median(steps[steps > 0])) if np.any(steps > 0) else 0.0


def neighbour_pairs(resid, t_s, groups, step_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(earlier, later) residuals of neighbouring samples: ≤ 3 ``step_s`` apart, same group.

    Args:
        resid: (N,) residuals, group after group (as :meth:`HarmonicModel.residuals`).
        t_s: (N,) sorted times (s); groups: the model's index arrays.
    """
    first, second, pos = [], [], 0
    for g in groups:
        r = resid[pos : pos + len(g)]
        pos += len(g)
        near = np.diff(np.asarray(t_s)[g]) <= 3 * step_s
        first.append(r[:-1][near])
        second.append(r[1:][near])
    return np.concatenate(first), np.concatenate(second)


def effective_samples(resid, t_s, groups, step_s: float) -> tuple[float, float]:
    """(N_eff, ρ): the lag-1 autocorrelation ρ of neighbouring residuals
    (:func:`neighbour_pairs`) and N (1 − ρ)/(1 + ρ), clipped to [N/50, N]."""
    a, b = neighbour_pairs(resid, t_s, groups, step_s)
    den = float(resid @ resid)
    rho = min(max(float(a @ b) / den if den > 0 else 0.0, 0.0), 0.999)
    n = len(resid)
    n_eff = n * (1 - rho) / (1 + rho)
    return float(min(max(n_eff, n / 50, 3.0), n)), float(rho)


def von_neumann_p(resid, t_s, groups, step_s: float) -> float:
    """p-value of white noise against slow variation (von Neumann ratio of neighbours).

    Under white noise the mean squared successive difference is twice the
    variance (ratio η ≈ 2, variance 4/M for M pairs); variation slower than
    the sampling makes η small.
    """
    from scipy import stats

    a, b = neighbour_pairs(resid, t_s, groups, step_s)
    m = len(a)
    var = float(np.mean(resid**2))
    if m < 5 or var <= 0:
        return 1.0
    eta = float((b - a) @ (b - a)) / m / var
    z = (2.0 - eta) / math.sqrt(4.0 / m)
    return float(stats.norm.sf(z))


@dataclasses.dataclass(frozen=True)
class Candidate:
    """A trial spin period: ``multiple`` × a periodogram peak, refined and scored."""

    frequency_hz: float
    multiple: int
    peak_period_s: float
    n_harmonics: int
    rss: float
    n_params: int

    @property
    def period_s(self) -> float:
        return 1.0 / self.frequency_hz


def spin_candidates(
    model: HarmonicModel, peaks_hz, df_hz: float, p_min: float, p_max: float
) -> list[Candidate]:
    """Every multiple (:data:`MULTIPLES`) of every peak frequency whose period is in
    [p_min, p_max] s, refined within ±2 grid steps ``df_hz``, with its number of
    harmonics chosen by BIC (all samples counted; the caller rescores with N_eff).

    Harmonics reach at most :data:`MAX_PEAK_HARMONICS` of the peak and what each
    group's samples can carry — above the Nyquist frequency too: deep, narrow
    features (an edge-on CubeSat) put power in high harmonics, which even
    sampling folds back into the band, and a series that cannot hold them
    prefers a wrong period (an aliased 8th harmonic of a 6.77 s spin seen at
    1 Hz looked like a 5.49 s period).
    """
    out = []
    h_cap = model.max_harmonics()
    for f_k in peaks_hz:
        for m in MULTIPLES:
            f_c = f_k / m
            if not p_min <= 1.0 / f_c <= p_max:
                continue
            h_max = min(MAX_PEAK_HARMONICS, h_cap // m, MAX_HARMONICS // m)
            if h_max < 1:
                continue
            f_c = model.refine(f_c, m * min(h_max, 3), 2 * df_hz / m)
            scored = []
            for h in range(1, h_max + 1):
                rss = model.rss(f_c, m * h)
                k = model.n_params(m * h)
                scored.append((bic(rss, model.n, k, model.n), h, rss, k))
            _, h, _, _ = min(scored)
            f_c = model.refine(f_c, m * h, 0.5 * df_hz / m)
            rss = model.rss(f_c, m * h)
            out.append(Candidate(f_c, m, 1.0 / f_k, m * h, rss, model.n_params(m * h)))
    return out

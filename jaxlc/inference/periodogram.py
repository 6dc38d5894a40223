"""Bounded periodograms and a false-alarm level taken from the data themselves.

* **Bounded work.** A frequency grid of step 1/(span × oversampling) grows
  with the time span, gaps included: two 15-s runs eleven days apart would
  ask for 10⁸ frequencies. :func:`segment_groups` keeps the grid under
  :data:`MAX_FREQUENCIES`: when the whole span does not fit, the samples are
  cut into groups (at their largest gaps, else every ``max_span_s``) and
  the periodogram is the sample-weighted mean of the groups' periodograms
  (Bartlett's incoherent average: the period is common, the phases are
  not carried across the cuts). Memory and time then follow the number of
  samples and the cap, never the length of a gap.
* **Significance from the data.** The analytic (Baluev) false-alarm
  probability assumes white noise; real tracks have red noise and trends,
  which it turns into "periods" with p = 10⁻¹⁰. :func:`permutation_fap`
  shuffles blocks of the detrended residuals (each block keeps its own
  correlated noise, the shuffle destroys any coherent period), takes the
  periodogram maximum of each shuffle and extrapolates a Gumbel law fitted
  to those maxima to the observed one.

Powers use astropy's ``standard`` normalisation (1 − χ²/χ²₀ of one sinusoid).
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np

from jaxlc.errors import JaxlcError

#: Most frequencies in one periodogram (the whole span, or each group).
MAX_FREQUENCIES = 2**17
#: Most runs in one periodogram (the fullest are kept), and most run × frequency
#: evaluations of one periodogram: with the cap on samples this bounds the time.
MAX_GROUPS = 8
MAX_GROUP_FREQUENCIES = 2 * MAX_FREQUENCIES
#: Oversampling of the false-alarm grid (observed and shuffled data alike).
FAP_SAMPLES_PER_PEAK = 3
#: Runs per group in a shuffle: more runs destroy more of a real period (power),
#: fewer keep more red noise (caution). 16 separates MMT's periodic tracks (FAP
#: ≤ 0.007) from its not-variable ones and a random walk (≥ 0.03; see
#: experiments/period_mmt.py).
BLOCKS = 16
#: Fewest shuffles before a false-alarm probability may stop early.
MIN_PERMUTATIONS = 30
#: Fewest samples a group needs to enter the periodogram.
MIN_GROUP_SAMPLES = 10


@dataclasses.dataclass(frozen=True)
class Grid:
    """A regular frequency grid (Hz) over sample groups (index arrays into sorted times)."""

    f0_hz: float
    df_hz: float
    n: int
    groups: tuple[np.ndarray, ...]
    span_s: float  # the span that sets the resolution (the longest group's)

    @property
    def frequency_hz(self) -> np.ndarray:
        """(n,) frequencies in Hz."""
        return self.f0_hz + self.df_hz * np.arange(self.n)

    @property
    def f_max_hz(self) -> float:
        """The highest frequency of the grid (Hz)."""
        return self.f0_hz + self.df_hz * (self.n - 1)

    @property
    def coherent(self) -> bool:
        """True when one group holds every sample (phases kept across the whole span)."""
        return len(self.groups) == 1


def segment_groups(t_s: np.ndarray, max_span_s: float) -> list[np.ndarray]:
    """Cut sorted times into runs each spanning at most ``max_span_s``.

    A new group starts at a gap longer than ``max_span_s / 8`` or where the
    group would outgrow ``max_span_s``. Groups with fewer than
    :data:`MIN_GROUP_SAMPLES` samples are dropped (and :func:`plan_grid` keeps
    the :data:`MAX_GROUPS` fullest).

    Returns:
        Index arrays into ``t_s``, in time order.
    """
    t = np.asarray(t_s, np.float64)
    if float(t[-1] - t[0]) <= max_span_s:
        return [np.arange(len(t))]
    starts = [0]
    group_t0 = t[0]
    for i in range(1, len(t)):
        if t[i] - t[i - 1] > max_span_s / 8 or t[i] - group_t0 > max_span_s:
            starts.append(i)
            group_t0 = t[i]
    edges = [*starts, len(t)]
    groups = [np.arange(a, b) for a, b in itertools.pairwise(edges)]
    return [g for g in groups if len(g) >= MIN_GROUP_SAMPLES]


def plan_grid(
    t_s: np.ndarray,
    min_period_s: float,
    max_period_s: float | None,
    samples_per_peak: float,
    max_frequencies: int = MAX_FREQUENCIES,
) -> Grid:
    """A frequency grid whose size is bounded whatever the span.

    Args:
        t_s: (N,) sorted sample times (s).
        min_period_s: shortest period (s).
        max_period_s: longest period (s), or None for half the longest
            group's span (two cycles seen).
        samples_per_peak: grid points per periodogram peak width 1/span.

    Raises:
        JaxlcError: when the range is empty or no group has enough samples.
    """
    if not (math.isfinite(min_period_s) and min_period_s > 0):
        raise JaxlcError(f"min_period_s (--min-period-s) = {min_period_s:g} must be > 0")
    if max_period_s is not None and not (
        math.isfinite(max_period_s) and max_period_s > min_period_s
    ):
        raise JaxlcError(
            f"max_period_s (--max-period-s) = {max_period_s:g} must exceed min_period_s = "
            f"{min_period_s:g}"
        )
    t = np.asarray(t_s, np.float64)
    f_hi = 1.0 / min_period_s
    span = float(t[-1] - t[0])
    # The span whose grid fits the cap (the lowest frequency is ~0 for this bound).
    fit_span = max_frequencies / (samples_per_peak * f_hi)
    groups = segment_groups(t, fit_span) if span > fit_span else [np.arange(len(t))]
    if not groups:
        raise JaxlcError(
            f"period search: no run of ≥ {MIN_GROUP_SAMPLES} samples within {fit_span:.4g} s "
            "(the span a bounded frequency grid resolves at this sampling); raise "
            "--min-period-s or analyse the runs separately"
        )
    if len(groups) > MAX_GROUPS:
        fullest = sorted(range(len(groups)), key=lambda i: -len(groups[i]))[:MAX_GROUPS]
        groups = [groups[i] for i in sorted(fullest)]
    group_span = max(float(t[g[-1]] - t[g[0]]) for g in groups)
    p_max = group_span / 2 if max_period_s is None else min(max_period_s, group_span / 2)
    if not 0 < min_period_s < p_max:
        raise JaxlcError(
            f"period search range [{min_period_s:.4g}, {p_max:.4g}] s is empty: the light "
            f"curve's {'' if len(groups) == 1 else 'longest run '}spans {group_span:.4g} s "
            "(two cycles must fit); lower --min-period-s or observe longer"
        )
    df = 1.0 / (samples_per_peak * group_span)
    f_lo = 1.0 / p_max
    n = max(math.ceil((f_hi - f_lo) / df) + 1, 2)
    n_cap = min(max_frequencies, MAX_GROUP_FREQUENCIES // len(groups))
    if n > n_cap:  # many runs: fewer points per peak
        df = (f_hi - f_lo) / (n_cap - 1)
        n = n_cap
    return Grid(f_lo, df, n, tuple(groups), group_span)


def coarse(grid: Grid) -> Grid:
    """The grid at :data:`FAP_SAMPLES_PER_PEAK` points per peak width, or ``grid`` itself
    when it is already that coarse (never coarser: an unresolved peak would be missed
    in the data and found in the broad peaks of the shuffles)."""
    df = max(1.0 / (FAP_SAMPLES_PER_PEAK * grid.span_s), grid.df_hz)
    n = max(int((grid.f_max_hz - grid.f0_hz) / df) + 1, 2)
    return dataclasses.replace(grid, df_hz=df, n=n)


def power(t_s, resid, dy, grid: Grid) -> np.ndarray:
    """(n,) Lomb–Scargle power on ``grid``: the sample-weighted mean over its groups.

    Args:
        t_s: (N,) sorted times (s); resid: (N,) detrended magnitudes;
        dy: (N,) 1σ errors (mag) or None.
    """
    from astropy.timeseries.periodograms.lombscargle.implementations import fast_impl

    total = np.zeros(grid.n)
    weight = 0
    for g in grid.groups:
        tg = t_s[g] - t_s[g[0]]
        p = fast_impl.lombscargle_fast(
            tg, resid[g], 1.0 if dy is None else dy[g], grid.f0_hz, grid.df_hz, grid.n
        )
        total += len(g) * np.nan_to_num(p)
        weight += len(g)
    return total / weight


def local_peaks(power_: np.ndarray, n_peaks: int, min_separation: int) -> np.ndarray:
    """Indices of the ``n_peaks`` highest local maxima, each ≥ ``min_separation`` bins apart."""
    p = np.asarray(power_)
    is_peak = np.r_[p[0] > p[1], (p[1:-1] >= p[:-2]) & (p[1:-1] >= p[2:]), p[-1] > p[-2]]
    out: list[int] = []
    for k in np.flatnonzero(is_peak)[np.argsort(-p[is_peak], kind="stable")]:
        if all(abs(k - j) >= min_separation for j in out):
            out.append(int(k))
        if len(out) == n_peaks:
            break
    return np.asarray(out, int)


def block_shuffle(values: np.ndarray, groups, blocks: int, rng: np.random.Generator):
    """The values with each group's samples cut into ``blocks`` runs, put in random order.

    The runs are of nearly equal length, each cut moved at random by up to a
    quarter of a run: runs of exactly equal length in evenly sampled data, a
    multiple of the period long, would keep the period through any shuffle.
    """
    out = values.copy()
    for g in groups:
        n = len(g)
        k = min(blocks, n)
        jitter = rng.uniform(-0.25, 0.25, size=k - 1)
        cuts = np.unique(np.clip(np.round((np.arange(1, k) + jitter) * n / k), 1, n - 1))
        parts = np.split(np.roll(values[g], int(rng.integers(n))), cuts.astype(int))
        order = rng.permutation(len(parts))
        out[g] = np.concatenate([parts[i] for i in order])
    return out


def permutation_fap(
    t_s,
    resid,
    dy,
    grid: Grid,
    n_permutations: int = 300,
    blocks: int = BLOCKS,
    rng: np.random.Generator | None = None,
    decide_at: float | None = None,
) -> tuple[float, float, int]:
    """False-alarm probability of the periodogram maximum against block-shuffled residuals.

    Args:
        t_s, resid, dy: as for :func:`power` (the trend already removed).
        grid: the search grid (its coarse version is used for every statistic).
        n_permutations: most shuffles.
        blocks: runs per group: each keeps its red noise, their order is random.
        decide_at: a threshold the caller compares the FAP with: shuffling stops
            early (after ≥ :data:`MIN_PERMUTATIONS`) once the FAP is 10× away from it.

    Returns:
        (FAP from a Gumbel law fitted to the shuffled maxima, the empirical
        FAP (k + 1)/(n + 1), the number of shuffles).
    """
    rng = rng or np.random.default_rng(0)
    g = coarse(grid)
    observed = float(np.max(power(t_s, resid, dy, g)))
    null: list[float] = []
    idx = np.arange(len(resid))
    while len(null) < n_permutations:
        perm = block_shuffle(idx, grid.groups, blocks, rng)
        null.append(float(np.max(power(t_s, resid[perm], None if dy is None else dy[perm], g))))
        if len(null) >= MIN_PERMUTATIONS and len(null) % 10 == 0:
            fap = gumbel_tail(np.asarray(null), observed)
            if decide_at is not None and not decide_at / 10 < fap < decide_at * 10:
                break
    null_arr = np.asarray(null)
    empirical = (1 + int(np.sum(null_arr >= observed))) / (len(null_arr) + 1)
    return gumbel_tail(null_arr, observed), float(empirical), len(null_arr)


def gumbel_tail(maxima: np.ndarray, value: float) -> float:
    """P(max > value) under a Gumbel law with the moments of the sampled ``maxima``."""
    sd = float(np.std(maxima, ddof=1))
    if sd <= 0:
        return 0.0 if value > maxima[0] else 1.0
    beta = sd * math.sqrt(6) / math.pi
    mu = float(np.mean(maxima)) - 0.5772156649 * beta
    return float(-math.expm1(-math.exp(-(value - mu) / beta)))


def baluev_fap(t_s, resid, dy, grid: Grid, z: float) -> float:
    """White-noise (Baluev) FAP of the maximum power; NaN for a grid cut into runs."""
    if not grid.coherent:
        return float("nan")
    from astropy.timeseries import LombScargle

    return float(
        LombScargle(t_s, resid, dy).false_alarm_probability(
            z, method="baluev", minimum_frequency=grid.f0_hz, maximum_frequency=grid.f_max_hz
        )
    )

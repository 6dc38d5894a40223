"""Plots of light-curve tables (matplotlib is imported only here)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.io.files import atomic_output


def save_figure(fig, path: str | Path, dpi: int = 120) -> Path:
    """Lay out, save atomically (format from the extension: png, pdf, svg) and close."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = Path(path)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=path.suffix.lstrip(".") or "png")
    plt.close(fig)
    return path


def plot_lightcurve(lc: pd.DataFrame, path: str | Path, title: str | None = None) -> Path:
    """Magnitude against time above phase angle and range; saved atomically.

    Invisible rows are shaded grey. The format follows the extension (png, pdf, svg).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = lc["t_s"].to_numpy()
    mag = lc["mag"].to_numpy()
    visible = lc["visible"].to_numpy(bool)
    fig, (ax, ax2) = plt.subplots(
        2, 1, figsize=(9, 5.5), sharex=True, gridspec_kw={"height_ratios": [3, 1.3]}
    )
    finite = visible & np.isfinite(mag)
    ax.plot(t[finite], mag[finite], ".-", ms=2.5, lw=0.6, color="tab:blue")
    ax.invert_yaxis()
    ax.set_ylabel("apparent magnitude")
    ax.grid(alpha=0.3)
    _shade_invisible(ax, t, visible)
    _shade_invisible(ax2, t, visible)
    (p1,) = ax2.plot(t, lc["phase_angle_deg"], color="tab:orange", lw=1.2, label="phase angle")
    ax2.set_ylabel("phase angle (°)", color="tab:orange")
    ax3 = ax2.twinx()
    (p2,) = ax3.plot(t, lc["range_m"] / 1e3, color="tab:green", lw=1.2, ls="--", label="range")
    ax3.set_ylabel("range (km)", color="tab:green")
    ax2.legend(handles=[p1, p2], loc="best", fontsize="small", frameon=False)
    ax2.set_xlabel("time since first sample (s)")
    n_vis = int(visible.sum())
    ax.set_title(title or f"light curve: {n_vis} of {len(lc)} samples visible")
    return save_figure(fig, path, dpi=120)


def _shade_invisible(ax, t, visible):
    if len(t) == 0 or visible.all():
        return
    edges = np.flatnonzero(np.diff(np.r_[0, (~visible).astype(int), 0]))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        ax.axvspan(t[start], t[stop - 1], color="0.85", lw=0, zorder=0)


def plot_period(
    result, path: str | Path, title: str | None = None, ylabel: str = "magnitude"
) -> Path:
    """Periodogram (power against period) above the curve folded at the spin period.

    When no period is significant the fold uses the best candidate and says
    so. The catalogue period (if any) is drawn over the spin line, wider and
    dashed, so that it stays visible when the two coincide.

    Args:
        result: a :class:`jaxlc.inference.period.PeriodResult` (its analysed samples).
        ylabel: the magnitude's name (MMT tracks: ``StdMag``, normalised to 1,000 km).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxlc.inference.harmonics import fourier_design
    from jaxlc.inference.period_result import fold_phase, format_p

    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(8, 7.5))
    if len(result.power):
        ax.plot(1.0 / result.frequency_hz, result.power, lw=0.7, color="tab:blue")
        ax.set_xscale("log")
        ax.axvline(result.ls_period_s, color="tab:red", ls="--", lw=1, label="periodogram peak")
    p_fold = result.period_s if result.periodic else result.best_period_s
    if np.isfinite(p_fold):
        label = (
            f"spin period ({result.harmonic_factor} × peak)"
            if result.periodic
            else "best candidate (not significant)"
        )
        ax.axvline(p_fold, color="tab:green", lw=2.5, alpha=0.7, label=label, zorder=2)
    if result.two_periods:
        ax.axvline(
            result.second_period_s, color="tab:orange", lw=2.5, alpha=0.7, label="second period"
        )
    if np.isfinite(result.catalogue_period_s) and result.catalogue_period_s > 0:
        ax.axvline(
            result.catalogue_period_s,
            color="k",
            ls=(0, (4, 3)),
            lw=1.3,
            label="catalogue",
            zorder=3,
        )
    ax.set_xlabel("period (s)")
    ax.set_ylabel("Lomb–Scargle power")
    ax.legend(fontsize="small", frameon=False)
    fap = format_p(result.false_alarm_probability)
    head = (
        f"P = {result.period_s:.5g} ± {result.period_err_s:.2g} s"
        if result.periodic
        else f"no period ({result.verdict})"
    )
    if result.two_periods:
        head = f"two periods: {result.period_s:.5g} s and {result.second_period_s:.5g} s"
    ax.set_title(title or f"{head}; FAP {fap}, ΔBIC {result.delta_bic:.1f}", fontsize=10)
    t = np.asarray(result.sample_t_s if result.sample_t_s is not None else [])
    y = np.asarray(result.sample_mag if result.sample_mag is not None else [])
    if len(t) and np.isfinite(p_fold):
        phase = fold_phase(t - t.min(), p_fold)
        trend = result.trend_mag - np.median(result.trend_mag)
        sc = ax2.scatter(phase, y - trend, s=3, c=t - t.min(), cmap="viridis", alpha=0.7)
        fig.colorbar(sc, ax=ax2, label="time since first sample (s)", pad=0.01)
        if result.n_groups == 1 and result.n_harmonics > 0:
            # the series alone, fitted to the detrended samples, on a fine phase grid
            harmonics = range(1, result.n_harmonics + 1)
            a = fourier_design(phase, 1.0, harmonics)
            coef, *_ = np.linalg.lstsq(a, y - trend, rcond=None)
            grid = np.linspace(0, 1, 400)
            ax2.plot(
                grid,
                fourier_design(grid, 1.0, harmonics) @ coef,
                "k",
                lw=0.8,
                label=f"{result.n_harmonics}-harmonic series",
            )
            ax2.legend(fontsize="small", frameon=False, loc="upper right")
        ax2.set_xlabel(f"rotational phase (P = {p_fold:.5g} s); trend removed")
    else:
        ax2.plot(t, y, ".", ms=2)
        ax2.set_xlabel("time (s)")
    ax2.invert_yaxis()
    ax2.set_ylabel(ylabel)
    ax2.set_title(textwrap.fill(result.decision, 120), fontsize=7, loc="left")
    return save_figure(fig, path, dpi=110)


def plot_corner(samples: pd.DataFrame, path: str | Path, columns=None) -> Path:
    """Pairwise posterior: histograms on the diagonal, 2-D histograms below it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    columns = columns or [
        "pole_ra_deg",
        "pole_dec_deg",
        "period_s",
        "phase_deg",
        "dmag",
        "noise_mag",
    ]
    k = len(columns)
    fig, axes = plt.subplots(k, k, figsize=(1.9 * k, 1.9 * k))
    for i, ci in enumerate(columns):
        for j, cj in enumerate(columns):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                ax.hist(samples[ci], bins=40, color="tab:blue", histtype="step")
                ax.set_yticks([])
            else:
                ax.hist2d(samples[cj], samples[ci], bins=40, cmap="Blues")
            if i == k - 1:
                ax.set_xlabel(cj, fontsize=8)
            else:
                ax.set_xticklabels([])
            if j == 0 and i > 0:
                ax.set_ylabel(ci, fontsize=8)
            elif j > 0:
                ax.set_yticklabels([])
            ax.tick_params(labelsize=6)
    fig.suptitle(f"posterior ({len(samples)} samples)")
    return save_figure(fig, path, dpi=100)


def plot_fit(t_s, mag, model_mag, path: str | Path, title: str | None = None) -> Path:
    """Observed magnitudes with the fitted model above the residuals (``title``: the fit's
    answer in one line)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(
        2, 1, figsize=(9, 5.5), sharex=True, gridspec_kw={"height_ratios": [3, 1.2]}
    )
    ax.plot(t_s, mag, ".", ms=2.5, color="k", label="data")
    ax.plot(t_s, model_mag, "-", lw=0.8, color="tab:red", label="MAP model")
    ax.invert_yaxis()
    ax.set_ylabel("magnitude")
    ax.legend(fontsize="small", frameon=False)
    if title is not None:
        ax.set_title(title)
    r = np.asarray(mag) - np.asarray(model_mag)
    ax2.plot(t_s, r, ".", ms=2, color="tab:blue")
    ax2.axhline(0, color="k", lw=0.5)
    ax2.set_ylabel("data − model")
    ax2.set_xlabel("time from the fit epoch (s)")
    return save_figure(fig, path, dpi=110)

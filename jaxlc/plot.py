"""Plots of light-curve tables (matplotlib is imported only here)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.files import atomic_output


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
    fig.tight_layout()
    path = Path(path)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=120, format=path.suffix.lstrip(".") or "png")
    plt.close(fig)
    return path


def _shade_invisible(ax, t, visible):
    if len(t) == 0 or visible.all():
        return
    edges = np.flatnonzero(np.diff(np.r_[0, (~visible).astype(int), 0]))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        ax.axvspan(t[start], t[stop - 1], color="0.85", lw=0, zorder=0)

"""Plots of the imaging pipeline: a frame with its detections, extracted vs injected curves."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc.plot import save_figure

#: Colours per detection class (as the seed's mask: object green, streaks white, partial blue).
KIND_COLOURS = {
    "object candidate": "lime", "catalogue star": "white", "other streak": "0.6",
    "partial": "deepskyblue",
}  # fmt: skip


def plot_frame(
    frame, stars, settings, path: str | Path, title: str | None = None, dpi: int = 120
) -> Path:
    """One frame (asinh stretch) with its detections outlined by class."""
    import matplotlib.pyplot as plt

    from jaxlc.imaging.extract import measure_frame

    res = measure_frame(frame, stars, settings)
    det, segm = res["detections"], res["segments"]
    data = frame.data
    lo, hi = np.percentile(data, [5, 99.7])
    fig, (ax, ax_mask) = plt.subplots(1, 2, figsize=(12, 6))
    ax.imshow(np.arcsinh((data - lo) / max(hi - lo, 1e-9) * 10), origin="lower", cmap="gray")
    classes = np.zeros(segm.shape, dtype=int)
    labels = {"object candidate": 1, "catalogue star": 2, "other streak": 3, "partial": 4}
    objects = res["objects"]
    for _, d in det.iterrows():
        if d["kind"] == "partial":
            kind = "partial"
        elif d["star"] >= 0:
            kind = "catalogue star"
        elif d["kind"] == "point":
            kind = "object candidate"
        else:
            kind = "other streak"
        classes[segm == d["label"]] = labels[kind]
    from matplotlib.colors import ListedColormap

    cmap = ListedColormap(["black"] + [KIND_COLOURS[k] for k in labels])
    ax_mask.imshow(classes, origin="lower", cmap=cmap, vmin=0, vmax=4, interpolation="nearest")
    for _, o in objects.iterrows():
        for a in (ax, ax_mask):
            a.add_patch(plt.Circle((o["x_px"], o["y_px"]), 12, fill=False, color="lime", lw=1.2))
    handles = [plt.Line2D([], [], color=KIND_COLOURS[k], lw=6, label=k) for k in labels]
    ax_mask.legend(handles=handles, loc="upper right", fontsize=8, facecolor="0.3",
                   labelcolor="white")  # fmt: skip
    zp = res["zp"]
    ax.set_title(title or f"{frame.path.name}: {frame.start.isoformat()}, {frame.exptime_s:g} s")
    ax_mask.set_title(
        f"{len(objects)} object candidate(s) (points; tracking keeps those seen in ≥ 3 frames),\n"
        f"{int((det['star'] >= 0).sum())} catalogue stars, "
        f"{int((det['kind'] == 'partial').sum())} partial; ZP {zp[0]:.3f} ± {zp[1]:.3f} "
        f"({zp[3]} stars)", fontsize=9,
    )  # fmt: skip
    for a in (ax, ax_mask):
        a.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    return save_figure(fig, path, dpi=dpi)


def plot_extracted(
    curves: list[pd.DataFrame],
    path: str | Path,
    injected: pd.DataFrame | None = None,
    title: str | None = None,
) -> Path:
    """Extracted light curve(s) with error bars, over the injected one when given.

    With ``injected`` (columns ``t_s, mag``, one row per frame, as the
    ``frames.csv`` of :func:`~jaxlc.imaging.frames.simulate_frames`) a lower
    panel shows the residuals in units of ``mag_err``.
    """
    import matplotlib.pyplot as plt

    rows = 2 if injected is not None else 1
    fig, axes = plt.subplots(rows, 1, figsize=(10, 3.2 * rows + 1), sharex=True, squeeze=False)
    ax = axes[0, 0]
    if injected is not None:
        ax.plot(injected["t_s"], injected["mag"], color="0.2", lw=1.0, label="injected", zorder=3)
    for k, lc in enumerate(curves):
        ok = lc["visible"].to_numpy(bool)
        ax.errorbar(lc["t_s"][ok], lc["mag"][ok], lc["mag_err"][ok], fmt=".", ms=3, lw=0.6,
                    label=f"extracted, object {k + 1} ({ok.sum()} frames)")  # fmt: skip
    ax.invert_yaxis()
    ax.set_ylabel("magnitude")
    ax.legend(fontsize=8)
    ax.set_title(title or "light curve extracted from frames")
    if injected is not None:
        lc = curves[0]
        res = (lc["mag"].to_numpy() - injected["mag"].to_numpy()) / lc["mag_err"].to_numpy()
        ok = np.isfinite(res)
        ax2 = axes[1, 0]
        ax2.plot(lc["t_s"][ok], res[ok], ".", ms=3)
        ax2.axhline(0, color="0.3", lw=0.8)
        chi2 = float(np.mean(res[ok] ** 2)) if ok.any() else float("nan")
        bias = float(np.nanmean(lc["mag"].to_numpy() - injected["mag"].to_numpy()))
        ax2.set_ylabel("(extracted − injected) / σ")
        ax2.set_title(
            f"all {ok.sum()} measured frames: bias {bias:+.4f} mag, reduced χ² {chi2:.2f}",
            fontsize=9,
        )
    axes[-1, 0].set_xlabel("t (s)")
    return save_figure(fig, path)

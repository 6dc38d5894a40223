"""The seed paper's Fig. 5: motion blur of a 3U CubeSat spinning in 10 s about its x axis.

The S5 CubeSat (its body-mounted cells as the Cycles-matched ``as-glossy``
lobe of the same rd, rs and exponent, so that both renderers compute the same
physics: :func:`calibrate.crosscheck.same_material`) spins in 10 s about body
x; 1 s exposures every 0.25 s (a sliding exposure, so that the curve shows
the features between whole seconds) over a synthetic pass (phase angle
60° → 65°, where the cells glint, at 1,000 km). Four light curves:

* JAX, sharp: one instant per exposure (its midpoint);
* JAX, blurred: the renderer's adaptive sub-exposures (the default);
* Cycles, sharp, and Cycles with motion blur (the spin keyframed over each
  exposure, Cycles' shutter open for the whole exposure).

Features are taken from the sharp JAX curve: the peaks (glints, local
magnitude minima, 0.5 mag prominent) and the narrow dark dip (the most
prominent local maximum). For each feature the table gives blurred − sharp in both
renderers and Cycles − JAX in both modes (``motion_blur.csv``), and the
figure shows the four curves with the features marked (``motion_blur.png``).

    python experiments/paper/motion_blur.py [--quick] [--out-dir DIR]

``--quick``: 10 s (40 exposures), 64 px and 16 samples per pixel (the test
suite's size); the default is 30 s (120 exposures) at 128 px and 64 samples.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.signal import find_peaks

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jaxlc
from calibrate.crosscheck import same_material
from calibrate.job import BlenderOptions
from calibrate.render import blender_render
from jaxlc import RenderOptions
from paper.common import RESULTS, provenance, pyplot, save_png, write_result

SPIN_PERIOD_S = 10.0
STEP_S = 0.25


def cubesat() -> jaxlc.Scene:
    """S5 spinning in 10 s about body x, in its Cycles-matched material."""
    scene = same_material(jaxlc.load_scene("s5_cubesat"))
    spin = dataclasses.replace(scene.attitude, body_axis=(1.0, 0.0, 0.0), period_s=SPIN_PERIOD_S)
    return dataclasses.replace(scene, attitude=spin)


def features(mag: np.ndarray) -> dict[str, np.ndarray]:
    """Indices of the peaks (local minima of magnitude, 0.5 mag prominent) and of
    the most prominent dip (one index)."""
    peaks, _ = find_peaks(-mag, prominence=0.5)
    dips, props = find_peaks(mag, prominence=0.2)
    dip = dips[[int(np.argmax(props["prominences"]))]] if len(dips) else np.array([], int)
    return {"peak": peaks, "dip": dip}


def main(argv=None) -> pd.DataFrame:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="20 exposures, small images")
    ap.add_argument("--out-dir", type=Path, default=RESULTS)
    args = ap.parse_args(argv)

    duration_s = 10.0 if args.quick else 30.0
    size = dict(resolution=64, samples=16) if args.quick else dict(resolution=128, samples=64)
    geo = jaxlc.synthetic_geometry(
        duration_s=duration_s,
        step_s=STEP_S,
        phase_start_deg=60.0,
        phase_end_deg=65.0,
        range_start_m=1.0e6,
        exposure_s=1.0,
    )
    scene = cubesat()
    curves, seconds = {}, {}
    for blur in (False, True):
        t0 = time.perf_counter()
        opts = RenderOptions(blur="auto" if blur else "off")
        curves["jax", blur] = jaxlc.render(scene, geo, precision="float64", options=opts)
        seconds["jax", blur] = time.perf_counter() - t0
        t0 = time.perf_counter()
        curves["cycles", blur] = blender_render(
            scene, geo, BlenderOptions(motion_blur=blur, **size)
        )
        seconds["cycles", blur] = time.perf_counter() - t0
    mag = {k: v["mag"].to_numpy() for k, v in curves.items()}
    marks = features(mag["jax", False])

    # each column: curve a − curve b, per feature and as the max |·| over all exposures
    diffs = {
        name: mag[a] - mag[b]
        for name, (a, b) in {
            "jax_blur_change_mag": (("jax", True), ("jax", False)),
            "cycles_blur_change_mag": (("cycles", True), ("cycles", False)),
            "cycles_minus_jax_sharp_mag": (("cycles", False), ("jax", False)),
            "cycles_minus_jax_blur_mag": (("cycles", True), ("jax", True)),
        }.items()
    }
    rows = [
        dict(
            feature=kind,
            t_s=float(geo["t_s"].iloc[i]),
            jax_sharp_mag=mag["jax", False][i],
            **{name: d[i] for name, d in diffs.items()},
        )
        for kind, idx in marks.items()
        for i in idx
    ]
    every = np.isfinite(mag["jax", False])
    rows.append(
        dict(
            feature="all exposures (max |.|)",
            t_s=np.nan,
            jax_sharp_mag=np.nan,
            **{name: np.nanmax(np.abs(d)[every]) for name, d in diffs.items()},
        )
    )
    table = pd.DataFrame(rows)
    out = Path(args.out_dir) / "motion_blur.csv"
    write_result(
        table,
        out,
        **provenance(
            "motion_blur.py",
            quick=args.quick,
            exposures=len(geo),
            step_s=STEP_S,
            cycles=f"{size['resolution']} px, {size['samples']} samples, direct light",
            cycles_motion_blur=curves["cycles", True].attrs["motion_blur"],
            **{
                f"seconds_{r}_{'blur' if b else 'sharp'}": f"{s:.2f}"
                for (r, b), s in seconds.items()
            },
        ),
    )
    with pd.option_context("display.width", 200, "display.float_format", "{:.4f}".format):
        print(table.to_string(index=False))
    print(f"→ {out}")
    plot(geo["t_s"].to_numpy(), mag, marks, table, out.with_suffix(".png"))
    return table


def plot(t, mag, marks, table, path: Path) -> None:
    plt = pyplot()
    fig, (ax, res) = plt.subplots(
        2, 1, figsize=(10, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1.3]}
    )
    styles = {
        ("jax", False): dict(color="tab:blue", ls="-", label="JAX, no blur"),
        ("jax", True): dict(color="tab:red", ls="-", label="JAX, motion blur"),
        ("cycles", False): dict(
            color="tab:blue", ls="none", marker="o", mfc="none", label="Cycles, no blur"
        ),
        ("cycles", True): dict(
            color="tab:red", ls="none", marker="s", mfc="none", label="Cycles, motion blur"
        ),
    }
    for k, st in styles.items():
        ax.plot(t, mag[k], lw=1, ms=5, **st)
    for i in marks["peak"]:
        ax.axvline(t[i], color="0.85", lw=0.8, zorder=0)
    for i in marks["dip"]:
        ax.axvline(t[i], color="k", lw=0.8, ls=":", zorder=0)
        ax.annotate(
            "narrow dark dip",
            (t[i], mag["jax", False][i]),
            fontsize=8,
            xytext=(5, -5),
            textcoords="offset points",
        )
    ax.invert_yaxis()
    ax.set_ylabel("mag")
    ax.legend(fontsize="small", ncol=2, frameon=False)
    peaks = table[table.feature == "peak"]
    ax.set_title(
        f"3U CubeSat spinning in {SPIN_PERIOD_S:g} s about x, 1 s exposures: "
        f"blur dims the peaks by {peaks.jax_blur_change_mag.median():.2f} mag (JAX) / "
        f"{peaks.cycles_blur_change_mag.median():.2f} mag (Cycles), median over {len(peaks)}",
        fontsize=9,
    )
    for blur, c in ((False, "tab:blue"), (True, "tab:red")):
        res.plot(t, mag["cycles", blur] - mag["jax", blur], "o-", ms=3, lw=0.6, color=c,
                 label="blur" if blur else "no blur")  # fmt: skip
    res.axhline(0, color="0.5", lw=0.6)
    res.set_ylabel("Cycles − JAX (mag)")
    res.set_xlabel("time (s)")
    res.legend(fontsize="small", frameon=False)
    save_png(fig, path)


if __name__ == "__main__":
    main()

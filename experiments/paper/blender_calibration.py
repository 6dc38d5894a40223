"""The seed paper's Eq. 7: Blender pixel sums turned into calibrated magnitudes.

1. **The plate.** The seed's 1 × 1 m white Lambert plate at 10 km, Sun behind
   the camera (phase angle 0): its facet-model magnitude m_ff, its Blender
   instrumental magnitude I_mb with the seed's perspective camera (positions
   divided by 1,000) and the zero point m_ff − I_mb that Eq. 7 adds to every
   frame (:func:`calibrate.render.seed_calibration`). The orthographic camera
   needs no zero point (I = B (ortho_scale/N)²): the same plate rendered
   through it, against m_ff, is its calibration error.
2. **The light curve of Fig. 4** (the stage S4 spinning 82.6 s about body x
   over the ``sweep`` pass of :mod:`paper.falcon9_vs_cylinder`), rendered in
   Cycles every ``--every`` seconds with both cameras, direct light only, and
   converted to magnitudes (the seed camera through Eq. 7), against the JAX
   curve with its self-shadowing. The materials are the Cycles-matched
   ``as-glossy`` lobes of S4's (:func:`calibrate.crosscheck.same_material`),
   so both renderers compute the same BRDF; motion blur is off on both sides.

Writes ``blender_calibration.csv`` (quantity rows) and ``.png`` under ``--out-dir``.

    python experiments/paper/blender_calibration.py [--quick] [--every 10] [--out-dir DIR]

``--quick``: 12 frames at 64 px and 16 samples (the test suite's size); the
default is every 10 s (120 frames) at 128 px and 64 samples.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jaxlc
from calibrate.crosscheck import same_material
from calibrate.job import BlenderOptions
from calibrate.render import blender_render, seed_calibration
from jaxlc import RenderOptions
from paper.common import (
    PHASE_SWEEP_START_UTC,
    RESULTS,
    demo_pass,
    provenance,
    pyplot,
    save_png,
    seed_spin,
    write_result,
)

#: The plate faces +z; this turn points it at +x, where the plate geometry puts the Sun.
PLATE_TOWARDS_X = (math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0)


def plate_at_10_km(reference_m: float) -> tuple[jaxlc.Scene, pd.DataFrame]:
    """The S1 plate facing the Sun and the observer (phase angle 0) at ``reference_m``."""
    plate = jaxlc.load_scene("s1_plate")
    attitude = {"model": "fixed", "quaternion": list(PLATE_TOWARDS_X)}
    scene = jaxlc.scene_from_dict(
        {
            "object": {"mesh": str(plate.mesh_path)},
            "material": [{"part": "*", "brdf": "lambert", "rd": 1.0}],
            "attitude": attitude,
        }
    )
    geo = jaxlc.synthetic_geometry(
        duration_s=1.0,
        step_s=1.0,
        phase_start_deg=0.0,
        phase_end_deg=0.0,
        range_start_m=reference_m,
    )
    return scene, geo


def stats(a, b) -> dict:
    d = np.abs(np.asarray(a) - np.asarray(b))
    d = d[np.isfinite(d)]
    return {
        "median": float(np.median(d)),
        "p95": float(np.percentile(d, 95)),
        "max": float(np.max(d)),
        "rms": float(np.sqrt(np.mean(d**2))),
        "frames": len(d),
    }


def main(argv=None) -> pd.DataFrame:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="12 frames, small images")
    ap.add_argument("--every", type=float, default=10.0, help="seconds between Cycles frames")
    ap.add_argument("--out-dir", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    size = dict(resolution=64, samples=16) if args.quick else dict(resolution=128, samples=64)
    every = 100.0 if args.quick else args.every

    seed = BlenderOptions(camera="seed", **size)
    ortho = BlenderOptions(camera="ortho", **size)
    with tempfile.TemporaryDirectory(prefix="jaxlc-paper-") as tmp:
        cal = seed_calibration(seed, Path(tmp))
    plate, plate_geo = plate_at_10_km(seed.reference_m)
    plate_ff = jaxlc.render(plate, plate_geo, precision="float64")["mag"].iloc[0]
    plate_ortho = blender_render(plate, plate_geo, ortho)["mag"].iloc[0]
    rows = [
        dict(quantity="m_ff: plate at 10 km, facet model (mag)", value=cal.m_ff),
        dict(quantity="I_mb: plate at 10 km, Blender seed camera (mag)", value=cal.i_mb),
        dict(quantity="zero point m_ff - I_mb, seed camera (mag)", value=cal.constant),
        dict(quantity="plate at 10 km, jaxlc.render (mag)", value=plate_ff),
        dict(quantity="plate at 10 km, Blender ortho camera (mag)", value=plate_ortho),
        dict(quantity="ortho camera minus facet model, plate (mag)", value=plate_ortho - cal.m_ff),
    ]

    scene = same_material(seed_spin(jaxlc.load_scene("s4_falcon9"), "x"))
    geo = demo_pass(start_utc=PHASE_SWEEP_START_UTC)
    sharp = RenderOptions(blur="off")
    jax_lc = jaxlc.render(scene, geo, options=sharp)
    pick = ((geo["t_s"] % every) < 0.5).to_numpy()
    frames = geo[pick].reset_index(drop=True)
    jax_frames = jax_lc[pick].reset_index(drop=True)  # each row renders on its own
    cycles, seconds = {}, {}
    for name, opts in (("seed", seed), ("ortho", ortho)):
        t0 = time.perf_counter()
        cycles[name] = blender_render(scene, frames, opts)
        seconds[name] = time.perf_counter() - t0
        s = stats(cycles[name]["mag"], jax_frames["mag"])
        rows += [
            dict(quantity=f"S4 light curve, Cycles {name} camera vs JAX: {k} |dm| (mag)", value=v)
            for k, v in s.items()
            if k != "frames"
        ]
        rows.append(dict(quantity=f"S4 light curve, {name} camera: frames", value=s["frames"]))
    d = stats(cycles["seed"]["mag"], cycles["ortho"]["mag"])
    rows.append(
        dict(quantity="S4 light curve, seed vs ortho camera: max |dm| (mag)", value=d["max"])
    )
    table = pd.DataFrame(rows)
    out = Path(args.out_dir) / "blender_calibration.csv"
    write_result(
        table,
        out,
        **provenance(
            "blender_calibration.py",
            quick=args.quick,
            cycles=f"{size['resolution']} px, {size['samples']} samples, direct light, no blur",
            frames_every_s=every,
            seed_scale=seed.scale,
            reference_m=seed.reference_m,
            **{f"cycles_{k}_s": f"{v:.1f}" for k, v in seconds.items()},
        ),
    )
    with pd.option_context("display.width", 200, "display.max_colwidth", 80):
        print(table.to_string(index=False))
    print(f"→ {out}")
    plot(jax_lc, jax_frames, cycles, cal, out.with_suffix(".png"))
    return table


def plot(jax_lc, jax_frames, cycles, cal, path: Path) -> None:
    plt = pyplot()
    fig, (ax, res) = plt.subplots(
        2, 1, figsize=(10, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1.3]}
    )
    ax.plot(jax_lc["t_s"], jax_lc["mag"], lw=0.8, color="k", label="JAX facet model (1 Hz)")
    jax_at = jax_frames["mag"].to_numpy()
    for (name, lc), m, c in zip(cycles.items(), ("o", "s"), ("tab:red", "tab:blue"), strict=True):
        label = "Cycles, seed camera + Eq. 7" if name == "seed" else "Cycles, orthographic camera"
        ax.plot(lc["t_s"], lc["mag"], m, mfc="none", color=c, ms=5, label=label)
        res.plot(lc["t_s"], lc["mag"] - jax_at, m, mfc="none", color=c, ms=4)
    ax.invert_yaxis()
    ax.set_ylabel("mag")
    ax.legend(fontsize="small", frameon=False)
    ax.set_title(
        f"S4 spinning 82.6 s about x (as-glossy, direct light). Seed calibration: "
        f"m_ff = {cal.m_ff:.3f}, I_mb = {cal.i_mb:.3f} (plate at 10 km)",
        fontsize=9,
    )
    res.axhline(0, color="0.5", lw=0.6)
    res.set_ylabel("Cycles − JAX (mag)")
    res.set_xlabel("time since first sample (s)")
    save_png(fig, path)


if __name__ == "__main__":
    main()

"""Cross-validation of the JAX facet model against Blender/Cycles (``jaxlc calibrate crosscheck``).

For each standard scene S1–S6 the materials are turned into their
Cycles-matched form (``lambert`` stays, everything else becomes an isotropic
``as-glossy`` lobe with the same rd, rs and n = √(nu nv)), so the two renderers
compute the same physics. Over a synthetic pass (phase angle 10° → 140°,
1,000 → 2,000 km) each scene is rendered in three modes:

* ``direct`` — Cycles direct light only against the JAX model with its shadow
  approximation (blur off on both sides: one instant per exposure);
* ``bounces`` — Cycles with 4 bounces against the same JAX render: what
  secondary reflections, which the facet model lacks, add;
* ``blur`` — Cycles motion blur (keyframed spin over each exposure) against the
  JAX model's adaptive sub-exposures.

The table gives RMS, median, 95th percentile and max |Δm| per scene and mode,
and the speed of both renderers on the same 20-minute pass at 1 Hz: JAX renders
it whole, Cycles is timed on the sub-sample of frames and scaled (as
BENCHMARKS.md asks). A plot per scene shows both light curves and the residuals.
A timing sweep records Cycles' seconds per frame against resolution and samples.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np
import pandas as pd

import jaxlc
from calibrate.job import BlenderOptions
from calibrate.render import blender_render
from jaxlc import ASGlossy, Lambert, RenderOptions, Scene, load_scene, write_table
from jaxlc.plot import save_figure
from jaxlc.scene import SHIPPED_SCENES, MaterialSpec

#: The standard scenes (shipped with jaxlc) by id.
SCENES = SHIPPED_SCENES
MODES = ("direct", "bounces", "blur")
#: Targets of issue 5 (direct light, same material): RMS |Δm|.
TARGET_RMS_MAG = {"convex": 0.02, "non-convex": 0.05}


def same_material(scene: Scene) -> Scene:
    """The scene with every material in its Cycles-matched form."""
    mats = []
    for m in scene.materials:
        b = m.brdf
        if not isinstance(b, Lambert):
            n = math.sqrt(float(b.nu) * float(b.nv))
            b = ASGlossy(rd=float(b.rd), rs=float(b.rs), nu=n, nv=n)
        mats.append(MaterialSpec(m.part, b))
    return dataclasses.replace(scene, materials=tuple(mats))


def crosscheck_geometry(
    frames: int = 24,
    duration_s: float = 1200.0,
    phase_start_deg: float = 10.0,
    phase_end_deg: float = 140.0,
) -> pd.DataFrame:
    """A synthetic pass sampled at ``frames`` exposures of 1 s."""
    return jaxlc.synthetic_geometry(
        duration_s=duration_s,
        step_s=duration_s / frames,
        phase_start_deg=phase_start_deg,
        phase_end_deg=phase_end_deg,
        range_start_m=1.0e6,
        range_end_m=2.0e6,
        sun_dec_deg=35,
        tilt_deg=50,
        exposure_s=1.0,
    )


def abs_mag_stats(blender: pd.DataFrame, jax_lc: pd.DataFrame) -> dict:
    ok = np.isfinite(blender["mag"]) & np.isfinite(jax_lc["mag"])
    dm = (blender["mag"] - jax_lc["mag"])[ok].to_numpy()
    if not dm.size:
        return dict(
            frames=0,
            rms_mag=np.nan,
            median_abs_mag=np.nan,
            p95_abs_mag=np.nan,
            max_abs_mag=np.nan,
            bias_mag=np.nan,
        )
    a = np.abs(dm)
    return dict(
        frames=int(dm.size),
        rms_mag=float(np.sqrt(np.mean(dm**2))),
        median_abs_mag=float(np.median(a)),
        p95_abs_mag=float(np.percentile(a, 95)),
        max_abs_mag=float(a.max()),
        bias_mag=float(np.mean(dm)),
    )


def run_crosscheck(
    scenes=tuple(SCENES),
    modes=MODES,
    frames: int = 24,
    resolution: int = 128,
    samples: int = 64,
    out_dir: Path | None = None,
    progress=None,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Render, compare and (with ``out_dir``) write the table, per-frame data and plots.

    Returns:
        (summary per scene and mode, per-frame magnitudes of both renderers).
    """
    geo = crosscheck_geometry(frames)
    full = crosscheck_geometry(1200)  # the whole pass at 1 Hz, for the speed ratio
    rows, per_frame = [], []
    for sid in scenes:
        scene = same_material(load_scene(sid))
        convex = scene.facets.convex
        for mode in modes:
            blur = mode == "blur"
            jax_opts = RenderOptions(blur="auto" if blur else "off")
            j = jaxlc.render(scene, geo, options=jax_opts)
            # Speed on the same pass: JAX renders it whole at 1 Hz (warm); Cycles is
            # timed on the sub-sample of frames and scaled to the pass (BENCHMARKS.md).
            jaxlc.render(scene, full, options=jax_opts)
            t0 = time.perf_counter()
            jaxlc.render(scene, full, options=jax_opts)
            jax_pass_s = time.perf_counter() - t0
            jax_s = jax_pass_s / len(full)
            b_opts = BlenderOptions(
                resolution=resolution,
                samples=samples,
                bounces=4 if mode == "bounces" else 0,
                motion_blur=blur,
            )
            b = blender_render(
                scene,
                geo,
                b_opts,
                progress=None
                if progress is None
                else (lambda d, n, s=sid, m=mode: progress(s, m, d, n)),
            )
            blender_s = float(np.nanmean(b["blender_seconds"]))
            stats = abs_mag_stats(b, j)
            target = (
                TARGET_RMS_MAG["convex" if convex else "non-convex"] if mode == "direct" else np.nan
            )
            rows.append(
                dict(
                    scene=sid,
                    mode=mode,
                    convex=convex,
                    shadows="n/a (convex)" if convex else "on",
                    **stats,
                    target_rms_mag=target,
                    meets_target=bool(stats["rms_mag"] <= target) if mode == "direct" else None,
                    blender_s_per_frame=blender_s,
                    jax_s_per_frame=jax_s,
                    pass_frames=len(full),
                    blender_pass_s_scaled=blender_s * len(full),
                    jax_pass_s=jax_pass_s,
                    speed_ratio=blender_s / jax_s if jax_s > 0 else np.nan,
                    resolution=resolution,
                    samples=samples,
                    motion_blur=b.attrs["motion_blur"],
                )
            )
            per_frame.append(
                pd.DataFrame(
                    {
                        "scene": sid,
                        "mode": mode,
                        "t_s": j["t_s"],
                        "phase_angle_deg": j["phase_angle_deg"],
                        "mag_jax": j["mag"],
                        "mag_blender": b["mag"],
                    }
                )
            )
    summary = pd.DataFrame(rows)
    frames_df = pd.concat(per_frame, ignore_index=True)
    if out_dir is not None:
        out_dir = Path(out_dir)
        write_table(summary, out_dir / "crosscheck.csv")
        write_table(frames_df, out_dir / "crosscheck_frames.csv")
        for sid in scenes:
            plot_scene(
                frames_df[frames_df.scene == sid],
                summary[summary.scene == sid],
                out_dir / f"crosscheck_{sid}.png",
            )
    return summary, frames_df


def plot_scene(frames_df: pd.DataFrame, summary: pd.DataFrame, path: Path) -> Path:
    """Both light curves per mode, and Cycles − JAX residuals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, res) = plt.subplots(
        2, 1, figsize=(9, 6), sharex=True, gridspec_kw={"height_ratios": [2.2, 1]}
    )
    colours = {"direct": "tab:blue", "bounces": "tab:green", "blur": "tab:red"}
    for mode, g in frames_df.groupby("mode", sort=False):
        c = colours.get(mode, "k")
        ax.plot(g["phase_angle_deg"], g["mag_jax"], "-", color=c, lw=1, label=f"JAX ({mode})")
        ax.plot(
            g["phase_angle_deg"],
            g["mag_blender"],
            "o",
            color=c,
            ms=3.5,
            mfc="none",
            label=f"Cycles ({mode})",
        )
        s = summary[summary["mode"] == mode]
        rms = float(s["rms_mag"].iloc[0]) if len(s) else float("nan")
        res.plot(
            g["phase_angle_deg"],
            g["mag_blender"] - g["mag_jax"],
            "o-",
            color=c,
            ms=3,
            lw=0.8,
            label=f"{mode}: RMS {rms:.4f} mag",
        )
    ax.invert_yaxis()
    ax.set_ylabel("magnitude")
    ax.legend(fontsize=7, ncol=3)
    ax.grid(alpha=0.3)
    scene = frames_df["scene"].iloc[0] if len(frames_df) else ""
    ax.set_title(f"{scene}: Cycles against the JAX facet model (same material)")
    res.axhline(0, color="0.5", lw=0.8)
    res.set_ylabel("Cycles − JAX (mag)")
    res.set_xlabel("phase angle (°)")
    res.legend(fontsize=7)
    res.grid(alpha=0.3)
    return save_figure(fig, path, dpi=110)


def timing_sweep(
    scene_id: str = "S4",
    resolutions=(64, 128, 256),
    samples=(16, 64, 256),
    frames: int = 4,
    out_dir: Path | None = None,
) -> pd.DataFrame:
    """Cycles seconds per frame against resolution and samples (direct light)."""
    scene = same_material(load_scene(scene_id))
    geo = crosscheck_geometry(frames)
    rows = []
    for res in resolutions:
        for spp in samples:
            b = blender_render(scene, geo, BlenderOptions(resolution=res, samples=spp))
            rows.append(
                dict(
                    scene=scene_id,
                    resolution=res,
                    samples=spp,
                    s_per_frame=float(np.nanmedian(b["blender_seconds"])),
                )
            )
    df = pd.DataFrame(rows)
    if out_dir is not None:
        write_table(df, Path(out_dir) / "crosscheck_timing.csv")
    return df

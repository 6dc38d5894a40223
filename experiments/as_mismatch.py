"""How far Cycles' closest material is from jaxlc's ``ashikhmin-shirley`` BRDF.

Cycles has no Schlick Fresnel term and no 28/23 diffuse shape, so
``calibrate.job.material_spec`` maps ``ashikhmin-shirley`` to Lambert
(albedo rd(1 − rs)) + the AS glossy lobe (colour rs). This script renders the
standard scenes that use ``ashikhmin-shirley`` (S3–S6) with their *native*
materials in Cycles (direct light) and in JAX, over the cross-check pass, and
writes the |Δm| statistics per scene plus the per-frame residuals against
phase angle:

    python experiments/as_mismatch.py   # ~2 min on 2 cores

Output: experiments/results/as_mismatch.csv, as_mismatch_frames.csv, as_mismatch.png
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import pandas as pd

import jaxlc
from calibrate.crosscheck import abs_mag_stats, crosscheck_geometry
from calibrate.job import BlenderOptions
from calibrate.render import blender_render
from jaxlc.io.tables import write_table
from jaxlc.plot import save_figure
from jaxlc.rendering.options import RenderOptions
from jaxlc.scene import load_scene

REPO = Path(__file__).resolve().parent.parent
OUT = REPO / "experiments" / "results"


def main(frames: int = 24) -> pd.DataFrame:
    geo = crosscheck_geometry(frames)
    rows, per = [], []
    for sid in ("S3", "S4", "S5", "S6"):
        scene = load_scene(sid)
        j = jaxlc.render(scene, geo, options=RenderOptions(blur="off"))
        b = blender_render(scene, geo, BlenderOptions(resolution=128, samples=64))
        rows.append(dict(scene=sid, material="ashikhmin-shirley (native)", **abs_mag_stats(b, j)))
        per.append(
            pd.DataFrame(
                dict(
                    scene=sid,
                    phase_angle_deg=j["phase_angle_deg"],
                    mag_jax=j["mag"],
                    mag_blender=b["mag"],
                    dmag=b["mag"] - j["mag"],
                )
            )
        )
        print(rows[-1])
    summary = pd.DataFrame(rows)
    frames_df = pd.concat(per, ignore_index=True)
    write_table(summary, OUT / "as_mismatch.csv")
    write_table(frames_df, OUT / "as_mismatch_frames.csv")
    fig, ax = plt.subplots(figsize=(7, 4))
    for sid, g in frames_df.groupby("scene"):
        ax.plot(g.phase_angle_deg, g.dmag, "o-", ms=3, label=sid)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("phase angle [deg]")
    ax.set_ylabel("m(Cycles) − m(JAX) [mag]")
    ax.set_title("ashikhmin-shirley: Cycles' closest material vs the facet model")
    ax.legend()
    save_figure(fig, OUT / "as_mismatch.png", dpi=120)
    return summary


if __name__ == "__main__":
    print(main().to_string(index=False))

"""The shadow approximation's tail against the exact twin (issue 16 item 4, first step).

Over the committed 1,000 random geometries of tests/data/shadow_reference_*.csv
(S4, S6; exact polygon clipping), for the geometries lit and seen at phase
≤ 160°: median, 95th and 99th percentile and max |Δm| of the facet model's
I/E, at a 32 × 32 and a 64 × 64 direction grid. Prints one line per setting:

    python experiments/shadow_tail.py [s4_falcon9 s6_boxwing]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

import jaxlc  # noqa: E402
from jaxlc.body.shadow import ShadowSettings  # noqa: E402
from jaxlc.rendering.kernel import body_intensity  # noqa: E402
from jaxlc.rendering.prepare import space_object  # noqa: E402

DATA = HERE.parent / "tests" / "data"


def tail(name: str, settings: ShadowSettings) -> str:
    ref = jaxlc.read_table(DATA / f"shadow_reference_{name.split('_')[0]}.csv")
    scene = jaxlc.load_scene(name)
    s = ref[["sun_x", "sun_y", "sun_z"]].to_numpy()
    v = ref[["obs_x", "obs_y", "obs_z"]].to_numpy()
    phase = np.degrees(np.arccos(np.clip(np.sum(s * v, 1), -1, 1)))
    exact = ref["i_exact_m2_sr"].to_numpy()
    keep = (exact > 0) & (phase <= 160)
    t0 = time.perf_counter()
    obj = space_object(scene, None, jnp.float32, shadow=settings)
    got = np.asarray(
        body_intensity(obj, jnp.asarray(s, jnp.float32), jnp.asarray(v, jnp.float32)), np.float64
    )
    dm = np.abs(2.5 * np.log10(got[keep] / exact[keep]))
    q = np.percentile(dm, [50, 95, 99])
    return (
        f"{name} grid {settings.grid}: {keep.sum()} geometries, median {q[0]:.4f} "
        f"p95 {q[1]:.4f} p99 {q[2]:.4f} max {dm.max():.3f} mag ({time.perf_counter() - t0:.0f} s)"
    )


if __name__ == "__main__":
    for name in sys.argv[1:] or ["s4_falcon9", "s6_boxwing"]:
        for grid in (32, 64):
            print(tail(name, ShadowSettings(grid=grid)), flush=True)

"""Exact-twin reference data for the shadow approximation (tests/data/shadow_reference_*.csv).

Per scene, n random geometries (Sun and observer directions
drawn isotropically in the body frame, fixed seed), the object's I/E with
exact self-shadowing (polygon clipping, :mod:`jaxlc.body.shadow_exact`, float64)
and without shadows. The CSV's metadata records the SHA-256 of the scene file
and of the mesh, so a test can tell when the reference is stale.

Committed: every scene at n = 2,000 (S4 ~35 minutes on 2 cores: the twin needs
~2 s per geometry; S6, S7 and S8 ~15-25 s each):

    python experiments/make_shadow_reference.py --n 2000 \\
        --scenes s4_falcon9 s6_boxwing s7_antenna_box s8_boom_panel
"""

from __future__ import annotations

import argparse
import hashlib
import multiprocessing as mp
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

import jaxlc  # noqa: E402
from jaxlc.io.tables import write_table  # noqa: E402

OUT = HERE.parent / "tests" / "data"
SEED = 20261122


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def geometries(n: int, seed: int = SEED) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) Sun and observer unit vectors, isotropic in the body frame."""
    rng = np.random.default_rng(seed)
    s = rng.normal(size=(n, 3))
    v = rng.normal(size=(n, 3))
    return s / np.linalg.norm(s, axis=1, keepdims=True), v / np.linalg.norm(
        v, axis=1, keepdims=True
    )


def twin_intensities(args):
    """(exact, unshadowed) I/E of (scene path, Sun, observer) for one pool worker."""
    scene_path, s, v = args
    import jax
    import jax.numpy as jnp

    from jaxlc.body.facet_model import facet_contributions, facet_model
    from jaxlc.body.shadow_exact import ExactShadows, exact_intensity

    scene = jaxlc.load_scene(scene_path)
    exact = ExactShadows(scene.mesh, scene.facets)
    with jax.enable_x64(True):
        model = facet_model(scene.facets, scene.materials_for(scene.facets.part_names), jnp.float64)
        plain = np.asarray(facet_contributions(model, jnp.asarray(s), jnp.asarray(v))).sum(axis=1)
    return exact_intensity(model, exact, s, v), plain


def reference(scene_name: str, n: int, workers: int) -> pd.DataFrame:
    scene_path = jaxlc.scene_path(scene_name)
    scene = jaxlc.load_scene(scene_path)
    s, v = geometries(n)
    t0 = time.perf_counter()
    parts = np.array_split(np.arange(n), max(1, workers * 8))
    with mp.get_context("fork").Pool(workers) as pool:
        done = pool.map(twin_intensities, [(scene_path, s[p], v[p]) for p in parts])
    exact = np.concatenate([d[0] for d in done])
    plain = np.concatenate([d[1] for d in done])
    df = pd.DataFrame(
        {
            **{f"sun_{c}": s[:, k] for k, c in enumerate("xyz")},
            **{f"obs_{c}": v[:, k] for k, c in enumerate("xyz")},
            "i_exact_m2_sr": exact,
            "i_unshadowed_m2_sr": plain,
        }
    )
    df.attrs.update(
        {
            "generator": "experiments/make_shadow_reference.py",
            "method": "exact polygon clipping (jaxlc.body.shadow_exact), float64",
            "scene": scene_path.name,
            "scene_sha256": sha256(scene_path),
            "mesh": scene.mesh_path.name,
            "mesh_sha256": sha256(scene.mesh_path),
            "seed": str(SEED),
            "n": str(n),
            "jaxlc": jaxlc.__version__,
            "seconds": f"{time.perf_counter() - t0:.0f}",
        }
    )
    return df


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="+", default=["s6_boxwing", "s4_falcon9"])
    parser.add_argument("--n", type=int, default=1000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    for name in args.scenes:
        df = reference(name, args.n, args.workers)
        path = write_table(df, args.out / f"shadow_reference_{name.split('_')[0]}.csv")
        print(f"{name}: {args.n} geometries in {df.attrs['seconds']} s → {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

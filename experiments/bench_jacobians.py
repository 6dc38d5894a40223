"""Time the fits' forward models and their Jacobians, compiled as the fits compile them
(:func:`jaxlc.xla.filter_jit`, the solvers' decorator).

Rows (median ± IQR of alternating calls, ``experiments/timing.timed_interleaved``):

* ``tumble rotations``: :meth:`jaxlc.body.tumble.Tumble.rotation` of 32 tumbles
  (the search's block) at 496 instants, and its ``jacfwd`` in the fit's 10 coordinates
  (the attitude map of a :class:`~jaxlc.inference.tumble_model.TumbleModel`);
* ``s5 refinement model``: the exact S5 spin model of a 600-sample pass at the
  shortest candidate period (64 sub-exposures: 38,400 instants, 8 facets), 6 starts
  (the refinement's block): its magnitudes and their Jacobian (through body turns).

    python experiments/bench_jacobians.py [--cores 1]

``--cores 1`` pins the process to one core (``os.sched_setaffinity``) before JAX
starts. Writes ``experiments/results/bench_jacobians.csv``.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ap.add_argument("--cores", type=int, default=0, help="pin to this many cores (0: all)")
ARGS = ap.parse_args()
if ARGS.cores:
    os.sched_setaffinity(0, set(sorted(os.sched_getaffinity(0))[: ARGS.cores]))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from timing import timed_interleaved  # noqa: E402

import jaxlc  # noqa: E402
from jaxlc.inference import tumble_model as tm  # noqa: E402
from jaxlc.inference.data import fit_data  # noqa: E402
from jaxlc.inference.model import spin_model, truth_theta  # noqa: E402
from jaxlc.xla import filter_jit  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "bench_jacobians.csv"


def tumble_rows() -> list[dict]:
    """The tumble fit's attitude map (:meth:`TumbleModel.attitude`) of a shipped tumbling
    scene's search model, at 32 random coordinates."""
    scene = jaxlc.load_scene("falcon9_tumble")
    geo = jaxlc.synthetic_geometry(duration_s=120.0, phase_start_deg=30, phase_end_deg=60)
    data = fit_data(jaxlc.render(scene, geo), geo, default_exposure_s=scene.exposure_s)
    model = tm.tumble_model(scene, data, tm.truth_theta(scene, data, 0.05), 0.05, exact=False)
    rng = np.random.default_rng(0)
    starts, instants = 32, 496
    theta = np.concatenate(
        [rng.normal(size=(starts, 2)), 0.3 * rng.normal(size=(starts, 3)),
         rng.normal(size=(starts, 4)), np.zeros((starts, 1))], axis=1,
    )  # fmt: skip
    theta = jnp.asarray(theta, jnp.float32)
    t = jnp.asarray(np.linspace(0.0, 600.0, instants), jnp.float32)

    def rotation(th):
        return model.attitude(th).rotation(t)

    fns = {
        "value": filter_jit(lambda th: jax.vmap(rotation)(th)),
        "jacobian": filter_jit(lambda th: jax.vmap(jax.jacfwd(rotation))(th)),
    }
    got = timed_interleaved({k: (lambda f=f: f(theta)) for k, f in fns.items()})
    size = f"{starts} tumbles × {instants} instants"
    return [row("tumble rotations", k, size, v) for k, v in got.items()]


def s5_rows() -> list[dict]:
    scene = jaxlc.load_scene("s5_cubesat")
    geo = jaxlc.synthetic_geometry(duration_s=600.0, phase_start_deg=30, phase_end_deg=90)
    data = fit_data(jaxlc.render(scene, geo), geo, default_exposure_s=scene.exposure_s)
    model = spin_model(scene, data, scene.attitude.period_s / 2, exact=True)
    truth = truth_theta(scene, data)
    starts = 6
    thetas = model.to_device(truth[None] + 0.01 * np.random.default_rng(0).normal(size=(starts, 6)))
    fns = {
        "value": filter_jit(lambda th: jax.vmap(model.magnitudes)(th)),
        "jacobian": filter_jit(lambda th: jax.vmap(jax.jacfwd(model.magnitudes))(th)),
    }
    got = timed_interleaved({k: (lambda f=f: f(thetas)) for k, f in fns.items()})
    size = f"{starts} starts × {len(model.inputs.weight)} instants × {model.obj.n_facets} facets"
    return [row("s5 refinement model", k, size, v) for k, v in got.items()]


def row(what: str, kind: str, size: str, timing) -> dict:
    median, iqr, reps = timing
    return {"what": what, "evaluation": kind, "size": size, "ms": 1e3 * median,
            "iqr_ms": 1e3 * iqr, "repeats": reps}  # fmt: skip


def main() -> None:
    df = pd.DataFrame(tumble_rows() + s5_rows())
    df.attrs.update(
        {
            "generator": "experiments/bench_jacobians.py",
            "jaxlc": jaxlc.__version__,
            "cores": str(len(os.sched_getaffinity(0))),
            "date_utc": pd.Timestamp.now(tz="UTC").strftime("%Y-%m-%dT%H:%M:%SZ"),
        }
    )
    print(df.to_string(index=False, float_format=lambda x: f"{x:.2f}"))
    jaxlc.write_table(df, OUT)


if __name__ == "__main__":
    main()

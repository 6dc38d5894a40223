"""Speed and accuracy of the JAX facet model (``make bench``).

Three tables, all from one run on one machine (absolute seconds drift on a
shared machine; compare ratios within a run):

A. one light curve of 1,800 samples (a 30-minute pass at 1 Hz) per standard
   scene S2–S6, float32 and float64: samples/s, facet-samples/s (facets after
   merging) and the float32 error against float64 over the same pass;
B. bulk: a batch of objects with random spin states rendered by ``jax.vmap``
   (the path of dataset generation): light curves/s;
C. the facet kernel itself on S2 (5,120 facets) and S4 (1,205 facets) with an
   Ashikhmin–Shirley material: a naive unfused JAX sum (whole facets × samples
   arrays, as a first implementation would write it) against the fused,
   chunked kernel with XLA's default CPU pipeline, with jaxlc's options, and
   with them and 512-bit vectors (what :func:`jaxlc.xla.jit` compiles where safe;
   tables A, B and D use that jit too).

Every time is the median of repeated calls after a warm-up (compilation not
included), with the interquartile range as its error. Writes
``experiments/results/bench_render.csv``.

    python experiments/bench_render.py [--quick] [--out PATH]
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import platform
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from timing import timed, timed_interleaved  # noqa: E402

import jaxlc  # noqa: E402
from jaxlc.body.brdf import AshikhminShirley  # noqa: E402
from jaxlc.body.facet_model import facet_intensity, facet_model  # noqa: E402
from jaxlc.io.tables import write_table  # noqa: E402
from jaxlc.rendering import photometry  # noqa: E402
from jaxlc.rendering.kernel import exposure_intensity, stack_objects, time_chunk  # noqa: E402
from jaxlc.xla import compiler_options, jit, wide_options  # noqa: E402

#: The instantaneous, unshadowed facet model (what tables A-C time).
PLAIN = jaxlc.RenderOptions(shadows="off", blur="off")

SCENES = {
    "S2": "s2_sphere",
    "S3": "s3_cylinder",
    "S4": "s4_falcon9",
    "S5": "s5_cubesat",
    "S6": "s6_boxwing",
}


def _row(table, scene, facets, triangles, precision, variant, batch, samples, timing, **extra):
    """One result row: the timing (median, IQR, repeats) and the rates derived from it."""
    med, iqr, reps = timing
    return dict(
        table=table,
        scene=scene,
        facets=facets,
        triangles=triangles,
        precision=precision,
        variant=variant,
        batch=batch,
        samples=samples,
        seconds=med,
        seconds_iqr=iqr,
        repeats=reps,
        samples_per_s=batch * samples / med,
        facet_samples_per_s=batch * samples * facets / med,
        lightcurves_per_s=batch / med,
        **extra,
    )


def pass_geometry(n_samples: int):
    return jaxlc.synthetic_geometry(
        duration_s=float(n_samples),
        step_s=1.0,
        phase_start_deg=20,
        phase_end_deg=120,
        range_start_m=1.0e6,
        range_end_m=2.0e6,
    )


def _kernel():
    """The kernel as jaxlc.render compiles it (512-bit vectors where safe, jaxlc.xla)."""
    return jit(exposure_intensity)


def single_curves(table, repeats_s):
    rows = []
    for sid, name in SCENES.items():
        mags = {}
        for precision in ("float32", "float64"):
            with jax.enable_x64(precision == "float64"):
                p = jaxlc.prepare(name, table, PLAIN, precision)
                f = _kernel()
                timing = timed(functools.partial(f, p.object, p.inputs), repeats_s)
                i = np.asarray(f(p.object, p.inputs), np.float64)
            g = p.geometry
            mags[precision] = photometry.magnitude(
                photometry.flux_w_m2(i, g.irradiance_w_m2, g.range_m)
            )
            rows.append(
                _row(
                    "A",
                    sid,
                    p.object.n_facets,
                    p.scene.facets.n_triangles,
                    precision,
                    "jaxlc",
                    1,
                    g.n_rows,
                    timing,
                )
            )
        ok = np.isfinite(mags["float32"]) & np.isfinite(mags["float64"])
        dm = np.abs(mags["float32"][ok] - mags["float64"][ok])
        for r in rows[-2:]:
            r.update(
                f32_err_median_mag=float(np.median(dm)),
                f32_err_p99_mag=float(np.percentile(dm, 99)),
                f32_err_max_mag=float(dm.max()),
            )
    return rows


def random_spins(name, table, n, rng):
    """n preparations of a scene with isotropic poles, log-uniform 5–200 s periods."""
    scene = jaxlc.load_scene(name)
    pole = rng.normal(size=(n, 3))
    pole /= np.linalg.norm(pole, axis=1, keepdims=True)
    out = []
    for k in range(n):
        spun = scene.with_spin(
            period_s=float(np.exp(rng.uniform(np.log(5), np.log(200)))),
            pole_ra_deg=math.degrees(math.atan2(pole[k, 1], pole[k, 0])),
            pole_dec_deg=math.degrees(math.asin(pole[k, 2])),
            phase_deg=float(rng.uniform(0, 360)),
        )
        out.append(jaxlc.prepare(spun, table, PLAIN))
    return out


def bulk(table, batch, repeats_s):
    rows = []
    rng = np.random.default_rng(0)
    f = jit(jax.vmap(exposure_intensity))
    for sid in ("S3", "S4", "S5", "S6"):
        prepared = random_spins(SCENES[sid], table, batch, rng)
        stacked = stack_objects([p.object for p in prepared])
        inputs = jax.tree_util.tree_map(lambda *x: np.stack(x), *[p.inputs for p in prepared])
        timing = timed(functools.partial(f, stacked, inputs), repeats_s)
        rows.append(
            _row(
                "B",
                sid,
                stacked.model.n_facets,
                prepared[0].scene.facets.n_triangles,
                "float32",
                "jaxlc, vmap",
                batch,
                prepared[0].geometry.n_rows,
                timing,
            )
        )
    return rows


def naive_as_sum(normals, u, w, area, rd, rs, nu, nv, s, v):
    """A first implementation: whole (F, T) arrays by matrix products, the formula as written."""
    mu0 = normals @ s.T
    mu = normals @ v.T
    h = (s + v) / jnp.linalg.norm(s + v, axis=-1, keepdims=True)
    nh = normals @ h.T
    hu = u @ h.T
    hw = w @ h.T
    hs = jnp.sum(h * s, axis=-1)[None, :]
    lit = (mu0 > 0) & (mu > 0)
    rho_d = 28 * rd / (23 * jnp.pi) * (1 - rs) * (1 - (1 - mu0 / 2) ** 5) * (1 - (1 - mu / 2) ** 5)
    z = (nu * hu**2 + nv * hw**2) / jnp.maximum(1 - nh**2, 1e-12)
    fresnel = rs + (1 - rs) * (1 - hs) ** 5
    rho_s = jnp.sqrt((nu + 1) * (nv + 1)) / (8 * jnp.pi) * jnp.maximum(nh, 1e-30) ** z
    rho_s = rho_s / (hs * jnp.maximum(mu0, mu)) * fresnel
    return jnp.sum(jnp.where(lit, area[:, None] * (rho_d + rho_s) * mu0 * mu, 0.0), axis=0)


def _chunked_kernel(model, s, v, chunk):
    """The fused kernel over time chunks (what light_curve_intensity runs per chunk)."""
    blocks = (s.reshape(-1, chunk, 3), v.reshape(-1, chunk, 3))
    return jax.lax.map(lambda a: facet_intensity(model, a[0], a[1]), blocks).reshape(-1)


def kernel_variants(n, repeats_s):
    rows = []
    rng = np.random.default_rng(1)
    s = rng.normal(size=(n, 3))
    v = rng.normal(size=(n, 3))
    s = jnp.asarray(s / np.linalg.norm(s, axis=1, keepdims=True), jnp.float32)
    v = jnp.asarray(v / np.linalg.norm(v, axis=1, keepdims=True), jnp.float32)
    brdf = AshikhminShirley(rd=0.5, rs=0.2, nu=100.0, nv=100.0)
    for sid in ("S2", "S4"):
        facets = jaxlc.load_scene(SCENES[sid]).facets
        model = facet_model(facets, [brdf] * len(facets.part_names), jnp.float32)
        nf = model.n_facets
        area = jnp.asarray(facets.areas_m2, jnp.float32)
        naive = jax.jit(naive_as_sum)
        naive_args = (
            model.normals,
            model.tangent_u,
            model.tangent_w,
            area,
            0.5,
            0.2,
            100.0,
            100.0,
            s,
            v,
        )
        chunk = time_chunk(nf)
        pad = (-n) % chunk
        sp = jnp.pad(s, ((0, pad), (0, 0)))
        vp = jnp.pad(v, ((0, pad), (0, 0)))
        fused_default = jax.jit(functools.partial(_chunked_kernel, chunk=chunk))
        chunked = functools.partial(_chunked_kernel, chunk=chunk)
        fused_jaxlc = jax.jit(chunked, compiler_options=compiler_options())
        variants = {
            "naive unfused": functools.partial(naive, *naive_args),
            "fused, XLA defaults": functools.partial(fused_default, model, sp, vp),
            "fused, jaxlc options": functools.partial(fused_jaxlc, model, sp, vp),
        }
        if wide_options() is not None:  # the CPU: what jaxlc.xla.jit uses where safe
            fused_wide = jax.jit(chunked, compiler_options=wide_options())
            variants["fused, jaxlc options, 512-bit"] = functools.partial(fused_wide, model, sp, vp)
        ref = np.asarray(naive(*naive_args))
        fused = np.asarray(variants["fused, jaxlc options"]())[:n]
        agreement = float(np.max(np.abs(fused - ref)) / np.max(ref))
        timings = timed_interleaved(variants, repeats_s)
        naive_s = timings["naive unfused"][0]
        for name, timing in timings.items():
            rows.append(
                _row(
                    "C",
                    sid,
                    nf,
                    facets.n_triangles,
                    "float32",
                    name,
                    1,
                    n,
                    timing,
                    speedup_vs_naive=naive_s / timing[0],
                    naive_vs_fused_max_rel_diff=agreement,
                )
            )
    return rows


def plan_costs(table, repeats_s, quick):
    """D: shadowed / unshadowed (S4, S6) and blurred / sharp (S5) cost, interleaved.

    The shadow precomputation is timed with the cache bypassed (a one-off cost
    per mesh and resolution; later renders load the table from disk).
    """
    from jaxlc.body.shadow import shadow_data

    rows = []
    f = _kernel()
    for sid, name in (("S4", "s4_falcon9"), ("S6", "s6_boxwing"), ("S5", "s5_cubesat")):
        plain = jaxlc.prepare(name, table, PLAIN)
        scene = plain.scene
        variants, extra = {"plain": functools.partial(f, plain.object, plain.inputs)}, {}
        if not scene.facets.convex:
            if not quick:
                mesh, facets = scene.body
                data = shadow_data(mesh, facets, scene.render.shadow, use_cache=False)
                extra = dict(
                    precompute_s=data.seconds, table_mb=data.nbytes / 1e6, subpoints=data.subpoints
                )
            shadowed = jaxlc.prepare(scene, table, jaxlc.RenderOptions(blur="off"))
            variants["shadows"] = functools.partial(f, shadowed.object, shadowed.inputs)
        else:
            blurred = jaxlc.prepare(scene, table, jaxlc.RenderOptions(shadows="off"))
            n = blurred.plan.subsamples
            variants[f"blur, {n} sub-exposures"] = functools.partial(
                f, blurred.object, blurred.inputs
            )
        timings = timed_interleaved(variants, repeats_s)
        base = timings["plain"][0]
        for name_v, timing in timings.items():
            rows.append(
                _row(
                    "D",
                    sid,
                    plain.object.n_facets,
                    scene.facets.n_triangles,
                    "float32",
                    name_v,
                    1,
                    plain.geometry.n_rows,
                    timing,
                    cost_vs_plain=timing[0] / base,
                    **(extra if name_v == "shadows" else {}),
                )
            )
    return rows


def print_table(df: pd.DataFrame) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(
        title="jaxlc render benchmark: median over repeats ± IQR",
        caption="A: one 1,800-sample curve per scene; B: a vmapped batch with random spins; "
        "C: the AS facet kernel alone (float32); D: shadows and blur against the plain render",
    )
    for col in (
        "table",
        "scene",
        "facets",
        "precision",
        "variant",
        "batch",
        "ms/call",
        "samples/s",
        "facet-samples/s",
        "curves/s",
        "f32 err med/max (mag)",
        "× plain",
    ):
        table.add_column(col, justify="right" if col not in ("table", "variant") else "left")
    for r in df.itertuples():
        err = ""
        if isinstance(getattr(r, "f32_err_max_mag", None), float) and not math.isnan(
            r.f32_err_max_mag
        ):
            err = f"{r.f32_err_median_mag:.1e} / {r.f32_err_max_mag:.1e}"
        table.add_row(
            r.table,
            r.scene,
            str(r.facets),
            r.precision,
            r.variant,
            str(r.batch),
            f"{r.seconds * 1e3:.2f} ± {r.seconds_iqr * 1e3:.2f}",
            f"{r.samples_per_s:.3g}",
            f"{r.facet_samples_per_s:.3g}",
            f"{r.lightcurves_per_s:.3g}",
            err,
            f"{r.cost_vs_plain:.2f}"
            if isinstance(getattr(r, "cost_vs_plain", None), float)
            and not math.isnan(r.cost_vs_plain)
            else "",
        )
    Console(width=170).print(table)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="few samples and repeats (smoke test)")
    parser.add_argument("--out", type=Path, default=HERE / "results" / "bench_render.csv")
    args = parser.parse_args(argv)
    n_samples, batch, repeats_s = (120, 4, 0.05) if args.quick else (1800, 64, 1.0)
    table = pass_geometry(n_samples)
    rows = (
        single_curves(table, repeats_s)
        + bulk(table, batch, repeats_s)
        + kernel_variants(n_samples, repeats_s)
        + plan_costs(table, repeats_s, args.quick)
    )
    df = pd.DataFrame(rows)
    df.attrs.update(
        {
            "generator": "experiments/bench_render.py",
            "jaxlc": jaxlc.__version__,
            "jax": jax.__version__,
            "backend": jax.default_backend(),
            "devices": ", ".join(d.device_kind for d in jax.devices()),
            "cpu_count": str(os.cpu_count()),
            "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
            "date_utc": pd.Timestamp.now(tz="UTC").strftime("%Y-%m-%dT%H:%M:%SZ"),
            "quick": str(args.quick),
        }
    )
    print_table(df)
    write_table(df, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Render bulk datasets: shards of curves, run in this process or on Dask.

A shard is a pure function of (config, shard index) (:func:`render_shard`):
its curves are drawn (:func:`jaxlc.dataset.draw_curve`), grouped by shape
class and rendered in batches (:mod:`jaxlc.bulk_render`), their flux turned
into magnitudes and, with a noise model, noisy values (:mod:`jaxlc.noise`).
:func:`generate` renders the missing shards of a store
(:mod:`jaxlc.datastore`): in this process (``workers=0``), on a local Dask
cluster (worker processes, one thread each) or on a cluster given by its
scheduler address, with a progress bar.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pandas as pd

from jaxlc import photometry
from jaxlc.bulk_render import class_kit, curve_geometry, render_class
from jaxlc.dataset import (
    DatasetConfig,
    DatasetError,
    PassSource,
    SyntheticSource,
    curve_rng,
    draw_curve,
    load_config,
)

# ---------------------------------------------------------------------------
# One shard


@dataclasses.dataclass(frozen=True)
class Shard:
    """A rendered shard: rows ``start … start + len(labels)`` of every array.

    Attributes:
        index: shard number.
        start: first curve.
        arrays: name → (n, T) arrays in their store dtypes.
        labels: (n rows) the label columns of :data:`jaxlc.datastore.LABELS`.
    """

    index: int
    start: int
    arrays: dict
    labels: pd.DataFrame


def render_shard(config: DatasetConfig, shard: int, pool=None) -> Shard:
    """Render shard ``shard`` of a dataset (a pure function of its arguments).

    Args:
        config: the dataset config.
        shard: shard index, 0 … n_shards − 1.
        pool: the pass pool (:class:`jaxlc.geometry.pool.PassPool`) for real passes.
    """
    from jaxlc.noise import add_noise, magnitude_of, scintillation_rel

    rows = config.shard_rows(shard)
    if isinstance(config.geometry, PassSource) and pool is None:
        raise DatasetError("render_shard: real-pass geometry needs the pass pool")
    lengths = pool.length if pool is not None else None
    curves = [draw_curve(config, i, lengths) for i in rows]
    geos = [curve_geometry(config, c, pool) for c in curves]
    n, t_len = len(curves), config.samples
    intensity = np.full((n, t_len), np.nan)
    subs = np.zeros(n, dtype=np.int64)
    shadows = np.zeros(n, dtype=bool)
    for class_id in sorted({c.class_id for c in curves}):
        idx = [j for j, c in enumerate(curves) if c.class_id == class_id]
        cls = config.classes[class_id]
        kit = class_kit(cls)
        mean, s = render_class(config, cls, kit, [curves[j] for j in idx], [geos[j] for j in idx])
        intensity[idx], subs[idx], shadows[idx] = mean, s, kit.shadow is not None

    vis = np.stack([g.visible for g in geos])
    bad = vis & ~np.isfinite(intensity)
    if bad.any():
        j = int(np.flatnonzero(bad.any(axis=1))[0])
        raise DatasetError(
            f"shard {shard}: curve {curves[j].index} gave a non-finite intensity on "
            f"{int(bad[j].sum())} visible sample(s); please report this with the config"
        )
    factor = np.array([c.scale for c in curves]) ** 2
    flux = np.stack(
        [
            photometry.flux_w_m2(intensity[j] * factor[j], g.irradiance_w_m2, g.range_m)
            for j, g in enumerate(geos)
        ]
    )
    flux[~vis] = np.nan
    mag = photometry.magnitude(flux)
    arrays = {
        "mag": mag.astype(np.float32),
        "flux_w_m2": flux.astype(np.float32),
        "phase_angle_deg": np.stack([g.phase_angle_deg for g in geos]).astype(np.float32),
        "range_m": np.stack([g.range_m for g in geos]).astype(np.float32),
        "visible": vis,
    }
    if config.noise is not None:
        nm = config.noise
        noisy = np.full_like(flux, np.nan)
        err = np.full_like(flux, np.nan)
        for j, (c, g) in enumerate(zip(curves, geos, strict=True)):
            scint = 0.0
            if nm.aperture_m is not None:
                alt = (
                    nm.altitude_m
                    if nm.altitude_m is not None
                    else pool.site_alt_m[c.geometry["pass_id"]]
                )
                scint = scintillation_rel(nm.aperture_m, g.airmass, alt, config.exposure_s)
            noisy[j], err[j] = add_noise(
                flux[j],
                config.exposure_s,
                curve_rng(config.seed, c.index, stream=1),
                nm.zero_point_mag,
                nm.sky_e_per_s,
                nm.read_noise_e,
                scint,
            )
        arrays["mag_noisy"] = magnitude_of(noisy).astype(np.float32)
        arrays["flux_noisy_w_m2"] = noisy.astype(np.float32)
        arrays["mag_err"] = err.astype(np.float32)
    return Shard(shard, rows.start, arrays, _labels(config, curves, geos, subs, shadows, pool))


def _labels(config, curves, geos, subs, shadows, pool) -> pd.DataFrame:
    out = []
    for c, g, s, sh in zip(curves, geos, subs, shadows, strict=True):
        cls = config.classes[c.class_id]
        v = g.visible
        any_v = bool(v.any())
        row = {
            "class": cls.name,
            "class_id": c.class_id,
            "mesh": str(cls.mesh_path),
            "scale": cls.mesh_scale * c.scale,
            "materials": json.dumps(list(c.materials)),
            "body_axis_x": cls.body_axis[0],
            "body_axis_y": cls.body_axis[1],
            "body_axis_z": cls.body_axis[2],
            "pole_ra_deg": c.pole_ra_deg,
            "pole_dec_deg": c.pole_dec_deg,
            "period_s": c.period_s,
            "phase_deg": c.phase_deg,
            "subsamples": int(s),
            "shadows": bool(sh),
            "utc_start": g.utc_start,
            "visible_samples": int(v.sum()),
            "phase_mean_deg": float(g.phase_angle_deg[v].mean()) if any_v else np.nan,
            "phase_min_deg": float(g.phase_angle_deg[v].min()) if any_v else np.nan,
            "phase_max_deg": float(g.phase_angle_deg[v].max()) if any_v else np.nan,
            "range_mean_m": float(g.range_m[v].mean()) if any_v else np.nan,
        }
        if isinstance(config.geometry, SyntheticSource):
            row.update(
                geometry="synthetic", pass_id=-1, pass_offset=-1, norad_id=-1, site="", **c.geometry
            )
        else:
            p = c.geometry["pass_id"]
            row.update(
                geometry="pass",
                pass_id=p,
                pass_offset=c.geometry["offset"],
                norad_id=int(pool.norad_id[p]),
                site=str(pool.site[p]),
            )
        out.append(row)
    from jaxlc.datastore import LABELS

    df = pd.DataFrame(out)
    for name, (dtype, fill, _) in LABELS.items():
        if name not in df:
            df[name] = fill
        if dtype != "str":
            df[name] = df[name].astype(dtype)
    return df[list(LABELS)]


_POOLS: dict = {}
#: Set in local workers' environment: where their JAX compilation cache lives.
_CACHE_ENV = "JAXLC_WORKER_XLA_CACHE"


def _use_compilation_cache() -> None:
    """In a local worker: turn on JAX's persistent compilation cache (once).

    Done here rather than by JAX's own environment variable because the
    worker may have imported JAX before its environment was set.
    """
    from jaxlc import compile_cache

    path = os.environ.get(_CACHE_ENV)
    if path:
        compile_cache.enable(path)


def run_shard(config: DatasetConfig, shard: int, store: str) -> tuple[int, int]:
    """Render shard ``shard`` and write it into ``store`` (the unit of work on a worker).

    Returns:
        (shard, number of curves).
    """
    from jaxlc.datastore import read_pool, write_shard

    _use_compilation_cache()
    pool = None
    if isinstance(config.geometry, PassSource):
        if store not in _POOLS:
            _POOLS[store] = read_pool(store)
        pool = _POOLS[store]
    data = render_shard(config, shard, pool)
    write_shard(store, shard, data.start, data.arrays, data.labels)
    return shard, len(data.labels)


# ---------------------------------------------------------------------------
# Running a dataset


def _progress_bar(enabled: bool):
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        ProgressColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )
    from rich.text import Text

    class Rate(ProgressColumn):
        def render(self, task):
            speed = task.finished_speed or task.speed
            unit = task.fields.get("unit", "curves")
            return Text("–" if speed is None else f"{speed:,.1f} {unit}/s")

    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        Rate(),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
        console=Console(stderr=True),
        disable=not enabled,
        transient=False,
    )


def _worker_env(n_workers: int) -> dict:
    """Environment of local worker processes.

    * One XLA thread each when the workers fill the cores: XLA's CPU thread
      pool would otherwise make every worker use every core, and the workers
      slow each other down.
    * JAX's persistent compilation cache (unless ``JAX_COMPILATION_CACHE_DIR``
      is set already): every worker, and every later run, loads the class
      kernels instead of compiling them (~5 s per worker process saved).
    """
    from jaxlc.shadow import cache_dir

    env = {}
    if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
        env[_CACHE_ENV] = str(cache_dir() / "xla")
    if n_workers >= (os.cpu_count() or 1):
        flags = os.environ.get("XLA_FLAGS", "")
        if "xla_cpu_multi_thread_eigen" not in flags:
            flags = (flags + " --xla_cpu_multi_thread_eigen=false").strip()
        env.update(XLA_FLAGS=flags, OMP_NUM_THREADS="1")
    return env


def generate(
    config: DatasetConfig | str | Path,
    out_path: str | Path,
    workers: int | None = None,
    scheduler: str | None = None,
    count: int | None = None,
    seed: int | None = None,
    progress: bool = True,
    on_shard=None,
):
    """Render a dataset into a Zarr store, or finish one a killed run left behind.

    Args:
        config: a :class:`~jaxlc.dataset.DatasetConfig` or the path of its TOML file.
        out_path: the store (a ``.zarr`` folder). If it exists it must come from
            the same config (and count, seed, meshes): its missing shards are rendered.
        workers: None: a local Dask cluster with one worker process per core;
            N > 0: N worker processes; 0: render in this process (no Dask).
        scheduler: address of a running Dask scheduler (e.g. ``tcp://host:8786``)
            instead of a local cluster; the workers must see ``out_path``.
        count, seed: override the config's ``count`` and ``seed``.
        progress: show a progress bar (rate and ETA) on stderr.
        on_shard: optional callable(shard) after each shard is written (in
            completion order); an exception from it stops the run (the shards
            written so far stay done).

    Returns:
        The finished :class:`~jaxlc.datastore.Dataset`.

    The arrays do not depend on ``workers`` or on the order shards finish in:
    same config, count and seed give the same bytes (on the same platform).
    """
    from jaxlc.datastore import check_store, create_store, done_shards, open_dataset

    if not isinstance(config, DatasetConfig):
        config = load_config(config)
    if count is not None:
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            raise DatasetError(f"count = {count!r} must be a whole number ≥ 1")
        config = dataclasses.replace(config, count=count)
    if seed is not None:
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise DatasetError(f"seed = {seed!r} must be a whole number ≥ 0")
        config = dataclasses.replace(config, seed=seed)
    if config.noise is not None and config.exposure_s <= 0:
        raise DatasetError(f"{config.source}: a [noise] model needs exposure_s > 0")
    if workers is not None and scheduler is not None:
        raise DatasetError("give either workers or a scheduler address, not both")
    if workers is not None and (isinstance(workers, bool) or workers < 0):
        raise DatasetError(f"workers = {workers!r} must be ≥ 0 (0: in this process)")
    if workers != 0:
        _require_dask()

    out = Path(out_path).resolve()
    bar = _progress_bar(progress)
    with bar:
        if out.exists():
            check_store(out, config)
        else:
            pool = None
            if isinstance(config.geometry, PassSource):
                pool = _build_pool(config, bar)
            _warm_shadow_tables(config, bar)
            create_store(out, config, pool)
            check_store(out, config)
        done = done_shards(out)
        todo = [k for k in range(config.n_shards) if not done[k]]
        done_curves = sum(len(config.shard_rows(k)) for k in np.flatnonzero(done))
        task = bar.add_task(f"{out.name}", total=config.count, completed=done_curves)

        def finished(k, n):
            bar.update(task, advance=n)
            if on_shard is not None:
                on_shard(k)

        if todo and workers == 0:
            for k in todo:
                finished(*run_shard(config, k, str(out)))
        elif todo:
            _run_dask(config, out, todo, workers, scheduler, finished)
    return open_dataset(out)


def _require_dask():
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise DatasetError(
            "running shards on workers needs dask and distributed: pip install 'jaxlc[dask]' "
            "(or use workers = 0 / --workers 0 to render in this process)"
        ) from None


def _build_pool(config, bar):
    from jaxlc.geometry.pool import build_pool

    g = config.geometry
    task = bar.add_task("pass pool", total=None, unit="passes")
    pool = build_pool(
        g.tle_paths,
        g.sites,
        g.start_utc,
        g.days,
        config.samples,
        config.cadence_s,
        config.exposure_s,
        norad=g.norad,
        search_step_s=g.search_step_s,
        rules=g.rules,
        min_pass_s=g.min_pass_s,
        max_passes=g.max_passes,
        progress=lambda d, n: bar.update(task, completed=d, total=n),
    )
    bar.update(task, description=f"pass pool: {len(pool)} passes")
    return pool


def _warm_shadow_tables(config, bar):
    """Trace missing shadow tables once here, so workers load them from the disk cache."""
    from jaxlc.mesh import facets_from_mesh, load_mesh
    from jaxlc.shadow import shadow_data

    for cls in config.classes:
        if cls.render.shadows == "off":
            continue
        mesh = load_mesh(cls.mesh_path, cls.mesh_scale)
        facets = facets_from_mesh(mesh)
        if facets.convex:
            continue
        task = bar.add_task(f"shadow table {cls.mesh_path.name}", total=None, unit="directions")
        shadow_data(
            mesh,
            facets,
            cls.render.shadow,
            progress=lambda d, n, t=task: bar.update(t, completed=d, total=n),
        )
        bar.remove_task(task)


def _run_dask(config, out: Path, todo, workers, scheduler, finished):
    import logging

    from distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="20s")
        except OSError as exc:
            raise DatasetError(f"cannot reach the Dask scheduler {scheduler!r}: {exc}") from None
    else:
        n = workers or min(os.cpu_count() or 1, len(todo))
        cluster = LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",  # any free port (8787 may be taken)
            silence_logs=logging.ERROR,
            env=_worker_env(n),
        )
        client = Client(cluster)
    futures = []
    try:
        tag = config.fingerprint()[:8]
        futures = [
            client.submit(run_shard, config, k, str(out), key=f"jaxlc-shard-{tag}-{k}", pure=False)
            for k in todo
        ]
        for fut in as_completed(futures):
            finished(*fut.result())
    finally:
        for fut in futures:
            fut.cancel()
        client.close()
        if cluster is not None:
            cluster.close()

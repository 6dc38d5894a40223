"""Run a dataset: render the missing shards of a store, here or on Dask.

:func:`generate` creates the store (:mod:`jaxlc.dataset.store`; with real
passes it first builds the pass pool, and it traces missing shadow tables
once, so workers load them from the cache), then renders the shards not yet
done (:func:`jaxlc.dataset.shards.run_shard`): in this process
(``workers=0``), on a local Dask cluster (worker processes, one thread each)
or on a cluster given by its scheduler address, with a progress bar.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from jaxlc.dataset.config import DatasetConfig, DatasetError, PassSource
from jaxlc.dataset.config_file import load_config
from jaxlc.dataset.shards import WORKER_CACHE_ENV, run_shard
from jaxlc.io.cache import cache_dir
from jaxlc.xla import XLA_CACHE_ENV

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
    env = {}
    cache_off = os.environ.get(XLA_CACHE_ENV, "").lower() == "off"
    if "JAX_COMPILATION_CACHE_DIR" not in os.environ and not cache_off:
        env[WORKER_CACHE_ENV] = str(cache_dir("xla"))
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
        The finished :class:`~jaxlc.dataset.store.Dataset`.

    The arrays do not depend on ``workers`` or on the order shards finish in:
    same config, count and seed give the same bytes (on the same platform).
    """
    from jaxlc.dataset.reader import open_dataset
    from jaxlc.dataset.store import check_store, create_store, done_shards

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
    from jaxlc.body.mesh import load_body
    from jaxlc.body.shadow import shadow_data

    for cls in config.classes:
        if cls.render.shadows == "off":
            continue
        mesh, facets = load_body(cls.mesh_path)
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

"""Run a dataset: render the missing shards of a store, here or on Dask.

:func:`generate` creates the store (:mod:`jaxlc.dataset.store`; with real
passes it first builds the pass pool, and it traces missing shadow tables
once, so workers load them from the cache), then renders the shards not yet
done (:func:`jaxlc.dataset.shards.run_shard`): in this process
(``workers=0``), on a local Dask cluster (worker processes, one thread each)
or on a cluster given by its scheduler address, with a progress bar.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
from pathlib import Path

import numpy as np

from jaxlc.dataset.config import MAX_COUNT, DatasetConfig, DatasetError, PassSource
from jaxlc.dataset.config_file import load_config
from jaxlc.dataset.local_cluster import local_cluster, pin_all
from jaxlc.dataset.shards import run_shard
from jaxlc.io.files import check_output

#: Seconds to connect to a scheduler given by address, and to wait for its first worker.
CONNECT_TIMEOUT_S = 10.0
#: Most local worker processes per core (each holds its own JAX and compiled kernels).
MAX_WORKERS_PER_CORE = 4

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
            N > 0: N worker processes (at most ``MAX_WORKERS_PER_CORE`` per core);
            0: render in this process (no Dask).
        scheduler: address of a running Dask scheduler (e.g. ``tcp://host:8786``)
            instead of a local cluster; the workers must see ``out_path``.
        count, seed: override the config's ``count`` and ``seed``.
        progress: show a progress bar (rate and ETA) on stderr.
        on_shard: optional callable(shard) after each shard is written (in
            completion order); an exception from it stops the run (the shards
            written so far stay done).

    Returns:
        The finished :class:`~jaxlc.dataset.store.Dataset`.

    Everything is checked before the store is created: the output path, the
    config and options, and the scheduler (connected to first, within
    ``CONNECT_TIMEOUT_S``). A new store that fails before its first shard is
    written is removed again; an existing one being resumed is never removed.

    The arrays do not depend on ``workers`` or on the order shards finish in:
    same config, count and seed give the same bytes (on the same platform).
    """
    from jaxlc.dataset.reader import open_dataset
    from jaxlc.dataset.store import (
        add_missing_labels,
        check_store,
        create_store,
        done_shards,
        remove_new_store,
    )

    out = check_output(out_path, "store", option="output").resolve()
    if not isinstance(config, DatasetConfig):
        config = load_config(config)
    config = _with_options(config, count, seed, workers, scheduler)
    resuming = out.exists()
    if resuming:
        check_store(out, config)
        add_missing_labels(out)  # a store from before a label column existed
    done = done_shards(out) if resuming else np.zeros(config.n_shards, bool)
    todo = [k for k in range(config.n_shards) if not done[k]]
    bar = _progress_bar(progress)
    with dask_client(workers if todo else 0, scheduler, len(todo)) as client, bar:
        created = False
        if not resuming:
            pool = None
            if isinstance(config.geometry, PassSource):
                pool = _build_pool(config, bar)
            _warm_shadow_tables(config, bar)
            created = create_store(out, config, pool)
            check_store(out, config)
            done = done_shards(out)  # another run may have created it meanwhile
            todo = [k for k in range(config.n_shards) if not done[k]]
        done_curves = sum(len(config.shard_rows(k)) for k in np.flatnonzero(done))
        task = bar.add_task(f"{out.name}", total=config.count, completed=done_curves)

        def finished(k, n):
            bar.update(task, advance=n)
            if on_shard is not None:
                on_shard(k)

        try:
            if client is None:
                for k in todo:
                    finished(*run_shard(config, k, str(out)))
            elif todo:
                _run_dask(client, config, out, todo, finished)
        except BaseException:
            if created:
                remove_new_store(out)  # only while no shard is done: nothing is lost
            raise
    return open_dataset(out)


def _with_options(config: DatasetConfig, count, seed, workers, scheduler) -> DatasetConfig:
    """The config with ``count``/``seed`` overrides, after checking every option."""
    if count is not None:
        if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= MAX_COUNT:
            raise DatasetError(
                f"count (--count) = {count!r} must be a whole number in [1, {MAX_COUNT:,}] "
                "(number of light curves)"
            )
        config = dataclasses.replace(config, count=count)
    if seed is not None:
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
            raise DatasetError(f"seed (--seed) = {seed!r} must be a whole number in [0, 2**63)")
        config = dataclasses.replace(config, seed=seed)
    if config.noise is not None and config.exposure_s <= 0:
        raise DatasetError(f"{config.source}: a [noise] model needs exposure_s > 0")
    if workers is not None and scheduler is not None:
        raise DatasetError(
            f"workers (--workers) = {workers!r} and scheduler (--scheduler) = {scheduler!r}: "
            "give one of them, not both"
        )
    cores = os.cpu_count() or 1
    most = MAX_WORKERS_PER_CORE * cores
    if workers is not None and (
        isinstance(workers, bool) or not isinstance(workers, int) or not 0 <= workers <= most
    ):
        raise DatasetError(
            f"workers (--workers) = {workers!r} must be a whole number in [0, {most}] "
            f"(0: in this process; at most {MAX_WORKERS_PER_CORE} processes per core, "
            f"{cores} core(s) here)"
        )
    if scheduler is not None and (not isinstance(scheduler, str) or not scheduler.strip()):
        raise DatasetError(
            f"scheduler (--scheduler) = {scheduler!r} must be a Dask scheduler address "
            "like tcp://host:8786"
        )
    if workers != 0:
        _require_dask()
    return config


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


@contextlib.contextmanager
def dask_client(workers, scheduler, n_todo: int):
    """A Dask client for the run (None for ``workers=0``), closed on the way out.

    Local workers (:func:`~jaxlc.dataset.local_cluster.local_cluster`) that fill the
    cores get one core each (not with ``$JAXLC_PIN_WORKERS=off``).

    A scheduler address is connected to here, before anything is written:
    an unreachable or malformed address, or a cluster without workers, is a
    :class:`DatasetError` within ``CONNECT_TIMEOUT_S``.
    """
    if workers == 0:
        yield None
        return
    from distributed import Client

    cluster = None
    if scheduler is not None:
        fix = (
            "check the address, start the scheduler (dask scheduler) and its workers, "
            "or leave out --scheduler to run a local cluster"
        )
        try:
            client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S:g}s")
        except (OSError, ValueError, TypeError) as exc:
            raise DatasetError(
                f"scheduler (--scheduler) = {scheduler!r}: cannot connect "
                f"({' '.join(str(exc).split())}); {fix}"
            ) from None
        try:
            client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError) as exc:
            client.close()
            raise DatasetError(
                f"scheduler (--scheduler) = {scheduler!r} has no workers after "
                f"{CONNECT_TIMEOUT_S:g} s ({type(exc).__name__}); {fix}"
            ) from None
    else:
        n = min(workers or os.cpu_count() or 1, max(n_todo, 1))
        cluster = local_cluster(n)
        client = Client(cluster)
    try:
        if cluster is not None:
            pin_all(client, n)
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _run_dask(client, config, out: Path, todo, finished):
    from distributed import as_completed

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

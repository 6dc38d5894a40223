"""Local Dask worker processes for a dataset run: their environment, cores and cluster.

:func:`local_cluster` starts the worker processes of ``jaxlc generate --workers N``
(one thread each, a nanny per worker), with an environment that keeps them as fast
as this process (:func:`worker_env`, :func:`spawn_environ`), without a dashboard and
with Dask's own diagnostics rare or off (:data:`QUIET_CONFIG`), and gives each its own
core when they fill the cores (:func:`pin_worker`).
"""

from __future__ import annotations

import contextlib
import os
import sys

from jaxlc.dataset.config import DatasetError
from jaxlc.dataset.shards import WORKER_CACHE_ENV
from jaxlc.io.cache import cache_dir
from jaxlc.xla import XLA_CACHE_ENV

#: ``JAXLC_PIN_WORKERS=off`` leaves local workers free to run on any core.
PIN_WORKERS_ENV = "JAXLC_PIN_WORKERS"
#: glibc's malloc setting that Dask's nanny exports to its workers by default
#: (``distributed.nanny.pre-spawn-environ``), and which :func:`spawn_environ` leaves out.
MALLOC_TRIM_ENV = "MALLOC_TRIM_THRESHOLD_"
#: Dask's diagnostics that a local run does not show, made rare or off: the workers'
#: statistical profiler (a stack sample every 10 ms), the event loops' latency tick
#: (every 20 ms) and the system and memory monitors (every 0.5 and 0.1 s). With no
#: dashboard (:func:`local_cluster`), two workers of the standard mix made 138-143
#: curves/s after the first shard against 126-134 (three interleaved runs each of 1,500
#: curves, the second worker's first shard counted in: the ratio stands, the rates are
#: ~9 % high); the main process's share of a core fell from 3.8 % to 1.0 %.
QUIET_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "5s",
}


def local_cluster(n_workers: int):
    """A :class:`distributed.LocalCluster` of ``n_workers`` processes, one thread each,
    started with :func:`spawn_environ`, :func:`worker_env` and :data:`QUIET_CONFIG`, and
    without a dashboard (its port was never shown; to watch a run, start a scheduler and
    workers yourself and pass ``--scheduler``)."""
    import logging

    import dask
    from distributed import LocalCluster

    check_spawnable()
    with dask.config.set({"distributed.nanny.pre-spawn-environ": spawn_environ(), **QUIET_CONFIG}):
        try:
            return LocalCluster(
                n_workers=n_workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                silence_logs=logging.ERROR,
                env=worker_env(n_workers),
            )
        except RuntimeError as exc:  # Dask's "Nanny failed to start." (the cause: stderr)
            raise DatasetError(
                f"local Dask workers (workers = {n_workers}) did not start "
                f"({' '.join(str(exc).split())}); render in this process with workers = 0 "
                "(--workers 0), or start a cluster yourself and pass its --scheduler"
            ) from None


def check_spawnable() -> None:
    """Refuse, with the fix, to start local workers that cannot start: a worker process
    begins by importing the caller's main module again (multiprocessing's spawn), which
    a script read from stdin (``python - <<EOF``) does not have as a file; Dask then
    fails with a traceback of its own. (``python -c``, notebooks, files and the CLI can.)
    """
    path = getattr(sys.modules.get("__main__"), "__file__", None)
    if isinstance(path, str) and not os.path.exists(path):
        raise DatasetError(
            f"local Dask workers cannot start from a script read from {path!r} (each "
            "worker imports the main module again): save the script to a file, or render "
            "in this process with workers = 0"
        )


def spawn_environ() -> dict:
    """Dask's environment for worker processes (set before they start) without
    ``MALLOC_TRIM_THRESHOLD_`` unless this process has it from elsewhere.

    Dask sets it to 65,536 so that workers hand freed memory back to the system. Any
    setting of it also fixes glibc's mmap threshold at 128 KiB (mallopt(3)), so every
    larger array — a curve's instants, a batch's blocks — is mapped afresh and its
    pages faulted in each time: a shard of the standard mix took 1.8–2.5 s in a
    worker against 1.4–1.6 s in a plain process pinned to one core, and the same
    1.8–2.2 s in that process with the variable set (2-core machine). Where this
    process's own environment holds another value, the user chose it, and it stays.
    """
    import dask

    env = dict(dask.config.get("distributed.nanny.pre-spawn-environ", default={}) or {})
    dask_value = env.pop(MALLOC_TRIM_ENV, None)
    mine = os.environ.get(MALLOC_TRIM_ENV)
    if mine is not None and mine != str(dask_value):  # not from an earlier nanny here
        env[MALLOC_TRIM_ENV] = mine
    elif mine is not None:  # an earlier nanny in this process exported Dask's value
        os.environ.pop(MALLOC_TRIM_ENV)
    return env


def worker_env(n_workers: int) -> dict:
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
    if n_workers >= len(cores()):
        flags = os.environ.get("XLA_FLAGS", "")
        if "xla_cpu_multi_thread_eigen" not in flags:
            flags = (flags + " --xla_cpu_multi_thread_eigen=false").strip()
        env.update(XLA_FLAGS=flags, OMP_NUM_THREADS="1")
    return env


def pin_workers(workers: int) -> bool:
    """Whether local workers get a core each: they fill the cores (more than one), and
    ``$JAXLC_PIN_WORKERS`` is not ``off``."""
    off = os.environ.get(PIN_WORKERS_ENV, "").lower() == "off"
    return not off and workers >= len(cores()) > 1


def cores() -> list[int]:
    """The cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return sorted(os.sched_getaffinity(0))
    return list(range(os.cpu_count() or 1))


def pin_all(client, n_workers: int) -> None:
    """Pin each of the client's workers to a core of its own where :func:`pin_workers`
    says so (an optimisation only: a worker that cannot be pinned runs as before)."""
    if pin_workers(workers=n_workers):
        with contextlib.suppress(Exception):
            client.run(pin_worker, sorted(client.scheduler_info()["workers"]))


def pin_worker(addresses: list[str], dask_worker=None) -> int | None:
    """Pin every thread of a local Dask worker to one core of its own (run by ``client.run``
    on each worker): the worker's place in ``addresses`` picks the core. When the workers
    fill the cores each runs XLA on one thread (:func:`worker_env`), and unpinned the two
    workers of the 2-core reference machine still moved between cores: pinned, the
    standard mix ran 78.4–81.1 → 91.8–94.1 curves/s steady (four rounds each). Returns the
    core, or None where threads cannot be pinned (the worker then runs as before)."""
    if dask_worker is None or not hasattr(os, "sched_setaffinity"):
        return None
    all_cores = cores()
    core = all_cores[addresses.index(dask_worker.address) % len(all_cores)]
    try:
        for tid in os.listdir("/proc/self/task"):  # threads made later inherit the core
            os.sched_setaffinity(int(tid), {core})
    except OSError:
        return None
    return core

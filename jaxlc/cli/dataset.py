"""``jaxlc generate``: bulk datasets (Zarr) from a dataset config."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from jaxlc.cli.app import app, console


@app.command()
def generate(
    config: Annotated[Path, typer.Argument(help="Dataset config (TOML).")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Dataset store (.zarr folder).")],
    workers: Annotated[
        int | None,
        typer.Option(help="Local worker processes (default: one per core; 0: in this process)."),
    ] = None,
    scheduler: Annotated[
        str | None, typer.Option(help="Address of a running Dask scheduler instead.")
    ] = None,
    count: Annotated[int | None, typer.Option(help="Number of light curves (overrides).")] = None,
    seed: Annotated[int | None, typer.Option(help="Random seed (overrides the config's).")] = None,
):
    """Render a bulk dataset (Zarr) from CONFIG; an unfinished OUTPUT is resumed."""
    from jaxlc.dataset import generate as make_dataset
    from jaxlc.dataset import load_config
    from jaxlc.xla import enable_persistent_cache

    t0 = time.perf_counter()
    cfg = load_config(config)
    if workers == 0 and scheduler is None:
        # rendered here: load the class kernels from JAX's persistent cache, as local
        # workers do (200 curves of the standard mix: 6.9 s instead of 13.8 s)
        enable_persistent_cache()
    ds = make_dataset(cfg, output, workers=workers, scheduler=scheduler, count=count, seed=seed)
    elapsed = time.perf_counter() - t0
    n = len(ds)
    console().print(
        f"{n} light curves × {ds.attrs['samples']} samples "
        f"({ds.attrs['n_shards']} shards, {len(ds.attrs['classes'])} shape class(es)"
        f"{', noise' if ds.attrs.get('noise') else ''}) in {elapsed:.1f} s → {output}"
    )

"""Safe file output: write to a temporary name beside the target, then rename.

A crash or a bad input part-way through never leaves a truncated file under
the requested name, and an existing file is only replaced once the new one is
complete.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path


@contextlib.contextmanager
def atomic_output(path: str | Path):
    """Yield a temporary path in the target's folder; rename it to ``path`` on success.

    The temporary name keeps the suffix, so writers that pick a format from the
    extension (pandas, matplotlib) still work. On any exception it is removed.

    Example:
        >>> with atomic_output("out.csv") as tmp:
        ...     df.to_csv(tmp)
    """
    path = Path(path)
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


#: Table formats by file extension (CSV, or Parquet).
TABLE_FORMATS = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet"}


def plot_formats() -> tuple[str, ...]:
    """File extensions matplotlib can save (without the dot), e.g. ``png``, ``pdf``, ``svg``."""
    from matplotlib.backend_bases import FigureCanvasBase

    return tuple(sorted(FigureCanvasBase.get_supported_filetypes()))


def check_output(path: str | Path | None, kind: str, option: str = "-o") -> Path | None:
    """Refuse an output path before any work is done (None passes through).

    Args:
        path: where the output will go.
        kind: ``"table"`` (.csv/.parquet), ``"plot"`` (a matplotlib format),
            ``"folder"`` (a directory, made if missing) or ``"store"`` (a ``.zarr`` folder).
        option: the command-line option that gave it, named in the message.

    Raises:
        JaxlcError: an unknown extension, a folder where a file goes (or the
        reverse), a parent that is a file, or a place that cannot be written.
    """
    from jaxlc.errors import JaxlcError

    if path is None:
        return None
    path = Path(path)
    suffix = path.suffix.lower()
    if kind == "table" and suffix not in TABLE_FORMATS:
        raise JaxlcError(
            f"{option} {path}: unknown table extension {path.suffix!r}; use .csv or .parquet"
        )
    if kind == "plot" and suffix.lstrip(".") not in plot_formats():
        raise JaxlcError(
            f"{option} {path}: cannot save a plot as {path.suffix or 'a file without extension'}; "
            f"use .png, .pdf or .svg (or {', '.join('.' + f for f in plot_formats())})"
        )
    if kind == "store" and suffix != ".zarr":
        raise JaxlcError(
            f"{option} {path}: a dataset store is a folder ending in .zarr; give e.g. "
            f"{path.with_suffix('.zarr').name}"
        )
    folder = kind in ("folder", "store")
    if path.exists() and path.is_dir() != folder:
        what = "a folder" if path.is_dir() else "a file"
        raise JaxlcError(
            f"{option} {path} is {what}; give {'a folder' if folder else 'a file name'} instead"
        )
    parent = path.parent.resolve()
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise JaxlcError(f"{option} {path}: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise JaxlcError(f"{option} {path}: cannot write in {parent} (permission denied)")
    return path


@contextlib.contextmanager
def atomic_outputs(*paths: str | Path | None):
    """Temporary names for several outputs, all renamed only when every one is written.

    A command that writes a table and a plot leaves neither (and keeps any
    older files under those names) when the second fails. None entries give None.

    Example:
        >>> with atomic_outputs("lc.csv", "lc.png") as (table, png):
        ...     write_table(lc, table); plot_lightcurve(lc, png)
    """
    targets = [None if p is None else Path(p) for p in paths]
    tmps = [
        None if p is None else p.with_name(f".{p.stem}.{os.getpid()}.part{p.suffix}")
        for p in targets
    ]
    try:
        yield tmps
        for tmp, target in zip(tmps, targets, strict=True):
            if target is not None:
                target.parent.mkdir(parents=True, exist_ok=True)
                os.replace(tmp, target)
    finally:
        for tmp in tmps:
            if tmp is not None:
                with contextlib.suppress(FileNotFoundError):
                    tmp.unlink()

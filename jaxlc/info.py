"""What this installation has: versions, JAX devices, precision, optional parts."""

from __future__ import annotations

import importlib.util
import platform
from importlib import metadata


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "not installed"


def info() -> dict:
    """A dict of everything :func:`print_info` shows."""
    import jax

    from calibrate.environment import find_blender_environment
    from jaxlc.io.provenance import jaxlc_version

    blender = find_blender_environment()
    dask_ok = all(importlib.util.find_spec(m) is not None for m in ("dask", "distributed"))
    return {
        "jaxlc": jaxlc_version(),
        "python": platform.python_version(),
        "versions": {
            d: _version(d)
            for d in ("jax", "jaxlib", "equinox", "numpy", "scipy", "trimesh", "pandas", "pyarrow")
        },
        "backend": jax.default_backend(),
        "devices": [f"{d.platform}:{d.id} {d.device_kind}" for d in jax.devices()],
        "default_precision": "float32 (x64 enabled globally)"
        if jax.config.jax_enable_x64
        else "float32 (float64 on request: --precision float64)",
        "optional": {
            "blender": blender.describe(),
            "dask": f"dask {_version('dask')}, distributed {_version('distributed')}"
            if dask_ok
            else "not installed (pip install 'jaxlc[dask]')",
        },
    }


def print_info() -> None:
    """Print :func:`info` as a small table."""
    from rich.console import Console
    from rich.table import Table

    data = info()
    table = Table(title=f"jaxlc {data['jaxlc']}", show_header=False)
    table.add_column(style="bold")
    table.add_column()
    table.add_row("python", data["python"])
    for k, v in data["versions"].items():
        table.add_row(k, v)
    table.add_row("JAX backend", data["backend"])
    table.add_row("JAX devices", ", ".join(data["devices"]))
    table.add_row("precision", data["default_precision"])
    for k, v in data["optional"].items():
        table.add_row(f"optional: {k}", v)
    Console().print(table)

"""What every result table of the experiments records about its run (written by
``jaxlc.write_table`` as ``# key: value`` lines above the CSV header)."""

from __future__ import annotations

import os
import platform

import pandas as pd

import jaxlc


def provenance(generator: str, **extra) -> dict[str, str]:
    """The script, versions, backend, machine and time of a run, plus ``extra``."""
    import jax

    return {
        "generator": generator,
        "jaxlc": jaxlc.__version__,
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "cpu_count": str(os.cpu_count()),
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "date_utc": pd.Timestamp.now(tz="UTC").strftime("%Y-%m-%dT%H:%M:%SZ"),
        **{k: str(v) for k, v in extra.items()},
    }

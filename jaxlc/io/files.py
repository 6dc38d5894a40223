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

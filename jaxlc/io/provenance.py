"""Where a result came from: the jaxlc version and the checkout's commit.

Written into the metadata of every table, dataset store and fit summary.
"""

from __future__ import annotations

import functools
import subprocess
from importlib import metadata
from pathlib import Path


def jaxlc_version() -> str:
    """The installed jaxlc version (``0+unknown`` in a source tree without install)."""
    try:
        return metadata.version("jaxlc")
    except metadata.PackageNotFoundError:
        return "0+unknown"


@functools.cache
def git_commit() -> str | None:
    """The checkout's commit (``+dirty`` with local changes), or None outside git."""
    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(
            ["git", "-C", str(here), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(here), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head + ("+dirty" if dirty else "") if head else None

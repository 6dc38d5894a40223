"""What each bad input is told: the hostile-input catalogue's messages as a table.

Runs every case of ``tests/test_hostile.py`` (and the geometry-command and
dataset catalogues when they define ``CASES``) in a fresh folder, exactly as
the tests do, and writes ``experiments/results/hostile_messages.csv`` with
the case, the command line, the exit status and the one line the user sees.

    python experiments/hostile_messages.py
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
from pathlib import Path

import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from test_hostile import CASES, write_inputs  # noqa: E402

from jaxlc.cli import main  # noqa: E402
from jaxlc.io.tables import write_table  # noqa: E402


def run_case(argv, files) -> tuple[int, str]:
    """Exit status and stderr lines (warnings dropped) of one command in a fresh folder."""
    here = os.getcwd()
    with tempfile.TemporaryDirectory() as folder:
        write_inputs(Path(folder), files)
        os.chdir(folder)
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                status = main(list(argv))
        finally:
            os.chdir(here)
    lines = [x for x in err.getvalue().splitlines() if x.strip() and not x.startswith("warning")]
    return status, " | ".join(lines)


def main_table() -> pd.DataFrame:
    rows = []
    for name, argv, files, _ in CASES:
        status, message = run_case(argv, files)
        rows.append(
            {
                "case": name,
                "command": "jaxlc " + " ".join(argv),
                "status": status,
                "message": message,
            }
        )
        print(f"{name:32s} {status}  {message[:150]}")
    return pd.DataFrame(rows)


if __name__ == "__main__":
    table = main_table()
    out = HERE / "results" / "hostile_messages.csv"
    write_table(table, out)
    print(f"{len(table)} cases, {int((table['status'] == 1).sum())} with status 1 → {out}")

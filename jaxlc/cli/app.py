"""The ``jaxlc`` command line: the application, shared options and the entry point.

One module per command group registers its commands on :data:`app`
(:mod:`jaxlc.cli.render`, :mod:`~jaxlc.cli.geometry`, :mod:`~jaxlc.cli.calibrate`,
:mod:`~jaxlc.cli.inference`, :mod:`~jaxlc.cli.dataset`). A wrong input exits
with status 1 and one line on stderr (``error: …``); add ``--debug`` (before
the command) or set ``JAXLC_DEBUG=1`` for the traceback.
"""

from __future__ import annotations

import os
import sys
import warnings
from typing import Annotated

import typer

app = typer.Typer(
    name="jaxlc",
    help="Light curves of resident space objects: JAX facet model, Blender reference.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
geometry_app = typer.Typer(help="Make geometry tables (object, Sun, observer per sample).")
app.add_typer(geometry_app, name="geometry")
calibrate_app = typer.Typer(help="The Blender/Cycles reference renderer (.venv-blender).")
app.add_typer(calibrate_app, name="calibrate")


def console(stderr: bool = True):
    """A rich console; wide when output goes to a file or pipe, not a terminal."""
    from rich.console import Console

    console = Console(stderr=stderr)
    return console if console.is_terminal else Console(stderr=stderr, width=160)


@app.callback()
def _root(
    debug: Annotated[bool, typer.Option("--debug", help="Show tracebacks of errors.")] = False,
):
    """jaxlc: scene + geometry → light curve."""


@app.command()
def info():
    """Versions, JAX backend and devices, precision, optional parts."""
    from jaxlc.info import print_info

    print_info()


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the CLI, turning user errors into one line and exit status 1.

    Usage errors (unknown option, missing argument) are reported by typer with
    status 2.
    """
    from jaxlc.errors import JaxlcError

    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv or os.environ.get("JAXLC_DEBUG", "") not in ("", "0")
    if not debug:  # warnings as one line each, without source locations
        warnings.showwarning = lambda message, category, *a, **k: print(
            f"warning: {message}", file=sys.stderr
        )
    try:
        app(args=argv, prog_name="jaxlc")  # standalone: always ends in SystemExit
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (JaxlcError, OSError) as exc:
        if debug:
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The ``jaxlc`` command line: the application, shared options and the entry point.

One module per command group registers its commands on :data:`app`
(:mod:`jaxlc.cli.render`, :mod:`~jaxlc.cli.geometry`, :mod:`~jaxlc.cli.calibrate`,
:mod:`~jaxlc.cli.inference`, :mod:`~jaxlc.cli.dataset`). A wrong input exits
with status 1 and one line on stderr (``error: …``); so does any other
exception (an unexpected one is named as such, with the command it hit), so
no traceback is printed unless ``--debug`` (before the command) or
``JAXLC_DEBUG=1`` asks for it.
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

    Usage errors (unknown option, missing argument, a value of the wrong type)
    are one line too, with status 2.
    """
    from jaxlc.errors import JaxlcError

    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv or os.environ.get("JAXLC_DEBUG", "") not in ("", "0")
    if not debug:  # warnings as one line each, without source locations
        warnings.showwarning = lambda message, category, *a, **k: print(
            f"warning: {message}", file=sys.stderr
        )
    try:
        typer.main.get_command(app).main(args=argv, prog_name="jaxlc", standalone_mode=False)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except typer.Abort:
        print("interrupted", file=sys.stderr)
        return 130
    except typer.TyperException as exc:  # click's usage errors (exit code 2), as one line
        ctx = getattr(exc, "ctx", None)
        if type(exc).__name__ == "NoArgsIsHelpError" and ctx is not None:
            print(ctx.get_help(), file=sys.stderr)  # bare `jaxlc` or a bare group: its help
            return 2
        command = ctx.command_path if ctx is not None else "jaxlc"
        print(f"error: {_one_line(exc.format_message())} (see `{command} --help`)", file=sys.stderr)
        return getattr(exc, "exit_code", 2)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (JaxlcError, OSError) as exc:
        if debug:
            raise
        print(f"error: {_one_line(exc)}", file=sys.stderr)
        return 1
    except MemoryError:
        if debug:
            raise
        print(
            f"error: out of memory in `jaxlc {_command(argv)}`; the input is too large for this "
            "machine (see the limits in the README) — rerun with --debug for the traceback",
            file=sys.stderr,
        )
        return 1
    except Exception as exc:  # the guard: never a traceback without --debug
        if debug:
            raise
        print(
            f"error: unexpected {type(exc).__name__} in `jaxlc {_command(argv)}`: "
            f"{_one_line(exc)} — rerun with --debug for the traceback, and please report it",
            file=sys.stderr,
        )
        return 1
    return 0


def _one_line(exc: BaseException, limit: int = 400) -> str:
    """The exception's message on one line (whitespace collapsed, at most ``limit`` chars)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _command(argv: list[str]) -> str:
    """The command and its arguments as typed (options after the inputs dropped)."""
    return " ".join(a for a in argv if a != "--debug")[:200]


if __name__ == "__main__":
    sys.exit(main())

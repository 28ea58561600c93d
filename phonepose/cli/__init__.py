"""The ``phonepose`` command line (typer + rich).

Each command lives in its own module of this package; ``main`` turns every
:class:`~phonepose.errors.PhoneposeError` into one line on stderr and its exit code.
"""

from __future__ import annotations

import sys

import typer

from phonepose import __version__
from phonepose.errors import PhoneposeError

app = typer.Typer(
    name="phonepose",
    help="Record, replay and evaluate sessions in which a smartphone is the 6DoF controller of an AR display.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode="rich",
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"phonepose {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version and exit."),
) -> None:
    """phonepose: smartphone 6DoF controller tracking (Park & Ogawa 2024), recorded, replayed and measured."""


# Command modules register themselves on ``app`` when imported.
from phonepose.cli import info  # noqa: E402,F401
from phonepose.cli import record  # noqa: E402,F401
from phonepose.cli import playback  # noqa: E402,F401
from phonepose.cli import evaluate  # noqa: E402,F401
from phonepose.cli import experiment  # noqa: E402,F401
from phonepose.cli import demo  # noqa: E402,F401
from phonepose.cli import recover  # noqa: E402,F401
from phonepose.cli import calibrate  # noqa: E402,F401  (board, marker, calibrate-camera)
from phonepose.cli import live  # noqa: E402,F401  (record live)
from phonepose.cli import batch  # noqa: E402,F401


def error(message: str, code: int = 1) -> None:
    typer.echo(f"phonepose: error: {message}", err=True)
    sys.exit(code)


def _click_exceptions():
    """The module of click's exception classes that this typer raises: ``click.exceptions`` up to
    typer 0.25, typer's own vendored copy from 0.26 on. Found through the public
    ``typer.BadParameter`` so that no private module is named (typer 0.12.5 has none)."""
    import importlib

    return importlib.import_module(typer.BadParameter.__module__)


def _usage_error(exc) -> None:
    """A typer/click usage error as one line: a bad option value is exit 5 (as ConfigError), the rest 2."""
    exceptions = _click_exceptions()
    no_args_is_help = getattr(exceptions, "NoArgsIsHelpError", ())   # click >= 8.2 only
    if no_args_is_help and isinstance(exc, no_args_is_help):   # typer has already printed the help
        sys.exit(exc.exit_code)
    ctx = getattr(exc, "ctx", None)
    where = f"{ctx.command_path}: " if ctx is not None and ctx.command_path != "phonepose" else ""
    hint = f" (see `{ctx.command_path} --help`)" if ctx is not None else ""
    message = " ".join(exc.format_message().split())
    code = 5 if isinstance(exc, typer.BadParameter) and not isinstance(exc, exceptions.MissingParameter) else exc.exit_code
    error(f"{where.removeprefix('phonepose ')}{message}{hint}", code)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the console script: every error is one line on stderr and its exit code."""
    ClickException = _click_exceptions().ClickException

    try:
        rv = app(args=argv, prog_name="phonepose", standalone_mode=False)
    except PhoneposeError as exc:
        error(str(exc), exc.exit_code)
    except ClickException as exc:
        _usage_error(exc)
    except (KeyboardInterrupt, typer.Abort):
        error("interrupted", 130)
    except BrokenPipeError:
        sys.exit(0)
    except OSError as exc:   # an OS failure no module turned into a PhoneposeError: still one line
        error(f"{exc.filename + ': ' if exc.filename else ''}{exc.strerror or exc}", 1)
    sys.exit(rv if isinstance(rv, int) and not isinstance(rv, bool) else 0)

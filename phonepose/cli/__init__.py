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


def error(message: str, code: int = 1) -> None:
    typer.echo(f"phonepose: error: {message}", err=True)
    sys.exit(code)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the console script: usage errors are typer's, everything else one line."""
    try:
        app(args=argv)
    except PhoneposeError as exc:
        error(str(exc), exc.exit_code)
    except KeyboardInterrupt:
        error("interrupted", 130)
    except BrokenPipeError:
        sys.exit(0)

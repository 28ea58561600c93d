"""The ``phonepose`` command line (typer + rich).

Each command lives in its own module of this package; ``main`` turns every
:class:`~phonepose.errors.PhoneposeError` into one line on stderr and its exit code, and makes
SIGTERM stop a command the way Ctrl-C does (its temporaries are removed on the way out).
"""

from __future__ import annotations

import errno
import functools
import inspect
import os
import signal
import sys
import threading

import typer

from phonepose import __version__, errors, logs
from phonepose.cli import flags, process
from phonepose.cli.output import ReportStream
from phonepose.errors import OutputError, PhoneposeError
from phonepose.files import forget_outputs, outputs_committed
from phonepose.text import printable

app = typer.Typer(
    name="phonepose",
    help="Record, replay and evaluate sessions in which a smartphone is the 6DoF controller of an AR display.\n\n"
         "Example: [bold]phonepose demo[/bold] (a simulated session recorded, replayed and scored end to end)",
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


# Command modules register themselves on ``app`` when imported, in this order (the order of --help):
# isort: off
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
# isort: on


def error(message: str, code: int = 1) -> None:
    # printable: a message may quote anyone's text (a session's schema name, a file's line), whose escape sequences
    # and newlines must not reach the terminal; the error stays the one line it is
    typer.echo(f"phonepose: error: {printable(message)}", err=True)
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
    message = " ".join(exc.format_message().split()).replace("Value error, ", "")   # typer's coercion prefix
    code = 5 if isinstance(exc, typer.BadParameter) and not isinstance(exc, exceptions.MissingParameter) else exc.exit_code
    error(f"{where.removeprefix('phonepose ')}{message}{hint}", code)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C's KeyboardInterrupt would be: the same clean stop."""


# The stops received while the command runs: an exception they cause inside a library (a C extension's import
# raises ImportError when one lands in it; typer returns a bare 130 for one outside the command) is the stop.
_stops: list[int] = []


def _terminate(signum, frame) -> None:
    _stops.append(signum)
    raise Terminated


def _interrupt(signum, frame) -> None:
    _stops.append(signum)
    raise KeyboardInterrupt


def _stopped(message: str, code: int) -> int:
    """The line of a stop, and its exit code: a stop that finds the command's outputs all in place (no output
    open, one or more committed) lost no work, so it says that and exits 0; otherwise the error line."""
    done = outputs_committed()
    if not done:
        error(message, code)
    what = message.split(":")[0]
    typer.echo(f"phonepose: warning: {what} after the outputs were complete: "
               f"{printable(', '.join(map(str, done)))}", err=True)
    return 0


def _stop_of(exc: KeyboardInterrupt | None = None) -> tuple[str, int]:
    """The line and code of a stop: the exception's kind, or without one the last signal received."""
    terminated = isinstance(exc, Terminated) if exc is not None else bool(_stops) and _stops[-1] == signal.SIGTERM
    return ("terminated (SIGTERM)", 143) if terminated else ("interrupted", 130)


class Interrupted(BaseException):
    """An interrupt on its way to ``main``: typer turns a KeyboardInterrupt into a silent exit 130."""

    def __init__(self, message: str, code: int):
        super().__init__(message)
        self.code = code


def _reporting_interrupts(callback):
    @functools.wraps(callback)
    def run(*args, **kwargs):
        try:
            return callback(*args, **kwargs)
        except KeyboardInterrupt as exc:
            detail = f": {exc}" if str(exc) else ""
            if isinstance(exc, Terminated):
                raise Interrupted(f"terminated (SIGTERM){detail}", 143) from None
            raise Interrupted(f"interrupted{detail}", 130) from None
        except BrokenPipeError as exc:   # not standard output's (ReportStream keeps that): typer hides any as exit 1
            raise PhoneposeError(f"{exc.filename + ': ' if exc.filename else ''}{exc.strerror or exc} (the other "
                                 f"end of a pipe or connection closed it)") from None
    run._reports_interrupts = True
    return run


def _reflowed(text: str) -> str:
    """A command's docstring with each paragraph on one line: typer's rich mode keeps the source's line
    breaks, which a terminal narrower than the source (80 columns) wrapped again into ragged lines."""
    return "\n\n".join(" ".join(para.split("\n")) for para in inspect.cleandoc(text).split("\n\n"))


def _prepare(command) -> None:
    """Every command of the tree: interrupts reported (one line, 130 or 143), its help's paragraphs
    reflowed, and ``--quiet`` in --help without a ``<bool>`` value placeholder (typer shows one for flags)."""
    if getattr(command, "callback", None) is not None and not getattr(command.callback, "_reports_interrupts", False):
        command.callback = _reporting_interrupts(command.callback)
    if getattr(command, "help", None):
        command.help = _reflowed(command.help)
    for param in getattr(command, "params", []):
        if getattr(param, "is_flag", False) and not getattr(param, "count", False):
            param.metavar = ""
    get_help = getattr(command, "get_help_option", None)
    if get_help is not None and getattr(command, "context_class", None) is not None:
        help_option = get_help(command.context_class(command, info_name=command.name))
        if help_option is not None:
            help_option.metavar = ""
    for sub in getattr(command, "commands", {}).values():
        _prepare(sub)


def command():
    """The click command of ``app``, as ``phonepose`` runs it."""
    cmd = typer.main.get_command(app)
    _prepare(cmd)
    return cmd


def _run(argv: list[str] | None) -> int:
    """The command, its every error one line on stderr: the exit code."""
    errors.show_parameters_as(flags.option)   # a line that the library writes itself names options too
    flags.set_command(sys.argv[1:] if argv is None else argv)
    try:
        return _run_command(argv)
    finally:
        errors.show_parameters_as(None)      # the library called in this process later speaks Python again
        flags.set_command([])


def _run_command(argv: list[str] | None) -> int:
    ClickException = _click_exceptions().ClickException
    try:
        process.check_before_any_work(sys.argv[1:] if argv is None else argv)
        rv = command()(args=argv, prog_name="phonepose", standalone_mode=False)
    except PhoneposeError as exc:
        error(flags.message(exc), exc.exit_code)
    except ClickException as exc:
        _usage_error(exc)
    except Interrupted as exc:
        return _stopped(str(exc), exc.code)
    except (KeyboardInterrupt, typer.Abort) as exc:
        return _stopped(*_stop_of(exc if isinstance(exc, KeyboardInterrupt) else None))
    except Exception as exc:   # noqa: BLE001 - the last net: a bug is one line too, the traceback on request
        if _stops:            # a stop that a library turned into its own error (an import: "initialization failed")
            return _stopped(*_stop_of())
        if os.environ.get("PHONEPOSE_TRACEBACK"):
            raise
        line = process.failure_line(exc)   # out of memory or open files, an OS failure: still one line
        if line is not None:
            error(line, 1)
        error(f"unexpected {type(exc).__name__}: {' '.join(str(exc).split())[:300]} (a bug in phonepose: please "
              f"report it with the command; PHONEPOSE_TRACEBACK=1 shows where it happened)", 1)
    if rv == INTERRUPTED_BY_TYPER:      # a stop outside the command's own code (typer returns 130, silent)
        return _stopped(*_stop_of())
    return rv if isinstance(rv, int) and not isinstance(rv, bool) else 0


INTERRUPTED_BY_TYPER = 130


def _exit_code(exc: SystemExit) -> int:
    return exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1


# A report whose reader went away (`phonepose info s.mcap | head -1`): silent, and the code a shell shows for a
# command stopped by SIGPIPE (as 130 and 143 for SIGINT and SIGTERM), never 0; the command's outputs are written.
EXIT_BROKEN_PIPE = 141


def main(argv: list[str] | None = None) -> None:
    """Entry point of the console script: every error is one line on stderr and its exit code.

    Standard output and error are :class:`~phonepose.cli.output.ReportStream` while the command runs: a report
    that cannot be written (``/dev/full``, a full disk, a closed pipe) never stops the work or loses an output,
    and is never success either: exit 6 and one line, or 141 and silence for a pipe whose reader left."""
    logs.quiet_libraries()
    logs.to_terminal()
    in_main = threading.current_thread() is threading.main_thread()
    old_term = signal.signal(signal.SIGTERM, _terminate) if in_main else None
    # Ctrl-C recorded like SIGTERM; left alone when ignored (a background job) or set by the caller
    old_int = signal.signal(signal.SIGINT, _interrupt) \
        if in_main and signal.getsignal(signal.SIGINT) is signal.default_int_handler else None
    _stops.clear()
    forget_outputs()
    code = 1
    saved = sys.stdout, sys.stderr
    out = sys.stdout = ReportStream(sys.stdout) if sys.stdout is not None else None
    sys.stderr = ReportStream(sys.stderr) if sys.stderr is not None else None
    try:
        try:
            code = _run(argv)
        except SystemExit as exc:
            code = _exit_code(exc)
        if out is not None:
            out.flush()
        if out is not None and out.failure is not None and code == 0:
            if out.failure.errno == errno.EPIPE:
                code = EXIT_BROKEN_PIPE
            else:
                code = OutputError.exit_code
                typer.echo(f"phonepose: error: cannot write the report to standard output: "
                           f"{out.failure.strerror or out.failure} (the report is incomplete; the command's own "
                           f"outputs, if any, are written)", err=True)
    finally:
        sys.stdout, sys.stderr = saved
        if argv is None and in_main:
            _exit_on_stops(code)
        else:         # called from other code (tests): its handlers back
            if old_term is not None:
                signal.signal(signal.SIGTERM, old_term)
            if old_int is not None:
                signal.signal(signal.SIGINT, old_int)
    sys.exit(code)


def _exit_on_stops(code: int) -> None:
    """The process's command is done and its code decided: a Ctrl-C or SIGTERM while the interpreter shuts down
    (atexit handlers, the libraries' threads: rerun's closes its sink) is ignored, so the process ends with that
    code, never killed by the signal with no line. (A Python handler would not do: the interpreter resets those
    to the default while it shuts down; an ignored signal stays ignored.)"""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)

"""How commands print: a progress bar that appears with the work, result tables that are never cut, and
standard output and error as streams whose failure never stops the work (:class:`ReportStream`)."""

from __future__ import annotations

import codecs
import errno
import io
import os
import time
from collections.abc import Callable

import typer
from rich.console import Console
from rich.markup import escape
from rich.measure import Measurement
from rich.progress import Progress
from rich.table import Table

from phonepose.text import printable


class ProgressBar(Progress):
    """A transient rich progress bar (on stderr) that appears with its first update, on a terminal
    only: a command that fails before its work starts prints its one error line and nothing else
    (rich's Live prints a newline when it stops, even when it showed nothing)."""

    def __init__(self, *columns, quiet: bool = False, **kwargs):
        console = kwargs.setdefault("console", Console(stderr=True))
        # not on a terminal (a log file, a pipe): no bar, and no blank line where it was
        super().__init__(*columns, transient=True, disable=quiet or not console.is_terminal, **kwargs)

    def update(self, *args, **kwargs) -> None:
        if not self.live.is_started:
            self.start()
        super().update(*args, **kwargs)

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc) -> None:
        if self.live.is_started:
            self.stop()


def shown(text: str) -> str:
    """Anyone's text (a session's topic names, an error quoting them) for rich's console: escape sequences and
    newlines shown, not obeyed (text.printable), and no markup ("[red]") read in it."""
    return escape(printable(text))


PIPED_WIDTH = 1000   # a table printed into a pipe or file is never cut to 80 columns


def stdout_console() -> Console:
    """The console for a command's results: the terminal's width, or unlimited when piped."""
    console = Console()
    return console if console.is_terminal else Console(width=PIPED_WIDTH)


def print_table(console: Console, table: Table) -> None:
    """A results table with every cell whole. rich fits a table to the terminal by cutting cells ("0.0…" for
    0.0123: a wrong number, "p_…" for both p_ATE and p_RE); here no column is narrower than its longest word,
    so cells wrap at their spaces. When that is still too wide, the cells lose their side padding if that makes
    the table fit (playback's table of every tracker needs 84 columns padded, 64 without, in an 80-column terminal); a terminal
    too narrow even for that wraps the table's lines instead."""
    unbounded = console.options.update_width(10**6)    # (a measurement is never wider than the options say)
    for column in table.columns:
        column.min_width = max(Measurement.get(console, unbounded, cell).minimum for cell in (column.header, *column.cells))
    needed = Measurement.get(console, unbounded, table).minimum
    width = console.width
    if needed > width:
        padding = table.padding
        table.padding = (0, 0)
        tight = Measurement.get(console, unbounded, table).minimum
        if tight <= width:
            needed = tight
        else:
            table.padding = padding    # wrapped by the terminal either way: the padded table reads better
    if needed > width:    # rich would squeeze the columns below their words (or drop one: width 0) to fit
        console.width = needed
    try:
        console.print(table, crop=False)
    finally:
        console.width = width


# ----------------------------------------------------------------------------- standard output and error
# What a terminal or file in a narrower encoding than UTF-8 (LC_ALL=C, PYTHONIOENCODING=ascii or latin-1) gets
# for the few symbols phonepose prints; anything else (a topic name's letters) is shown as its escape, \u2192.
_PLAIN = {"±": "+/-", "°": " deg", "×": "x", "–": "-", "—": "-", "…": "...", "Δ": "delta",
          "σ": "sigma", "²": "^2", "·": "*", "≤": "<=", "≥": ">=", "µ": "u", "━": "-", "─": "-", "│": "|"}


def _plain(exc: UnicodeError) -> tuple[str, int]:
    if not isinstance(exc, UnicodeEncodeError):
        raise exc
    text = exc.object[exc.start:exc.end]
    return "".join(_PLAIN.get(c) or c.encode("ascii", "backslashreplace").decode("ascii") for c in text), exc.end


codecs.register_error("phonepose-plain", _plain)


def takes_unicode(stream) -> bool:
    """Does ``stream`` take every character (UTF-8, -16, -32), or only some (ASCII, latin-1)?"""
    return codecs.lookup(getattr(stream, "encoding", None) or "utf-8").name.startswith("utf-")


class ReportStream(io.TextIOBase):
    """``sys.stdout`` or ``sys.stderr`` while a command runs. A write that fails (the reader of a pipe gone,
    ``/dev/full``, a full disk, a file size limit) never stops the command's work, so its outputs are still
    written; the failure is kept in :attr:`failure` for ``main`` to report, and what follows is dropped. Text
    the stream's encoding cannot hold is written as plain ASCII (``+/-`` for ``±``) or escapes, never a
    UnicodeEncodeError."""

    def __init__(self, stream):
        super().__init__()
        self.stream = stream
        self.failure: OSError | None = None
        self._narrow = not takes_unicode(stream)

    # rich draws ASCII tables for an ASCII stream; click writes through this one (it has no .buffer to go around it)
    @property
    def encoding(self) -> str:  # type: ignore[override]
        return getattr(self.stream, "encoding", None) or "utf-8"

    @property
    def errors(self) -> str | None:  # type: ignore[override]
        return getattr(self.stream, "errors", None)

    def isatty(self) -> bool:
        try:
            return self.stream.isatty()
        except (OSError, ValueError):
            return False

    def fileno(self) -> int:
        return self.stream.fileno()

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        if not isinstance(text, str):       # (click asks with b"" whether a stream takes bytes: it does not)
            raise TypeError(f"write() argument must be str, not {type(text).__name__}")
        if self.failure is None:
            if self._narrow:
                text = text.encode(self.encoding, "phonepose-plain").decode(self.encoding)
            self._guarded(self.stream.write, text)
        return len(text)

    def flush(self) -> None:
        if self.failure is None:
            self._guarded(self.stream.flush)

    def _guarded(self, call, *args) -> None:
        try:
            call(*args)
        except OSError as exc:
            self.failure = exc
            self._discard()
        except ValueError:      # closed underneath (I/O operation on closed file)
            self.failure = OSError(errno.EBADF, os.strerror(errno.EBADF))

    def _discard(self) -> None:
        """What the stream still buffers goes to /dev/null, so that Python's own flush at exit fails no more."""
        try:
            fd = self.stream.fileno()
        except (OSError, ValueError, AttributeError):
            return
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(null, fd)
        finally:
            os.close(null)


def progress_lines(quiet: bool, stamp: bool = False) -> Callable[[str], None]:
    """Where a command's progress lines go: standard error (``stamp``: after the wall-clock time), with --quiet
    only the warnings among them (a step may prefix one with its name: ``  record live: warning: ...``)."""
    def echo(line: str) -> None:
        if not quiet or "warning: " in line:
            typer.echo(f"[{time.strftime('%H:%M:%S')}] {line}" if stamp else line, err=True)
    return echo

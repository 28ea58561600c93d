"""How commands print: a progress bar that appears with the work, result tables that are never cut."""

from __future__ import annotations

from rich.console import Console
from rich.markup import escape
from rich.progress import Progress

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


def stdout_console(min_width: int = 0) -> Console:
    """The console for a command's results: the terminal's width (at least ``min_width``), or
    unlimited when piped."""
    console = Console()
    if not console.is_terminal:
        return Console(width=PIPED_WIDTH)
    return console if console.width >= min_width else Console(width=min_width)

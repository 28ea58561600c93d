"""phonepose's error types. Each carries the exit code the CLI uses for it.

Errors a user can cause end in one line on stderr and this exit code, never a traceback
(see docs/reliability.md for the table).
"""

from __future__ import annotations


class PhoneposeError(Exception):
    """Base class: a problem with the user's input or environment, reported in one line."""

    exit_code = 1


class InputFileError(PhoneposeError):
    """Missing, unreadable, empty, or non-MCAP file."""

    exit_code = 2


class DamagedFileError(PhoneposeError):
    """An MCAP file that is truncated or corrupt (use `phonepose recover`)."""

    exit_code = 3


class SessionContentError(PhoneposeError):
    """A readable session that lacks what the command needs (camera, VIO, ...), or bad data in it."""

    exit_code = 4


class ConfigError(PhoneposeError):
    """Bad option, config file or value (names the key and the allowed values)."""

    exit_code = 5


class OutputError(PhoneposeError):
    """Output cannot be written (directory not writable, disk full)."""

    exit_code = 6


class TrackerError(ConfigError):
    """A user's tracker (``-t package.module:Class`` or an entry point) failed in its own code: its
    ``reset`` or ``step`` raised, called ``sys.exit()``, or returned what is not a pose. Exit 5, like
    every other problem with a ``-t`` (docs/writing-a-tracker.md). ``tracker``: its name."""

    def __init__(self, message: str, tracker: str):
        super().__init__(message)
        self.tracker = tracker

    def __reduce__(self):   # sent back from a worker process (experiment --workers, batch) whole
        return type(self), (str(self), self.tracker)


class StopRequest(BaseException):
    """phonepose's own stop raised into whatever code runs at that moment (a unit's time budget, from
    SIGALRM): like KeyboardInterrupt, it passes through a user's tracker unchanged, never becomes the
    tracker's error."""


# What a recorder's disk-full error adds: the file it wrote so far is a valid prefix (docs/reliability.md).
RECOVER_HINT = " (the file written so far stays readable; run `phonepose recover`)"

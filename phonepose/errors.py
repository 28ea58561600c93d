"""phonepose's error types. Each carries the exit code the CLI uses for it.

Errors a user can cause end in one line on stderr and this exit code, never a traceback
(see docs/reliability.md for the table).

An error about a value the caller gave names it as the Python API does: ``parameter`` is the keyword
(``rate``, ``out``, ``align_frames``), ``value`` what was given, ``expected`` what is allowed. Its message
is a template in which ``{rate}`` (or ``{force=True}``) stands for a parameter: ``str(error)`` shows the
keyword (``rate must be > 0 (got 0)``), and the command line shows its own option in its place
(:meth:`PhoneposeError.render`).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable
from typing import Any


class _NoValue:
    def __repr__(self) -> str:
        return "NO_VALUE"

    def __reduce__(self) -> str:   # one object across pickling
        return "NO_VALUE"


#: ``value`` when the error names no value (``None`` can be the value given).
NO_VALUE: Any = _NoValue()

_PLACEHOLDER = re.compile(r"\{([A-Za-z_][A-Za-z0-9_]*)(=[^{}]*)?\}")


class PhoneposeError(Exception):
    """Base class: a problem with the user's input or environment, reported in one line.

    ``parameter``: the keyword of the value at fault; ``also``: other keywords the message names;
    ``value``, ``expected``: the value given and what is allowed (``NO_VALUE`` / ``None`` when not told)."""

    exit_code = 1

    def __init__(self, message: str = "", *args: Any, parameter: str | None = None, value: Any = NO_VALUE,
                 expected: str | None = None, also: Iterable[str] = ()):
        super().__init__(message, *args)
        self.template = message
        self.parameter = parameter
        self.value = value
        self.expected = expected
        self.also = tuple(also)

    @property
    def parameters(self) -> tuple[str, ...]:
        """Every keyword the message names, ``parameter`` first."""
        return ((self.parameter,) if self.parameter else ()) + self.also

    def render(self, name: Callable[[str, str], str] | None = None) -> str:
        """The message with each ``{keyword}`` placeholder as ``name(keyword, as_python)`` gives it
        (``as_python``: ``rate`` or ``force=True``); without ``name``, as Python spells it."""
        if len(self.args) != 1 or not isinstance(self.args[0], str):
            return super().__str__()
        names = set(self.parameters)
        if not names:
            return self.template

        def one(m: re.Match[str]) -> str:
            key, python = m.group(1), m.group(1) + (m.group(2) or "")
            if key not in names:
                return m.group(0)
            return python if name is None else name(key, python)

        return _PLACEHOLDER.sub(one, self.template)

    def __str__(self) -> str:
        return self.render()

    def __reduce__(self):   # sent back from a worker process (an experiment's or a batch's) with its fields
        return _rebuild, (type(self), self.args, self.__dict__)


_show_parameter: Callable[[str, str], str] | None = None


def show_parameters_as(name: Callable[[str, str], str] | None) -> None:
    """How :func:`shown` names a parameter: ``name(keyword, as_python)``; the CLI gives its options."""
    global _show_parameter
    _show_parameter = name


def keyword(name: str) -> str:
    """A parameter as a warning or status line names it: the keyword, or the CLI's option while a
    command runs (:func:`show_parameters_as`)."""
    return name if _show_parameter is None else _show_parameter(name, name)


def shown(error: PhoneposeError) -> str:
    """The error's line for its reader: with the parameters named as :func:`show_parameters_as` set
    (the command line's options), else as Python spells them."""
    return error.render(_show_parameter)


def _rebuild(cls: type[PhoneposeError], args: tuple, fields: dict) -> PhoneposeError:
    error = cls.__new__(cls)
    Exception.__init__(error, *args)
    error.__dict__.update(fields)
    return error


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

    def __init__(self, message: str, tracker: str, **fields: Any):
        super().__init__(message, **fields)
        self.tracker = tracker


class StopRequest(BaseException):
    """phonepose's own stop raised into whatever code runs at that moment (a unit's time budget, from
    SIGALRM): like KeyboardInterrupt, it passes through a user's tracker unchanged, never becomes the
    tracker's error."""


# What a recorder's disk-full error adds: the file it wrote so far is a valid prefix (docs/reliability.md).
RECOVER_HINT = " (the file written so far stays readable; run `phonepose recover`)"

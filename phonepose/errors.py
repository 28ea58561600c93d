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

    def __reduce__(self):   # sent back from a worker process (experiment --jobs, batch) whole
        return type(self), (str(self), self.tracker)


class StopRequest(BaseException):
    """phonepose's own stop raised into whatever code runs at that moment (a unit's time budget, from
    SIGALRM): like KeyboardInterrupt, it passes through a user's tracker unchanged, never becomes the
    tracker's error."""


# What a recorder's disk-full error adds: the file it wrote so far is a valid prefix (docs/reliability.md).
RECOVER_HINT = " (the file written so far stays readable; run `phonepose recover`)"


def quiet_library_warnings() -> None:
    """Keep the libraries' own diagnostics off the user's terminal: phonepose reports what matters in
    its own lines (``phonepose: error:`` / ``phonepose: warning:``). numpy's floating-point warnings
    (an overflow on an absurd input: results are checked for NaN/inf where they are used), the
    RuntimeWarnings numpy and scipy raise themselves, and OpenCV's WARN log lines (a camera or video
    that cannot be opened), FFmpeg's lines from inside OpenCV's video reader ("moov atom not found" for
    a file that is no video: phonepose says "not a video OpenCV can read"), and rerun's log lines
    ("Dropping data in MemorySink" at exit; a write that failed is phonepose's own line, see
    ``viewer.sink.close_recording``). ``OPENCV_LOG_LEVEL``, ``OPENCV_FFMPEG_LOGLEVEL`` or ``RUST_LOG`` set
    by the user wins. Called by the CLI and by every worker
    process it starts."""
    import os
    import sys
    import warnings

    os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")     # read when cv2 loads (workers inherit it)
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET, read when a video is first opened
    os.environ.setdefault("RUST_LOG", "off")   # rerun's Rust log, read when it loads: its errors are our lines
                                               # (its "Failed to write" named the temporary, in colour)
    cv2 = sys.modules.get("cv2")
    if cv2 is not None and os.environ["OPENCV_LOG_LEVEL"] == "ERROR":
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    warnings.filterwarnings("ignore", category=RuntimeWarning, module=r"(numpy|scipy)(\.|$)")
    import numpy as np
    np.seterr(all="ignore")

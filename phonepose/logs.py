"""phonepose's log and what reaches a terminal.

The library logs plain messages (``s.mcap: 3 sample(s) skipped``) to the ``phonepose`` logger and leaves its
handlers to the application: in a notebook they show through Python's last-resort handler or the user's own
logging configuration. The command line (and the worker processes it starts) call :func:`to_terminal`, which
prints each record as one ``phonepose: warning: ...`` line, and :func:`quiet_libraries`, which keeps numpy's,
OpenCV's, FFmpeg's and rerun's own diagnostics off the terminal (phonepose reports what matters in its lines).
"""

from __future__ import annotations

import logging
import sys

from phonepose.text import printable

log = logging.getLogger("phonepose")


class _Terminal(logging.StreamHandler):
    """Each record as one ``phonepose: LEVEL: message`` line on whatever ``sys.stderr`` is at the time."""

    def __init__(self) -> None:
        super().__init__()

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:   # StreamHandler assigns one in __init__: the current stderr is used instead
        pass

    def format(self, record: logging.LogRecord) -> str:
        # printable: a message may quote anyone's text (a schema name, a file's line): it stays one line
        return f"phonepose: {record.levelname.lower()}: {printable(record.getMessage())}"


def to_terminal() -> None:
    """Print the ``phonepose`` logger's warnings and errors as one line each on standard error (once a process)."""
    if not on_terminal():
        log.addHandler(_Terminal())


def on_terminal() -> bool:
    """Whether :func:`to_terminal` was called in this process."""
    return any(isinstance(h, _Terminal) for h in log.handlers)


def quiet_libraries() -> None:
    """Keep the libraries' own diagnostics off the terminal: numpy's floating-point warnings (an overflow on an
    absurd input: results are checked for NaN/inf where they are used) and the RuntimeWarnings numpy and scipy
    raise, OpenCV's WARN lines, FFmpeg's lines from inside OpenCV's video reader ("moov atom not found": phonepose
    says "not a video OpenCV can read"), and rerun's Rust log (a write that failed is phonepose's own line,
    ``viewer.sink.close_recording``). ``OPENCV_LOG_LEVEL``, ``OPENCV_FFMPEG_LOGLEVEL`` or ``RUST_LOG`` set by the
    user wins. For a command-line process and the workers it starts, never for a library user's process."""
    import os
    import warnings

    os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")     # read when cv2 loads (workers inherit it)
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET, read when a video is first opened
    os.environ.setdefault("RUST_LOG", "off")               # rerun's Rust log, read when it loads
    cv2 = sys.modules.get("cv2")
    if cv2 is not None and os.environ["OPENCV_LOG_LEVEL"] == "ERROR":
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    warnings.filterwarnings("ignore", category=RuntimeWarning, module=r"(numpy|scipy)(\.|$)")
    import numpy as np
    np.seterr(all="ignore")

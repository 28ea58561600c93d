"""The one Rerun sink set-up and the one column buffer of phonepose's Rerun loggers.

:func:`open_recording` makes the ``RecordingStream`` for ``record`` and ``playback`` alike: a file
(``--rerun FILE.rrd``, a path the caller has already checked and may be a temporary of
:mod:`phonepose.files`: nothing here creates folders) or a spawned viewer (``--spawn``); a
recording id given by the caller (same inputs, same id: the viewer merges recordings that share
one, so different runs must not); a recording name for the viewer's sources panel; and no
wall-clock ``log_time`` timeline (only the session's own clocks, so a recording's duration is the
session's, not the seconds the logging took).

:class:`Columns` buffers the rows of one entity and sends them with one ``send_columns`` call:
one ``log`` call per entity per tick would dominate playback.
"""

from __future__ import annotations

import errno
import os
import shutil
from collections.abc import Callable
from typing import Any

import numpy as np
import rerun as rr

from phonepose.errors import ConfigError, OutputError
from phonepose.viewer.entities import SESSION_TIME, TICK, TIME

VIEWER_PORT = 9876                      # rerun's own default: a viewer already listening there is reused
VIEWER_BIND = "127.0.0.1"               # the spawned viewer's server address unless PHONEPOSE_VIEWER_BIND says another
VIEWER_BIND_ENV = "PHONEPOSE_VIEWER_BIND"


def viewer_bind() -> str:
    """The address a spawned viewer listens on: :data:`VIEWER_BIND`, or an IP address in ``$PHONEPOSE_VIEWER_BIND``
    (``0.0.0.0``: every interface, for a viewer on another machine)."""
    import ipaddress

    given = os.environ.get(VIEWER_BIND_ENV, "").strip()
    if not given:
        return VIEWER_BIND
    try:
        return str(ipaddress.ip_address(given))
    except ValueError:
        raise ConfigError(f"{VIEWER_BIND_ENV}={given[:60]!r}: expected an IP address such as 127.0.0.1 or "
                          f"0.0.0.0") from None


def _reach(bind: str) -> str:
    """Where this process reaches a viewer listening on ``bind``: loopback for a wildcard or loopback address."""
    import ipaddress

    ip = ipaddress.ip_address(bind)
    if ip.is_unspecified or ip.is_loopback:
        return "[::1]" if ip.version == 6 and not ip.is_unspecified else "127.0.0.1"
    return f"[{ip}]" if ip.version == 6 else str(ip)


def spawn_viewer(*, port: int, bind: str, headless: bool = False) -> int | None:
    """Start a Rerun viewer whose server listens on ``bind``:``port`` and wait until it takes connections; its
    pid (None: a viewer already listening on ``port`` is used). ``rr.spawn`` has no bind address and rerun's
    own default is 0.0.0.0, so the viewer's ``--bind`` goes through the same binding ``rr.spawn`` calls."""
    import rerun_bindings

    return rerun_bindings.spawn(port=port, memory_limit="75%", hide_welcome_screen=False, detach_process=True,
                                executable_name="rerun", extra_args=["--bind", bind],
                                extra_env=[("RERUN_APP_ONLY", "true")], headless=headless)


def open_recording(application_id: str, recording_id: str, *, name: str, rrd_path: str | os.PathLike | None = None,
                   spawn: bool = False, blueprint=None, start_time_ns: int | None = None) -> rr.RecordingStream:
    """A recording stream saved to ``rrd_path`` or streamed to a spawned viewer (one of them).

    Any sink failure is one :class:`OutputError` line. ``start_time_ns`` (the session's start)
    replaces the wall-clock start time in the recording's properties.
    """
    rec = rr.RecordingStream(application_id, recording_id=recording_id)
    rec.set_log_time_enabled(False)
    try:
        if spawn:
            bind = viewer_bind()
            if rr.is_enabled(rec) and os.environ.get("_RERUN_TEST_FORCE_SAVE") is None:   # as rr.spawn skips
                spawn_viewer(port=VIEWER_PORT, bind=bind)
            rec.connect_grpc(f"rerun+http://{_reach(bind)}:{VIEWER_PORT}/proxy", default_blueprint=blueprint)
        elif rrd_path is not None:
            path: str = os.fspath(rrd_path)
            if os.path.isdir(path):
                raise OutputError(f"cannot write {path}: is a directory")
            rec.save(path, default_blueprint=blueprint)
        else:
            raise ValueError("open_recording needs rrd_path or spawn")
    except (RuntimeError, OSError) as exc:   # rerun reports sink failures as RuntimeError
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if spawn:
            raise OutputError(f"cannot spawn the Rerun viewer ({first}); save a recording with {{rerun}} FILE.rrd "
                              "instead", parameter="spawn", value=True, also=["rerun"]) from None
        raise OutputError(f"cannot write {rrd_path}: {first}") from None
    rec.send_recording_name(name)
    if start_time_ns is not None:
        rec.send_recording_start_time_nanos(int(start_time_ns))
    return rec


# How long closing waits for the sink to take what is still buffered. rerun's own default is forever, and a
# flush can wait on a file writer that has stopped (`ulimit -f`). A .rrd's writer keeps up with the logging
# while the command runs, so what is left at the end takes seconds.
FLUSH_TIMEOUT_S = 120.0


def close_recording(rec: rr.RecordingStream, rrd_path: str | os.PathLike | None) -> None:
    """Send what is buffered and close the sink (a .rrd gets its footer only then). A write that failed on the
    way (a full disk, `ulimit -f`: rerun's file writer stopped and the process carried on), or a sink that does
    not take the rest within FLUSH_TIMEOUT_S, is one OutputError naming ``rrd_path``, so that the caller never
    puts a cut .rrd in place and never waits forever."""
    try:
        rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        rec.disconnect()
    except RuntimeError as exc:    # "File-writer thread shut down prematurely"; the cause is in rerun's log line
        if rrd_path is None:
            raise OutputError(f"the Rerun viewer stopped taking the recording ({exc})") from None
        raise OutputError(f"cannot write {rrd_path}: {_sink_failure(rrd_path, exc)}") from None
    if rrd_path is not None and not os.path.exists(rrd_path):      # its folder removed meanwhile
        raise OutputError(f"cannot write {rrd_path}: {os.strerror(errno.ENOENT)} (removed while it was written)")
    if rrd_path is not None and not _ends_with_footer(rrd_path):   # the last write failed: rerun only logged it
        raise OutputError(f"cannot write {rrd_path}: {_sink_failure(rrd_path, None)}")


RRD_FOOTER = b"RRF2FOOT"    # what the last bytes of a complete .rrd hold (rerun's footer), its version after it


def _ends_with_footer(rrd_path: str | os.PathLike) -> bool:
    try:
        with open(rrd_path, "rb") as f:
            f.seek(max(os.fstat(f.fileno()).st_size - 64, 0))
            return RRD_FOOTER in f.read()
    except OSError:
        return False


def _sink_failure(rrd_path: str | os.PathLike, exc: Exception | None) -> str:
    """Why rerun's file writer stopped: it logs the OS error and raises a generic one; the file system says."""
    try:
        if shutil.disk_usage(os.path.dirname(os.path.abspath(rrd_path))).free == 0:
            return os.strerror(errno.ENOSPC)
    except OSError:
        pass
    limit = _file_size_limit()
    if limit is not None and os.path.exists(rrd_path) and os.path.getsize(rrd_path) >= limit:
        return f"{os.strerror(errno.EFBIG)} (the limit of `ulimit -f`, {limit} bytes)"
    if exc is None:
        return "it ends without its footer (a write failed)"
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def _file_size_limit() -> int | None:
    """`ulimit -f` in bytes; None when unlimited or where the system has no such limit (Windows)."""
    try:
        import resource
    except ImportError:
        return None
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    return None if limit == resource.RLIM_INFINITY else limit


def time_columns(t_ns, ticks=None, start_ns: int | None = None) -> list:
    """The index columns of a batch of rows: ``time`` (and ``tick`` when given, and ``session_time``,
    the duration since ``start_ns``, when that is given)."""
    out = []
    t = np.asarray(t_ns, dtype=np.int64)
    if ticks is not None:
        out.append(rr.TimeColumn(TICK, sequence=np.asarray(ticks, dtype=np.int64)))
    if start_ns is not None:
        out.append(rr.TimeColumn(SESSION_TIME, duration=(t - np.int64(start_ns)).astype("timedelta64[ns]")))
    out.append(rr.TimeColumn(TIME, timestamp=t.astype("datetime64[ns]")))
    return out


class Columns:
    """Rows of one entity, buffered and sent as columns.

    ``make(fields)`` turns the buffered field lists (one list per keyword given to :meth:`add`)
    into Rerun component columns, e.g. ``lambda f: rr.Scalars.columns(scalars=f["value"])``.
    Rows carry their own ``time`` (and ``tick``, and ``session_time`` from ``start_ns``), so a
    flush at any moment is correct.
    """

    def __init__(self, rec: rr.RecordingStream, path: str, make: Callable[[dict[str, list]], Any],
                 with_ticks: bool = True, start_ns: int | None = None):
        self.rec = rec
        self.start_ns = start_ns
        self.path = path
        self.make = make
        self.with_ticks = with_ticks
        self.t: list[int] = []
        self.ticks: list[int] = []
        self.fields: dict[str, list] = {}

    def __len__(self) -> int:
        return len(self.t)

    def add(self, t_ns: int, tick: int | None = None, **fields) -> None:
        self.t.append(int(t_ns))
        if self.with_ticks:
            assert tick is not None, "a Columns with ticks needs the tick of every row"
            self.ticks.append(int(tick))
        for key, value in fields.items():
            self.fields.setdefault(key, []).append(value)

    def flush(self) -> None:
        if not self.t:
            return
        columns = self.make(self.fields)
        self.rec.send_columns(self.path, indexes=time_columns(self.t, self.ticks if self.with_ticks else None,
                                                                      self.start_ns),
                              columns=columns)
        self.t, self.ticks, self.fields = [], [], {}


def transform_columns(fields: dict[str, list]) -> Any:
    """``Columns`` maker for rows added with ``translation=`` and ``quaternion=`` (xyzw)."""
    return rr.Transform3D.columns(translation=np.asarray(fields["translation"], dtype=np.float32).reshape(-1, 3),
                                  quaternion=np.asarray(fields["quaternion"], dtype=np.float32).reshape(-1, 4))

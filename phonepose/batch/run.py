"""One unit of a batch → its rows. Runs in a worker process (local pool or Dask worker).

:func:`run_unit` never raises for a bad session: whatever goes wrong in the playback becomes rows
with ``status = "error"`` and a one-line ``error``, so one session cannot stop a batch.
"""

from __future__ import annotations

import contextlib
import dataclasses
import signal
import threading
import time
from collections.abc import Callable, Iterator

from phonepose import __version__
from phonepose.batch.plan import Unit, params_json, session_signature
from phonepose.errors import PhoneposeError, StopRequest, TrackerError

FIXED_COLUMNS = ("session", "params", "tracker", "status", "error", "session_bytes", "session_mtime_ns",
                 "n_ticks", "n_task_ticks", "frames_decoded", "runtime_s", "phonepose_version")
MAX_ERROR_CHARS = 400


def init_worker() -> None:
    """One OpenCV thread per worker: the pool's processes are the parallelism (idempotent, cheap)."""
    try:
        import cv2
        cv2.setNumThreads(1)
    except Exception:   # noqa: BLE001 - OpenCV missing is the playback's error to report, not ours
        pass


def one_line(exc: BaseException) -> str:
    """The error column: a PhoneposeError's own message; anything else prefixed with its type."""
    text = str(exc) if isinstance(exc, (PhoneposeError, UnitTimeout)) else f"{type(exc).__name__}: {exc}"
    text = " ".join(text.split()) or type(exc).__name__
    return text if len(text) <= MAX_ERROR_CHARS else text[:MAX_ERROR_CHARS - 3] + "..."


def flatten_tracker_metrics(metrics: dict) -> dict:
    """A tracker's entry of metrics.json as flat columns, generically: ``{"total": {"p_ate_m": x}}``
    → ``p_ate_m_total``; a scalar at the tracker's level keeps its name; deeper levels join with ``_``
    (metric path first, scope last). New keys in metrics.json become new columns by themselves."""
    out: dict = {}

    def walk(path: list[str], value) -> None:
        if isinstance(value, dict):
            for k, v in value.items():
                walk(path + [str(k)], v)
            return
        name = "_".join(path[1:] + path[:1]) if len(path) > 1 else path[0]
        if name in FIXED_COLUMNS or name.startswith("param_"):
            name = "metric_" + name
        out[name] = value

    for key, value in metrics.items():
        walk([str(key)], value)
    return out


def base_row(unit: Unit, tracker: str) -> dict:
    params = unit.params_dict
    row = {"session": unit.session, "params": params_json(params), "tracker": tracker}
    for k, v in params.items():
        row[f"param_{k}"] = v
    return row


def error_rows(unit: Unit, exc: BaseException | str, runtime_s: float | None = None) -> list[dict]:
    """Rows for a unit that failed (in the playback, or its worker died)."""
    message = exc if isinstance(exc, str) else one_line(exc)
    sig = session_signature(unit.path)
    rows = []
    for tracker in unit.trackers:
        row = base_row(unit, tracker)
        row.update(status="error", error=message, session_bytes=sig[0] if sig else None,
                   session_mtime_ns=sig[1] if sig else None, n_ticks=None, n_task_ticks=None, frames_decoded=None,
                   runtime_s=runtime_s, phonepose_version=__version__)
        rows.append(row)
    return rows


class UnitTimeout(StopRequest):
    """A unit ran past its time budget (``batch --unit-timeout``). A BaseException, like
    KeyboardInterrupt: the SIGALRM raising it may land in code that turns any Exception into its own
    error (the session reader's "damaged MCAP data"), or in a user's tracker (a StopRequest passes
    through its guard unchanged)."""

    def __init__(self, budget_s: float):
        super().__init__(f"stopped after its time budget of {budget_s:g} s (unit_timeout_s)")


@contextlib.contextmanager
def time_budget(budget_s: float | None) -> Iterator[Callable[[int, int], None]]:
    """A progress callback that raises UnitTimeout once ``budget_s`` has passed (checked every tick),
    and, in a process's main thread (a local worker), a SIGALRM that raises it between ticks too
    (opening a session, planning). Dask runs units in threads: there the tick check alone applies."""
    deadline = None if budget_s is None else time.monotonic() + budget_s

    def check(done: int, total: int) -> None:
        if deadline is not None and budget_s is not None and time.monotonic() > deadline:   # (both or neither)
            raise UnitTimeout(budget_s)

    alarm = budget_s is not None and threading.current_thread() is threading.main_thread() \
        and hasattr(signal, "setitimer")
    if alarm:
        assert budget_s is not None   # alarm implies it
        def on_alarm(signum, frame):
            raise UnitTimeout(budget_s)
        old = signal.signal(signal.SIGALRM, on_alarm)
        signal.setitimer(signal.ITIMER_REAL, budget_s)
    try:
        yield check
    finally:
        if alarm:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, old)


def run_unit(unit: Unit, budget_s: float | None = None) -> list[dict]:
    """Play ``unit.path`` back once with every tracker of the unit (in memory, no files); one row per tracker.

    ``runtime_s`` is the playback's wall time in the worker (run_playback's ``wall_s``: open, ticks,
    metrics), the same in every row of the unit: the trackers share the playback. A playback longer
    than ``budget_s`` seconds is stopped and becomes error rows. A user's tracker that fails in its own
    code (TrackerError) gets an error row, and the playback runs again without it for the others.
    """
    init_worker()
    from phonepose.pipeline.trackers import make_trackers
    from phonepose.playback.engine import run_playback

    params = unit.params_dict
    cm1_reading = params.get("cm1_reading", "consistent")
    t0 = time.perf_counter()
    sig = session_signature(unit.path)
    failed: dict[str, str] = {}    # a user's tracker that failed in its own code -> its error
    result = None
    try:
        with time_budget(budget_s) as check_budget:
            calibration = None
            if params.get("gt_calibration") == "calibrate-gt":
                from phonepose.calibration.calibrate_gt import calibrate_gt_session
                calibration = calibrate_gt_session(unit.path)
            # the trackers share one playback: one whose own code fails is taken out and the playback run
            # again, so the others' rows are still made (its own row says why it failed)
            while refs := [ref for name, ref in zip(unit.trackers, unit.tracker_refs, strict=True) if name not in failed]:
                try:
                    result = run_playback(
                        unit.path, trackers=refs, rate_hz=params.get("rate_hz", 20.0),
                        correction_math=params.get("correction_math", "paper"), start_s=params.get("start_s"),
                        end_s=params.get("end_s"), write_outputs=False, progress=check_budget,
                        gt_calibration=calibration,
                        tracker_factory=lambda names, math: make_trackers(names, math, cm1_reading))
                    break
                except TrackerError as exc:
                    if exc.tracker not in unit.trackers or exc.tracker in failed:
                        raise
                    failed[exc.tracker] = one_line(exc)
    except KeyboardInterrupt:
        raise
    except BaseException as exc:   # noqa: BLE001 - every failure of one session is that session's rows: an
        # Exception, the time budget, and a SystemExit that got this far (which would otherwise end a local
        # worker's task as a SystemExit raised in the batch itself: a silent exit with no table)
        return error_rows(unit, exc, time.perf_counter() - t0)
    ran = tuple(t for t in unit.trackers if t not in failed)    # none: every tracker failed, no result
    rows = {r["tracker"]: r for r in _result_rows(dataclasses.replace(unit, trackers=ran), result, sig)} if ran else {}
    for name, message in failed.items():
        rows[name] = error_rows(dataclasses.replace(unit, trackers=(name,)), message, time.perf_counter() - t0)[0]
    return [rows[t] for t in unit.trackers]


def _result_rows(unit: Unit, result, sig) -> list[dict]:
    """One ok row per tracker of ``unit`` from its playback's ``result``."""
    renamed = [t for t in unit.trackers if t not in result.metrics["trackers"]]
    if renamed:   # a user's tracker whose name depends on the process (it is read in the batch, then here)
        return error_rows(unit, f"tracker {renamed[0]!r} has another name in this worker ("
                                f"{', '.join(result.metrics['trackers'])}): a tracker's name must be fixed",
                          result.wall_s)
    rows = []
    for tracker in unit.trackers:
        row = base_row(unit, tracker)
        row.update(status="ok", error=None, session_bytes=sig[0] if sig else None,
                   session_mtime_ns=sig[1] if sig else None, n_ticks=result.n_ticks, n_task_ticks=result.n_task_ticks,
                   frames_decoded=result.frames_decoded, runtime_s=result.wall_s, phonepose_version=__version__)
        row.update(flatten_tracker_metrics(result.metrics["trackers"][tracker]))
        rows.append(row)
    return rows

"""A bound on every tracker step of a playback (``playback --tick-timeout``).

A thread watches the step in progress. When one runs past its time, the watchdog first stops it where it
is: on POSIX a signal to the main thread raises :class:`StepTimeout` inside the step (it passes a user's
tracker's guard, as Ctrl-C does), the playback unwinds, the output plan removes its temporaries and the
engine reports :class:`~phonepose.errors.TrackerError`. A step that does not unwind within
:data:`GRACE_S` (code that blocks the signal, a C call that never returns), and every overdue step where
no signal can be sent to the main thread (Windows, a playback outside the main thread), is ended by the
watchdog itself: the same line, the open plans' temporaries removed, and the process exits with the same
code. No SIGALRM: a batch's ``--unit-timeout`` owns it.
"""

from __future__ import annotations

import os
import signal
import threading
import time

from phonepose.errors import StopRequest, TrackerError, shown

GRACE_S = 5.0    # how long a stopped step may take to unwind before the process ends without it
_SIGNAL = getattr(signal, "SIGUSR1", None)


class StepTimeout(StopRequest):
    """Raised into a tracker step that ran past its time (passes the user's tracker's guard)."""


class StepWatchdog:
    """Arm before a step (:meth:`arm`), disarm after it; :meth:`close` ends the watch. ``timeout_s`` per step."""

    def __init__(self, timeout_s: float):
        self.timeout_s = float(timeout_s)
        self._armed: tuple[float, str, int] | None = None   # (deadline, who, tick): replaced whole, never edited
        self._overdue: tuple[float, str, int] | None = None
        self._closed = threading.Event()
        self._main = threading.main_thread().ident
        self._soft = _SIGNAL is not None and hasattr(signal, "pthread_kill") and \
            threading.current_thread() is threading.main_thread()
        self._old_handler = signal.signal(_SIGNAL, self._on_signal) if self._soft and _SIGNAL is not None else None
        self._thread = threading.Thread(target=self._watch, name="phonepose-step-watchdog", daemon=True)
        self._thread.start()

    def arm(self, who: str, tick: int) -> None:
        self._armed = (time.monotonic() + self.timeout_s, who, tick)

    def disarm(self) -> None:
        self._armed = None

    def close(self) -> None:
        self._closed.set()
        self._thread.join()
        if self._soft and _SIGNAL is not None:
            signal.signal(_SIGNAL, self._old_handler)

    def message(self, armed: tuple[float, str, int]) -> str:
        _, who, tick = armed
        return f"{who} did not return from step() at tick {tick} within {{tick_timeout}} {self.timeout_s:g} s: stopped"

    def _on_signal(self, signum, frame) -> None:
        overdue = self._overdue
        if overdue is not None and self._armed is overdue:    # still in that step (else it returned meanwhile)
            raise StepTimeout(self.message(overdue))   # a template: the engine's TrackerError names tick_timeout

    def _watch(self) -> None:
        while not self._closed.is_set():
            armed = self._armed
            if armed is None:
                self._closed.wait(min(self.timeout_s, 0.5))
                continue
            left = armed[0] - time.monotonic()
            if left > 0:
                self._closed.wait(left)
                continue
            if self._armed is not armed:
                continue                                         # that step returned; a later one is armed
            self._overdue = armed
            if self._soft and _SIGNAL is not None and self._main is not None:
                signal.pthread_kill(self._main, _SIGNAL)
                end = time.monotonic() + GRACE_S
                while self._armed is armed and not self._closed.is_set() and time.monotonic() < end:
                    self._closed.wait(0.05)
                if self._armed is not armed or self._closed.is_set():
                    return                                       # it unwound: the engine reports it
            self._end_process(self.message(armed))

    @staticmethod
    def _end_process(message: str) -> None:
        """The step never came back: the line, the temporaries removed, the tracker error's exit code."""
        from phonepose.files import abort_open_plans

        try:
            line = shown(TrackerError(message, "", parameter="tick_timeout"))
            os.write(2, f"phonepose: error: {line}\n".encode("utf-8", "replace"))
        finally:
            abort_open_plans()
            os._exit(TrackerError.exit_code)

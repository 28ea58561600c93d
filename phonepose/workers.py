"""Worker processes that stop with the command that started them (batch, experiment exp2).

A ``ProcessPoolExecutor`` on its own outlives a killed parent: its workers finish their unit (a
minute of playback, ~135 MB each) and hold the caller's stdout open, and on Ctrl-C or SIGTERM
``shutdown(wait=True)`` waits for them. Here:

- each worker asks the kernel for SIGKILL when its parent dies (Linux ``prctl(PR_SET_PDEATHSIG)``,
  through ctypes: the standard library has no call for it), and checks that the parent is still the
  one that started it (it may have died before the request);
- workers ignore SIGINT: Ctrl-C reaches the whole process group, and the parent alone decides;
- when the parent's block ends with an exception (KeyboardInterrupt, SIGTERM, an error), the
  workers are killed at once instead of awaited.

The ``spawn`` start method: no fork of a process that may hold OpenCV's or Rerun's threads.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager

from phonepose import logs

PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int) -> None:
    """In a worker: be killed when ``parent_pid`` ends; leave SIGINT to the parent."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):   # no prctl: the parent's kill on the way out still applies
            pass
    if os.getppid() != parent_pid:          # the parent died before the request: nothing will signal us
        os._exit(1)


def _initialize(parent_pid: int, initializer: Callable[[], None] | None, terminal: bool) -> None:
    die_with_parent(parent_pid)
    if terminal:   # a worker of a command prints on its parent's terminal, as its parent does
        from phonepose import logs
        logs.to_terminal()
        logs.quiet_libraries()
    if initializer is not None:
        initializer()


def kill_workers(pool: ProcessPoolExecutor) -> None:
    """SIGKILL every worker of ``pool`` now (ProcessPoolExecutor has no public call for it before
    Python 3.14's ``kill_workers``)."""
    kill = getattr(pool, "kill_workers", None)
    if kill is not None:
        kill()
        return
    for proc in list(getattr(pool, "_processes", {}).values()):
        try:
            proc.kill()
        except (OSError, AttributeError, ValueError):
            pass


# After a SIGKILL of the parent, multiprocessing's resource tracker frees the pool's semaphores and
# warns about each "leak" on the user's terminal: noise, since freeing them is its job. The tracker
# process takes its -W options from sys.warnoptions when it starts.
_QUIET_TRACKER = "ignore::UserWarning:multiprocessing.resource_tracker"


@contextmanager
def worker_pool(workers: int, initializer: Callable[[], None] | None = None) -> Iterator[ProcessPoolExecutor]:
    """A process pool whose workers die with this process; on an exception they are killed, not awaited."""
    if _QUIET_TRACKER not in sys.warnoptions:
        sys.warnoptions.append(_QUIET_TRACKER)
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_initialize, initargs=(os.getpid(), initializer, logs.on_terminal()))
    try:
        yield pool
    except BaseException:
        kill_workers(pool)
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True, cancel_futures=True)

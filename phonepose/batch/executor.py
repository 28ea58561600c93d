"""Where a batch's units run: a local process pool, or a Dask distributed cluster.

Both are a :class:`concurrent.futures.Executor`: the batch submits :func:`run_unit` and waits
with :func:`concurrent.futures.as_completed` the same way on either. Locally a process pool whose
workers die with the batch (:func:`phonepose.workers.worker_pool`); with a scheduler address,
``distributed.Client(address).get_executor()`` (Dask's own implementation of the interface; Dask
does the scheduling, and its workers belong to the cluster, not to this command).
"""

from __future__ import annotations

import os
import time
import weakref
from collections.abc import Callable, Iterator
from concurrent.futures import Executor
from contextlib import contextmanager

from phonepose.batch.run import init_worker
from phonepose.errors import ConfigError
from phonepose.workers import worker_pool

CONNECT_TIMEOUT_S = 10
NO_WORKER_TIMEOUT_S = 30.0   # how long a Dask batch waits for a worker when its cluster has none (--keep-waiting: for ever)
WATCH_INTERVAL_S = 2.0       # how often a Dask batch asks its scheduler how many workers it has

_clients: weakref.WeakKeyDictionary[Executor, object] = weakref.WeakKeyDictionary()   # a Dask executor's Client


def workers_now(executor: Executor) -> int | None:
    """How many workers a Dask executor's cluster has now (asked of its scheduler); None for a local pool (its
    workers are the batch's own) or when the scheduler does not answer."""
    client = _clients.get(executor)
    if client is None:
        return None
    try:
        return len(client.scheduler_info().get("workers", {}))   # type: ignore[attr-defined]
    except (OSError, TimeoutError, RuntimeError, ValueError):
        return None


class NoWorkers:
    """The worker count of a Dask batch, watched while it waits for its units: each change is reported
    (``on_count(n)``), and a cluster left without a worker for ``timeout_s`` (None: for ever) is
    :meth:`overdue`: its tasks would wait for ever, with nothing said."""

    def __init__(self, executor: Executor, on_count: Callable[[int], None] | None, timeout_s: float | None,
                 count: Callable[[Executor], int | None] = workers_now):
        self.executor, self.on_count, self.timeout_s, self.count = executor, on_count, timeout_s, count
        self.last: int | None = None
        self.none_since: float | None = None

    def check(self) -> bool:
        """Ask the count now; True when the cluster has had no worker for longer than ``timeout_s``."""
        n = self.count(self.executor)
        if n is None:
            return False
        if n != self.last and (self.last is not None or n == 0) and self.on_count is not None:
            self.on_count(n)       # (the count at the start is in the batch's first line)
        self.last = n
        if n > 0:
            self.none_since = None
            return False
        if self.none_since is None:
            self.none_since = time.monotonic()
        return self.timeout_s is not None and time.monotonic() - self.none_since >= self.timeout_s


def default_workers() -> int:
    """One worker per core the process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def check_scheduler_address(address: str) -> None:
    """A Dask address (``tcp://host:8786``, or ``host:8786`` as Dask reads it) or one line, before a
    Client exists: a Client whose constructor fails on a malformed address prints a traceback from its
    ``__del__`` 20 s after the error."""
    from distributed.comm import parse_address
    from distributed.comm.registry import backends

    try:
        scheme, location = parse_address(address)
    except (ValueError, TypeError):
        scheme, location = "", ""
    host, _, port = location.rpartition(":")
    ok = scheme in backends and bool(location) and " " not in location
    if ok and scheme in ("tcp", "tls"):
        ok = bool(host) and port.isdigit() and 0 < int(port) < 65536
    if not ok:
        raise ConfigError(f"{{scheduler}} {address!r}: expected a Dask scheduler address such as tcp://host:8786",
                          parameter="scheduler", value=address, expected="a Dask scheduler address")


@contextmanager
def open_executor(workers: int | None = None, scheduler: str | None = None) -> Iterator[tuple[Executor, str]]:
    """``(executor, description)``; ``scheduler`` (``tcp://host:8786``) selects Dask, else a local pool."""
    if scheduler is not None:
        if workers is not None:
            raise ConfigError("{workers} and {scheduler} are exclusive: the cluster's workers are set by `dask worker`",
                              parameter="workers", value=workers, also=["scheduler"])
        try:
            from distributed import Client
        except ImportError:
            raise ConfigError("{scheduler} needs Dask: pip install 'phonepose[cluster]'", parameter="scheduler",
                              value=scheduler) from None
        check_scheduler_address(scheduler)
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise ConfigError(f"{{scheduler}} {scheduler}: cannot connect within {CONNECT_TIMEOUT_S} s "
                              f"({' '.join(str(exc).split()) or type(exc).__name__})", parameter="scheduler",
                              value=scheduler) from None
        try:
            n = len(client.scheduler_info().get("workers", {}))
            # pure=False: a rerun of the same unit is a new task, never a cached result
            executor = client.get_executor(pure=False)
            _clients[executor] = client
            yield executor, f"Dask cluster {scheduler} ({n} workers now)"
        finally:
            client.close()
        return
    n = default_workers() if workers is None else workers
    if n < 1:
        raise ConfigError(f"{{workers}} must be >= 1 (got {n})", parameter="workers", value=n, expected=">= 1")
    with worker_pool(n, init_worker) as pool:    # workers die with the batch (phonepose.workers)
        yield pool, f"{n} local worker process{'es' if n != 1 else ''}"

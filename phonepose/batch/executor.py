"""Where a batch's units run: a local process pool, or a Dask distributed cluster.

Both are a :class:`concurrent.futures.Executor`: the batch submits :func:`run_unit` and waits
with :func:`concurrent.futures.as_completed` the same way on either. Locally a process pool whose
workers die with the batch (:func:`phonepose.workers.worker_pool`); with a scheduler address,
``distributed.Client(address).get_executor()`` (Dask's own implementation of the interface; Dask
does the scheduling, and its workers belong to the cluster, not to this command).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from concurrent.futures import Executor
from contextlib import contextmanager

from phonepose.batch.run import init_worker
from phonepose.errors import ConfigError
from phonepose.workers import worker_pool

CONNECT_TIMEOUT_S = 10


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
        raise ConfigError(f"--scheduler {address!r}: expected a Dask scheduler address such as tcp://host:8786")


@contextmanager
def open_executor(workers: int | None = None, scheduler: str | None = None) -> Iterator[tuple[Executor, str]]:
    """``(executor, description)``; ``scheduler`` (``tcp://host:8786``) selects Dask, else a local pool."""
    if scheduler is not None:
        if workers is not None:
            raise ConfigError("--workers and --scheduler are exclusive: the cluster's workers are set by `dask worker`")
        try:
            from distributed import Client
        except ImportError:
            raise ConfigError("--scheduler needs Dask: pip install 'phonepose[cluster]'") from None
        check_scheduler_address(scheduler)
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise ConfigError(f"--scheduler {scheduler}: cannot connect within {CONNECT_TIMEOUT_S} s "
                              f"({' '.join(str(exc).split()) or type(exc).__name__})") from None
        try:
            n = len(client.scheduler_info().get("workers", {}))
            # pure=False: a rerun of the same unit is a new task, never a cached result
            yield client.get_executor(pure=False), f"Dask cluster {scheduler} ({n} workers now)"
        finally:
            client.close()
        return
    n = default_workers() if workers is None else workers
    if n < 1:
        raise ConfigError(f"--workers must be >= 1 (got {n})")
    with worker_pool(n, init_worker) as pool:    # workers die with the batch (phonepose.workers)
        yield pool, f"{n} local worker process{'es' if n != 1 else ''}"

"""Where sweep tasks run: in this process, in local worker processes, or on a Dask cluster.

Every executor yields ``(key, result)`` as tasks finish, in any order; results do not depend
on the executor because every task carries its own seed.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import AbstractContextManager
from typing import Any

Task = tuple[Any, Callable[..., Any], tuple[Any, ...]]  # (key, function, args)


def default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


class InlineExecutor(AbstractContextManager):
    """Runs tasks one after another in this process."""

    name = "inline"

    def run(self, tasks: Sequence[Task]) -> Iterator[tuple[Any, Any]]:
        for key, fn, args in tasks:
            yield key, fn(*args)

    def __exit__(self, *exc: object) -> None:
        return None


class ProcessExecutor(AbstractContextManager):
    """Local worker processes (spawned, so no thread state is forked)."""

    def __init__(self, workers: int) -> None:
        self.workers = workers
        self.name = f"{workers} local processes"
        self._pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"))

    def run(self, tasks: Sequence[Task]) -> Iterator[tuple[Any, Any]]:
        futures = {self._pool.submit(fn, *args): key for key, fn, args in tasks}
        for fut in as_completed(futures):
            yield futures[fut], fut.result()

    def __exit__(self, *exc: object) -> None:
        self._pool.shutdown(cancel_futures=True)


class DaskExecutor(AbstractContextManager):
    """A Dask distributed cluster at ``tcp://HOST:PORT``, or ``local`` for a LocalCluster on
    this machine. Needs the optional extra ``swarmraft[cluster]``."""

    def __init__(self, scheduler: str, workers: int) -> None:
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise RuntimeError("--scheduler needs Dask: pip install 'swarmraft[cluster]'") from None
        self._cluster = None
        if scheduler == "local":
            self._cluster = LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
            )
            scheduler = self._cluster.scheduler_address
        try:
            self._client = Client(scheduler, timeout="10s")
        except OSError as exc:
            raise RuntimeError(f"--scheduler: cannot reach {scheduler}: {exc}") from None
        self.name = f"Dask at {scheduler}"

    def run(self, tasks: Sequence[Task]) -> Iterator[tuple[Any, Any]]:
        from distributed import as_completed as dask_completed

        futures = {}
        for key, fn, args in tasks:
            futures[self._client.submit(fn, *args, pure=False)] = key
        for fut in dask_completed(list(futures)):
            yield futures[fut], fut.result()

    def __exit__(self, *exc: object) -> None:
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()


def check_executor(workers: int | None = None, scheduler: str | None = None) -> None:
    """Raise a one-line ValueError naming ``--workers`` or ``--scheduler`` if they cannot
    work, before anything starts: a worker count below 1, a scheduler that is neither
    ``local`` nor an address like ``tcp://HOST:PORT``, or a scheduler without Dask."""
    if workers is not None and workers < 1:
        raise ValueError(f"--workers: {workers} is not a worker count (1 or more)")
    if scheduler is None:
        return
    scheme, sep, rest = scheduler.partition("://")
    if scheduler != "local" and not (sep and scheme.isalpha() and rest):
        raise ValueError(f"--scheduler: expected tcp://HOST:PORT or 'local', got {scheduler!r}")
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise ValueError("--scheduler needs Dask: pip install 'swarmraft[cluster]'") from None


def make_executor(workers: int | None = None, scheduler: str | None = None) -> AbstractContextManager:
    check_executor(workers, scheduler)
    workers = workers or default_workers()
    if scheduler:
        return DaskExecutor(scheduler, workers)
    return InlineExecutor() if workers == 1 else ProcessExecutor(workers)

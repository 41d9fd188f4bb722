"""BLAS on one thread for the estimation code.

Detectors and the Cramér-Rao bound work on many small matrices (a mission step is one
snapshot of n drones; a sweep is parallel by processes): BLAS threads gain little there and, on
a busy machine, fight over the cores. Measured (OpenBLAS, 2 threads, load average 30): 64
inversions of 192 x 192 took 7-14 s with 2 threads and 0.4 s with one. The thread count can
also change a result's last bits, so one thread makes them independent of the machine.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

_libraries: list[Any] | None = None  # threadpoolctl's BLAS controllers, found on first use


def _blas() -> list[Any]:
    global _libraries
    if _libraries is None:
        from threadpoolctl import ThreadpoolController

        _libraries = list(ThreadpoolController().select(user_api="blas").lib_controllers)
    return _libraries


_lock = threading.Lock()
_inside = 0  # contexts open, in every thread
_restore: list[tuple[Any, int]] = []  # the thread counts the first one in changed


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """A context in which BLAS runs on one thread. It sets and restores the thread count of
    the BLAS libraries loaded at its first use directly (about 2 us; threadpoolctl's
    `limit`, which inspects every loaded library each time, took 10-50 us, twice a leader
    step), and does nothing where they already run on one thread.

    The count is the process's, and a networked drone verifies in one thread while it audits
    in another: the first context in sets it, the last one out (in whichever thread) restores
    it, so nested use and use from several threads at once leave it at one until every
    context has closed."""
    global _inside
    with _lock:
        if _inside == 0:
            for lib in _blas():
                threads = lib.get_num_threads()
                if threads != 1:
                    lib.set_num_threads(1)
                    _restore.append((lib, threads))
        _inside += 1
    try:
        yield
    finally:
        with _lock:
            _inside -= 1
            if _inside == 0:
                for lib, threads in _restore:
                    lib.set_num_threads(threads)
                _restore.clear()


def pin_one_blas_thread() -> None:
    """BLAS on one thread from now on, for good: for a process that verifies in several
    threads (a networked drone: its event loop, verify and audit threads). Call it from the
    main thread before the others start. OpenBLAS ignores a thread count set from another
    thread once the main thread has set one above 1 (measured with the OpenBLAS of numpy's
    and scipy's wheels: after the main thread's context restored 2, a context in another
    thread set 1 and read back 2), so a context in the verify or audit thread cannot rely on
    setting it; with the count pinned at 1 every context finds nothing to change."""
    with _lock:
        for lib in _blas():
            lib.set_num_threads(1)
        _restore.clear()  # a context open now must not set the old count back

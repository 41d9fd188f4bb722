"""BLAS on one thread for the estimation code.

Detectors and the Cramér-Rao bound work on many small matrices (a mission step is one
snapshot of n drones; a sweep is parallel by processes): BLAS threads gain little there and, on
a busy machine, fight over the cores. Measured (OpenBLAS, 2 threads, load average 30): 64
inversions of 192 x 192 took 7-14 s with 2 threads and 0.4 s with one. The thread count can
also change a result's last bits, so one thread makes them independent of the machine.
"""

from __future__ import annotations

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


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """A context in which BLAS runs on one thread. It sets and restores the thread count of
    the BLAS libraries loaded at its first use directly (about 2 us; threadpoolctl's
    `limit`, which inspects every loaded library each time, took 10-50 us, twice a leader
    step), and does nothing where they already run on one thread (nested use)."""
    changed = []
    for lib in _blas():
        threads = lib.get_num_threads()
        if threads != 1:
            lib.set_num_threads(1)
            changed.append((lib, threads))
    try:
        yield
    finally:
        for lib, threads in changed:
            lib.set_num_threads(threads)

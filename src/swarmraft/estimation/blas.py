"""BLAS on one thread for the estimation code.

Detectors and the Cramér-Rao bound work on many small matrices (a mission step is one
snapshot of n drones; a sweep is parallel by processes): BLAS threads gain little there and, on
a busy machine, fight over the cores. Measured (OpenBLAS, 2 threads, load average 30): 64
inversions of 192 x 192 took 7-14 s with 2 threads and 0.4 s with one. The thread count can
also change a result's last bits, so one thread makes them independent of the machine.
"""

from __future__ import annotations

from typing import Any

_controller = None  # threadpoolctl's, made on first use (it inspects the loaded libraries)


def one_blas_thread() -> Any:
    """A context manager in which BLAS runs on one thread (about 0.1 ms to enter and leave)."""
    global _controller
    if _controller is None:
        from threadpoolctl import ThreadpoolController

        _controller = ThreadpoolController()
    return _controller.limit(limits=1, user_api="blas")

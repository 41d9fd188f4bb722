"""Timing helper shared by the micro-benchmarks (bench_crypto.py, bench_wire.py)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def per_op_us(fn: Callable[[], object], ops: int, runs: int) -> tuple[float, float]:
    """Best and median over ``runs`` runs of the mean time of one call, in microseconds."""
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        for _ in range(ops):
            fn()
        times.append((time.perf_counter() - t0) / ops * 1e6)
    return min(times), statistics.median(times)

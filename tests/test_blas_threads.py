"""Detectors run with BLAS on one thread (estimation.blas): on a busy machine BLAS threads
fighting over the cores made a 64-drone step 20-30x slower, and one thread makes a verdict's
last bits independent of the machine's core count."""

import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from swarmraft.estimation import blas, registry
from swarmraft.estimation.blas import _blas, one_blas_thread
from swarmraft.estimation.snapshot import SnapshotBatch


def blas_threads() -> set[int]:
    return {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}


def test_one_blas_thread_inside_and_restored_after():
    before = blas_threads()
    with one_blas_thread():
        assert blas_threads() == {1}
    assert blas_threads() == before


def test_verify_batch_runs_the_detector_on_one_blas_thread(monkeypatch):
    seen = []
    real = registry.get_detector("paper")

    class Spy:
        params = real.params

        def run(self, batch, p):
            seen.append(blas_threads())
            return real.run(batch, p)

    monkeypatch.setattr(registry, "get_detector", lambda name: Spy() if name == "paper" else real)
    rng = np.random.default_rng(0)
    pos = rng.uniform(0, 50, (1, 6, 3))
    ranges = np.linalg.norm(pos[:, :, None] - pos[:, None], axis=-1)
    registry.verify_batch(SnapshotBatch(pos, ranges, (1.5, 3.0), 0.1), "paper")
    assert seen == [{1}]


def test_one_blas_thread_nests_and_restores_after_an_error():
    before = blas_threads()
    try:
        with one_blas_thread():
            with one_blas_thread():
                assert blas_threads() == {1}
            assert blas_threads() == {1}  # the inner exit leaves the outer's limit alone
            raise KeyError("inside")
    except KeyError:
        pass
    assert blas_threads() == before


class _FakeBlas:
    """A BLAS library's thread count, as threadpoolctl's controllers give it."""

    def __init__(self, threads: int) -> None:
        self.threads = threads

    def get_num_threads(self) -> int:
        return self.threads

    def set_num_threads(self, k: int) -> None:
        self.threads = k


def test_one_blas_thread_holds_until_the_last_thread_inside_leaves(monkeypatch):
    """A networked drone verifies in one thread and audits in another, both inside the
    context. The thread count is the process's: when the first thread out restored it, the
    other computed on as many BLAS threads as cores (two threads fighting over two loaded
    cores, and results whose last bits depend on the core count). Fake libraries: OpenBLAS's
    own count set from a thread is not always taken (the pinning test below)."""
    libs = [_FakeBlas(2), _FakeBlas(4)]
    monkeypatch.setattr(blas, "_libraries", libs)
    a_inside, a_left, b_inside = threading.Event(), threading.Event(), threading.Event()
    seen = []

    def counts() -> list[int]:
        return [lib.threads for lib in libs]

    def a() -> None:
        with one_blas_thread():
            a_inside.set()
            b_inside.wait(10)
            seen.append(("a inside", counts()))
        a_left.set()

    def b() -> None:
        a_inside.wait(10)
        with one_blas_thread():
            b_inside.set()
            a_left.wait(10)
            seen.append(("b inside after a left", counts()))

    threads = [threading.Thread(target=a), threading.Thread(target=b)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert seen == [("a inside", [1, 1]), ("b inside after a left", [1, 1])]
    assert counts() == [2, 4]  # the last one out set them back


_LOCKOUT = """
import sys, threading
from swarmraft.estimation.blas import _blas, one_blas_thread, pin_one_blas_thread
if sys.argv[1] == "pin":
    pin_one_blas_thread()
with one_blas_thread():  # the event loop verifies a record: 1, then its count set back
    pass
seen = []
def audit():
    with one_blas_thread():
        seen.append(sorted({lib.get_num_threads() for lib in _blas()}))
t = threading.Thread(target=audit)
t.start()
t.join()
print(seen[0])
"""


@pytest.mark.parametrize("pin", ["pin", "no pin"])
def test_a_pinned_process_verifies_on_one_blas_thread_in_every_thread(pin):
    """OpenBLAS ignores a thread count set from another thread once the main thread has set
    one above 1: a networked drone's audit thread, after its event loop's context restored
    the count, computed on every core (`blas.pin_one_blas_thread`, which `net.node` calls).
    A fresh process each, so that this one's BLAS state does not matter."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).parents[1] / "src")}
    env.pop("OPENBLAS_NUM_THREADS", None)
    out = subprocess.run(
        [sys.executable, "-c", _LOCKOUT, pin], capture_output=True, text=True, env=env, check=True
    ).stdout.strip()
    assert out == ("[1]" if pin == "pin" else f"[{max(lib.get_num_threads() for lib in _blas())}]")

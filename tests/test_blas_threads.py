"""Detectors run with BLAS on one thread (estimation.blas): on a busy machine BLAS threads
fighting over the cores made a 64-drone step 20-30x slower, and one thread makes a verdict's
last bits independent of the machine's core count."""

import numpy as np
from threadpoolctl import threadpool_info

from swarmraft.estimation import registry
from swarmraft.estimation.blas import one_blas_thread
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

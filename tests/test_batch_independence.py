"""A verdict depends only on its own snapshot, never on the other trials of its batch.

A leader verifies one snapshot a step (a batch of 1); a sweep verifies chunks of
``chunk_size`` trials. If a detector took a max, min, mean or early stop across the trial
axis (one GNC parameter for the whole batch, one ridge from the batch's largest
information, one swap count from the batch's fewest trusted drones), a trial's verdict
would change with the trials beside it: a mission step and the same snapshot in a sweep
would disagree, and a sweep's numbers would change with its chunk size. Every registered
detector is checked: the whole batch, the batch in chunks of 5 and every trial alone give
the same verdicts bit for bit (status, flags, per-drone status, positions, protection
levels and every diagnostic).

(A sweep's chunk size also fixes its seeds, `trials.chunk_seed`, so two sweeps with
different chunk sizes verify different snapshots; the sweep test below therefore compares
one sweep with the same sweep verified one trial at a time.)
"""

from __future__ import annotations

import numpy as np
import pytest

from swarmraft.estimation import SnapshotBatch, VerdictBatch, verify_batch
from swarmraft.estimation.bounds import gnss_covariance
from swarmraft.estimation.mirror import mirror_ambiguous
from swarmraft.estimation.noise import NoiseModel
from swarmraft.estimation.registry import detector_names
from swarmraft.estimation.rivals import rival_sets
from swarmraft.experiments import build_config, run_sweep
from swarmraft.experiments import trials as trials_module
from swarmraft.experiments.trials import draw, snapshot_batch

# (n, f, geometry): a small swarm at its most attackers, a mid one, a near-collinear one
CELLS = ((5, 2, "cube"), (9, 4, "cube"), (13, 3, "line"))
TRIALS = 12
# paper with the joint recovery at a vote threshold that suits realistic noise (8 m, about
# what calibration gives), so that it flags only some drones and its verdicts vary
VARIANTS = [(name, {}) for name in detector_names()] + [("paper", {"recovery": "joint", "tau": 8.0})]


def _batch(n: int, f: int, geometry: str) -> SnapshotBatch:
    config = build_config("realistic", n=(n,), f=(f,), trials=TRIALS, geometry=geometry, calibrate=False)
    d = draw(config, np.random.default_rng(np.random.SeedSequence(2025, spawn_key=(n, f))), TRIALS, n, f)
    return snapshot_batch(config, d)


def _fields(v: VerdictBatch) -> dict[str, np.ndarray]:
    out = {
        k: np.asarray(getattr(v, k)) for k in ("positions", "faulty", "status", "drone_status", "hpl", "vpl")
    }
    out.update({f"diagnostics.{k}": np.asarray(a) for k, a in v.diagnostics.items()})
    return out


def _in_parts(batch: SnapshotBatch, size: int, detector: str, params: dict) -> dict[str, np.ndarray]:
    """The batch verified ``size`` trials at a time, the parts' fields stacked."""
    T = batch.reported.shape[0]
    parts = [
        _fields(verify_batch(batch.subset(np.arange(a, min(T, a + size))), detector, **params))
        for a in range(0, T, size)
    ]
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _differences(whole: dict[str, np.ndarray], other: dict[str, np.ndarray]) -> list[str]:
    assert set(whole) == set(other)
    bad = []
    for k, a in whole.items():
        b = other[k]
        same = a.shape == b.shape and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
        if not same:
            rows = [t for t in range(len(a)) if not np.array_equal(a[t], b[t], equal_nan=a.dtype.kind == "f")]
            bad.append(f"{k}: trials {rows}")
    return bad


@pytest.mark.parametrize(
    ("detector", "params"), VARIANTS, ids=[d + ("-joint" if p else "") for d, p in VARIANTS]
)
def test_a_verdict_does_not_depend_on_its_batch(detector, params):
    statuses = set()
    verdicts, diagnostics = [], []  # what differs: the verdict itself first, then diagnostics
    for n, f, geometry in CELLS:
        batch = _batch(n, f, geometry)
        whole = _fields(verify_batch(batch, detector, **params))
        statuses |= set(whole["status"].tolist())
        for size in (5, 1):
            for line in _differences(whole, _in_parts(batch, size, detector, params)):
                where = f"{(n, f, geometry)} in parts of {size}: {line}"
                (diagnostics if line.startswith("diagnostics.") else verdicts).append(where)
    assert verdicts == []
    assert diagnostics == []
    assert len(statuses) >= 2  # the cells are not all one kind of verdict


def _one_at_a_time(batch, detector, **params):
    """verify_batch, one snapshot at a time (as a leader step), stacked as one batch."""
    T = batch.reported.shape[0]
    parts = [verify_batch(batch.subset(np.array([t])), detector, **params) for t in range(T)]
    diag = {k: np.concatenate([p.diagnostics[k] for p in parts]) for k in parts[0].diagnostics}
    return VerdictBatch(
        *(np.concatenate([getattr(p, k) for p in parts]) for k in ("positions", "faulty", "status")),
        diag,
        *(np.concatenate([getattr(p, k) for p in parts]) for k in ("drone_status", "hpl", "vpl")),
    )


@pytest.mark.parametrize("detector", ["joint", "fde"])
def test_a_sweep_is_the_same_verified_one_trial_at_a_time(detector, tmp_path, monkeypatch):
    config = build_config(
        "realistic", n=(9,), f=(4,), trials=14, chunk_size=7, detector=detector, calibrate=False
    )
    run_sweep(config, tmp_path / "batched", workers=1)
    monkeypatch.setattr(trials_module, "verify_batch", _one_at_a_time)
    run_sweep(config, tmp_path / "alone", workers=1)
    batched = (tmp_path / "batched" / "trials.csv").read_text()
    assert batched.count("\n") == 15
    assert batched == (tmp_path / "alone" / "trials.csv").read_text()


def test_rival_swaps_are_counted_per_trial():
    """`rivals.rival_sets` tries up to ``swaps`` swaps per flagged drone, capped by the
    trial's own trusted count: a trial with one trusted drone beside a trial with many must
    not cut the other's swaps to one."""
    rng = np.random.default_rng(4)
    n = 7
    x = rng.uniform(0, 100, (2, n, 3))
    ranges = np.linalg.norm(x[:, :, None] - x[:, None], axis=3) + rng.normal(0, 0.1, (2, n, n))
    reported = x + rng.normal(0, 1.5, x.shape)
    trusted = np.ones((2, n), dtype=bool)
    trusted[0, 1:] = False  # one trusted drone
    trusted[1, :2] = False  # five trusted drones
    noise = NoiseModel(gnss_covariance(1.5, 3.0), 0.1)
    both = rival_sets(x, reported, ranges, trusted, noise, 1e-3, np.array([0, 1]))
    for t in (0, 1):
        alone = rival_sets(
            x[t : t + 1],
            reported[t : t + 1],
            ranges[t : t + 1],
            trusted[t : t + 1],
            noise,
            1e-3,
            np.array([0]),
        )
        mine = both.owner == t
        assert np.array_equal(both.trusted[mine], alone.trusted)
        assert np.array_equal(both.x[mine], alone.x)
        assert np.array_equal(both.passed[mine], alone.passed)
    assert (both.owner == 1).sum() == 2 * 2  # two flagged drones, two swaps each


def test_mirror_ridge_is_per_trial():
    """`mirror.mirror_ambiguous` regularises each drone's 3x3 inverse with a ridge far below
    the largest information of its own trial. Trial 0: a drone 500 m off a line of 4
    collinear anchors, whose rotation about the line the ranges do not fix (only the ridge
    does); its mirror is ambiguous or not depending on that ridge. Trial 1: 40 drones on a
    line, all ranges measured (information about 10 times larger). Batched or alone, trial
    0's answer must be the same."""
    n = 40
    x = np.zeros((2, n, 3))
    x[0, :4, 0] = (0.0, 10.0, 20.0, 30.0)
    x[0, 4] = (15.0, 300.0, 400.0)
    x[0, 5:] = np.arange(5, n)[:, None] * (0.0, 0.0, 1000.0)  # far away, no ranges
    x[1, :, 0] = np.arange(n) * 5.0
    ranges = np.linalg.norm(x[:, :, None] - x[:, None], axis=3)
    ranges[0, :, 5:] = np.nan
    ranges[0, 5:, :] = np.nan
    trusted = np.ones((2, n), dtype=bool)
    trusted[0, 4:] = False
    noise = NoiseModel(gnss_covariance(1.5, 3.0), 1e-3)
    both = mirror_ambiguous(x, ranges, trusted, noise, 10.83)
    for t in (0, 1):
        alone = mirror_ambiguous(x[t : t + 1], ranges[t : t + 1], trusted[t : t + 1], noise, 10.83)
        assert np.array_equal(both[t], alone[0])
    assert not both[0, 4]  # alone, the ridge leaves the mirror within the drone's uncertainty

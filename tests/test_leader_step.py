"""When a leader closes a step (`SwarmDrone.has_all`) and which records are carried on
(`records.settled`): a step is verified from the reports of every drone known to be alive,
and a record that checked no drone is never the next step's prior."""

from __future__ import annotations

import numpy as np
import pytest

from swarmraft.protocol import Keyring, SwarmDrone
from swarmraft.protocol.drone import ProtocolConfig, compute_record
from swarmraft.protocol.records import settled

N = 9


def world(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """True positions of N drones 30 m apart or so, and their two-way ranges (0.1 m noise)."""
    rng = np.random.default_rng(seed)
    truth = rng.uniform(-30, 30, (N, 3)) + [0, 0, 100]
    d = np.linalg.norm(truth[:, None] - truth[None], axis=2)
    e = rng.normal(0, 0.1, (N, N))
    ranges = d + (e + e.T) / 2
    np.fill_diagonal(ranges, 0.0)
    return truth, ranges


def reports(keys: Keyring, cfg: ProtocolConfig, step: int, drones, spoof: dict | None = None) -> dict:
    truth, ranges = world(step)
    rng = np.random.default_rng(100 + step)
    out = {}
    for i in drones:
        fix = truth[i] + rng.normal(0, 1, 3) * [1.5, 1.5, 3.0] + (spoof or {}).get(i, 0.0)
        out[i] = SwarmDrone(i, cfg, keys).make_report(step, fix, "gnss", ranges[i], None)
    return out


@pytest.fixture
def swarm() -> tuple[Keyring, ProtocolConfig]:
    return Keyring.generate(N, np.random.default_rng(0)), ProtocolConfig(n=N, detector="joint")


def applied_record(drone: SwarmDrone, keys: Keyring, cfg: ProtocolConfig, step: int, present) -> None:
    """A record of ``step`` from the reports of ``present``, sealed by drone 0, applied by ``drone``."""
    rec = compute_record(step, 1, reports(keys, cfg, step, present), None, cfg)
    drone.apply(SwarmDrone(0, cfg, keys).seal(rec))


def test_a_new_leader_does_not_close_a_step_on_its_own_report(swarm):
    """A drone that just became leader has heard only from itself; the log says who reported
    in the last record. Before, its own report closed the step (the others arrived a
    millisecond later and were left out: a record of 1 report after every leader change)."""
    keys, cfg = swarm
    leader = SwarmDrone(4, cfg, keys)
    applied_record(leader, keys, cfg, 9, range(N - 1))  # drone 8 silent in the last record
    rs = reports(keys, cfg, 10, range(N))
    assert leader.receive(rs[4])
    assert not leader.has_all(10)
    for i in (0, 1, 2, 3, 5, 6, 7):
        leader.receive(rs[i])
        assert leader.has_all(10) == (i == 7), i  # closes when 0-7 are in
    # a drone that left the swarm is not waited for, though the last record holds its report
    leader.forget(7)
    rs = reports(keys, cfg, 11, range(N))
    for i in range(N - 2):
        leader.receive(rs[i])
    assert leader.has_all(11)


def test_without_a_recent_record_a_leader_waits_for_every_drone(swarm):
    """At the swarm's start (no record yet), or with the newest record older than the window,
    the leader does not know who is alive: only all n reports close a step before its
    deadline."""
    keys, cfg = swarm
    leader = SwarmDrone(0, cfg, keys)
    rs = reports(keys, cfg, 0, range(N))
    for i in range(N - 1):
        leader.receive(rs[i])
        assert not leader.has_all(0)
    leader.receive(rs[N - 1])
    assert leader.has_all(0)
    applied_record(leader, keys, cfg, 1, range(N - 1))  # drone 8 silent
    # drone 8, last heard at step 0, is no longer waited for at step 11 (the record of step 1
    # is 10 steps old); at step 12 the record is too old to say who is alive
    for step, closes in ((11, True), (12, False)):
        rs = reports(keys, cfg, step, range(N - 1))
        for r in rs.values():
            leader.receive(r)
        assert leader.has_all(step, recent=10) == closes, step


@pytest.mark.parametrize("detector", ["paper", "clique", "fde", "joint"])
def test_a_record_of_one_report_is_never_carried_on(detector):
    """A leader alone with its own report (spoofed 30 m here) makes a `degenerate` record that
    checked nothing; no detector's record of it is a prior or an INS alignment (`paper`'s,
    whose levels are nan, was: its lone fix became the next step's prior)."""
    keys = Keyring.generate(N, np.random.default_rng(0))
    cfg = ProtocolConfig(n=N, detector=detector)
    alone = reports(keys, cfg, 10, [0], spoof={0: np.array([30.0, 0.0, 0.0])})
    rec = compute_record(10, 1, alone, None, cfg)
    assert rec.status == "degenerate"
    assert not settled(rec)
    full = ProtocolConfig(n=N, detector="joint")  # (`paper` uncalibrated: an alarm here)
    assert settled(compute_record(10, 1, reports(keys, full, 10, range(N)), None, full))  # a full step is


def test_the_gates_re_estimate_keeps_what_the_detector_withheld():
    """The temporal gate flags a drone the detector trusted, and the record is estimated again
    without it. A drone the detector withheld (its level above the alert limits: here 1 m,
    so every drone) stays withheld: its position the prior, its levels inf, and no drone
    aligns its INS to the record. Before, the re-estimate placed every drone by the ranges
    with levels nan, and 8 drones 0.6-4 m off aligned to it (a review's reproduction)."""
    from swarmraft.protocol.drift import realigns
    from swarmraft.protocol.drone import Prior

    keys = Keyring.generate(N, np.random.default_rng(0))
    cfg = ProtocolConfig(n=N, detector="joint", detector_params={"alert_limit_h": 1.0, "alert_limit_v": 1.0})
    truth, _ = world(10)
    prior = Prior(9, truth + 0.5, np.zeros(N, bool))
    plain = reports(keys, cfg, 10, range(N))
    quiet = compute_record(10, 1, plain, prior, cfg)
    assert np.isinf(quiet.hpl).all() and not settled(quiet)
    gated = {
        i: SwarmDrone(i, cfg, keys).make_report(
            10, r.position, "gnss", r.ranges, np.array([4.0, 0, 0]) if i == 3 else np.zeros(3)
        )
        for i, r in plain.items()
    }
    rec = compute_record(10, 1, gated, prior, cfg)
    assert rec.faulty[3]  # the gate fired
    assert np.isinf(rec.hpl).all() and np.isinf(rec.vpl).all()
    np.testing.assert_array_equal(rec.positions, quiet.positions)
    assert not settled(rec)
    assert not any(realigns(rec, i, None) for i in range(N))


def test_a_withheld_drones_position_is_never_carried_more_than_one_step():
    """A drone whose level is above the alert limit (9 m horizontally here) is withheld, its
    position the prior, the previous record's. That record then went on as the next step's
    prior, and so on: in a swarm flying 7 m/s three drones' committed positions fell 8.6 m
    behind by step 12 (a review's reproduction), with the prior's 3 m sigma pulling the
    estimate. Now a carried position is not carried again (`records.carried_positions`): at
    most one step old, then nan."""
    keys = Keyring.generate(N, np.random.default_rng(0))
    cfg = ProtocolConfig(
        n=N,
        detector="joint",
        detector_params={"alert_limit_h": 9.0, "alert_limit_v": 1e6},
        innovation_gate=None,
    )
    rng = np.random.default_rng(5)
    truth0 = rng.uniform(-30, 30, (N, 3)) + [0, 0, 100]
    # step 0 without the limit, so that every drone starts with a position (as a drone whose
    # level grows past the limit does)
    leader = SwarmDrone(0, ProtocolConfig(n=N, detector="joint", innovation_gate=None), keys)
    withheld = 0
    for k in range(14):
        leader.config = leader.config if k == 0 else cfg
        truth = truth0 + [0.7 * k, 0, 0]  # 7 m/s, 10 Hz
        d = np.linalg.norm(truth[:, None] - truth[None], axis=2)
        e = rng.normal(0, 0.1, (N, N))
        ranges = d + (e + e.T) / 2
        np.fill_diagonal(ranges, 0.0)
        for i in range(N):
            fix = truth[i] + rng.normal(0, 1, 3) * [1.5, 1.5, 3.0]
            leader.receive(SwarmDrone(i, cfg, keys).make_report(k, fix, "gnss", ranges[i], None))
        rec = leader.verify_step(k, 1)
        leader.apply(leader.seal(rec))
        err = np.linalg.norm(rec.positions - truth, axis=1)[np.isinf(rec.hpl)]
        withheld += err.size
        # a position one step old is off by its estimate's error and 0.7 m; nan: not placed
        assert not (err > 5.0).any(), (k, np.round(err, 1))
    assert withheld >= 10  # the test is about withheld drones: there are some


def test_a_drone_flagged_by_the_gate_is_never_committed_at_its_report():
    """A new leader alone at its deadline (the others' reports went to the leader that just
    died: a networked run, 2026-12-05) with its own report spoofed 30 m: the temporal gate
    flags it, too few drones are trusted to place it again, and the record committed the
    spoofed report as its position (31.5 m off, flagged, level inf). A flagged drone still at
    its report takes its prior, or nan without one, as one the detector flagged does."""
    from swarmraft.protocol.drone import Prior

    keys = Keyring.generate(N, np.random.default_rng(0))
    cfg = ProtocolConfig(n=N, detector="joint")
    truth, _ = world(10)
    r = reports(keys, cfg, 10, [2], spoof={2: np.array([30.0, 0.0, 0.0])})[2]
    jumped = SwarmDrone(2, cfg, keys).make_report(
        10, r.position, "gnss", r.ranges, np.array([30.0, 0.0, 0.0])
    )
    for prior, want in (
        (Prior(9, truth + 0.5, np.zeros(N, bool)), truth[2] + 0.5),
        (None, np.full(3, np.nan)),
    ):
        rec = compute_record(10, 1, {2: jumped}, prior, cfg)
        assert rec.faulty[2] and not settled(rec)
        np.testing.assert_array_equal(rec.positions[2], want)

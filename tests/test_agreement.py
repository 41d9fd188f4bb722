"""The identical-records check (`sim.agreement`): it still finds a drone that applied a
different record, and what it holds stays bounded however long the mission."""

import dataclasses
import json

import pytest

from swarmraft.experiments.mission import error_series, summarize
from swarmraft.protocol import SwarmDrone
from swarmraft.raft import SnapshotPolicy
from swarmraft.sim.agreement import Disagreement, RecordAgreement
from swarmraft.sim.mission import AGREEMENT_PRUNE_STEPS, Mission
from swarmraft.sim.scenario import Scenario

#: small snapshots so a short mission compacts its logs many times
SMALL = SnapshotPolicy(every=100, keep=50)


def scenario(duration_s: float, **kw) -> Scenario:
    return Scenario(
        name="agreement",
        drones=5,
        duration_s=duration_s,
        seed=4,
        network={"loss": 0.05},
        protocol={"detector": "paper"},
        **kw,
    )


def test_a_differing_digest_is_a_disagreement_kept_in_full():
    a = RecordAgreement()
    a.note(1, 0, "aa", 1)
    a.note(2, 0, "aa", 1)
    a.note(3, 0, "bb", 1)
    a.note(1, 1, "cc", 2)
    assert not a.identical
    assert a.disagreements == [Disagreement(step=0, node=3, digest="bb", first="aa")]
    assert a.checked == 2 and a.applied == {1: 2, 2: 1, 3: 1}


def test_prune_closes_every_step_no_drone_can_apply():
    a = RecordAgreement()
    for step in range(10):
        a.note(1, step, f"d{step}", step + 1)
    # a drone that is down still holds entries 2 and 3 (steps 1 and 2): they stay open
    assert a.prune(lambda step, index: index in (2, 3) or index > 4) == 2
    assert sorted(a.open) == [1, 2, *range(4, 10)] and a.closed_max == 3
    a.note(2, 5, "d5", 6)  # an open step is still compared
    a.note(2, 6, "other", 7)
    assert [d.step for d in a.disagreements] == [6]
    # a record for a closed step means the host closed it too early: loud, never silent
    a.note(3, 2, "d2", 3)  # the drone that was down, replaying its log
    with pytest.raises(AssertionError, match="step 3, closed already"):
        a.note(3, 3, "d3", 4)


def test_replays_are_counted_per_drone():
    a = RecordAgreement()
    for step in (0, 1, 2, 1, 2, 3):
        a.note(4, step, f"d{step}", step + 1)
    assert a.repeats == {4: 2} and a.identical


def _lying_replay(monkeypatch, node: int) -> list[int]:
    """Drone ``node`` applies a different digest for the first step it applies a second
    time (replaying its log after a restart). Returns [that step] once it happened."""
    highest: dict[int, int] = {}
    changed: list[int] = []
    apply = SwarmDrone.apply

    def patched(self, data):
        rec = apply(self, data)
        if rec is None or self.index != node - 1:
            return rec
        if not changed and rec.step <= highest.get(self.index, -1):
            changed.append(rec.step)
            return dataclasses.replace(rec, digest="f" * 32)
        highest[self.index] = max(highest.get(self.index, -1), rec.step)
        return rec

    monkeypatch.setattr(SwarmDrone, "apply", patched)
    return changed


def test_the_summary_finds_a_drone_that_applied_a_different_record(monkeypatch):
    target = 40
    apply = SwarmDrone.apply

    def patched(self, data):
        rec = apply(self, data)
        if rec is not None and self.index == 2 and rec.step == target:
            return dataclasses.replace(rec, digest="0" * 32)
        return rec

    monkeypatch.setattr(SwarmDrone, "apply", patched)
    log = Mission(scenario(8.0), snapshots=SMALL).run()
    summary = summarize(log, error_series(log))
    assert summary["records_identical_on_all_nodes"] is False
    assert [(d.step, d.node, d.digest) for d in log.agreement.disagreements] == [(target, 3, "0" * 32)]


def test_a_restarted_drone_replaying_a_different_record_is_found(monkeypatch):
    """The replayed step was applied by every drone long before: the check must still hold it
    (drone 2's storage keeps it above its snapshot while it is down). Drone 2 is down at the
    prunes of steps 200 and 300, when every live drone has snapshotted past its log's tail."""
    changed = _lying_replay(monkeypatch, 2)
    sc = scenario(
        45.0,
        fault=[{"kind": "crash", "drone": 2, "at_s": 14.0}, {"kind": "restart", "drone": 2, "at_s": 36.0}],
    )
    log = Mission(sc, snapshots=SMALL).run()
    assert changed, "drone 2 replayed no record after its restart"
    assert log.agreement.repeats.get(2, 0) >= 1
    summary = summarize(log, error_series(log))
    assert summary["records_identical_on_all_nodes"] is False
    assert [(d.step, d.node) for d in log.agreement.disagreements] == [(changed[0], 2)]


def test_what_the_check_holds_stays_flat_in_a_long_mission():
    """A 150 s mission (1501 steps, 15 snapshots per drone, a drone down for 30 s): the items
    the check holds stop growing once the logs are compacted; the old per-drone lists grew by
    one item per drone per step (7,500 here)."""
    sc = scenario(
        150.0,
        fault=[{"kind": "crash", "drone": 4, "at_s": 60.0}, {"kind": "restart", "drone": 4, "at_s": 90.0}],
    )
    m = Mission(sc, snapshots=SMALL)
    held: dict[int, int] = {}
    k = 0

    def progress(_n: int) -> None:
        nonlocal k
        held[k] = m.log.agreement.held()
        k += 1

    log = m.run(progress)
    assert log.agreement.identical and log.committed.sum() > 1400
    assert sum(log.agreement.applied.values()) > 6000
    after_warm_up = [held[k] for k in range(300, len(held))]
    # bounded by the logs: the live drones' logs (every + keep entries: 150 steps), the tail
    # above its snapshot that the drone down for 300 steps holds (up to every + keep), and
    # what was applied since the last prune (AGREEMENT_PRUNE_STEPS); measured: 457 at most
    bound = 3 * (SMALL.every + SMALL.keep) + AGREEMENT_PRUNE_STEPS
    assert max(after_warm_up) <= bound, max(after_warm_up)
    # flat: the last third holds no more than the second
    assert max(held[k] for k in range(1000, len(held))) <= max(held[k] for k in range(300, 1000))


def test_a_networked_run_with_a_differing_record_says_so(tmp_path):
    """`net.results.launch_log` feeds every drone's step file into the same check."""
    from swarmraft.net.results import launch_log
    from swarmraft.net.swarmfile import drone_file
    from swarmraft.sim.sensing import ScenarioWorld

    world = ScenarioWorld.build(Scenario(name="net", drones=4, duration_s=1.0, seed=2))
    for d in (1, 2, 3, 4):
        rows = []
        for k in range(world.sc.steps + 1):
            digest = "b" * 32 if (d, k) == (2, 4) else f"{k:032d}"
            rows.append(
                {
                    "step": k,
                    "reported": [0.0, 0.0, 0.0],
                    "committed": True,
                    "record": digest,
                    "applied_unix_s": 100.0 + 0.1 * k + 0.01,
                    "status": "ok",
                    "term": 1,
                    "positions": [[0.0, 0.0, 0.0]] * 4,
                    "faulty": [],
                    "missing": [],
                }
            )
        drone_file(tmp_path, d, "steps.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
        drone_file(tmp_path, d, "events.jsonl").write_text(json.dumps({"t": 99.0, "event": "start"}) + "\n")
    log = launch_log(world, tmp_path, 100.0, [])
    assert [(x.step, x.node, x.digest) for x in log.agreement.disagreements] == [(4, 2, "b" * 32)]
    assert log.agreement.applied == {1: 11, 2: 11, 3: 11, 4: 11} and log.agreement.checked == 33
    assert summarize(log, error_series(log))["records_identical_on_all_nodes"] is False

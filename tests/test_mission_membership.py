"""Drones join and leave a flying swarm (issue 12 item 5): scenario faults `join` and `leave`.

A joiner is outside the swarm until its join, then a Raft learner that catches up (here by
the leader's snapshot) and applies every record; a leaving voter is replaced by a promoted
learner, removed, and its node shuts down; a drone outside the swarm counts in no metric."""

import re

import numpy as np
import pytest
from pydantic import ValidationError

from swarmraft.experiments.mission import error_series, judged, summarize, write_results
from swarmraft.experiments.mission_folder import read_mission
from swarmraft.raft import SnapshotPolicy
from swarmraft.sim.mission import Mission
from swarmraft.sim.scenario import Scenario

JOIN_S, LEAVE_S = 2.0, 4.0


@pytest.fixture(scope="module")
def committee_mission():
    """10 drones, a committee of 5 (drones 1-5 vote, 6-9 are learners, drone 10 flies outside
    the swarm); drone 10 joins at 2 s, voter 2 leaves at 4 s. Snapshots every 10 entries, so
    the joiner can only catch up from the leader's snapshot."""
    sc = Scenario(
        drones=10,
        duration_s=8,
        seed=1,
        network={"loss": 0.05},
        protocol={"committee": 5},
        fault=[
            {"kind": "join", "at_s": JOIN_S, "drone": 10},
            {"kind": "leave", "at_s": LEAVE_S, "drone": 2},
        ],
    )
    voters: list[tuple[int, ...]] = []

    def hook(_log, _k):  # the leader's configuration at every step
        lead = m.cluster.leader()
        if lead is not None:
            voters.append(m.cluster.nodes[lead].conf_state.voters)

    m = Mission(sc, on_step=hook, snapshots=SnapshotPolicy(every=10, keep=2))
    log = m.run()
    return m, log, summarize(log, error_series(log)), voters


def _event_time(summary: dict, pattern: str) -> float | None:
    for e in summary["events"]:
        if mt := re.fullmatch(r"(\d+\.\d+) s: " + pattern, e):
            return float(mt.group(1))
    return None


def test_the_joiner_becomes_a_learner_catches_up_and_applies_every_record(committee_mission):
    m, log, summary, _ = committee_mission
    added = _event_time(summary, "committee: add-learner drone 10")
    assert added is not None and JOIN_S <= added <= JOIN_S + 0.5, summary["events"]
    assert 10 in m.cluster.nodes[m.cluster.leader()].conf_state.learners
    # its log was compacted away on the leader: the joiner got the leader's snapshot
    assert m.cluster.snapshots_installed >= 1
    k_join = int(JOIN_S / 0.1)
    after = [k for k in np.flatnonzero(log.committed) if k > k_join]
    # what it applied is what every drone applied; a step it did not apply came in a snapshot
    assert log.agreement.identical and log.agreement.highest[10] == log.agreement.highest[1]
    assert log.agreement.applied[10] >= 0.8 * len(after)
    assert summary["records_identical_on_all_nodes"]
    # the joiner audits every record it applies (old ones too) and refuses none; nobody
    # refuses an entry or suspects censorship
    assert log.audit["refused_applies"] == log.audit["refused_entries"] == 0
    assert log.audit["censorship_findings"] == 0
    # and its replicated state ends as drone 1's: the same last step and records
    a, b = m.drones[9].state, m.drones[0].state
    assert a.last_step == b.last_step == max(after)
    assert {k: r.digest for k, r in a.records.items()} == {k: r.digest for k, r in b.records.items()}
    # outside the swarm until it joins: no report, no position; then reported and verified
    assert not log.member[:k_join, 9].any() and log.member[k_join + 1 :, 9].all()
    assert np.isnan(log.reported[:k_join, 9]).all() and np.isnan(log.verified[:k_join, 9]).all()
    late = slice(k_join + 10, None)
    assert np.isfinite(log.verified[late, 9]).all(axis=1)[log.committed[late]].all()
    assert not log.missing[late, 9][log.committed[late]].any()


def test_a_leaving_voter_is_replaced_first_then_removed_and_its_node_stops(committee_mission):
    m, log, summary, voters = committee_mission
    left = _event_time(summary, "drone 2 leaves the swarm")
    promoted = _event_time(summary, r"committee: promote drone (?:[6-9]|10)")
    removed = _event_time(summary, "committee: remove drone 2")
    gone = _event_time(summary, "drone 2 left: its removal is committed")
    assert left == LEAVE_S and promoted is not None and removed is not None and gone is not None
    assert left <= promoted <= removed <= gone <= LEAVE_S + 1.0, summary["events"]
    conf = m.cluster.nodes[m.cluster.leader()].conf_state
    assert 2 not in conf.members and len(conf.voters) == 5
    assert not m.cluster.alive(2) and not log.alive[-1, 1] and 2 in m.left
    # drone 2 applied nothing after it left
    assert log.agreement.highest[2] <= int(gone / 0.1) + 1
    # the committee: odd and at most 5 voters, but for the step between a promotion and the
    # removal it prepares (6 voters), never without drone 2 before the promotion
    sizes = [len(v) for v in voters]
    assert max(sizes) == 6 and sizes.count(6) <= 3 and sizes[-1] == 5
    assert all(s == 5 for s, v in zip(sizes, voters, strict=True) if 2 not in v)


def test_drones_outside_the_swarm_count_in_no_metric(committee_mission):
    _, log, summary, _ = committee_mission
    errors = error_series(log)
    out = ~log.member
    assert out[:, 9].any() and out[:, 1].any()
    for name, e in errors.items():
        assert np.isnan(e[out]).all(), name
    assert not judged(log)[out].any()
    # the bound of the drones in the swarm is that of the swarm they are in: finite throughout
    assert np.isfinite(errors["snapshot_bound"][log.member]).all()
    # no record is degenerate or worse for want of a drone outside the swarm
    assert (log.status[log.committed] == "ok").mean() > 0.9, summary["integrity"]
    # a departed drone's receiver running wild after it left changes no number
    wild = log.gnss.copy()
    wild[out[:, :, None].repeat(3, axis=2)] += 1000.0
    log2 = type(log)(**{**log.__dict__, "gnss": wild})
    again = summarize(log2, error_series(log2))
    assert again == summary


def test_the_member_column_round_trips_through_a_mission_folder(committee_mission, tmp_path):
    _, log, _, _ = committee_mission
    write_results(log, tmp_path)
    assert (tmp_path / "steps.csv").read_text().splitlines()[0].endswith(",member")
    back = read_mission(tmp_path, "--results")
    assert np.array_equal(back.log.member, log.member)


def test_without_a_committee_the_joiner_votes_and_a_leaving_leader_hands_over():
    """Every member votes: the joiner is promoted once caught up; drone 5, the leader at 3 s
    with this seed, leaves: it hands leadership over, then the new leader removes it."""
    sc = Scenario(
        drones=6,
        duration_s=5,
        seed=3,
        fault=[{"kind": "join", "at_s": 1, "drone": 6}, {"kind": "leave", "at_s": 3, "drone": 5}],
    )
    m = Mission(sc)
    log = m.run()
    summary = summarize(log, error_series(log))
    assert log.leader[29] == 5  # the leader when it leaves
    assert _event_time(summary, "membership: promote drone 6") is not None
    handed = _event_time(summary, r"leader 5 hands over to drone \d \(it leaves the swarm\)")
    removed = _event_time(summary, "membership: remove drone 5")
    assert handed is not None and removed is not None and 3.0 <= handed < removed <= 3.5, summary["events"]
    conf = m.cluster.nodes[m.cluster.leader()].conf_state
    assert conf.voters == (1, 2, 3, 4, 6) and not conf.learners
    assert summary["records_identical_on_all_nodes"]
    assert log.committed[10:-1].all()  # no step lost to the join, the hand-over or the removal


def test_missions_without_joins_keep_their_columns():
    sc = Scenario(drones=5, duration_s=0.5)
    assert sc.joiners == set() and not sc.dynamic
    log = Mission(sc).run()
    assert log.member is None and log.in_swarm().all()


def _scenario(*faults, drones=6):
    return Scenario(drones=drones, duration_s=10, fault=list(faults))


@pytest.mark.parametrize(
    ("faults", "message"),
    [
        (
            [{"kind": "join", "at_s": 1, "drone": 6}, {"kind": "join", "at_s": 2, "drone": 6}],
            r"fault\[1\]\.drone: drone 6 is in the swarm at 2 s already",
        ),
        (
            [{"kind": "leave", "at_s": 1, "drone": 7}],
            r"fault\[0\]\.drone: drone ids must be in 1\.\.6, got \[7\]",
        ),
        ([{"kind": "leave", "at_s": 1}], r"fault\[0\]\.drone: leave needs a drone"),
        ([{"kind": "join", "at_s": 1}], r"fault\[0\]\.drone: join needs a drone"),
        (
            [{"kind": "join", "at_s": 5, "drone": 6}, {"kind": "leave", "at_s": 1, "drone": 6}],
            r"fault\[1\]\.drone: drone 6 is not in the swarm at 1 s \(has not joined yet\)",
        ),
        (
            [{"kind": "leave", "at_s": 1, "drone": 6}, {"kind": "leave", "at_s": 2, "drone": 6}],
            r"fault\[1\]\.drone: drone 6 is not in the swarm at 2 s \(left already\)",
        ),
        (
            [{"kind": k, "at_s": t, "drone": 6} for k, t in (("join", 1), ("leave", 2), ("join", 3))],
            r"fault\[2\]\.drone: drone 6 left the swarm for good before 3 s",
        ),
        (
            [{"kind": "leave", "at_s": t, "drone": d} for t, d in ((1, 1), (2, 2), (3, 3), (4, 4))],
            r"fault\[3\]\.drone: after drone 4 leaves at 4 s only 2 drones are in the swarm; at least 3",
        ),
        (
            [{"kind": "join", "at_s": 1, "drone": d} for d in (3, 4, 5, 6)],
            r"fault\[0\]\.drone: with 4 drones joining later only 2 are in the swarm at the start; "
            "at least 3",
        ),
        (
            [{"kind": "join", "at_s": 3, "drone": 6}, {"kind": "crash", "at_s": 1, "drone": 6}],
            r"fault\[1\]\.drone: drone 6 is not in the swarm at 1 s \(crash\)",
        ),
        (
            [{"kind": "leave", "at_s": 3, "drone": 6}, {"kind": "restart", "at_s": 4, "drone": 6}],
            r"fault\[1\]\.drone: drone 6 is not in the swarm at 4 s \(restart\)",
        ),
    ],
)
def test_bad_joins_and_leaves_are_one_line_errors_naming_the_field(faults, message):
    with pytest.raises(ValidationError, match=message) as info:
        _scenario(*faults)
    assert len(str(info.value.errors()[0]["msg"]).splitlines()) == 1


def test_a_join_and_leave_scenario_is_valid():
    sc = _scenario(
        {"kind": "join", "at_s": 2, "drone": 6},
        {"kind": "crash", "at_s": 3, "drone": 6},
        {"kind": "restart", "at_s": 4, "drone": 6},
        {"kind": "leave", "at_s": 5, "drone": 1},
    )
    assert sc.joiners == {6} and sc.dynamic


def test_a_leaving_leader_that_is_the_only_voter_has_a_learner_promoted_first():
    """A committee of one: nobody to hand over to until a learner is promoted."""
    sc = Scenario(
        drones=5,
        duration_s=4,
        seed=2,
        protocol={"committee": 1},
        fault=[{"kind": "leave", "at_s": 2, "drone": 1}],
    )
    m = Mission(sc)
    log = m.run()
    assert [e for t, e in log.events if t >= 2] == [
        "drone 1 leaves the swarm",
        "committee: promote drone 2",
        "leader 1 hands over to drone 2 (it leaves the swarm)",
        "committee: remove drone 1",
        "drone 1 left: its removal is committed",
    ]
    assert m.cluster.nodes[m.cluster.leader()].conf_state.voters == (2,)
    assert log.committed[5:-1].all()
    # the learners' own reports, made before they knew a leader to send them to, are no
    # evidence of censorship (each learner found its honest leader censoring at 1.2 s when
    # the sender held its own report)
    assert m.suspicions == []
    assert log.audit["censorship_findings"] == 0


def test_a_crashed_joiner_restarts_a_member_and_a_crashed_leaver_is_let_go():
    sc = Scenario(
        drones=6,
        duration_s=5,
        seed=4,
        protocol={"committee": 3},
        network={"loss": 0.05},
        fault=[
            {"kind": "join", "at_s": 1, "drone": 6},
            {"kind": "crash", "at_s": 1.5, "drone": 2},
            {"kind": "crash", "at_s": 2, "drone": 6},
            {"kind": "restart", "at_s": 2.5, "drone": 6},
            {"kind": "leave", "at_s": 3, "drone": 2},
        ],
    )
    m = Mission(sc)
    log = m.run()
    summary = summarize(log, error_series(log))
    conf = m.cluster.nodes[m.cluster.leader()].conf_state
    assert 2 not in conf.members and 6 in conf.members and len(conf.voters) == 3
    assert 2 in m.left and not m.cluster.alive(2)
    assert summary["records_identical_on_all_nodes"]
    assert log.agreement.highest[6] == len(log.t) - 1  # back and up to date

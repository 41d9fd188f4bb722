"""A mission with a voting committee (issue 12 item 6): 5 voters, every other drone a Raft
learner; a crashed voter is replaced by a promoted learner and removed, automatically, and
every drone (learners too) applies the same records."""

import re

import numpy as np
import pytest
from pydantic import ValidationError

from swarmraft.experiments.mission import error_series, summarize
from swarmraft.sim.mission import Mission
from swarmraft.sim.scenario import Scenario


@pytest.fixture(scope="module")
def committee_mission():
    sc = Scenario(
        drones=11,
        duration_s=8,
        seed=1,
        network={"loss": 0.05},
        protocol={"committee": 5},
        fault=[{"kind": "crash", "at_s": 3, "drone": 2}],
    )
    m = Mission(sc)
    log = m.run()
    return m, log, summarize(log, error_series(log))


def test_only_the_committee_votes_and_learners_apply_every_record(committee_mission):
    m, log, summary = committee_mission
    lead = m.cluster.leader()
    conf = m.cluster.nodes[lead].conf_state
    assert len(conf.voters) == 5 and set(conf.learners) | set(conf.voters) >= {1, 3, 4, 5, 6, 7, 8, 9, 10, 11}
    assert summary["records_identical_on_all_nodes"]
    # learners (drones 6-11 at the start) applied records like the voters
    for node in (8, 9, 10, 11):
        assert log.agreement.applied[node] >= 70
    assert log.committed[-20:].all()


def test_reports_are_fanned_out_to_voters_only(committee_mission):
    """The audit's censorship copies go to the voters (only they can depose a leader): a
    drone that was a learner throughout holds no report, not even its own (a sender holds
    none of its own: the other voters hold it from the fan-out)."""
    m, log, summary = committee_mission
    conf = m.cluster.nodes[m.cluster.leader()].conf_state
    learners = [d for d in conf.learners if d >= 8]  # never promoted
    assert learners
    for d in learners:
        assert set().union(*m.drones[d - 1].audit.timely.values()) == set(), d
    voters = [v for v in conf.voters if v != m.cluster.leader()]
    assert all(sum(map(len, m.drones[v - 1].audit.timely.values())) > 10 for v in voters)


def test_a_crashed_voter_is_replaced_by_a_learner_within_two_seconds(committee_mission):
    m, log, summary = committee_mission
    events = summary["events"]
    times = {}
    for e in events:
        if mt := re.fullmatch(r"(\d+\.\d+) s: committee: (promote|remove) drone (\d+)", e):
            times.setdefault((mt.group(2), int(mt.group(3))), float(mt.group(1)))
    removed = [t for (kind, d), t in times.items() if kind == "remove" and d == 2]
    promoted = [(d, t) for (kind, d), t in times.items() if kind == "promote"]
    assert removed and 3.0 < removed[0] <= 5.0, events
    assert promoted and promoted[0][0] >= 6 and 3.0 < promoted[0][1] <= removed[0], events
    conf = m.cluster.nodes[m.cluster.leader()].conf_state
    assert 2 not in conf.voters and promoted[0][0] in conf.voters and len(conf.voters) == 5
    # no step lost to the change beyond the crash's own election, if the leader was drone 2
    assert int(np.sum(~log.committed[40:])) <= 6


@pytest.mark.parametrize("size", [2, 9])
def test_committee_size_is_odd_and_at_most_7(size):
    with pytest.raises(ValidationError, match=r"protocol\.committee: committee size must be odd"):
        Scenario(drones=11, protocol={"committee": size})


def test_drones_share_one_decoded_copy_of_each_record(committee_mission):
    """Memory at scale: every drone keeps its newest records (and their n signed reports);
    in the simulator they share one decoded copy (protocol.drone.RecordMemo.decode)."""
    m, log, summary = committee_mission
    live = [d for d in m.drones if d.state.records]
    last = min(max(d.state.records) for d in live)
    held = [d.state.records[last] for d in live if last in d.state.records]
    assert len(held) >= 8 and all(r is held[0] for r in held)

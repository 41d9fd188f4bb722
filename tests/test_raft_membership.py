"""Membership (learners, single-server changes), leader transfer and ReadIndex reads
(issue 12 item 5), in the simulator and on the bare core."""

import random
import re

import pytest

from swarmraft.raft import (
    ConfChange,
    ConfChangeRefused,
    ConfChangeType,
    ConfState,
    Entry,
    EntryKind,
    LeaderTransferring,
    MemoryStorage,
    NotLeader,
    RaftConfig,
    RaftNode,
    Role,
    SQLiteStorage,
)
from swarmraft.raft.types import Message, MsgType
from swarmraft.sim import Cluster, InvariantViolation
from swarmraft.sim.fuzz import FuzzConfig, run_seed

ADD, PROMOTE, REMOVE = ConfChangeType.ADD_LEARNER, ConfChangeType.PROMOTE, ConfChangeType.REMOVE


def elected(c: Cluster) -> int:
    assert c.run_until(lambda: c.leader() is not None, 3000)
    c.run(100)  # the no-op commits
    return c.leader()


def with_learner(n: int = 3, seed: int = 1) -> tuple[Cluster, int]:
    c = Cluster(n, seed=seed)
    elected(c)
    k = c.add_node()
    c.propose_conf_change(ConfChange(ADD, k))
    c.run(300)
    return c, k


# -- values ----------------------------------------------------------------------------------


def test_conf_change_round_trips_and_bad_payloads_are_refused():
    for t in ConfChangeType:
        cc = ConfChange(t, 12)
        assert ConfChange.decode(cc.encode()) == cc
    for bad in (b"", b"promote", b"promote x", b"jump 3", b"\xff 1"):
        with pytest.raises(ValueError, match="not a configuration change"):
            ConfChange.decode(bad)


def test_conf_state_rules():
    cs = ConfState((1, 2, 3), (4,))
    assert cs.apply(ConfChange(PROMOTE, 4)) == ConfState((1, 2, 3, 4))
    assert cs.apply(ConfChange(REMOVE, 2)) == ConfState((1, 3), (4,))
    assert cs.apply(ConfChange(REMOVE, 4)) == ConfState((1, 2, 3))
    assert cs.apply(ConfChange(ADD, 7)) == ConfState((1, 2, 3), (4, 7))
    assert cs.check(ConfChange(PROMOTE, 3)) == "node 3 is not a learner"
    assert cs.check(ConfChange(ADD, 2)) == "node 2 is a voter already"
    assert cs.check(ConfChange(REMOVE, 9)) == "node 9 is not a member"
    assert ConfState((5,)).check(ConfChange(REMOVE, 5)) == "node 5 is the last voter"
    assert cs.apply(ConfChange(PROMOTE, 3)) == cs  # refused: unchanged
    with pytest.raises(ValueError, match="both a voter and a learner"):
        ConfState((1, 2), (2,))


def test_raft_config_bootstrap_configuration_is_validated():
    with pytest.raises(ValueError, match="promote_gap"):
        RaftConfig(id=1, peers=(2,), promote_gap=-1)
    with pytest.raises(ValueError, match="voters and learners must be distinct"):
        RaftConfig(id=1, peers=(2,), voters=(1, 2), learners=(2,))
    with pytest.raises(ValueError, match="voters must not be empty"):
        RaftConfig(id=1, peers=(2,), voters=())
    node = RaftNode(RaftConfig(id=4, peers=(1, 2, 3), voters=(1, 2, 3)), MemoryStorage(), random.Random(0))
    assert node.conf_state == ConfState((1, 2, 3))  # a joining node: not a member yet


# -- learners --------------------------------------------------------------------------------


def test_a_learner_gets_the_log_but_never_campaigns_nor_counts_in_the_quorum():
    c, k = with_learner()
    lead = c.leader()
    for i in range(5):
        c.propose(b"e%d" % i)
    c.run(300)
    assert c.applied(k)[-5:] == [b"e%d" % i for i in range(5)]
    assert c.conf_state(k) == ConfState((1, 2, 3), (k,))
    assert c.nodes[lead].progress(k).match == c.status(lead).last_index  # visible to the leader
    # the two other voters crash: leader + learner are 2 of 4 nodes, but 1 of 3 voters
    for v in [v for v in (1, 2, 3) if v != lead]:
        c.crash(v)
    commit = c.status(lead).commit
    c.propose(b"lost", via=lead)
    c.run(100)
    assert c.nodes[lead].progress(k).match == c.status(lead).last_index  # the learner has it
    assert c.status(lead).commit == commit  # but it does not count
    c.run(3000)
    assert b"lost" not in c.applied(k)
    assert c.status(k).role == Role.FOLLOWER


def test_a_learner_never_sends_a_vote_request():
    c, k = with_learner()
    node = c.nodes[k]
    for _ in range(200):  # far beyond any election timeout, the leader unheard
        node.tick()
    rd = node.ready()
    assert not {m.type for m in (rd.messages if rd else ())} & {MsgType.VOTE, MsgType.PRE_VOTE}
    node.campaign(force=True)  # a learner ignores even a forced campaign
    assert node.role == Role.FOLLOWER and not node.msgs


def test_a_learner_cannot_depose_its_leader():
    """A learner that finds its leader faulty (a refused entry, a censorship finding) keeps
    following it: it cannot elect another, and dropping the leader's appends would leave it
    behind for good (found in a committee of one, whose learner was then never promoted)."""
    c, k = with_learner()
    node = c.nodes[k]
    lead = node.lead
    assert lead is not None
    node.depose(lead)
    assert node.lead == lead and node.role == Role.FOLLOWER and not node.msgs
    before = node.log.last_index()
    c.propose(b"after")
    c.run(300)
    assert c.nodes[k].log.last_index() > before  # still receives the leader's appends


def test_promotion_of_a_learner_that_is_behind_is_refused_with_the_reason():
    c, k = with_learner()
    c.crash(k)
    for i in range(80):
        c.propose(b"x%d" % i)
        c.run(5)
    c.run(200)
    with pytest.raises(ConfChangeRefused, match=rf"learner {k} is not caught up \(match \d+, last index \d+"):
        c.propose_conf_change(ConfChange(PROMOTE, k))
    c.restart(k)
    assert c.run_until(lambda: c.nodes[c.leader()].progress(k).match == c.status(c.leader()).last_index, 3000)
    c.propose_conf_change(ConfChange(PROMOTE, k))
    c.run(300)
    assert all(c.conf_state(i) == ConfState((1, 2, 3, k)) for i in c.ids)


def test_one_change_at_a_time_and_none_before_the_leader_commits_in_its_term():
    c, k = with_learner()
    c.propose_conf_change(ConfChange(PROMOTE, k))
    with pytest.raises(ConfChangeRefused, match="is not committed yet"):
        c.propose_conf_change(ConfChange(REMOVE, 1))
    with pytest.raises(NotLeader):
        c.propose_conf_change(ConfChange(REMOVE, 1), via=next(i for i in c.ids if i != c.leader()))
    # a brand-new leader before its no-op commits
    node = RaftNode(RaftConfig(id=1, peers=(2, 3)), MemoryStorage(), random.Random(0))
    node.campaign(force=True)
    node.step(Message(MsgType.VOTE_RESP, 2, 1, node.term))
    assert node.role == Role.LEADER
    with pytest.raises(ConfChangeRefused, match=f"no entry of term {node.term} is committed yet"):
        node.propose_conf_change(ConfChange(ADD, 4))


# -- removal -----------------------------------------------------------------------------------


def test_removing_dead_voters_lets_the_rest_survive_one_more_crash():
    c = Cluster(5, seed=2)
    lead = elected(c)
    dead = [i for i in c.ids if i != lead][:2]
    for d in dead:
        c.crash(d)
    for d in dead:
        c.propose_conf_change(ConfChange(REMOVE, d))
        assert c.run_until(lambda: c.status(c.leader()).commit >= c.status(c.leader()).last_index, 2000)
    live = [i for i in c.ids if i not in dead]
    assert all(c.conf_state(i).voters == tuple(live) for i in live)
    c.crash(next(i for i in live if i != lead))  # 2 of 3 voters left (2 of 5 would be no quorum)
    before = c.status(lead).commit
    assert c.propose(b"still")
    assert c.run_until(lambda: c.status(lead).commit > before, 2000)


def test_a_leader_that_removes_itself_leads_until_it_commits_then_steps_down():
    c = Cluster(3, seed=4)
    lead = elected(c)
    index = c.propose_conf_change(ConfChange(REMOVE, lead))
    assert c.nodes[lead].role == Role.LEADER and lead not in c.conf_state(lead).voters
    assert c.run_until(lambda: c.nodes[lead].role != Role.LEADER, 1000)
    assert c.status(lead).commit >= index  # stepped down once its removal committed
    assert c.run_until(lambda: c.leader() not in (None, lead), 3000)
    c.run(3000)
    assert c.status(lead).role == Role.FOLLOWER  # and never campaigns again
    assert c.propose(b"after")


@pytest.mark.parametrize("storage", ["memory", "sqlite"])
def test_a_restarted_node_learns_its_configuration_from_storage(storage, tmp_path):
    st = MemoryStorage() if storage == "memory" else SQLiteStorage(tmp_path / "raft.db")
    entries = [
        Entry(1, 1, b"", EntryKind.NOOP),
        Entry(1, 2, ConfChange(ADD, 4).encode(), EntryKind.CONF_CHANGE),
        Entry(1, 3, b"data"),
        Entry(1, 4, ConfChange(PROMOTE, 4).encode(), EntryKind.CONF_CHANGE),
        Entry(1, 5, ConfChange(REMOVE, 2).encode(), EntryKind.CONF_CHANGE),
    ]
    st.save(None, entries)
    node = RaftNode(RaftConfig(id=1, peers=(2, 3)), st, random.Random(0))
    assert node.conf_state == ConfState((1, 3, 4))
    assert node.confs.last_index == 5


def test_a_truncated_configuration_entry_is_undone():
    node = RaftNode(RaftConfig(id=2, peers=(1, 3)), MemoryStorage(), random.Random(0))
    cc = Entry(1, 1, ConfChange(ADD, 4).encode(), EntryKind.CONF_CHANGE)
    node.step(Message(MsgType.APP, 1, 2, 1, entries=(cc,)))
    assert node.conf_state == ConfState((1, 2, 3), (4,))
    # a leader of term 2 overwrites index 1
    node.step(Message(MsgType.APP, 3, 2, 2, entries=(Entry(2, 1, b"", EntryKind.NOOP),)))
    assert node.conf_state == ConfState((1, 2, 3))


# -- leader transfer ---------------------------------------------------------------------------


def test_transfer_catches_the_target_up_then_it_wins_a_forced_election():
    c = Cluster(5, seed=5)
    lead = elected(c)
    target = next(i for i in c.ids if i != lead)
    c.crash(target)
    for i in range(10):
        c.propose(b"t%d" % i)
    c.run(200)
    c.restart(target)
    c.transfer_leader(target)
    with pytest.raises(LeaderTransferring, match=f"handing leadership over to node {target}"):
        c.nodes[lead].propose(b"refused")
    assert c.run_until(lambda: c.leader() == target, 1000)
    assert c.messages["MsgTimeoutNow"] == 1
    assert c.applied(target)[-10:] == [b"t%d" % i for i in range(10)] or c.run_until(
        lambda: c.applied(target)[-10:] == [b"t%d" % i for i in range(10)], 1000
    )


def test_a_transfer_to_a_dead_node_is_aborted_after_an_election_timeout():
    c = Cluster(3, seed=6)
    lead = elected(c)
    target = next(i for i in c.ids if i != lead)
    c.crash(target)
    c.transfer_leader(target)
    assert not c.propose(b"during")
    c.run(15 * 10 + 20)  # election_tick ticks of 10 ms
    assert c.leader() == lead and c.propose(b"after")
    with pytest.raises(ValueError, match="node 9 is not a voter|no node 9"):
        c.nodes[lead].transfer_leader(9)


# -- reads -------------------------------------------------------------------------------------


def test_reads_at_leader_and_followers_are_answered_after_the_commits_before_them():
    c = Cluster(5, seed=7)
    lead = elected(c)
    for i in range(5):
        c.propose(b"r%d" % i)
    c.run(100)
    commit = c.status(lead).commit
    ctxs = {v: c.read_index(v) for v in c.ids}
    c.run(200)
    for v, ctx in ctxs.items():
        node, index, _ = c.read_states[ctx]
        assert node == v and index >= commit
    assert c.messages["MsgReadIndex"] == 4 and c.messages["MsgReadIndexResp"] == 4


def test_a_leader_cut_off_from_the_quorum_never_answers_a_read():
    c = Cluster(5, seed=8)
    lead = elected(c)
    c.isolate(lead)
    ctx = c.read_index(lead)
    c.run(2000)
    assert ctx not in c.read_states
    assert c.leader() not in (None, lead)


def test_the_read_checker_catches_a_stale_read_and_an_unapplied_one():
    c = Cluster(3, seed=9)
    with pytest.raises(InvariantViolation, match="read-linearizable: .*index 5 was committed"):
        c.checker.read_answered(1.0, 1, 1, 3, floor=5, applied=9)
    with pytest.raises(InvariantViolation, match="having applied only 2"):
        c.checker.read_answered(1.0, 1, 1, 3, floor=0, applied=2)


def test_the_transfer_checker_catches_timeout_now_to_a_node_behind():
    c = Cluster(3, seed=9)
    st = MemoryStorage()
    st.save(None, [Entry(1, 1, b"")])
    m = Message(MsgType.TIMEOUT_NOW, 1, 2, 1, log_term=1, index=3)
    with pytest.raises(InvariantViolation, match="transfer-caught-up"):
        c.checker.timeout_now(1.0, m, st)
    c.checker.timeout_now(1.0, Message(MsgType.TIMEOUT_NOW, 1, 2, 1, log_term=1, index=1), st)


# -- under the fuzzer --------------------------------------------------------------------------


def test_membership_seeds_change_the_configuration_and_answer_reads_without_violation():
    results = [run_seed(s, FuzzConfig(membership=1.0, fault_ms=2000)) for s in range(6)]
    assert all(r.ok for r in results), [r.error for r in results if not r.ok]
    assert sum(r.conf_changes for r in results) >= 5
    assert sum(r.reads for r in results) >= 5


def test_seeds_without_membership_run_exactly_as_before():
    # the membership draws come from a generator of their own
    a = run_seed(3, FuzzConfig(membership=0.0))
    b = run_seed(3, FuzzConfig(membership=0.0, p_member=0.9))
    assert a == b and a.conf_changes == 0


def test_raft_fuzz_membership_flag_runs_membership_in_every_seed():
    from click.testing import CliRunner

    from swarmraft.cli import main

    r = CliRunner().invoke(main, ["raft-fuzz", "--membership", "--seeds", "3", "--seed-start", "100"])
    assert r.exit_code == 0, r.output
    out = " ".join(r.output.split())  # the console wraps long lines
    m = re.search(r"(\d+) configuration changes, (\d+) reads answered, \d+ s: no violation", out)
    assert m and int(m.group(1)) > 0 and int(m.group(2)) > 0, out
    r = CliRunner().invoke(main, ["raft-fuzz", "--no-membership", "--seeds", "2"])
    assert "0 configuration changes, 0 reads answered" in " ".join(r.output.split()), r.output


def test_the_conf_change_checker_catches_a_second_pending_change_and_an_early_one():
    c, k = with_learner()
    lead = c.leader()
    node = c.nodes[lead]
    node._append_and_broadcast([ConfChange(PROMOTE, k).encode()], kind=EntryKind.CONF_CHANGE)
    node._append_and_broadcast([ConfChange(REMOVE, k).encode()], kind=EntryKind.CONF_CHANGE)
    with pytest.raises(InvariantViolation, match="conf-change-rule: leader .* while the one at"):
        c._process(lead)
    # a new leader before its no-op commits
    c = Cluster(3, seed=3)
    lead = elected(c)
    c.isolate(lead)
    assert c.run_until(lambda: c.leader() not in (None, lead), 3000)
    new = c.leader()
    c.crash(lead)
    c.heal()
    c.partition([new])  # alone: its no-op cannot commit
    c.nodes[new]._append_and_broadcast([ConfChange(REMOVE, lead).encode()], kind=EntryKind.CONF_CHANGE)
    with pytest.raises(InvariantViolation, match="before committing an entry of its term"):
        c._process(new)

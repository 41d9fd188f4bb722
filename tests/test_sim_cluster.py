"""Scenarios on the simulated cluster: elections, replication, partitions, crashes."""

import random

import pytest

from swarmraft.raft import Entry, EntryKind, HardState
from swarmraft.sim import Cluster, InvariantViolation, LinkModel
from swarmraft.sim.fuzz import FuzzConfig, run_seed


def elected(c: Cluster, timeout=3000) -> int:
    """Run until there is a leader that every live node (reachable or not) has heard of."""

    def known() -> bool:
        lead = c.leader()
        return lead is not None and all(c.status(i).leader == lead for i in c.alive_ids())

    assert c.run_until(lambda: c.leader() is not None, timeout)
    c.run_until(known, 500)
    return c.leader()


def all_applied(c: Cluster, want: list[bytes], ids=None) -> bool:
    return all(c.applied(i) == want for i in (ids or c.alive_ids()))


def test_elects_one_leader_and_replicates():
    c = Cluster(5, seed=1)
    lead = elected(c)
    assert c.status(lead).role == "leader"
    assert all(c.status(i).role == "follower" for i in c.ids if i != lead)
    for k in range(20):
        assert c.propose(f"x{k}".encode())
    want = [f"x{k}".encode() for k in range(20)]
    assert c.run_until(lambda: all_applied(c, want), 1000)
    assert {c.status(i).commit for i in c.ids} == {21}  # + the leader's no-op
    c.run(100)
    assert c.messages["MsgApp"] > 0 and c.messages["MsgHeartbeat"] > 0


def test_one_proposal_per_ms_costs_at_most_three_messages_per_follower_per_commit():
    n = 5
    c = Cluster(n, seed=1)
    lead = elected(c)
    c.run(200)
    sent0, commit0 = sum(c.sent.values()), c.status(lead).commit
    for k in range(300):
        assert c.propose(f"p{k}".encode())
        c.run(1)
    commits = c.status(lead).commit - commit0
    assert commits >= 290
    assert sum(c.sent.values()) - sent0 <= 3 * (n - 1) * commits
    want = [f"p{k}".encode() for k in range(300)]
    assert c.run_until(lambda: all_applied(c, want), 1000)  # the last commit index arrives too


def test_cluster_counts_proposals_refused_beyond_the_uncommitted_cap():
    c = Cluster(3, seed=2, raft_options={"max_uncommitted_bytes": 150})
    lead = elected(c)
    c.isolate(lead)  # nothing it appends can commit
    assert c.propose(bytes(100), via=lead)
    assert not c.propose(bytes(100), via=lead) and c.refused == 1
    c.heal()
    assert c.run_until(lambda: all_applied(c, [bytes(100)]), 3000)


def test_proposal_forwarding_through_a_follower():
    c = Cluster(3, seed=2)
    lead = elected(c)
    follower = next(i for i in c.ids if i != lead)
    assert c.propose(b"via follower", via=follower) is False  # forwarded, in flight
    assert c.run_until(lambda: all_applied(c, [b"via follower"]), 1000)
    assert c.messages["MsgProp"] == 1


def test_leader_in_a_minority_commits_nothing_and_its_tail_is_discarded():
    c = Cluster(5, seed=3)
    old = elected(c)
    c.propose(b"before")
    c.run(200)
    others = [i for i in c.ids if i != old]
    c.partition([old, others[0]], others[1:])
    c.propose(b"lost", via=old)  # accepted into the old leader's log only
    assert any(e.data == b"lost" for e in c.log(old))
    assert c.run_until(lambda: c.leader() not in (None, old), 3000)
    new = c.leader()
    c.propose(b"after")
    c.run(500)
    assert c.status(old).commit < len(c.log(old))  # nothing new committed in the minority
    assert b"lost" not in c.applied(old)
    c.heal()
    assert c.run_until(lambda: all_applied(c, [b"before", b"after"], c.ids), 3000)
    assert c.status(old).role == "follower" and c.status(old).term >= c.status(new).term
    assert not any(e.data == b"lost" for e in c.log(old))  # uncommitted tail discarded


def test_crash_and_restart_keep_the_log():
    c = Cluster(3, seed=4)
    elected(c)
    for k in range(5):
        c.propose(f"a{k}".encode())
    c.run(300)
    f = next(i for i in c.ids if i != c.leader())
    c.crash(f)
    with pytest.raises(ValueError, match="crashed"):
        c.status(f)
    c.propose(b"while down")
    c.run(300)
    c.restart(f)
    want = [*(f"a{k}".encode() for k in range(5)), b"while down"]
    assert c.run_until(lambda: all_applied(c, want), 2000)


def test_leader_crash_elects_a_new_leader_and_keeps_committed_entries():
    c = Cluster(5, seed=5)
    old = elected(c)
    c.propose(b"one")
    c.run(200)
    c.crash(old)
    t0 = c.now
    new = elected(c)
    assert new != old and c.now - t0 < 1000
    c.propose(b"two")
    c.restart(old)
    assert c.run_until(lambda: all_applied(c, [b"one", b"two"], c.ids), 2000)


def test_whole_cluster_cold_restart_in_random_order():
    c = Cluster(5, seed=6)
    elected(c)
    for k in range(10):
        c.propose(f"c{k}".encode())
    c.run(300)
    want = [f"c{k}".encode() for k in range(10)]
    assert all_applied(c, want)
    terms = {i: c.status(i).term for i in c.ids}
    for i in c.ids:
        c.crash(i)
    order = list(c.ids)
    random.Random(6).shuffle(order)
    for i in order:
        c.run(37)
        c.restart(i)
    elected(c)
    c.propose(b"after restart")
    assert c.run_until(lambda: all_applied(c, [*want, b"after restart"], c.ids), 3000)
    assert all(c.status(i).term >= terms[i] for i in c.ids)


def test_lossy_network_still_commits():
    c = Cluster(5, seed=7, network=LinkModel(loss=0.2, duplicate=0.1, reorder=0.2))
    elected(c, 5000)
    for k in range(30):
        c.propose(f"l{k}".encode())
        c.run(30)
    c.set_loss(0.0)
    c.run(3000)
    applied = c.applied(1)
    assert len(applied) > 0 and all(c.applied(i) == applied for i in c.ids)


def test_links_cuts_and_isolation():
    c = Cluster(3, seed=8)
    lead = elected(c)
    c.isolate(lead)
    assert c.run_until(lambda: c.leader() not in (None, lead), 3000)
    c.heal()
    c.cut(1, 2)
    c.set_link(1, 3, delay_ms=5.0, loss=0.1)
    c.run(1000)
    assert c.network.link(1, 3).delay_ms == (5.0, 5.0) and c.network.link(3, 1).loss == 0.1
    with pytest.raises(ValueError, match="no node 9"):
        c.crash(9)


def test_same_seed_replays_exactly():
    def trace(seed):
        c = Cluster(5, seed=seed, network=LinkModel(loss=0.1, reorder=0.1))
        c.run(500)
        c.propose(b"x")
        c.crash(c.leader() or 1)
        c.run(1000)
        return c.loop.events, dict(c.messages), [c.log(i) for i in c.ids]

    assert trace(11) == trace(11)
    assert trace(11) != trace(12)


def test_invariant_violation_names_the_seed():
    c = Cluster(3, seed=99)
    elected(c)
    lead = c.leader()
    node = c.nodes[lead]
    # Corrupt a follower's storage behind Raft's back: a committed entry rewritten.
    f = next(i for i in c.ids if i != lead)
    c.crash(f)
    st = c.storage[f]
    st.save(
        HardState(term=st.initial_state().term, vote=st.initial_state().vote, commit=1),
        [Entry(node.term, 1, b"forged", EntryKind.NORMAL)],
    )
    with pytest.raises(InvariantViolation, match="seed 99"):
        c.restart(f)


def test_fuzz_100_seeds_no_violation_and_everything_committed_everywhere():
    bad = [r for r in (run_seed(s, FuzzConfig()) for s in range(100)) if not r.ok]
    assert not bad, bad[:3]


def test_a_leader_of_an_older_term_need_not_hold_what_a_later_term_committed():
    # seed 7841: a vote granted in term 9 reached its candidate 150 ms late (deep reordering),
    # after node 3 had led term 10 and committed entry 1; the candidate then led term 9
    # without it. Raft allows that (leader completeness is about later terms); the checker
    # once flagged it
    r = run_seed(7841)
    assert r.ok, r.error
    assert r.nodes == 3 and not r.pre_vote  # the draw that made the case


def test_fuzz_replays_a_seed_exactly():
    assert run_seed(123) == run_seed(123)


def test_a_paused_leader_is_replaced_and_handles_what_waited_for_it_when_it_resumes():
    c = Cluster(5, seed=3)
    lead = elected(c)
    term = c.status(lead).term
    for k in range(3):
        assert c.propose(f"a{k}".encode())
    assert c.run_until(lambda: all_applied(c, [b"a0", b"a1", b"a2"]), 1000)
    c.pause(lead, 2000)
    assert c.paused(lead) and c.alive(lead)
    # a frozen node gets no ticks: it does not notice it lost its quorum, and is not the leader
    assert c.leader() != lead
    assert c.run_until(lambda: c.leader() not in (None, lead), 1000)
    new = c.leader()
    assert c.status(new).term > term
    assert c.status(lead).role == "leader" and c.status(lead).term == term  # frozen as it was
    assert c.propose(b"b0", via=new)
    others = [i for i in c.ids if i != lead]
    want = [b"a0", b"a1", b"a2", b"b0"]
    assert c.run_until(lambda: all_applied(c, want, others), 1000)
    assert c.applied(lead) == want[:3]  # nothing reached it while frozen
    c.run(2000)
    assert not c.paused(lead)
    # on resume it reads what was delivered meanwhile, steps down and catches up
    assert c.run_until(lambda: all_applied(c, want), 2000)
    assert c.status(lead).role == "follower" and c.status(lead).term == c.status(new).term


def test_pausing_every_node_at_once_resumes_into_one_leader():
    c = Cluster(5, seed=4)
    elected(c)
    assert c.propose(b"before")
    c.run(50)
    for i in c.ids:
        c.pause(i, 2000)
    assert c.leader() is None
    c.run(1990)
    assert all(c.paused(i) for i in c.ids)
    c.run(20)
    lead = elected(c)
    assert c.propose(b"after", via=lead)
    assert c.run_until(lambda: all_applied(c, [b"before", b"after"]), 2000)


def test_a_crash_during_a_pause_ends_it():
    c = Cluster(3, seed=5)
    elected(c)
    c.pause(2, 1000)
    c.crash(2)
    assert not c.paused(2)
    c.restart(2)
    c.pause(2, 5000)
    c.run(1500)  # the first pause's end must not resume the second
    assert c.paused(2)
    with pytest.raises(ValueError, match="ms must be > 0"):
        c.pause(1, 0)

"""Flow control and the leader's lease, after etcd-io/raft's progress tracker: what a leader
sends, and what it holds back, in answer to proposals, acknowledgements, rejections and ticks;
and the Raft thesis' section 9.6 rule that keeps a node that cannot hear the leader from
deposing it."""

import pytest

from raftnet import Net, flush, make_node, msgs_of, storage_with
from swarmraft.raft import Entry, HardState, Message, MsgType, ProposalDropped, RaftNode, Role
from swarmraft.sim.network import LinkModel
from swarmraft.sim.runtime import Cluster

PEERS3 = (1, 2, 3)


def replicating_leader(peers=PEERS3, **options) -> RaftNode:
    """Node 1, leader of term 1, whose followers all acknowledged its no-op (index 1): they are
    in the replicate state, the commit index is 1 and nothing is left to send."""
    n = make_node(1, peers, **options)
    n.campaign()
    flush(n)
    for p in peers[1:]:
        n.step(Message(MsgType.VOTE_RESP, p, 1, n.term))
    flush(n)
    for p in peers[1:]:
        n.step(Message(MsgType.APP_RESP, p, 1, n.term, index=1))
    flush(n)
    assert n.role == Role.LEADER and n.log.committed == 1
    assert all(not pr.probe for pr in n.prs.values())
    return n


def ack(n: RaftNode, frm: int, index: int) -> None:
    n.step(Message(MsgType.APP_RESP, frm, n.id, n.term, index=index))


def reject(n: RaftNode, frm: int, index: int, hint: int) -> None:
    n.step(Message(MsgType.APP_RESP, frm, n.id, n.term, index=index, reject=True, reject_hint=hint))


def appends_to(msgs, to: int) -> list[Message]:
    return [m for m in msgs if m.type == MsgType.APP and m.to == to]


# -- answers to acknowledgements and rejections ------------------------------------------------
def test_acks_send_nothing_when_everything_is_already_in_flight():
    n = replicating_leader()
    n.propose(b"x")
    n.propose(b"y")
    assert len(appends_to(flush(n), 2)) == 2  # each entry went out at once
    ack(n, 2, 2)  # commits index 2: the new commit index rides the next append or heartbeat
    assert n.log.committed == 2 and flush(n) == []
    ack(n, 3, 2)  # advances neither the commit index nor anything left to send
    assert flush(n) == []
    ack(n, 3, 2)  # a duplicate
    assert flush(n) == []


def test_ack_sends_what_the_follower_still_lacks():
    n = replicating_leader(max_inflight_msgs=1)
    n.propose(b"x")
    n.propose(b"y")  # waits: one append in flight
    assert [e.data for m in appends_to(flush(n), 2) for e in m.entries] == [b"x"]
    ack(n, 2, 2)
    assert [e.data for m in appends_to(flush(n), 2) for e in m.entries] == [b"y"]


def test_stale_rejection_at_the_match_index_is_ignored_in_replicate_state():
    n = replicating_leader()
    n.propose(b"x")
    n.propose(b"y")
    flush(n)
    ack(n, 2, 3)
    flush(n)
    reject(n, 2, index=3, hint=2)  # answers an append the follower has since acknowledged
    assert flush(n) == [] and not n.prs[2].probe and n.prs[2].next == 4


def test_rejection_above_the_match_index_falls_back_to_probing():
    n = replicating_leader()
    n.propose(b"x")
    n.propose(b"y")
    flush(n)
    reject(n, 2, index=2, hint=2)  # the append of index 2 (prev 1) was lost; y's was refused
    (m,) = appends_to(flush(n), 2)
    assert n.prs[2].probe and m.index == 1 and [e.data for e in m.entries] == [b"x", b"y"]


def test_stale_rejection_is_ignored_in_probe_state():
    lead = make_node(1, PEERS3, storage_with((1, 1, 1, 1, 1), HardState(term=1)))
    lead.campaign()
    flush(lead)
    for p in (2, 3):
        lead.step(Message(MsgType.VOTE_RESP, p, 1, lead.term))
    (probe,) = appends_to(flush(lead), 2)
    assert probe.index == 5  # the no-op at 6 after the leader's 5 entries
    reject(lead, 2, index=5, hint=3)  # the follower holds 2 entries
    (again,) = appends_to(flush(lead), 2)
    assert again.index == 2 and lead.prs[2].next == 3
    reject(lead, 2, index=5, hint=3)  # the first rejection, duplicated by the network
    assert flush(lead) == [] and lead.prs[2].next == 3


# -- the in-flight window and the byte limits ----------------------------------------------------
def test_full_inflight_window_holds_appends_until_acks_free_it():
    n = replicating_leader(max_inflight_msgs=2)
    for d in (b"a", b"b", b"c"):
        n.propose(d)
    sent = appends_to(flush(n), 2)
    assert [e.data for m in sent for e in m.entries] == [b"a", b"b"]
    ack(n, 2, 2)  # frees the first slot
    sent = appends_to(flush(n), 2)
    assert [e.data for m in sent for e in m.entries] == [b"c"]
    assert appends_to(flush(n), 2) == []


def test_byte_limit_per_append():
    n = replicating_leader(max_inflight_msgs=1, max_msg_bytes=250)
    for _ in range(4):
        n.propose(bytes(100))
    assert [len(m.entries) for m in appends_to(flush(n), 2)] == [1]
    ack(n, 2, 2)
    assert [len(m.entries) for m in appends_to(flush(n), 2)] == [2]  # 300 bytes would pass 250
    ack(n, 2, 4)
    assert [len(m.entries) for m in appends_to(flush(n), 2)] == [1]


def test_inflight_byte_limit_per_follower():
    n = replicating_leader(max_inflight_bytes=250)
    for _ in range(4):
        n.propose(bytes(100))
    assert len(appends_to(flush(n), 2)) == 3  # full once 300 bytes are in flight
    ack(n, 2, 2)
    assert len(appends_to(flush(n), 2)) == 1


def test_single_entry_above_the_message_limit_still_goes():
    n = replicating_leader(max_msg_bytes=10)
    n.propose(bytes(100))
    (m,) = appends_to(flush(n), 2)
    assert len(m.entries) == 1


# -- the cap on uncommitted entries --------------------------------------------------------------
def test_proposals_beyond_the_uncommitted_cap_are_refused():
    n = replicating_leader(max_uncommitted_bytes=250)
    n.propose(bytes(100))
    n.propose(bytes(100))
    with pytest.raises(ProposalDropped, match="max_uncommitted_bytes"):
        n.propose(bytes(100))
    assert n.log.last_index() == 3  # nothing appended
    flush(n)
    ack(n, 2, 3)  # both commit
    assert n.propose(bytes(100)) == 4


def test_uncommitted_cap_admits_one_large_entry_and_empty_ones():
    n = replicating_leader(max_uncommitted_bytes=50)
    assert n.propose(bytes(1000)) == 2  # nothing uncommitted: one entry may exceed the cap
    assert n.propose(b"") == 3  # empty entries cost nothing
    with pytest.raises(ProposalDropped):
        n.propose(b"x")


def test_forwarded_proposal_beyond_the_cap_is_dropped():
    n = replicating_leader(max_uncommitted_bytes=150)
    n.propose(bytes(100))
    flush(n)
    n.step(Message(MsgType.PROP, 2, 1, 0, entries=(n.log.slice(2, 3)[0],)))
    assert n.log.last_index() == 2 and flush(n) == []


# -- heartbeats ---------------------------------------------------------------------------------
def answer(n: RaftNode, msgs) -> list[Message]:
    """Followers that answer every heartbeat and acknowledge every append; returns ``msgs``."""
    for m in msgs:
        if m.type == MsgType.HEARTBEAT:
            n.step(Message(MsgType.HEARTBEAT_RESP, m.to, n.id, n.term))
        elif m.type == MsgType.APP:
            ack(n, m.to, m.index + len(m.entries))
    return msgs


def ticked(n: RaftNode, ticks: int) -> list[Message]:
    """Heartbeats the leader sends over ``ticks`` ticks, its followers answering."""
    beats = []
    for _ in range(ticks):
        n.tick()
        beats += [m for m in answer(n, flush(n)) if m.type == MsgType.HEARTBEAT]
    return beats


def test_heartbeats_are_suppressed_while_appends_flow():
    n = replicating_leader(election=15, heartbeat=5)
    assert n.config.flow_heartbeat_tick == 13
    assert len(ticked(n, 5)) == 2  # idle: one heartbeat per interval
    beats = []
    for step in range(6):  # an append every 10 ticks: no heartbeat at all
        n.propose(f"step {step}".encode())
        assert len([m for m in answer(n, flush(n)) if m.type == MsgType.APP]) == 2
        beats += ticked(n, 10)
    assert beats == []
    assert [m.to for m in ticked(n, 3)] == [2, 3]  # the appends stopped: 13 ticks after the last
    assert ticked(n, 4) == []
    assert len(ticked(n, 1)) == 2  # idle again: every heartbeat interval


def test_heartbeat_answer_resends_only_if_no_append_followed_the_heartbeat():
    n = replicating_leader()
    n.tick()
    assert len(msgs_of(n, MsgType.HEARTBEAT)) == 2
    n.propose(b"x")
    flush(n)  # the append of index 2 leaves after the heartbeat
    n.step(Message(MsgType.HEARTBEAT_RESP, 2, 1, n.term))  # follower 2 lacks index 2 yet
    assert flush(n) == []  # the append's own answer will tell
    n.tick()  # no answer came: the commit waits, so heartbeats keep their interval
    assert sorted(m.to for m in msgs_of(n, MsgType.HEARTBEAT)) == [2, 3]
    n.step(Message(MsgType.HEARTBEAT_RESP, 2, 1, n.term))  # no append followed this heartbeat
    (m,) = msgs_of(n, MsgType.APP)
    assert m.to == 2 and m.index == 2 and not m.entries  # the follower's answer repairs it


def test_heartbeats_keep_their_interval_to_followers_a_waiting_commit_needs():
    n = replicating_leader(range(1, 6), election=15, heartbeat=5)
    n.propose(b"x")
    flush(n)
    ack(n, 2, 2)
    ack(n, 3, 2)  # committed: the silence of 4 and 5 costs nothing
    assert n.log.committed == 2 and ticked(n, 12) == []
    n.propose(b"y")
    flush(n)
    ack(n, 2, 3)  # not committed: 3, 4 and 5 owe answers, and one may have been lost
    assert sorted(m.to for m in ticked(n, 5)) == [3, 4, 5]


def test_followers_that_do_not_answer_get_heartbeats_at_the_slower_pace():
    n = replicating_leader(election=15, heartbeat=5)
    beats = []
    for _ in range(3 * 15):  # follower 3 answers nothing from now on
        n.tick()
        msgs = flush(n)
        answer(n, [m for m in msgs if m.to == 2])
        beats += [m.to for m in msgs if m.type == MsgType.HEARTBEAT]
    # 2: every 5 ticks; 3: every 5 ticks until an election timeout (ticks 15-30) passed without
    # its answer, then every 13 (tick 38)
    assert beats.count(2) == 9 and beats.count(3) == 6
    n.step(Message(MsgType.HEARTBEAT_RESP, 3, 1, n.term))  # it is back
    assert [m.to for m in ticked(n, 5)].count(3) == 1


def test_heartbeat_carries_the_commit_index_after_the_appends_stop():
    a, b, c = (make_node(i, PEERS3) for i in PEERS3)
    net = Net(a, b, c)
    net.campaign(1)
    net.propose(1, b"x")
    assert a.log.committed == 2 and b.log.committed < 2
    for _ in range(a.config.election_tick):
        a.tick()
        net.send()
    assert b.log.committed == 2 and c.log.committed == 2


# -- PreVote and the lease (Raft thesis, section 9.6) ----------------------------------------------
def test_follower_that_heard_the_leader_ignores_prevotes():
    f = make_node(3, PEERS3, pre_vote=True, check_quorum=False)
    f.step(Message(MsgType.HEARTBEAT, 1, 3, term=1))
    flush(f)
    f.step(Message(MsgType.PRE_VOTE, 2, 3, term=2, index=5, log_term=1))
    assert msgs_of(f, MsgType.PRE_VOTE_RESP) == [] and f.term == 1


def test_follower_grants_prevotes_once_the_leader_went_quiet():
    f = make_node(3, PEERS3, pre_vote=True, check_quorum=False)
    f.step(Message(MsgType.HEARTBEAT, 1, 3, term=1))
    for _ in range(f.config.election_tick):
        f.tick()
    flush(f)
    f.step(Message(MsgType.PRE_VOTE, 2, 3, term=2, index=5, log_term=1))
    (resp,) = msgs_of(f, MsgType.PRE_VOTE_RESP)
    assert not resp.reject and f.term == 1


def test_prevote_without_check_quorum_a_follower_that_cannot_hear_the_leader_does_not_depose_it():
    a, b, c = (make_node(i, PEERS3, pre_vote=True, check_quorum=False) for i in PEERS3)
    net = Net(a, b, c)
    net.campaign(1)
    net.drop.add((1, 3))  # 3 no longer hears the leader; everything else gets through
    for _ in range(10 * a.config.election_tick):
        for node in (a, b, c):
            node.tick()
        net.send()
    assert a.role == Role.LEADER and a.term == 1 and b.term == 1
    assert c.role == Role.PRE_CANDIDATE and c.term == 1


# -- appends that overtake one another ---------------------------------------------------------
def pipelining_follower() -> RaftNode:
    """Node 2, follower of leader 1 in term 1, that just took an append (entry 2): more appends
    in the same tick are a burst."""
    f = make_node(2, PEERS3, storage_with((1,), HardState(term=1)))
    f.step(Message(MsgType.APP, 1, 2, 1, log_term=1, index=1, entries=(Entry(1, 2, b"a"),)))
    (resp,) = msgs_of(f, MsgType.APP_RESP)
    assert not resp.reject and resp.index == 2
    return f


def app(prev: int, *terms: int) -> Message:
    entries = tuple(Entry(t, prev + 1 + k, f"e{prev + 1 + k}".encode()) for k, t in enumerate(terms))
    return Message(MsgType.APP, 1, 2, 1, log_term=1, index=prev, entries=entries)


def test_an_append_that_overtook_the_one_before_waits_for_it():
    f = pipelining_follower()
    f.step(app(3, 1))  # entry 4 arrives before entry 3
    assert msgs_of(f) == [] and f.log.last_index() == 2  # held: no answer, not appended
    f.step(app(2, 1))  # entry 3: both go in, both are acknowledged in order
    assert [(m.index, m.reject) for m in msgs_of(f, MsgType.APP_RESP)] == [(3, False), (4, False)]
    assert f.log.last_index() == 4


def test_a_held_append_is_rejected_after_a_tick_if_the_gap_stays():
    f = pipelining_follower()
    f.step(app(4, 1))
    f.step(app(3, 1))
    assert msgs_of(f) == []
    f.tick()
    # one rejection, of the lowest held append, saying where our log ends; the rest dropped
    assert [(m.index, m.reject, m.reject_hint) for m in msgs_of(f, MsgType.APP_RESP)] == [(3, True, 3)]
    f.step(app(2, 1))
    assert [m.index for m in msgs_of(f, MsgType.APP_RESP)] == [3]  # nothing held any more


def test_a_lone_append_past_the_end_is_rejected_at_once():
    f = make_node(2, PEERS3, storage_with((1,), HardState(term=1)))  # a probe: nothing before it
    f.step(app(3, 1))
    assert [(m.reject, m.reject_hint) for m in msgs_of(f, MsgType.APP_RESP)] == [(True, 2)]
    f = pipelining_follower()
    f.tick()  # the next step's append, after the one before was lost
    f.step(app(3, 1))
    assert [(m.reject, m.reject_hint) for m in msgs_of(f, MsgType.APP_RESP)] == [(True, 3)]


def test_held_appends_are_dropped_when_the_term_changes():
    f = pipelining_follower()
    f.step(app(3, 1))
    f.step(Message(MsgType.HEARTBEAT, 3, 2, 2))  # a new leader, term 2
    f.tick()
    assert not [m for m in msgs_of(f) if m.type == MsgType.APP_RESP]
    assert f.log.last_index() == 2


def test_reordered_pipelined_appends_do_not_storm():
    """Seed 5651 of raft-fuzz: with one entry per append and per-message delays of 1-3 ms, a
    burst of appends arrives out of order. Rejecting each overtaking append made the leader
    resend its window once per rejection: 2.1 million messages to replicate 1000 entries to 4
    followers. Holding them for a tick: about 12,000 (2 per entry per follower is the least)."""
    c = Cluster(
        5,
        seed=1,
        network=LinkModel(delay_ms=(1.0, 3.0)),
        raft_options={"max_entries_per_msg": 1},
    )
    assert c.run_until(lambda: c.leader() is not None, 5000)
    before = sum(c.sent.values())
    c.propose_batch([f"e{k}".encode() for k in range(1000)])
    bound = 16_000  # 2 x the least
    done = c.run_until(
        lambda: all(c.status(i).commit >= 1000 for i in c.ids) or sum(c.sent.values()) - before > bound,
        5000,
    )
    assert done and sum(c.sent.values()) - before <= bound
    assert all(c.status(i).commit >= 1000 for i in c.ids)

"""The behaviour of etcd-io/raft's paper tests (raft_paper_test.go), on our core."""

import random

import pytest

from raftnet import Net, flush, make_node, msgs_of, storage_with
from swarmraft.raft import (
    Entry,
    EntryKind,
    HardState,
    MemoryStorage,
    Message,
    MsgType,
    NotLeader,
    RaftConfig,
    RaftNode,
    RaftSafetyError,
    Role,
)

PEERS3 = (1, 2, 3)


def leader_of_term(term_before: int, peers=PEERS3, terms=()):
    """Node 1 elected leader in term term_before + 1 by votes from the others."""
    n = make_node(1, peers, storage_with(terms, HardState(term=term_before)))
    n.campaign()
    flush(n)
    for p in peers[1:]:
        n.step(Message(MsgType.VOTE_RESP, p, 1, n.term))
    flush(n)
    assert n.role == Role.LEADER
    return n


# -- terms ---------------------------------------------------------------------------------
@pytest.mark.parametrize("role", ["follower", "candidate", "leader"])
def test_update_term_from_message_and_step_down(role):
    n = make_node(1, PEERS3)
    if role == "candidate":
        n.campaign()
    elif role == "leader":
        n = leader_of_term(0)
    flush(n)
    n.step(Message(MsgType.APP, 2, 1, term=5))
    assert n.term == 5 and n.role == Role.FOLLOWER and n.lead == 2


def test_reject_stale_term_message():
    n = make_node(1, PEERS3, storage_with((), HardState(term=2)))
    n.step(Message(MsgType.APP, 2, 1, term=1, index=0, log_term=0, entries=(Entry(1, 1, b"x"),)))
    assert n.log.last_index() == 0 and n.term == 2


def test_start_as_follower():
    n = make_node(1, PEERS3)
    assert n.role == Role.FOLLOWER and n.term == 0 and n.lead is None


def test_leader_broadcasts_heartbeats():
    n = leader_of_term(0)
    n.tick()  # heartbeat_tick = 1
    beats = msgs_of(n, MsgType.HEARTBEAT)
    assert sorted(m.to for m in beats) == [2, 3] and all(m.term == 1 for m in beats)


# -- elections -----------------------------------------------------------------------------
@pytest.mark.parametrize("start_role", ["follower", "candidate"])
def test_election_timeout_starts_an_election(start_role):
    n = make_node(1, PEERS3, storage_with((), HardState(term=1)))
    if start_role == "candidate":
        n.campaign()
        flush(n)
    term0 = n.term
    for _ in range(2 * n.config.election_tick):
        n.tick()
    votes = msgs_of(n, MsgType.VOTE)
    assert n.role == Role.CANDIDATE and n.term == term0 + 1 and n.vote == 1
    assert sorted(m.to for m in votes if m.term == n.term) == [2, 3]


@pytest.mark.parametrize(
    "size,votes,role",
    [
        (1, {}, Role.LEADER),
        (3, {2: True, 3: True}, Role.LEADER),
        (3, {2: True}, Role.LEADER),
        (5, {2: True, 3: True, 4: True, 5: True}, Role.LEADER),
        (5, {2: True, 3: True, 4: True}, Role.LEADER),
        (5, {2: True, 3: True}, Role.LEADER),
        (3, {2: False, 3: False}, Role.FOLLOWER),
        (5, {2: False, 3: False, 4: False, 5: False}, Role.FOLLOWER),
        (5, {2: True, 3: False, 4: False, 5: False}, Role.FOLLOWER),
        (3, {}, Role.CANDIDATE),
        (5, {2: True}, Role.CANDIDATE),
        (5, {2: False, 3: False}, Role.CANDIDATE),
        (5, {}, Role.CANDIDATE),
    ],
)
def test_election_outcome_by_vote_count(size, votes, role):
    n = make_node(1, range(1, size + 1))
    n.campaign()
    flush(n)
    for p, granted in votes.items():
        n.step(Message(MsgType.VOTE_RESP, p, 1, n.term, reject=not granted))
    assert n.role == role and n.term == 1


@pytest.mark.parametrize(
    "vote,candidate,reject",
    [(None, 2, False), (None, 3, False), (2, 2, False), (3, 3, False), (2, 3, True), (3, 2, True)],
)
def test_follower_votes_once_per_term(vote, candidate, reject):
    n = make_node(1, PEERS3, storage_with((), HardState(term=1, vote=vote)))
    n.step(Message(MsgType.VOTE, candidate, 1, term=1, log_term=0, index=0))
    (resp,) = msgs_of(n, MsgType.VOTE_RESP)
    assert resp.reject == reject and resp.to == candidate


def test_vote_survives_restart():
    s = MemoryStorage()
    n = make_node(1, PEERS3, s)
    n.step(Message(MsgType.VOTE, 2, 1, term=1))
    flush(n)
    again = make_node(1, PEERS3, s)  # restart from storage
    again.step(Message(MsgType.VOTE, 3, 1, term=1))
    (resp,) = msgs_of(again, MsgType.VOTE_RESP)
    assert again.vote == 2 and resp.reject


@pytest.mark.parametrize("term_offset", [0, 1])
def test_candidate_falls_back_on_append_from_leader(term_offset):
    n = make_node(1, PEERS3)
    n.campaign()
    flush(n)
    n.step(Message(MsgType.APP, 2, 1, term=n.term + term_offset))
    assert n.role == Role.FOLLOWER and n.lead == 2


def test_election_timeouts_are_randomised_in_range():
    seen = set()
    for seed in range(200):
        n = RaftNode(
            RaftConfig(1, (2, 3), election_tick=10, heartbeat_tick=1, pre_vote=False),
            MemoryStorage(),
            random.Random(seed),
        )
        ticks = 0
        while n.role == Role.FOLLOWER:
            n.tick()
            ticks += 1
        seen.add(ticks)
    assert seen == set(range(10, 20))


def test_candidate_sends_last_log_index_and_term():
    n = make_node(1, PEERS3, storage_with((1, 2), HardState(term=2)))
    n.campaign()
    votes = msgs_of(n, MsgType.VOTE)
    assert {(m.to, m.term, m.index, m.log_term) for m in votes} == {(2, 3, 2, 2), (3, 3, 2, 2)}


@pytest.mark.parametrize(
    "terms,log_term,index,reject",
    [
        ((1, 1), 1, 1, True),  # same last term, shorter log
        ((1, 1), 1, 2, False),
        ((1, 1), 1, 3, False),
        ((1,), 2, 1, False),  # higher last term wins
        ((1,), 2, 2, False),
        ((1,), 2, 3, False),
        ((2, 2), 1, 1, True),  # lower last term loses, whatever the length
        ((2, 2), 1, 2, True),
        ((2, 2), 1, 3, True),
    ],
)
def test_vote_restriction_up_to_date_log(terms, log_term, index, reject):
    n = make_node(1, PEERS3, storage_with(terms, HardState(term=2)))
    n.step(Message(MsgType.VOTE, 2, 1, term=3, log_term=log_term, index=index))
    (resp,) = msgs_of(n, MsgType.VOTE_RESP)
    assert resp.reject == reject


# -- replication and commit ----------------------------------------------------------------
def test_leader_starts_replication():
    n = leader_of_term(0)  # its no-op went out as a probe to each follower
    n.propose(b"some data")
    assert not msgs_of(n, MsgType.APP)  # probing: one append in flight per follower
    for p in (2, 3):
        n.step(Message(MsgType.APP_RESP, p, 1, n.term, index=1))
    apps = msgs_of(n, MsgType.APP)
    data = [m for m in apps if any(e.data == b"some data" for e in m.entries)]
    assert {m.to for m in data} == {2, 3}
    m = data[0]
    assert m.index == 1 and m.log_term == 1 and m.entries[0].index == 2 and m.entries[0].term == 1
    assert m.term == 1


def test_leader_commits_by_majority_and_tells_followers():
    a, b, c = (make_node(i, PEERS3) for i in PEERS3)
    net = Net(a, b, c)
    net.campaign(1)
    net.propose(1, b"x")
    assert a.log.committed == 2 and [e.data for e in a.log.slice(1, 3)] == [b"", b"x"]
    # the commit index travels with the leader's next message: here its next heartbeat, due
    # once the followers have heard nothing for flow_heartbeat_tick ticks after the append
    for _ in range(a.config.flow_heartbeat_tick):
        assert b.log.committed < 2
        a.tick()
        net.send()
    assert b.log.committed == 2 and c.log.committed == 2
    assert b.status.applied == 2


@pytest.mark.parametrize(
    "size,acceptors,committed",
    [
        (1, set(), True),
        (3, set(), False),
        (3, {2}, True),
        (3, {2, 3}, True),
        (5, set(), False),
        (5, {2}, False),
        (5, {2, 3}, True),
        (5, {2, 3, 4}, True),
        (5, {2, 3, 4, 5}, True),
    ],
)
def test_leader_acknowledges_commit_by_quorum(size, acceptors, committed):
    peers = tuple(range(1, size + 1))
    n = leader_of_term(0, peers)
    flush(n)
    n.propose(b"some data")  # index 2 after the no-op
    flush(n)
    for p in acceptors:
        n.step(Message(MsgType.APP_RESP, p, 1, n.term, index=2))
    assert (n.log.committed >= 2) == committed


def test_leader_commits_preceding_entries_through_current_term():
    for terms in [(), (2,), (1, 1), (1,), (1, 2)]:
        n = leader_of_term(2, PEERS3, terms)  # leader in term 3
        n.propose(b"some data")
        flush(n)
        last = n.log.last_index()
        for p in (2, 3):
            n.step(Message(MsgType.APP_RESP, p, 1, n.term, index=last))
        assert n.log.committed == last
        assert [e.index for e in n.log.slice(1, last + 1)] == list(range(1, last + 1))


@pytest.mark.parametrize("ack,commit", [(1, 0), (2, 0), (3, 3)])
def test_leader_only_commits_entries_of_its_term_figure_8(ack, commit):
    n = leader_of_term(2, PEERS3, terms=(1, 2))  # leader in term 3, no-op at index 3
    n.propose(b"x")
    flush(n)
    n.step(Message(MsgType.APP_RESP, 2, 1, n.term, index=ack))
    assert n.log.committed == commit


def test_follower_commits_what_the_leader_says():
    n = make_node(1, PEERS3)
    ents = (Entry(1, 1, b"a"), Entry(1, 2, b"b"))
    n.step(Message(MsgType.APP, 2, 1, 1, log_term=0, index=0, entries=ents, commit=1))
    assert n.log.committed == 1
    assert [e.data for e in flush_committed(n)] == [b"a"]


def flush_committed(n):
    out = []
    while (rd := n.ready()) is not None:
        n.log.storage.save(rd.hard_state, rd.entries)
        out += rd.committed
        n.advance(rd)
    return out


@pytest.mark.parametrize(
    "log_term,index,reject,hint",
    [
        (0, 0, False, 0),  # match with committed entries
        (1, 1, False, 0),
        (2, 2, False, 0),  # match with uncommitted entries
        (1, 2, True, 2),  # unmatch with existing entry: hint = first index of term 2
        (3, 3, True, 3),  # unexisting entry: hint = last + 1
    ],
)
def test_follower_consistency_check(log_term, index, reject, hint):
    n = make_node(1, PEERS3, storage_with((1, 2), HardState(term=2, commit=1)))
    n.step(Message(MsgType.APP, 2, 1, 2, log_term=log_term, index=index, commit=1))
    (resp,) = msgs_of(n, MsgType.APP_RESP)
    assert resp.reject == reject
    if reject:
        assert resp.reject_hint == hint and resp.index == index


@pytest.mark.parametrize(
    "index,log_term,new,want",
    [
        (2, 2, [(3, 3)], [1, 2, 3]),
        (1, 1, [(2, 3), (3, 4)], [1, 3, 4]),
        (0, 0, [(1, 1)], [1, 2]),
        (0, 0, [(1, 3)], [3]),
    ],
)
def test_follower_truncates_only_from_the_first_conflict(index, log_term, new, want):
    n = make_node(1, PEERS3, storage_with((1, 2), HardState(term=1)))
    ents = tuple(Entry(t, i, f"n{i}".encode()) for i, t in new)
    n.step(Message(MsgType.APP, 2, 1, 2, log_term=log_term, index=index, entries=ents))
    flush(n)
    assert [e.term for e in n.log.slice(1, n.log.last_index() + 1)] == want
    assert [e.term for e in n.log.storage.entries(1, n.log.storage.last_index() + 1)] == want


def test_committed_entries_are_never_truncated():
    n = make_node(1, PEERS3, storage_with((1, 1), HardState(term=1, commit=2)))
    with pytest.raises(RaftSafetyError):
        n.log.maybe_append(1, 1, 2, [Entry(2, 2, b"other")])


FIG7_LEADER = (1, 1, 1, 4, 4, 5, 5, 6, 6, 6)
FIG7_FOLLOWERS = {
    "a": (1, 1, 1, 4, 4, 5, 5, 6, 6),
    "b": (1, 1, 1, 4),
    "c": (1, 1, 1, 4, 4, 5, 5, 6, 6, 6, 6),
    "d": (1, 1, 1, 4, 4, 5, 5, 6, 6, 6, 7, 7),
    "e": (1, 1, 1, 4, 4, 4, 4),
    "f": (1, 1, 1, 2, 2, 2, 3, 3, 3, 3, 3),
}


@pytest.mark.parametrize("name", sorted(FIG7_FOLLOWERS))
def test_leader_repairs_the_follower_logs_of_figure_7(name):
    lead = make_node(1, PEERS3, storage_with(FIG7_LEADER, HardState(term=7, commit=len(FIG7_LEADER))))
    follower = make_node(2, PEERS3, storage_with(FIG7_FOLLOWERS[name], HardState(term=7)))
    voter = make_node(3, PEERS3)
    net = Net(lead, follower, voter)
    net.campaign(1)
    assert lead.role == Role.LEADER and lead.term == 8
    for _ in range(3):  # heartbeats carry the repair through to the end
        lead.tick()
        net.send()
    want = [(e.term, e.data) for e in lead.log.slice(1, lead.log.last_index() + 1)]
    got = [(e.term, e.data) for e in follower.log.slice(1, follower.log.last_index() + 1)]
    assert got == want and follower.log.committed == lead.log.committed == 11


def test_follower_forwards_proposals_or_says_who_leads():
    a, b, c = (make_node(i, PEERS3) for i in PEERS3)
    net = Net(a, b, c)
    net.campaign(1)
    assert b.propose(b"via follower") is None  # forwarded
    net.send()
    a.tick()
    net.send()
    assert [e.data for e in c.log.slice(1, 3) if e.kind == EntryKind.NORMAL] == [b"via follower"]
    lone = make_node(4, (4, 5, 6))
    with pytest.raises(NotLeader) as info:
        lone.propose(b"x")
    assert info.value.leader is None and "no leader" in str(info.value)
    nf = make_node(2, PEERS3, pre_vote=False)
    nf.step(Message(MsgType.HEARTBEAT, 1, 2, 1))
    nf2 = RaftNode(
        RaftConfig(2, (1, 3), election_tick=10, heartbeat_tick=1, forward_proposals=False),
        MemoryStorage(),
        random.Random(0),
    )
    nf2.step(Message(MsgType.HEARTBEAT, 1, 2, 1))
    with pytest.raises(NotLeader) as info2:
        nf2.propose(b"x")
    assert info2.value.leader == 1


def test_messages_leave_only_with_the_state_they_depend_on():
    n = make_node(1, PEERS3)
    n.step(Message(MsgType.VOTE, 2, 1, term=4))
    rd = n.ready()
    assert any(m.type == MsgType.VOTE_RESP and not m.reject for m in rd.messages)
    assert rd.hard_state == HardState(term=4, vote=2, commit=0)  # persisted in the same Ready
    n.step(Message(MsgType.APP, 2, 1, 4, entries=(Entry(4, 1, b"x"),)))
    rd = n.ready()
    assert rd.entries and any(m.type == MsgType.APP_RESP for m in rd.messages)


# -- PreVote and CheckQuorum ---------------------------------------------------------------
def test_prevote_does_not_disrupt_terms():
    a, b, c = (make_node(i, PEERS3, pre_vote=True) for i in PEERS3)
    net = Net(a, b, c)
    net.campaign(1)
    assert a.role == Role.LEADER and a.term == 1
    net.drop |= {(3, 1), (3, 2), (1, 3), (2, 3)}  # isolate 3
    for _ in range(50):
        c.tick()
        net.send()
    assert c.term == 1 and c.role == Role.PRE_CANDIDATE  # it never raised its term
    net.drop.clear()
    a.tick()
    net.send()
    assert a.role == Role.LEADER and a.term == 1 and c.role == Role.FOLLOWER


def test_check_quorum_leader_steps_down_without_a_quorum():
    a = make_node(1, PEERS3, check_quorum=True)
    b, c = make_node(2, PEERS3, check_quorum=True), make_node(3, PEERS3, check_quorum=True)
    net = Net(a, b, c)
    net.campaign(1)
    net.drop |= {(2, 1), (3, 1)}
    for _ in range(2 * a.config.election_tick + 1):
        a.tick()
        net.send()
    assert a.role == Role.FOLLOWER


def test_check_quorum_followers_ignore_votes_while_the_leader_is_alive():
    a, b, c = (make_node(i, PEERS3, check_quorum=True) for i in PEERS3)
    net = Net(a, b, c)
    net.campaign(1)
    b.tick()
    net.send()
    c.step(Message(MsgType.VOTE, 2, 3, term=5, index=5, log_term=5))
    assert c.term == 1 and not msgs_of(c, MsgType.VOTE_RESP)


@pytest.mark.parametrize("pre_vote", [True, False])
def test_forced_campaign_deposes_a_live_leader(pre_vote):
    """A forced election (a leader transfer, or a voter that found its leader faulty) skips the
    pre-vote and is answered inside the leader lease; an ordinary one is not (tested above)."""
    a, b, c = (make_node(i, PEERS3, check_quorum=True, pre_vote=pre_vote) for i in PEERS3)
    net = Net(a, b, c)
    net.campaign(1)
    assert a.role == Role.LEADER and a.term == 1
    b.tick()
    net.send()
    b.campaign()  # ordinary: a pre-vote (or vote) nobody in the lease answers
    net.send()
    assert a.role == Role.LEADER and b.role != Role.LEADER
    b.campaign(force=True)
    votes = msgs_of(b, MsgType.VOTE)
    assert votes and all(m.force for m in votes) and not msgs_of(b, MsgType.PRE_VOTE)
    net.send(*votes)
    assert b.role == Role.LEADER and b.term > 1
    net.send()
    assert a.role == Role.FOLLOWER and a.lead == 2


def test_forced_campaign_still_needs_an_up_to_date_log():
    a, b, c = (make_node(i, PEERS3, check_quorum=True) for i in PEERS3)
    net = Net(a, b, c)
    net.campaign(1)
    net.drop |= {(1, 3)}
    net.propose(1, b"x")  # reaches 2, not 3
    net.drop.clear()
    c.campaign(force=True)
    votes = msgs_of(c, MsgType.VOTE)
    answers = []
    for m in votes:
        net.nodes[m.to].step(m)
        answers += msgs_of(net.nodes[m.to], MsgType.VOTE_RESP)
    assert len(answers) == 2 and all(r.reject for r in answers)  # answered, and refused
    for r in answers:
        c.step(r)
    assert c.role == Role.FOLLOWER and c.term == 2

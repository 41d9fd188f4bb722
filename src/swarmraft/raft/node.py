"""A Raft node as a pure state machine, in the style of etcd-io/raft.

The host drives it: ``tick()`` on a clock, ``step(message)`` for each message received,
``propose(data)`` for new entries, then ``ready()`` -> persist, send, apply -> ``advance()``.
No I/O, no clock, no global randomness: election timeouts come from the ``random.Random``
passed in.

Flow control follows etcd-io/raft (`progress`): a leader answers an acknowledgement only with
entries the follower still lacks, pipelines appends within a window per follower, and refuses
proposals beyond a cap on uncommitted bytes (`ProposalDropped`). A new commit index travels
with the next append or heartbeat, never in a message of its own, and a follower that gets
appends gets no heartbeats until it has heard nothing for ``flow_heartbeat_tick`` ticks.
"""

from __future__ import annotations

import random
from collections import deque
from collections.abc import Callable

from swarmraft.raft.log import RaftLog
from swarmraft.raft.progress import Inflights, Progress
from swarmraft.raft.storage import Storage
from swarmraft.raft.types import (
    Entry,
    EntryKind,
    HardState,
    Message,
    MsgType,
    NotLeader,
    ProposalDropped,
    RaftConfig,
    Ready,
    Role,
    Status,
)


class RaftNode:
    """``validate`` (optional): the host's check of a new entry before the node persists and
    acknowledges it (a SwarmRaft voter's audit of its leader's record). See `_handle_append`."""

    def __init__(
        self,
        config: RaftConfig,
        storage: Storage,
        rng: random.Random,
        applied: int = 0,
        validate: Callable[[Entry], bool] | None = None,
    ) -> None:
        self.config = config
        self.validate = validate
        self.refused = 0  # entries ``validate`` refused
        self.id = config.id
        self.rng = rng
        hs = storage.initial_state()
        self.log = RaftLog(storage, committed=hs.commit, applied=applied)
        self.term = hs.term
        self.vote = hs.vote
        self._persisted_hs = hs
        self.role = Role.FOLLOWER
        self.lead: int | None = None
        self.votes: dict[int, bool] = {}
        self.prs: dict[int, Progress] = {}
        self.msgs: list[Message] = []
        self.election_elapsed = 0
        self.randomized_timeout = self._draw_timeout()
        # the leader's entries of its term not yet committed: (index, payload bytes), in order
        self._uncommitted: deque[tuple[int, int]] = deque()
        self._uncommitted_bytes = 0

    # -- public API -----------------------------------------------------------------------
    @property
    def status(self) -> Status:
        return Status(
            id=self.id,
            role=self.role,
            term=self.term,
            vote=self.vote,
            leader=self.lead,
            commit=self.log.committed,
            applied=self.log.applied,
            last_index=self.log.last_index(),
            refused=self.refused,
        )

    def tick(self) -> None:
        if self.role == Role.LEADER:
            self._tick_leader()
            return
        self.election_elapsed += 1
        if self.election_elapsed >= self.randomized_timeout:
            self.election_elapsed = 0
            self.campaign()

    def campaign(self, force: bool = False) -> None:
        """Start an election now: a pre-vote first when PreVote is on. With ``force`` (a leader
        transfer, or a voter that found its leader faulty), no pre-vote, and the votes ask the
        other nodes to answer even while they hear from a leader: the reason to depose it is
        carried, so neither PreVote nor the leader lease stops the election. The vote
        restriction still holds: only a node whose log is up to date can win."""
        if self.role == Role.LEADER:
            return
        if self.config.pre_vote and not force:
            self._become_pre_candidate()
        else:
            self._become_candidate(force)

    def propose(self, data: bytes) -> int | None:
        """Propose an entry. The leader appends it and returns its index, or raises
        `ProposalDropped` if its uncommitted entries would pass ``max_uncommitted_bytes``; a
        follower that knows the leader forwards it (returns None); otherwise `NotLeader`."""
        if not isinstance(data, bytes | bytearray):
            raise TypeError("propose: data must be bytes")
        if self.role == Role.LEADER:
            self._check_uncommitted(len(data))
            return self._append_and_broadcast([bytes(data)])
        if self.role == Role.FOLLOWER and self.lead is not None and self.config.forward_proposals:
            self._send(Message(MsgType.PROP, self.id, self.lead, 0, entries=(Entry(0, 0, bytes(data)),)))
            return None
        raise NotLeader(self.id, self.lead)

    def has_ready(self) -> bool:
        """Whether `ready` would return work (cheap: no objects are built)."""
        p, log = self._persisted_hs, self.log
        return bool(
            self.msgs
            or log.unstable
            or self.term != p.term
            or self.vote != p.vote
            or log.committed != p.commit
            or (log.committed > log.applied and log.stable_last() > log.applied)
        )

    def ready(self) -> Ready | None:
        return self._ready() if self.has_ready() else None

    def _ready(self) -> Ready:
        hs = HardState(self.term, self.vote, self.log.committed)
        return Ready(
            hard_state=hs if hs != self._persisted_hs else None,
            entries=self.log.unstable_entries(),
            committed=tuple(self.log.next_committed()),
            messages=tuple(self.msgs),
        )

    def advance(self, rd: Ready) -> None:
        if rd.hard_state is not None:
            self._persisted_hs = rd.hard_state
        if rd.entries:
            last = rd.entries[-1]
            self.log.stable_to(last.index, last.term)
        if rd.committed:
            self.log.applied_to(rd.committed[-1].index)
        del self.msgs[: len(rd.messages)]

    def step(self, m: Message) -> None:
        if m.to != self.id:
            raise ValueError(f"node {self.id}: message for node {m.to}")
        if m.type == MsgType.PROP:
            self._step_prop(m)
            return
        if m.term > self.term:
            if m.type in (MsgType.VOTE, MsgType.PRE_VOTE):
                # The Raft thesis, section 9.6: a node that heard from a leader within the
                # shortest election timeout ignores (pre-)votes, so a node that cannot hear the
                # leader cannot depose it. On with CheckQuorum or PreVote: with PreVote alone,
                # nodes that still hear the leader would grant the pre-vote.
                in_lease = (
                    (self.config.check_quorum or self.config.pre_vote)
                    and self.lead is not None
                    and self.election_elapsed < self.config.election_tick
                )
                if in_lease and not m.force:
                    return  # we heard from a live leader recently: ignore the disruption
            if m.type == MsgType.PRE_VOTE or (m.type == MsgType.PRE_VOTE_RESP and not m.reject):
                pass  # pre-votes never change our term
            elif m.type in (MsgType.APP, MsgType.HEARTBEAT):
                self._become_follower(m.term, m.frm)
            else:
                self._become_follower(m.term, None)
        elif m.term < self.term:
            if (self.config.check_quorum or self.config.pre_vote) and m.type in (
                MsgType.APP,
                MsgType.HEARTBEAT,
            ):
                # tell a stale leader about the newer term so it steps down
                self._send(Message(MsgType.APP_RESP, self.id, m.frm, self.term))
            elif m.type == MsgType.PRE_VOTE:
                self._send(Message(MsgType.PRE_VOTE_RESP, self.id, m.frm, self.term, reject=True))
            return

        if m.type in (MsgType.VOTE, MsgType.PRE_VOTE):
            self._handle_vote_request(m)
        elif self.role == Role.LEADER:
            self._step_leader(m)
        elif self.role in (Role.CANDIDATE, Role.PRE_CANDIDATE):
            self._step_candidate(m)
        else:
            self._step_follower(m)

    # -- roles ----------------------------------------------------------------------------
    def _draw_timeout(self) -> int:
        et = self.config.election_tick
        return et + self.rng.randrange(et)  # uniform in [election_tick, 2 election_tick)

    def _reset(self, term: int) -> None:
        if term != self.term:
            self.term = term
            self.vote = None
        self.lead = None
        self.election_elapsed = 0
        self.randomized_timeout = self._draw_timeout()
        self.votes = {}

    def _become_follower(self, term: int, lead: int | None) -> None:
        self._reset(term)
        self.role = Role.FOLLOWER
        self.lead = lead

    def _become_pre_candidate(self) -> None:
        # A pre-candidate keeps its term and vote: it only asks whether it could win.
        self.role = Role.PRE_CANDIDATE
        self.votes = {}
        self.lead = None
        self.election_elapsed = 0
        self.randomized_timeout = self._draw_timeout()
        self._poll(MsgType.PRE_VOTE, self.term + 1)

    def _become_candidate(self, force: bool = False) -> None:
        self._reset(self.term + 1)
        self.role = Role.CANDIDATE
        self.vote = self.id
        self._poll(MsgType.VOTE, self.term, force)

    def _poll(self, kind: MsgType, term: int, force: bool = False) -> None:
        self.votes = {self.id: True}
        if self._tally() == "won":
            self._win(kind)
            return
        last, last_term = self.log.last_index(), self.log.last_term()
        for p in self.config.peers:
            self._send(Message(kind, self.id, p, term, log_term=last_term, index=last, force=force))

    def _quorum(self) -> int:
        return len(self.config.members) // 2 + 1

    def _tally(self) -> str:
        granted = sum(self.votes.values())
        rejected = len(self.votes) - granted
        if granted >= self._quorum():
            return "won"
        if rejected >= self._quorum():
            return "lost"
        return "pending"

    def _win(self, kind: MsgType) -> None:
        if kind == MsgType.PRE_VOTE:
            self._become_candidate()
        else:
            self._become_leader()

    def _become_leader(self) -> None:
        self._reset(self.term)
        self.role = Role.LEADER
        self.lead = self.id
        last, cfg = self.log.last_index(), self.config
        self.prs = {
            p: Progress(Inflights(cfg.max_inflight_msgs, cfg.max_inflight_bytes), match=0, next=last + 1)
            for p in cfg.peers
        }
        self._uncommitted.clear()
        self._uncommitted_bytes = 0
        # A no-op entry of the new term lets entries of earlier terms commit through it.
        self._append_and_broadcast([b""], kind=EntryKind.NOOP)

    # -- leader ---------------------------------------------------------------------------
    def _tick_leader(self) -> None:
        self.election_elapsed += 1
        if self.election_elapsed >= self.config.election_tick:
            self.election_elapsed = 0
            active = 1 + sum(pr.recent_active for pr in self.prs.values())
            for pr in self.prs.values():
                pr.responsive, pr.recent_active = pr.recent_active, False
            if self.config.check_quorum and active < self._quorum():
                self._become_follower(self.term, None)
                return
        # A heartbeat goes to a follower that heard nothing from us for a heartbeat interval;
        # for flow_heartbeat_tick when our last message to it was a pipelined append (unless
        # it still owes an answer for entries that are not committed: a lost answer would stall
        # the commit until the next append), or when it answered nothing in the last election
        # timeout (crashed or cut off: once back, it still hears from us before its own
        # election timeout ends).
        beat, flow_beat = self.config.heartbeat_tick, self.config.flow_heartbeat_tick
        last = self.log.last_index()
        stalled = self.log.committed < last
        for p, pr in self.prs.items():
            pr.silent += 1
            owes = stalled and pr.match < last
            slow = (pr.flowing and not owes) or not (pr.responsive or pr.recent_active)
            if pr.silent >= (flow_beat if slow else beat):
                pr.silent, pr.flowing = 0, False
                self._send(
                    Message(
                        MsgType.HEARTBEAT, self.id, p, self.term, commit=min(pr.match, self.log.committed)
                    )
                )

    def _check_uncommitted(self, size: int) -> None:
        """Raise `ProposalDropped` if ``size`` more bytes would pass the uncommitted cap (one
        entry is always admitted when nothing is uncommitted, and empty ones always are)."""
        u, cap = self._uncommitted_bytes, self.config.max_uncommitted_bytes
        if u > 0 and size > 0 and u + size > cap:
            raise ProposalDropped(self.id, size, u, cap)

    def _append_and_broadcast(self, datas: list[bytes], kind: EntryKind = EntryKind.NORMAL) -> int:
        first = self.log.last_index() + 1
        entries = [Entry(self.term, first + i, d, kind) for i, d in enumerate(datas)]
        last = self.log.append(entries)
        size = sum(len(d) for d in datas)
        if size:
            self._uncommitted.append((last, size))
            self._uncommitted_bytes += size
        self._maybe_commit()  # a one-node cluster commits at once
        for p in self.prs:
            self._send_append(p, send_if_empty=False)
        return last

    def _entries_from(self, index: int) -> list[Entry]:
        """Entries for one append from ``index``: at most max_entries_per_msg and
        max_msg_bytes of payload, but at least one entry if there is one."""
        entries = self.log.slice(index, index + self.config.max_entries_per_msg)
        budget = self.config.max_msg_bytes
        for k, e in enumerate(entries):
            budget -= len(e.data)
            if budget < 0 and k > 0:
                return entries[:k]
        return entries

    def _send_append(self, to: int, send_if_empty: bool = True) -> bool:
        """Send ``to`` the entries it lacks (or, with ``send_if_empty``, an append without
        entries: a probe); False if its window or probe holds it back, or nothing was sent."""
        pr = self.prs[to]
        if not pr.can_send():
            return False
        entries = self._entries_from(pr.next)
        if not entries and not send_if_empty:
            return False
        prev = pr.next - 1
        self._send(
            Message(
                MsgType.APP,
                self.id,
                to,
                self.term,
                log_term=self.log.term(prev) or 0,
                index=prev,
                entries=tuple(entries),
                commit=self.log.committed,
            )
        )
        pr.silent, pr.flowing = 0, bool(entries) and not pr.probe
        if pr.probe:
            pr.paused = True
        elif entries:
            pr.next = entries[-1].index + 1
            pr.inflights.add(pr.next - 1, sum(len(e.data) for e in entries))
        return True

    def _maybe_commit(self, acked: int | None = None) -> bool:
        """Advance the commit index to the highest index a quorum holds, if it is of the
        current term. ``acked``: the index a follower just acknowledged; nothing can change
        if it is not above the commit index (most answers, under steady load)."""
        if acked is not None and acked <= self.log.committed:
            return False
        matches = sorted([self.log.last_index(), *(pr.match for pr in self.prs.values())], reverse=True)
        n = matches[self._quorum() - 1]
        # The commit rule: only an entry of the current term commits by counting replicas.
        if n > self.log.committed and self.log.term(n) == self.term:
            self.log.commit_to(n)
            while self._uncommitted and self._uncommitted[0][0] <= n:
                self._uncommitted_bytes -= self._uncommitted.popleft()[1]
            return True
        return False

    def _step_leader(self, m: Message) -> None:
        pr = self.prs.get(m.frm)
        if pr is None:
            return
        if m.type == MsgType.APP_RESP:
            pr.recent_active = True
            if m.reject:
                if pr.maybe_decrease(m.index, m.reject_hint):  # else stale: nothing changes
                    self._send_append(m.frm)
                return
            if pr.maybe_update(m.index) or (pr.probe and m.index == pr.match):
                if pr.probe:
                    pr.become_replicate()
                else:
                    pr.inflights.free_le(m.index)
                # the new commit index, if any, travels with the next append or heartbeat
                self._maybe_commit(pr.match)
                while self._send_append(m.frm, send_if_empty=False):
                    pass
        elif m.type == MsgType.HEARTBEAT_RESP:
            pr.recent_active = True
            pr.paused = False
            if not pr.probe and pr.inflights.full():
                pr.inflights.free_first()
            # A follower that lacks entries after a heartbeat lost an append or its answer,
            # unless an append went out after the heartbeat (``flowing``): its answer will tell.
            if pr.match < self.log.last_index() and (pr.probe or not pr.flowing):
                self._send_append(m.frm)

    def _step_prop(self, m: Message) -> None:
        datas = [e.data for e in m.entries]
        if self.role == Role.LEADER:
            try:
                self._check_uncommitted(sum(len(d) for d in datas))
            except ProposalDropped:
                return  # dropped, as etcd does: the proposer learns it did not commit
            self._append_and_broadcast(datas)
        elif self.role == Role.FOLLOWER and self.lead is not None and self.config.forward_proposals:
            self._send(Message(MsgType.PROP, self.id, self.lead, 0, entries=m.entries))
        # otherwise dropped: the proposer learns it was not committed and may retry

    # -- candidate and follower -----------------------------------------------------------
    def _handle_vote_request(self, m: Message) -> None:
        pre = m.type == MsgType.PRE_VOTE
        can_vote = (
            self.vote == m.frm or (self.vote is None and self.lead is None) or (pre and m.term > self.term)
        )
        resp = MsgType.PRE_VOTE_RESP if pre else MsgType.VOTE_RESP
        if can_vote and self.log.is_up_to_date(m.index, m.log_term):
            self._send(Message(resp, self.id, m.frm, m.term))
            if not pre:
                self.election_elapsed = 0
                self.vote = m.frm
        else:
            self._send(Message(resp, self.id, m.frm, self.term, reject=True))

    def _step_candidate(self, m: Message) -> None:
        if m.type == MsgType.APP:
            self._become_follower(m.term, m.frm)
            self._handle_append(m)
        elif m.type == MsgType.HEARTBEAT:
            self._become_follower(m.term, m.frm)
            self._handle_heartbeat(m)
        elif (m.type == MsgType.VOTE_RESP and self.role == Role.CANDIDATE) or (
            m.type == MsgType.PRE_VOTE_RESP and self.role == Role.PRE_CANDIDATE
        ):
            self.votes.setdefault(m.frm, not m.reject)
            outcome = self._tally()
            if outcome == "won":
                self._win(MsgType.PRE_VOTE if self.role == Role.PRE_CANDIDATE else MsgType.VOTE)
            elif outcome == "lost":
                self._become_follower(self.term, None)

    def _step_follower(self, m: Message) -> None:
        if m.type == MsgType.APP:
            self.election_elapsed = 0
            self.lead = m.frm
            self._handle_append(m)
        elif m.type == MsgType.HEARTBEAT:
            self.election_elapsed = 0
            self.lead = m.frm
            self._handle_heartbeat(m)

    def _handle_append(self, m: Message) -> None:
        if m.index < self.log.committed:
            self._send(Message(MsgType.APP_RESP, self.id, m.frm, self.term, index=self.log.committed))
            return
        entries, refused = m.entries, False
        if self.validate is not None and entries and self.log.match_term(m.index, m.log_term):
            # New normal entries (not those the log already holds) are validated in order; at
            # the first refused one the node keeps the valid prefix and acknowledges only that.
            # No reject (the leader would probe and resend forever): it counts the refusal and
            # starts a forced election (the leader is faulty: the reason is carried, so neither
            # PreVote nor the lease stops it). The vote restriction still holds.
            for k, e in enumerate(entries):
                if self.log.match_term(e.index, e.term) or e.kind != EntryKind.NORMAL:
                    continue
                if not self.validate(e):
                    entries, refused = entries[:k], True
                    break
        last = self.log.maybe_append(m.index, m.log_term, m.commit, entries)
        if refused:
            self.refused += 1
            self._send(Message(MsgType.APP_RESP, self.id, m.frm, self.term, index=m.index + len(entries)))
            self.campaign(force=True)
            return
        if last is not None:
            self._send(Message(MsgType.APP_RESP, self.id, m.frm, self.term, index=last))
        else:
            self._send(
                Message(
                    MsgType.APP_RESP,
                    self.id,
                    m.frm,
                    self.term,
                    index=m.index,
                    reject=True,
                    reject_hint=self.log.conflict_hint(m.index),
                )
            )

    def _handle_heartbeat(self, m: Message) -> None:
        self.log.commit_to(min(m.commit, self.log.last_index()))
        self._send(Message(MsgType.HEARTBEAT_RESP, self.id, m.frm, self.term))

    def _send(self, m: Message) -> None:
        self.msgs.append(m)

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

Membership (`raft.membership`: learners, single-server changes taking effect on append),
leader transfer (`transfer_leader`, MsgTimeoutNow) and linearizable reads (`read_index`, the
thesis's section 6.4) live in the sections marked "membership", "transfer" and "reads". The
configuration is ``conf_state``; it is rebuilt on restart from the snapshot's configuration
(or the bootstrap one in `RaftConfig`) and the configuration entries in storage after it.

Snapshots (InstallSnapshot): the host snapshots its state machine and compacts the log
(`Storage.create_snapshot`, with the configuration at the snapshot's index,
`conf_state_at`); a follower that needs an entry the leader no longer holds gets the
leader's stored snapshot in a MsgSnap, installs it if it is newer than its commit index
(`Ready.snapshot`, persisted and restored by the host before any entry is applied; its
configuration becomes the node's base configuration) and acknowledges its index with a
MsgAppResp.
"""

from __future__ import annotations

import random
from collections import deque
from collections.abc import Callable

from swarmraft.raft.log import RaftLog
from swarmraft.raft.membership import ConfChange, ConfChangeType, ConfLog, ConfState
from swarmraft.raft.progress import Inflights, Progress
from swarmraft.raft.storage import Storage
from swarmraft.raft.types import (
    ConfChangeRefused,
    Entry,
    EntryKind,
    HardState,
    LeaderTransferring,
    Message,
    MsgType,
    NotLeader,
    ProposalDropped,
    RaftConfig,
    ReadState,
    Ready,
    Role,
    Snapshot,
    Status,
)


class RaftNode:
    """``validate`` (optional): the host's check of a new entry before the node persists and
    acknowledges it (a SwarmRaft voter's audit of its leader's record). See `_handle_append`.
    ``validate_snapshot`` (optional): the same for a leader's snapshot before the node
    installs it (`_handle_snapshot`): a snapshot holds the state the entries it replaces
    made, and a leader that could send any would get round ``validate``."""

    def __init__(
        self,
        config: RaftConfig,
        storage: Storage,
        rng: random.Random,
        applied: int = 0,
        validate: Callable[[Entry], bool] | None = None,
        validate_snapshot: Callable[[Snapshot], bool] | None = None,
    ) -> None:
        self.config = config
        self.validate = validate
        self.validate_snapshot = validate_snapshot
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
        # a follower's appends that overtook an earlier one from the same leader, by the index
        # of their previous entry, held for this tick (see `_handle_append`), and the tick
        # (counted from the start) in which the last append of the current term arrived
        self._early: dict[int, Message] = {}
        self._ticks = 0
        self._app_tick = -1
        # the leader's entries of its term not yet committed: (index, payload bytes), in order
        self._uncommitted: deque[tuple[int, int]] = deque()
        self._uncommitted_bytes = 0
        # membership: the snapshot's configuration (else the bootstrap one), then every
        # configuration entry in the log after it
        self.confs = self._base_confs(storage.snapshot())
        self.confs.add(storage.conf_entries())
        self._term_start = 0  # a leader's first index of its term (its no-op)
        # transfer: the node a leader hands over to, and ticks since it began
        self.lead_transferee: int | None = None
        self._transfer_elapsed = 0
        # reads: a leader's read rounds (each heartbeat carries the latest), the round each
        # voter last acknowledged, reads waiting for a quorum [(round, index, ctx, asker)],
        # reads waiting for the term's first commit [(ctx, asker)]; answered reads waiting to
        # be applied (every role)
        self._read_round = 0
        self._acked_round: dict[int, int] = {}
        self._pending_reads: deque[tuple[int, int, int, int]] = deque()
        self._early_reads: list[tuple[int, int]] = []
        self._read_states: list[ReadState] = []
        # a leader this node deposed (`depose`): not listened to in that term, not voted for,
        # until another leader is heard
        self._distrusted: int | None = None
        self._distrusted_term = 0  # the term it led when deposed

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
        self._ticks += 1
        if self._early:
            self._give_up_early()
        if self.role == Role.LEADER:
            self._tick_leader()
            return
        self.election_elapsed += 1
        if self.election_elapsed >= self.randomized_timeout:
            self.election_elapsed = 0
            self.campaign()  # a learner or a removed node does nothing

    def campaign(self, force: bool = False) -> None:
        """Start an election now: a pre-vote first when PreVote is on. With ``force`` (a leader
        transfer, or a voter that found its leader faulty), no pre-vote, and the votes ask the
        other nodes to answer even while they hear from a leader: the reason to depose it is
        carried, so neither PreVote nor the leader lease stops the election. The vote
        restriction still holds: only a node whose log is up to date can win. A node that is
        not a voter (a learner, a removed node) does nothing."""
        if self.role == Role.LEADER or self.id not in self.conf_state.voters:
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
            if self.lead_transferee is not None:
                raise LeaderTransferring(self.id, self.lead_transferee)
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
            or log.pending is not None
            or self.term != p.term
            or self.vote != p.vote
            or log.committed != p.commit
            or (log.committed > log.applied and log.stable_last() > log.applied)
            or (self._read_states and any(r.index <= log.applied for r in self._read_states))
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
            read_states=tuple(r for r in self._read_states if r.index <= self.log.applied)
            if self._read_states
            else (),
            snapshot=self.log.pending,
        )

    def advance(self, rd: Ready) -> None:
        if rd.hard_state is not None:
            self._persisted_hs = rd.hard_state
        if rd.snapshot is not None:
            self.log.snapshot_applied(rd.snapshot)
        if rd.entries:
            last = rd.entries[-1]
            self.log.stable_to(last.index, last.term)
        if rd.committed:
            self.log.applied_to(rd.committed[-1].index)
        del self.msgs[: len(rd.messages)]
        if rd.read_states:
            done = set(rd.read_states)
            self._read_states = [r for r in self._read_states if r not in done]

    def step(self, m: Message) -> None:
        if m.to != self.id:
            raise ValueError(f"node {self.id}: message for node {m.to}")
        if m.type == MsgType.PROP:
            self._step_prop(m)
            return
        if (
            m.frm == self._distrusted
            and m.term <= self._distrusted_term
            and m.type in (MsgType.APP, MsgType.HEARTBEAT, MsgType.SNAP)
        ):
            return  # the leadership we deposed (`depose`): dropped, as if lost
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
            elif m.type in (MsgType.APP, MsgType.HEARTBEAT, MsgType.SNAP):
                self._become_follower(m.term, m.frm)
            else:
                self._become_follower(m.term, None)
        elif m.term < self.term:
            if (self.config.check_quorum or self.config.pre_vote) and m.type in (
                MsgType.APP,
                MsgType.HEARTBEAT,
                MsgType.SNAP,
            ):
                # tell a stale leader about the newer term so it steps down
                self._send(Message(MsgType.APP_RESP, self.id, m.frm, self.term))
            elif m.type == MsgType.PRE_VOTE:
                self._send(Message(MsgType.PRE_VOTE_RESP, self.id, m.frm, self.term, reject=True))
            return

        if m.type in (MsgType.VOTE, MsgType.PRE_VOTE):
            self._handle_vote_request(m)
        elif m.type == MsgType.TIMEOUT_NOW:
            self._handle_timeout_now(m)
        elif m.type in (MsgType.READ_INDEX, MsgType.READ_INDEX_RESP):
            self._step_read(m)
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
        self._early.clear()
        self._app_tick = -1
        if term != self.term:
            self.term = term
            self.vote = None
        self.lead = None
        self.election_elapsed = 0
        self.randomized_timeout = self._draw_timeout()
        self.votes = {}
        self.lead_transferee = None
        self._pending_reads.clear()  # a read not answered is dropped: the asker retries
        self._early_reads.clear()
        self._acked_round.clear()

    def _become_follower(self, term: int, lead: int | None) -> None:
        self._reset(term)
        self.role = Role.FOLLOWER
        self.lead = lead
        if lead is not None:
            self._distrusted = None  # another leader took over (`depose`)

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
        for p in self.conf_state.voters:
            if p == self.id:
                continue
            self._send(Message(kind, self.id, p, term, log_term=last_term, index=last, force=force))

    def _quorum(self) -> int:
        return len(self.conf_state.voters) // 2 + 1

    def _tally(self) -> str:
        voters = self.conf_state.voters
        granted = sum(v for p, v in self.votes.items() if p in voters)
        rejected = sum(not v for p, v in self.votes.items() if p in voters)
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
        self._distrusted = None  # another leader (this one) took over (`depose`)
        last = self.log.last_index()
        self.prs = {p: self._new_progress(last + 1) for p in self.conf_state.members if p != self.id}
        self._uncommitted.clear()
        self._uncommitted_bytes = 0
        # A no-op entry of the new term lets entries of earlier terms commit through it.
        self._term_start = self._append_and_broadcast([b""], kind=EntryKind.NOOP)

    def _new_progress(self, next_index: int) -> Progress:
        cfg = self.config
        return Progress(Inflights(cfg.max_inflight_msgs, cfg.max_inflight_bytes), match=0, next=next_index)

    # -- leader ---------------------------------------------------------------------------
    def _tick_leader(self) -> None:
        self.election_elapsed += 1
        if self.election_elapsed >= self.config.election_tick:
            self.election_elapsed = 0
            voters = self.conf_state.voters
            active = (self.id in voters) + sum(pr.recent_active for p, pr in self.prs.items() if p in voters)
            for pr in self.prs.values():
                pr.responsive, pr.recent_active = pr.recent_active, False
            if self.config.check_quorum and active < self._quorum():
                self._become_follower(self.term, None)
                return
        if self.lead_transferee is not None:
            self._transfer_elapsed += 1
            if self._transfer_elapsed >= self.config.election_tick:
                self.lead_transferee = None  # the transfer failed: take proposals again
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
                        MsgType.HEARTBEAT,
                        self.id,
                        p,
                        self.term,
                        index=self._read_round,
                        commit=min(pr.match, self.log.committed),
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
        if kind == EntryKind.CONF_CHANGE:
            self._conf_appended(entries)
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
        if pr.next < self.log.first_index():
            return self._send_snapshot(to, pr)
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

    def _send_snapshot(self, to: int, pr: Progress) -> bool:
        """The follower needs entries we compacted: send our stored snapshot instead."""
        snap: Snapshot = self.log.storage.snapshot()
        self._send(Message(MsgType.SNAP, self.id, to, self.term, snapshot=snap))
        pr.become_snapshot(snap.index)
        pr.silent, pr.flowing = 0, False
        return True

    def _maybe_commit(self, acked: int | None = None) -> bool:
        """Advance the commit index to the highest index a quorum holds, if it is of the
        current term. ``acked``: the index a follower just acknowledged; nothing can change
        if it is not above the commit index (most answers, under steady load)."""
        if acked is not None and acked <= self.log.committed:
            return False
        voters = self.conf_state.voters
        matches = [pr.match for p, pr in self.prs.items() if p in voters]
        if self.id in voters:
            matches.append(self.log.last_index())
        matches.sort(reverse=True)
        n = matches[self._quorum() - 1]
        # The commit rule: only an entry of the current term commits by counting replicas.
        if n > self.log.committed and self.log.term(n) == self.term:
            self.log.commit_to(n)
            while self._uncommitted and self._uncommitted[0][0] <= n:
                self._uncommitted_bytes -= self._uncommitted.popleft()[1]
            self._committed_in_term()
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
                if pr.pending_snapshot:
                    if pr.match + 1 < self.log.first_index():
                        return  # still short of our log: wait for the snapshot's answer
                    pr.pending_snapshot = 0
                if pr.probe:
                    pr.become_replicate()
                else:
                    pr.inflights.free_le(m.index)
                # the new commit index, if any, travels with the next append or heartbeat
                self._maybe_commit(pr.match)
                if self.role != Role.LEADER:
                    return  # it committed its own removal and stepped down
                while self._send_append(m.frm, send_if_empty=False):
                    pass
                if m.frm == self.lead_transferee and pr.match == self.log.last_index():
                    self._send_timeout_now(m.frm)
        elif m.type == MsgType.HEARTBEAT_RESP:
            pr.recent_active = True
            if m.index and self._pending_reads:
                self._read_acked(m.frm, m.index)
            pr.paused = False
            if pr.pending_snapshot:  # the snapshot or its answer may be lost: probe again
                pr.become_probe()
            if not pr.probe and pr.inflights.full():
                pr.inflights.free_first()
            # A follower that lacks entries after a heartbeat lost an append or its answer,
            # unless an append went out after the heartbeat (``flowing``): its answer will tell.
            if pr.match < self.log.last_index() and (pr.probe or not pr.flowing):
                self._send_append(m.frm)

    def _step_prop(self, m: Message) -> None:
        datas = [e.data for e in m.entries]
        if self.role == Role.LEADER:
            if self.lead_transferee is not None:
                return  # handing over: dropped, the proposer retries at the new leader
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
        if m.frm == self._distrusted:
            can_vote = False  # it led with an entry we refused: not again (`depose`)
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
        elif m.type == MsgType.SNAP:
            self._become_follower(m.term, m.frm)
            self._handle_snapshot(m)
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
        elif m.type == MsgType.SNAP:
            self.election_elapsed = 0
            self.lead = m.frm
            self._handle_snapshot(m)

    def _handle_append(self, m: Message) -> None:
        if m.index < self.log.committed:
            self._send(Message(MsgType.APP_RESP, self.id, m.frm, self.term, index=self.log.committed))
            return
        last_index = self.log.last_index()
        burst, self._app_tick = self._app_tick == self._ticks, self._ticks
        if m.index > last_index and burst and len(self._early) < self.config.max_inflight_msgs:
            # An append past our end, in a burst of appends (another came in this tick): it
            # overtook an earlier one still on its way (each message has its own delay), or
            # the one before it was lost. Hold it until the next tick, as a network delay
            # would; rejecting it at once made the leader resend its whole window for every
            # overtaken append, and again for the answers to those (seed 5651 of raft-fuzz:
            # 1.3 million appends in 2.75 s). A lone append past our end (a probe, or a step's
            # append after a lost one) is rejected at once, as before.
            self._early.setdefault(m.index, m)
            return
        last, refused = self._take_append(m)
        # held appends that continue from here (one after the other) go in after it
        while True:
            if last is None:
                self._reject_append(m)
                return
            self._send(Message(MsgType.APP_RESP, self.id, m.frm, self.term, index=last))
            if refused:
                # No reject (the leader would probe and resend forever): the refusal is
                # counted and the leader deposed (`depose`: one forced election, the reason
                # carried, so neither PreVote nor the lease stops it; the vote restriction
                # still holds).
                self.refused += 1
                self.depose(m.frm)
                return
            if last <= last_index or (held := self._early.pop(last, None)) is None:
                return
            last_index, m = last, held
            last, refused = self._take_append(m)

    def ignores(self, m: Message) -> bool:
        """Whether `step` would drop the append, heartbeat or snapshot ``m`` without reading
        its entries: from the leadership this node deposed (`depose`), or of a term below its
        own (answered with the newer term, nothing appended). A pure query: a host that does
        work per entry before stepping (an audit) can skip that work for these."""
        if m.type not in (MsgType.APP, MsgType.HEARTBEAT, MsgType.SNAP):
            return False
        deposed = m.frm == self._distrusted and m.term <= self._distrusted_term
        return deposed or m.term < self.term

    def depose(self, leader: int | None, term: int | None = None) -> None:
        """This node found ``leader`` faulty: its entry was refused (`validate`), or the host
        found it censoring in ``term`` (nothing if this node's term has moved on since, or it
        has no leader). Every voter finds such a fault at about the same time (on the
        same entry); were they all to campaign at once, each would vote for itself and the vote
        would split, costing a randomised election timeout. So only the first voter after
        ``leader`` in id order (cyclically) starts a forced election (the reason is carried:
        neither PreVote nor the lease stops it); the others stop listening to ``leader`` (its
        appends, heartbeats and snapshots of that term are dropped, as if lost, and it is no
        longer their leader: their election timers run and no lease holds) and vote for that voter when it
        asks, or, if it does not win (down, or its log behind), elect one by their election
        timeout as usual. Until another leader is heard (or this node leads), ``leader`` gets
        no vote or pre-vote: after a refusal its log holds the refused entry, so it is more up
        to date than the voters that refused it and would otherwise win again whenever its
        timer fired first. A learner (or a removed node) cannot depose: it keeps following
        ``leader`` (it cannot elect another, and dropping the appends would leave it behind;
        its audit still refuses to apply a lie)."""
        stale = term is not None and term != self.term
        if leader is None or stale or self.id not in self.conf_state.voters:
            return
        self._distrusted, self._distrusted_term = leader, self.term
        self.lead = None
        others = sorted(p for p in self.conf_state.voters if p != leader)
        if others and next((p for p in others if p > leader), others[0]) == self.id:
            self.campaign(force=True)

    def _take_append(self, m: Message) -> tuple[int | None, bool]:
        """The log's consistency check and append (`RaftLog.maybe_append`), and the
        configurations the log now holds (a truncation may undo one, an entry add one). With
        a validator, new normal entries (not those the log already holds) are validated in
        order first; at the first refused one only the valid prefix goes in. Returns the last
        index appended (None: the check failed) and whether an entry was refused."""
        entries, refused = m.entries, False
        if self.validate is not None and entries and self.log.match_term(m.index, m.log_term):
            for k, e in enumerate(entries):
                if self.log.match_term(e.index, e.term) or e.kind != EntryKind.NORMAL:
                    continue
                if not self.validate(e):
                    entries, refused = entries[:k], True
                    break
        last = self.log.maybe_append(m.index, m.log_term, m.commit, entries)
        if last is not None and (self.confs.changes or any(e.kind == EntryKind.CONF_CHANGE for e in entries)):
            self.confs.truncate(self.log.term, self.log.first_index())
            self.confs.add(entries)
        return last, refused

    def _reject_append(self, m: Message) -> None:
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

    def _give_up_early(self) -> None:
        """A tick passed and the held appends still do not continue the log: what they
        follow was lost. The lowest is rejected (the leader goes back and resends from where
        our log ends); the others are dropped, as the network might have dropped them."""
        first = min(self._early)
        self._reject_append(self._early[first])
        self._early.clear()

    def _handle_heartbeat(self, m: Message) -> None:
        self.log.commit_to(min(m.commit, self.log.last_index()))
        self._send(Message(MsgType.HEARTBEAT_RESP, self.id, m.frm, self.term, index=m.index))

    def _handle_snapshot(self, m: Message) -> None:
        """Install the leader's snapshot unless our log already holds what it covers; either
        way acknowledge the index we now hold committed."""
        snap = m.snapshot
        assert snap is not None
        if snap.index <= self.log.committed:
            pass  # older than what we have committed: nothing to do
        elif self.log.match_term(snap.index, snap.term):
            self.log.commit_to(snap.index)  # we hold its last entry: our log covers it
        elif self.validate_snapshot is not None and not self.validate_snapshot(snap):
            # refused as an entry is: not installed, not acknowledged (no reject), counted,
            # and the leader deposed
            self.refused += 1
            self.depose(m.frm)
            return
        else:
            self.log.restore(snap)
            self.confs = self._base_confs(snap)  # the log it replaced held the configurations
        self._send(Message(MsgType.APP_RESP, self.id, m.frm, self.term, index=self.log.committed))

    def _send(self, m: Message) -> None:
        self.msgs.append(m)

    # -- membership -----------------------------------------------------------------------
    @property
    def conf_state(self) -> ConfState:
        """The configuration in effect: the newest in the log, committed or not."""
        return self.confs.current

    def conf_state_at(self, index: int) -> ConfState:
        """The configuration in effect at ``index``: a snapshot taken there must carry it
        (`Storage.create_snapshot`'s ``conf``)."""
        return self.confs.at(index)

    def _base_confs(self, snap: Snapshot) -> ConfLog:
        """The configurations known without reading the log: the snapshot's (if it has one),
        else the bootstrap one of `RaftConfig`."""
        if snap.index and snap.voters:
            return ConfLog(ConfState(tuple(snap.voters), tuple(snap.learners)), snap.index)
        boot = self.config.voters if self.config.voters is not None else self.config.members
        return ConfLog(ConfState(tuple(sorted(boot)), tuple(sorted(self.config.learners))))

    def progress(self, node: int) -> Progress | None:
        """The leader's view of a member (``match``: the highest index it is known to hold);
        None on a follower or for a node that is not a member."""
        return self.prs.get(node) if self.role == Role.LEADER else None

    def propose_conf_change(self, cc: ConfChange) -> int:
        """Append a single-server configuration change (leader only) and return its index;
        it takes effect at once (`raft.membership`). Raises `NotLeader` on a follower (changes
        are not forwarded), `LeaderTransferring` during a transfer, and `ConfChangeRefused`
        while another change is uncommitted, before the leader has committed an entry of its
        term, for a change that does not apply (`ConfState.check`), or to promote a learner
        whose match index is more than ``promote_gap`` behind the leader's last index. A leader
        that removes itself keeps leading until the change commits, then steps down."""
        if self.role != Role.LEADER:
            raise NotLeader(self.id, self.lead)
        if self.lead_transferee is not None:
            raise LeaderTransferring(self.id, self.lead_transferee)
        if self.log.committed < self._term_start:
            raise ConfChangeRefused(self.id, f"no entry of term {self.term} is committed yet; retry")
        if self.confs.last_index > self.log.committed:
            raise ConfChangeRefused(
                self.id, f"the change at index {self.confs.last_index} is not committed yet; retry"
            )
        if (why := self.conf_state.check(cc)) is not None:
            raise ConfChangeRefused(self.id, why)
        if cc.type == ConfChangeType.PROMOTE:
            match, last, gap = self.prs[cc.node].match, self.log.last_index(), self.config.promote_gap
            if match + gap < last:
                raise ConfChangeRefused(
                    self.id,
                    f"learner {cc.node} is not caught up "
                    f"(match {match}, last index {last}, promote_gap {gap})",
                )
        return self._append_and_broadcast([cc.encode()], kind=EntryKind.CONF_CHANGE)

    def _conf_appended(self, entries: list[Entry]) -> None:
        """The leader appended a configuration entry: it takes effect now; new members get a
        progress (probed from that entry on), removed ones lose theirs."""
        self.confs.add(entries)
        members = set(self.conf_state.members)
        for p in members - set(self.prs) - {self.id}:
            self.prs[p] = self._new_progress(entries[0].index)
        for p in set(self.prs) - members:
            del self.prs[p]
        if self.lead_transferee is not None and self.lead_transferee not in self.conf_state.voters:
            self.lead_transferee = None

    def _committed_in_term(self) -> None:
        """The leader's commit index moved. Once it covers the current configuration, a leader
        that is no longer a voter steps down (etcd); once it covers the term's first entry,
        reads that waited for it start."""
        if self.id not in self.conf_state.voters and self.log.committed >= self.confs.last_index:
            self._become_follower(self.term, None)
            return
        if self._early_reads and self.log.committed >= self._term_start:
            early, self._early_reads = self._early_reads, []
            for ctx, asker in early:
                self._start_read(ctx, asker)

    # -- transfer -------------------------------------------------------------------------
    def transfer_leader(self, to: int) -> None:
        """Hand leadership to voter ``to`` (Raft thesis, section 3.10): the leader stops taking
        proposals, brings ``to`` up to date, then sends it MsgTimeoutNow, on which it starts a
        forced election (`campaign` with ``force``). Aborted after an election timeout
        (``election_tick`` ticks), when proposals are taken again. `NotLeader` on a follower;
        ValueError if ``to`` is not a voter."""
        if self.role != Role.LEADER:
            raise NotLeader(self.id, self.lead)
        if to == self.id or self.lead_transferee == to:
            return
        if to not in self.conf_state.voters:
            raise ValueError(f"transfer_leader: node {to} is not a voter")
        self.lead_transferee, self._transfer_elapsed = to, 0
        pr = self.prs[to]
        if pr.match == self.log.last_index():
            self._send_timeout_now(to)
        else:
            self._send_append(to)

    def _send_timeout_now(self, to: int) -> None:
        last = self.log.last_index()
        self._send(
            Message(
                MsgType.TIMEOUT_NOW, self.id, to, self.term, log_term=self.log.term(last) or 0, index=last
            )
        )

    def _handle_timeout_now(self, m: Message) -> None:
        self.campaign(force=True)  # nothing on a leader, a learner or a removed node

    # -- reads ----------------------------------------------------------------------------
    def read_index(self, ctx: int) -> None:
        """Ask for a linearizable read (Raft thesis, section 6.4), ``ctx`` (an int >= 1) naming
        it. The leader records its commit index, confirms it still leads with a heartbeat round
        answered by a quorum of voters, and answers once it has applied up to that index; a
        follower or learner forwards the request to its leader and answers once it has applied
        up to the index the leader sends back. The answer is a `ReadState` in a later `Ready`;
        a read lost (a leader change, a lost message) is never answered: ask again. A new
        leader starts reads once it has committed an entry of its term. `NotLeader` when no
        leader is known."""
        if ctx < 1:
            raise ValueError("read_index: ctx must be >= 1")
        if self.role == Role.LEADER:
            self._leader_read(ctx, self.id)
        elif self.lead is not None and self.role == Role.FOLLOWER:
            self._send(Message(MsgType.READ_INDEX, self.id, self.lead, self.term, index=ctx))
        else:
            raise NotLeader(self.id, self.lead)

    def _leader_read(self, ctx: int, asker: int) -> None:
        if self.log.committed < self._term_start:
            self._early_reads.append((ctx, asker))
        else:
            self._start_read(ctx, asker)

    def _start_read(self, ctx: int, asker: int) -> None:
        self._read_round += 1
        r, index = self._read_round, self.log.committed
        if self._read_confirmed(r):  # a single voter
            self._read_done(index, ctx, asker)
            return
        self._pending_reads.append((r, index, ctx, asker))
        for p, pr in self.prs.items():
            if p in self.conf_state.voters:
                pr.silent = 0
                self._send(
                    Message(
                        MsgType.HEARTBEAT,
                        self.id,
                        p,
                        self.term,
                        index=r,
                        commit=min(pr.match, self.log.committed),
                    )
                )

    def _read_confirmed(self, r: int) -> bool:
        voters = self.conf_state.voters
        acks = (self.id in voters) + sum(self._acked_round.get(p, 0) >= r for p in voters if p != self.id)
        return acks >= self._quorum()

    def _read_acked(self, frm: int, r: int) -> None:
        if r > self._acked_round.get(frm, 0):
            self._acked_round[frm] = r
        while self._pending_reads and self._read_confirmed(self._pending_reads[0][0]):
            _, index, ctx, asker = self._pending_reads.popleft()
            self._read_done(index, ctx, asker)

    def _read_done(self, index: int, ctx: int, asker: int) -> None:
        if asker == self.id:
            self._read_states.append(ReadState(index, ctx))
        else:
            self._send(Message(MsgType.READ_INDEX_RESP, self.id, asker, self.term, index=ctx, commit=index))

    def _step_read(self, m: Message) -> None:
        if m.type == MsgType.READ_INDEX:
            if self.role == Role.LEADER and m.frm in self.prs:
                self._leader_read(m.index, m.frm)
        elif self.role != Role.LEADER and m.frm == self.lead:
            self._read_states.append(ReadState(m.commit, m.index))

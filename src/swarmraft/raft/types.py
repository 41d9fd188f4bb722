"""Values the Raft core exchanges with its host: entries, messages, hard state, Ready."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import NamedTuple


class EntryKind(StrEnum):
    NORMAL = "normal"
    NOOP = "noop"  # appended by a new leader to commit entries of earlier terms
    CONF_CHANGE = "conf-change"  # a membership change (raft.membership.ConfChange)


@dataclass(frozen=True, slots=True)
class Entry:
    term: int
    index: int
    data: bytes = b""
    kind: EntryKind = EntryKind.NORMAL


class HardState(NamedTuple):
    """What must survive a crash: current term, vote in that term, commit index."""

    term: int = 0
    vote: int | None = None
    commit: int = 0


@dataclass(frozen=True, slots=True)
class Snapshot:
    """The state machine at log index ``index`` (of term ``term``): ``data`` is the host's
    encoding of it (the core never reads it). Index 0 is "no snapshot".

    # membership: the configuration in force at ``index`` goes here once membership changes
    # exist: ``voters`` and ``learners`` (empty: the static `RaftConfig` peers)."""

    index: int = 0
    term: int = 0
    data: bytes = b""
    voters: tuple[int, ...] = ()
    learners: tuple[int, ...] = ()


class MsgType(StrEnum):
    PROP = "MsgProp"  # a proposal forwarded to the leader
    APP = "MsgApp"
    APP_RESP = "MsgAppResp"
    VOTE = "MsgVote"
    VOTE_RESP = "MsgVoteResp"
    PRE_VOTE = "MsgPreVote"
    PRE_VOTE_RESP = "MsgPreVoteResp"
    HEARTBEAT = "MsgHeartbeat"
    HEARTBEAT_RESP = "MsgHeartbeatResp"
    TIMEOUT_NOW = "MsgTimeoutNow"  # leader transfer: campaign now (a forced election)
    READ_INDEX = "MsgReadIndex"  # a follower asks the leader for a read index
    READ_INDEX_RESP = "MsgReadIndexResp"
    # InstallSnapshot: the leader's snapshot for a follower behind its log (answer: MsgAppResp)
    SNAP = "MsgSnap"


@dataclass(slots=True)
class Message:
    """One Raft message. ``index``/``log_term`` are the previous entry for MsgApp, the last
    entry for votes, and the matched (or rejected) index for MsgAppResp. ``reject_hint`` on a
    rejected MsgAppResp is the index the leader should try next. ``force`` on MsgVote marks a
    forced election (`RaftNode.campaign` with ``force=True``: a leader transfer, or a voter that
    found its leader faulty): receivers answer it even while they hear from a leader (etcd's
    campaignTransfer context).

    ReadIndex (`RaftNode.read_index`) uses fields the message types leave free, so the wire
    format did not change: a heartbeat's ``index`` is the leader's latest read round and its
    answer echoes it; MsgReadIndex carries the request's ``ctx`` in ``index``; MsgReadIndexResp
    the ``ctx`` in ``index`` and the read index in ``commit``. MsgTimeoutNow carries the
    leader's last entry (``index``, ``log_term``) the target was caught up to.

    Treat it as immutable (it is not frozen only because frozen dataclasses are four times
    slower to build, and messages are the simulator's hot path)."""

    type: MsgType
    frm: int
    to: int
    term: int
    log_term: int = 0
    index: int = 0
    entries: tuple[Entry, ...] = ()
    commit: int = 0
    reject: bool = False
    reject_hint: int = 0
    force: bool = False
    snapshot: Snapshot | None = None  # MsgSnap only


class Role(StrEnum):
    FOLLOWER = "follower"
    PRE_CANDIDATE = "pre-candidate"
    CANDIDATE = "candidate"
    LEADER = "leader"


class ReadState(NamedTuple):
    """A linearizable read is answered: state applied up to ``index`` includes every write
    committed before the read began (`RaftNode.read_index` with this ``ctx``)."""

    index: int
    ctx: int


@dataclass(slots=True)
class Ready:
    """Work for the host, in this order: persist ``snapshot`` (if not None: a leader's
    snapshot this follower installs; it replaces the whole stored log), ``hard_state`` (if
    not None) and ``entries`` (they replace any stored entries from their first index on),
    then send ``messages``, then restore the state machine from ``snapshot`` and apply
    ``committed``, then call ``advance(ready)``. Messages may depend on the state in the same
    Ready, so they must not leave before it is persisted. ``read_states``: reads answered
    (`ReadState`); the node has already applied their index."""

    hard_state: HardState | None
    entries: tuple[Entry, ...]
    committed: tuple[Entry, ...]
    messages: tuple[Message, ...]
    read_states: tuple[ReadState, ...] = ()
    snapshot: Snapshot | None = None

    def __bool__(self) -> bool:
        return bool(
            self.snapshot
            or self.hard_state
            or self.entries
            or self.committed
            or self.messages
            or self.read_states
        )


@dataclass(frozen=True)
class Status:
    id: int
    role: Role
    term: int
    vote: int | None
    leader: int | None
    commit: int
    applied: int
    last_index: int
    refused: int = 0  # entries the node's validator refused (RaftNode ``validate``)


@dataclass(frozen=True)
class RaftConfig:
    """A node's settings. Ticks are the host's unit of time: with 10 ms ticks,
    ``election_tick`` 15 and ``heartbeat_tick`` 5 give the Raft paper's 150-300 ms randomised
    election timeout and a 50 ms heartbeat (the Raft paper's setting).

    Flow control, after etcd-io/raft (sizes count entry payload bytes): an append carries at
    most ``max_entries_per_msg`` entries and ``max_msg_bytes`` (etcd's MaxSizePerMsg; one entry
    always goes, however large); a follower in the replicate state has at most
    ``max_inflight_msgs`` appends (etcd's MaxInflightMsgs, default 256) and
    ``max_inflight_bytes`` unacknowledged (etcd's MaxInflightBytes); the leader refuses a
    proposal with `ProposalDropped` when its uncommitted entries would pass
    ``max_uncommitted_bytes`` (etcd's MaxUncommittedEntriesSize). The defaults are far above a
    swarm's load (a 17-drone record is about 2 KB at 10 Hz): they bind only when a leader cannot
    commit (a partition) or a follower cannot keep up."""

    id: int
    peers: tuple[int, ...]
    election_tick: int = 15
    heartbeat_tick: int = 5
    pre_vote: bool = True
    check_quorum: bool = True
    max_entries_per_msg: int = 64
    forward_proposals: bool = True
    max_msg_bytes: int = 1 << 20
    max_inflight_msgs: int = 256
    max_inflight_bytes: int = 4 << 20
    max_uncommitted_bytes: int = 1 << 20
    voters: tuple[int, ...] | None = None
    learners: tuple[int, ...] = ()
    promote_gap: int = 64

    def __post_init__(self) -> None:
        if self.id in self.peers:
            raise ValueError(f"RaftConfig: peers must not contain the node's own id {self.id}")
        if self.id < 1 or any(p < 1 for p in self.peers):
            raise ValueError("RaftConfig: node ids must be >= 1")
        if len(set(self.peers)) != len(self.peers):
            raise ValueError("RaftConfig: duplicate peer id")
        if self.heartbeat_tick < 1 or self.election_tick <= self.heartbeat_tick:
            raise ValueError("RaftConfig: need 1 <= heartbeat_tick < election_tick")
        for name in (
            "max_entries_per_msg",
            "max_msg_bytes",
            "max_inflight_msgs",
            "max_inflight_bytes",
            "max_uncommitted_bytes",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"RaftConfig: {name} must be >= 1")
        if self.promote_gap < 0:
            raise ValueError("RaftConfig: promote_gap must be >= 0")
        boot = (*(self.voters if self.voters is not None else self.members), *self.learners)
        if any(i < 1 for i in boot) or len(set(boot)) != len(boot):
            raise ValueError("RaftConfig: voters and learners must be distinct ids >= 1")
        if self.voters is not None and not self.voters:
            raise ValueError("RaftConfig: voters must not be empty")

    @property
    def members(self) -> tuple[int, ...]:
        return tuple(sorted((self.id, *self.peers)))

    @property
    def flow_heartbeat_tick(self) -> int:
        """Ticks of silence after which the leader sends a heartbeat to a follower whose last
        message from it was a pipelined append (appends are flowing, and each stands in for a
        heartbeat): ``election_tick - 2``, so the follower still hears from the leader two ticks
        before its shortest election timeout ends, however the appends are spaced (never below
        ``heartbeat_tick``). With 10 Hz steps and 15-tick timeouts a step's append comes well
        within it, so steady steps cost no heartbeats."""
        return max(self.heartbeat_tick, self.election_tick - 2)


class ProposalDropped(Exception):
    """The leader refused a proposal: its uncommitted entries would pass
    ``max_uncommitted_bytes``. Nothing was appended; the proposer may retry once entries
    commit (etcd's ErrProposalDropped)."""

    def __init__(self, node: int, size: int, uncommitted: int, cap: int) -> None:
        self.node, self.size, self.uncommitted, self.cap = node, size, uncommitted, cap
        super().__init__(
            f"node {node} refused a proposal of {size} bytes: {uncommitted} bytes are uncommitted "
            f"and max_uncommitted_bytes is {cap}; retry once entries commit"
        )


class NotLeader(Exception):
    """A proposal reached a node that cannot take it; ``leader`` is its best guess of the
    leader (None when it knows none)."""

    def __init__(self, node: int, leader: int | None) -> None:
        self.node, self.leader = node, leader
        hint = f"; try node {leader}" if leader is not None else "; no leader is known"
        super().__init__(f"node {node} is not the leader{hint}")


class ConfChangeRefused(Exception):
    """The leader refused a configuration change; the message says why (another change is
    pending, no entry of its term committed yet, a learner not caught up, ...)."""

    def __init__(self, node: int, reason: str) -> None:
        self.node, self.reason = node, reason
        super().__init__(f"node {node} refused the configuration change: {reason}")


class LeaderTransferring(NotLeader):
    """A proposal reached a leader that is handing over to ``leader`` (`RaftNode.transfer_leader`);
    retry there."""

    def __init__(self, node: int, to: int) -> None:
        Exception.__init__(self, f"node {node} is handing leadership over to node {to}; try node {to}")
        self.node, self.leader = node, to

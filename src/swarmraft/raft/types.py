"""Values the Raft core exchanges with its host: entries, messages, hard state, Ready."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import NamedTuple


class EntryKind(StrEnum):
    NORMAL = "normal"
    NOOP = "noop"  # appended by a new leader to commit entries of earlier terms


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


@dataclass(slots=True)
class Message:
    """One Raft message. ``index``/``log_term`` are the previous entry for MsgApp, the last
    entry for votes, and the matched (or rejected) index for MsgAppResp. ``reject_hint`` on a
    rejected MsgAppResp is the index the leader should try next.

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


class Role(StrEnum):
    FOLLOWER = "follower"
    PRE_CANDIDATE = "pre-candidate"
    CANDIDATE = "candidate"
    LEADER = "leader"


@dataclass(slots=True)
class Ready:
    """Work for the host, in this order: persist ``hard_state`` (if not None) and
    ``entries`` (they replace any stored entries from their first index on), then send
    ``messages``, then apply ``committed``, then call ``advance(ready)``. Messages may depend on
    the state in the same Ready, so they must not leave before it is persisted."""

    hard_state: HardState | None
    entries: tuple[Entry, ...]
    committed: tuple[Entry, ...]
    messages: tuple[Message, ...]

    def __bool__(self) -> bool:
        return bool(self.hard_state or self.entries or self.committed or self.messages)


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


@dataclass(frozen=True)
class RaftConfig:
    """A node's settings. Ticks are the host's unit of time: with 10 ms ticks,
    ``election_tick`` 15 and ``heartbeat_tick`` 5 give the Raft paper's 150-300 ms randomised
    election timeout and a 50 ms heartbeat (the Raft paper's setting)."""

    id: int
    peers: tuple[int, ...]
    election_tick: int = 15
    heartbeat_tick: int = 5
    pre_vote: bool = True
    check_quorum: bool = True
    max_entries_per_msg: int = 64
    forward_proposals: bool = True

    def __post_init__(self) -> None:
        if self.id in self.peers:
            raise ValueError(f"RaftConfig: peers must not contain the node's own id {self.id}")
        if self.id < 1 or any(p < 1 for p in self.peers):
            raise ValueError("RaftConfig: node ids must be >= 1")
        if len(set(self.peers)) != len(self.peers):
            raise ValueError("RaftConfig: duplicate peer id")
        if self.heartbeat_tick < 1 or self.election_tick <= self.heartbeat_tick:
            raise ValueError("RaftConfig: need 1 <= heartbeat_tick < election_tick")
        if self.max_entries_per_msg < 1:
            raise ValueError("RaftConfig: max_entries_per_msg must be >= 1")

    @property
    def members(self) -> tuple[int, ...]:
        return tuple(sorted((self.id, *self.peers)))


class NotLeader(Exception):
    """A proposal reached a node that cannot take it; ``leader`` is its best guess of the
    leader (None when it knows none)."""

    def __init__(self, node: int, leader: int | None) -> None:
        self.node, self.leader = node, leader
        hint = f"; try node {leader}" if leader is not None else "; no leader is known"
        super().__init__(f"node {node} is not the leader{hint}")

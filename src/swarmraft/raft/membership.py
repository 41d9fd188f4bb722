"""Cluster membership: the configuration (`ConfState`), the single-server changes that move
it (`ConfChange`, carried by entries of kind ``EntryKind.CONF_CHANGE``), and the node's record
of the configurations its log holds (`ConfLog`).

The rule (Raft thesis, chapter 4, single-server changes): one voter is added (a learner
promoted) or removed at a time, so any majority of the old voters and any majority of the new
ones share a voter, and two leaders of one term can never be elected by the two
configurations. A configuration takes effect **as soon as its entry is in a node's log**
(appended, committed or not; it is undone if the entry is truncated), as in the thesis: a
node then never needs to know what is committed to know which voters count, and a leader that
removes itself stops counting its own vote at once. etcd applies a change only once it is
committed and applied, which needs an extra rule (no campaign while a change is unapplied);
appending needs only the two below, which the leader enforces:

- at most one change is pending: a new change is refused while the log holds an uncommitted one
  (etcd's pendingConfIndex);
- a leader proposes a change only once it has committed an entry of its own term (Ongaro's
  2015 fix to the single-server algorithm: without it a change from a deposed leader's term
  and one from the new leader can both commit with disjoint majorities).

Learners receive the log and apply it but never vote, never campaign and do not count in any
quorum (commit, election, CheckQuorum, ReadIndex).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from swarmraft.raft.types import Entry, EntryKind


class ConfChangeType(StrEnum):
    ADD_LEARNER = "add-learner"  # a new non-voting member (or nothing, if it is one already)
    PROMOTE = "promote"  # a learner becomes a voter
    REMOVE = "remove"  # a voter or a learner leaves


@dataclass(frozen=True, slots=True)
class ConfChange:
    type: ConfChangeType
    node: int

    def encode(self) -> bytes:
        """The entry payload: ASCII ``"<type> <node>"`` (e.g. ``b"promote 4"``)."""
        return f"{self.type.value} {self.node}".encode()

    @classmethod
    def decode(cls, data: bytes) -> ConfChange:
        try:
            kind, node = data.decode("ascii").split(" ")
            return cls(ConfChangeType(kind), int(node))
        except (UnicodeDecodeError, ValueError) as exc:
            raise ValueError(f"not a configuration change: {data!r}") from exc


@dataclass(frozen=True, slots=True)
class ConfState:
    """A configuration: the voters and the learners (disjoint, sorted)."""

    voters: tuple[int, ...]
    learners: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if set(self.voters) & set(self.learners):
            raise ValueError("ConfState: a node cannot be both a voter and a learner")

    @property
    def members(self) -> tuple[int, ...]:
        return tuple(sorted((*self.voters, *self.learners)))

    def quorum(self) -> int:
        return len(self.voters) // 2 + 1

    def check(self, cc: ConfChange) -> str | None:
        """Why ``cc`` cannot apply to this configuration, or None if it can."""
        if cc.node < 1:
            return f"node ids are >= 1, got {cc.node}"
        if cc.type == ConfChangeType.ADD_LEARNER and cc.node in self.voters:
            return f"node {cc.node} is a voter already"
        if cc.type == ConfChangeType.PROMOTE and cc.node not in self.learners:
            return f"node {cc.node} is not a learner"
        if cc.type == ConfChangeType.REMOVE:
            if cc.node not in self.members:
                return f"node {cc.node} is not a member"
            if self.voters == (cc.node,):
                return f"node {cc.node} is the last voter"
        return None

    def apply(self, cc: ConfChange) -> ConfState:
        """The configuration after ``cc``; a change that `check` refuses leaves it as it is
        (the leader never proposes one, so this is only defence)."""
        if self.check(cc) is not None:
            return self
        v, lr = set(self.voters), set(self.learners)
        if cc.type == ConfChangeType.ADD_LEARNER:
            lr.add(cc.node)
        elif cc.type == ConfChangeType.PROMOTE:
            lr.discard(cc.node)
            v.add(cc.node)
        else:
            v.discard(cc.node)
            lr.discard(cc.node)
        return ConfState(tuple(sorted(v)), tuple(sorted(lr)))


class ConfLog:
    """The configurations a node's log holds: the base one (the bootstrap configuration, or
    what a snapshot saved) and one per configuration-change entry after it, newest last. The
    current configuration is the newest (`current`), committed or not."""

    def __init__(self, base: ConfState, base_index: int = 0) -> None:
        self.base, self.base_index = base, base_index
        self.changes: list[tuple[int, int, ConfState]] = []  # (index, term, configuration)

    @property
    def current(self) -> ConfState:
        return self.changes[-1][2] if self.changes else self.base

    @property
    def last_index(self) -> int:
        """Index of the newest configuration entry (``base_index`` if none)."""
        return self.changes[-1][0] if self.changes else self.base_index

    def add(self, entries: list[Entry] | tuple[Entry, ...]) -> None:
        """Entries just appended at the end of the log (after `truncate`)."""
        for e in entries:
            if e.kind == EntryKind.CONF_CHANGE and e.index > self.last_index:
                self.changes.append((e.index, e.term, self.current.apply(ConfChange.decode(e.data))))

    def truncate(self, term_of, first_index: int = 1) -> None:  # noqa: ANN001 (index -> term or None)
        """Forget configurations whose entry is no longer in the log (``term_of(index)``
        differs from the term it was appended with). Entries before ``first_index`` are in a
        snapshot: committed, so never undone."""
        while (
            self.changes
            and self.changes[-1][0] >= first_index
            and term_of(self.changes[-1][0]) != self.changes[-1][1]
        ):
            self.changes.pop()

    def at(self, index: int) -> ConfState:
        """The configuration in effect at log index ``index`` (what a snapshot there holds)."""
        for i, _term, conf in reversed(self.changes):
            if i <= index:
                return conf
        return self.base

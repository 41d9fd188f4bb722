"""The node's view of its log: what storage holds (after its compaction point) plus the
unstable part not yet persisted: a leader's snapshot being installed, then the tail."""

from __future__ import annotations

from collections.abc import Sequence

from swarmraft.raft.storage import Compacted, Storage
from swarmraft.raft.types import Entry, Snapshot


class RaftSafetyError(AssertionError):
    """The core was asked to do something Raft forbids (e.g. truncate a committed entry)."""


class RaftLog:
    def __init__(self, storage: Storage, committed: int = 0, applied: int = 0) -> None:
        self.storage = storage
        self.unstable: list[Entry] = []
        self.offset = storage.last_index() + 1  # index of unstable[0]
        self.committed = committed
        # the host restores the state machine from the stored snapshot before it starts a node
        self.applied = max(applied, storage.snapshot().index)
        self.pending: Snapshot | None = None  # a leader's snapshot to install, not yet persisted
        self.dirty_from: int | None = None  # lowest index written since take_dirty()

    # -- reading --------------------------------------------------------------------------
    def first_index(self) -> int:
        """The first entry held: entries before it are in a snapshot."""
        return self.pending.index + 1 if self.pending is not None else self.storage.first_index()

    def last_index(self) -> int:
        # offset is always one past the persisted prefix the log builds on: storage's end when
        # nothing is unstable, so this needs no storage call
        return self.offset + len(self.unstable) - 1

    def term(self, index: int) -> int | None:
        """Term of entry ``index`` (0 for index 0), None if the log does not reach it."""
        if index == 0:
            return 0
        if self.unstable and index >= self.offset:
            pos = index - self.offset
            return self.unstable[pos].term if pos < len(self.unstable) else None
        if index > self.last_index():
            return None
        if self.pending is not None:
            return self.pending.term if index == self.pending.index else None
        try:
            return self.storage.term(index)
        except Compacted:
            return None

    def last_term(self) -> int:
        return self.term(self.last_index()) or 0

    def match_term(self, index: int, term: int) -> bool:
        return self.term(index) == term

    def slice(self, lo: int, hi: int) -> list[Entry]:
        """Entries [lo, hi)."""
        hi = min(hi, self.last_index() + 1)
        if lo >= hi:
            return []
        if lo < self.first_index():
            raise Compacted(f"entries from {lo} are compacted (the log starts at {self.first_index()})")
        out: list[Entry] = []
        if lo < self.offset:
            out += self.storage.entries(lo, min(hi, self.offset))
        if hi > self.offset and self.unstable:
            out += self.unstable[max(lo, self.offset) - self.offset : hi - self.offset]
        return out

    def is_up_to_date(self, last_index: int, last_term: int) -> bool:
        """The vote restriction: a candidate's log must be at least as up to date as ours."""
        mine = self.last_term()
        return last_term > mine or (last_term == mine and last_index >= self.last_index())

    def conflict_hint(self, index: int) -> int:
        """For a rejected append at ``index``: the next index the leader should try: past
        our end, or the first index of the conflicting term (skipping a whole term)."""
        last = self.last_index()
        if index > last:
            return last + 1
        t = self.term(index)
        i = index
        while i - 1 > self.committed and self.term(i - 1) == t:
            i -= 1
        return max(i, 1)

    # -- writing --------------------------------------------------------------------------
    def _mark(self, index: int) -> None:
        self.dirty_from = index if self.dirty_from is None else min(self.dirty_from, index)

    def take_dirty(self) -> int | None:
        d, self.dirty_from = self.dirty_from, None
        return d

    def append(self, entries: Sequence[Entry]) -> int:
        """Append at the end (the leader's own entries)."""
        if entries:
            if entries[0].index != self.last_index() + 1:
                raise RaftSafetyError("append must continue the log")
            self._truncate_and_append(entries)
        return self.last_index()

    def _truncate_and_append(self, entries: Sequence[Entry]) -> None:
        after = entries[0].index
        if after <= self.committed:
            raise RaftSafetyError(f"would overwrite committed entry {after} (commit {self.committed})")
        self._mark(after)
        if self.unstable and after == self.offset + len(self.unstable):
            self.unstable.extend(entries)
        elif after <= self.offset:
            self.unstable = list(entries)
            self.offset = after
        elif not self.unstable:
            raise RaftSafetyError(f"entries at {after} leave a gap after {self.last_index()}")
        else:
            self.unstable = self.unstable[: after - self.offset] + list(entries)

    def maybe_append(
        self, prev_index: int, prev_term: int, commit: int, entries: Sequence[Entry]
    ) -> int | None:
        """The follower's consistency check and append: None if the log does not contain an
        entry at prev_index with prev_term; otherwise truncate only from the first
        conflicting entry, append the rest, advance the commit, return the last new index."""
        if not self.match_term(prev_index, prev_term):
            return None
        last_new = prev_index + len(entries)
        for e in entries:
            if not self.match_term(e.index, e.term):
                self._truncate_and_append(entries[e.index - entries[0].index :])
                break
        self.commit_to(min(commit, last_new))
        return last_new

    def commit_to(self, index: int) -> None:
        if index > self.committed:
            if index > self.last_index():
                raise RaftSafetyError(f"commit {index} beyond last index {self.last_index()}")
            self.committed = index

    def restore(self, snap: Snapshot) -> None:
        """Install a leader's snapshot (the node checked that it is newer than our commit
        index): the log is replaced by it, to be persisted with the next Ready."""
        self._mark(self.committed + 1)  # what we held after our commit index is replaced
        self.pending = snap
        self.unstable = []
        self.offset = snap.index + 1
        self.committed = snap.index

    # -- persistence and application ------------------------------------------------------
    def snapshot_applied(self, snap: Snapshot) -> None:
        """The host persisted the pending snapshot and restored its state machine from it."""
        if self.pending is not None and self.pending.index == snap.index:
            self.pending = None
        self.applied = max(self.applied, snap.index)

    def unstable_entries(self) -> tuple[Entry, ...]:
        return tuple(self.unstable)

    def stable_to(self, index: int, term: int) -> None:
        """The host persisted entries up to ``index`` (of ``term``)."""
        if self.unstable and self.offset <= index and self.term(index) == term:
            self.unstable = self.unstable[index + 1 - self.offset :]
            self.offset = index + 1

    def stable_last(self) -> int:
        return self.offset - 1

    def next_committed(self) -> list[Entry]:
        """Committed, persisted entries not yet applied (none while a snapshot is pending:
        it comes first)."""
        if self.pending is not None:
            return []
        hi = min(self.committed, self.stable_last())
        return self.slice(self.applied + 1, hi + 1) if hi > self.applied else []

    def applied_to(self, index: int) -> None:
        if index > self.committed:
            raise RaftSafetyError(f"applied {index} beyond commit {self.committed}")
        self.applied = max(self.applied, index)

"""Raft stable storage: hard state (term, vote, commit), the latest snapshot, and the log
after the compaction point.

The host writes to storage (``save``, ``create_snapshot``, ``compact``) when it handles a
`Ready` or has applied entries; the node only reads it. `MemoryStorage` survives a simulated
crash (it plays the disk); `SQLiteStorage` survives a real one: WAL journal, synchronous
writes, one transaction per call.

The log starts after a compaction point (index and term of the last entry removed, 0 and 0
at first), as etcd-io/raft's MemoryStorage keeps a dummy entry: ``term`` answers for the
compaction point too, so an append right after it can be checked. A snapshot is at or above
the compaction point (``create_snapshot`` with ``compact_to`` keeps a margin of entries
below the snapshot for followers a little behind); installing a leader's snapshot
(``save(..., snapshot=)``) drops the whole log.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

from swarmraft.raft.membership import ConfState
from swarmraft.raft.types import Entry, EntryKind, HardState, Snapshot


class Compacted(IndexError):
    """The entry asked for is at or below the compaction point (in a snapshot now)."""


class Storage(Protocol):
    def initial_state(self) -> HardState: ...
    def first_index(self) -> int: ...
    def last_index(self) -> int: ...
    def term(self, index: int) -> int: ...
    def entries(self, lo: int, hi: int) -> list[Entry]: ...
    def conf_entries(self) -> list[Entry]: ...
    def snapshot(self) -> Snapshot: ...
    def save(
        self, hard_state: HardState | None, entries: Sequence[Entry], snapshot: Snapshot | None = None
    ) -> None: ...
    def create_snapshot(
        self, index: int, data: bytes, compact_to: int | None = None, conf: ConfState | None = None
    ) -> Snapshot: ...
    def compact(self, index: int) -> None: ...


def _snapshot(index: int, term: int, data: bytes, conf: ConfState | None) -> Snapshot:
    if conf is None:
        return Snapshot(index, term, bytes(data))
    return Snapshot(index, term, bytes(data), tuple(conf.voters), tuple(conf.learners))


def _check_contiguous(entries: Sequence[Entry], base: int, last: int) -> None:
    if not entries:
        return
    first = entries[0].index
    if first <= base or first > last + 1:
        raise ValueError(f"storage: entries start at {first}, the log holds ({base}, {last}]")
    for a, b in zip(entries, entries[1:], strict=False):
        if b.index != a.index + 1:
            raise ValueError("storage: entries must have consecutive indexes")


class _Bounds:
    """The in-memory index of a stored log: the compaction point and the term of every
    entry after it (bounded by compaction, not by the log's history)."""

    def __init__(self, base: int = 0, base_term: int = 0, terms: list[int] | None = None) -> None:
        self.base, self.base_term = base, base_term
        self.terms = terms or []  # entry base + 1 + k has term terms[k]

    def first(self) -> int:
        return self.base + 1

    def last(self) -> int:
        return self.base + len(self.terms)

    def term(self, index: int) -> int:
        if index == self.base:
            return self.base_term
        if index < self.base:
            raise Compacted(f"storage: entry {index} is compacted (log starts at {self.base + 1})")
        if index > self.last():
            raise IndexError(f"storage: no entry {index} (last {self.last()})")
        return self.terms[index - self.base - 1]

    def check_range(self, lo: int, hi: int) -> None:
        if lo <= self.base:
            raise Compacted(f"storage: entries from {lo} are compacted (log starts at {self.base + 1})")
        if hi > self.last() + 1 or lo > hi:
            raise IndexError(f"storage: entries [{lo}, {hi}) out of range (last {self.last()})")

    def check_snapshot(self, index: int, current: Snapshot) -> None:
        if index < current.index:
            raise ValueError(f"storage: snapshot at {index} is older than the stored one at {current.index}")
        if not self.base <= index <= self.last():
            raise IndexError(f"storage: snapshot index {index} outside the log ({self.base}, {self.last()}]")

    def check_compact(self, index: int) -> None:
        if not self.base < index <= self.last():
            raise IndexError(f"storage: compact to {index} outside the log ({self.base}, {self.last()}]")


class MemoryStorage:
    """In-memory storage (the simulator's disk)."""

    def __init__(self) -> None:
        self._hs = HardState()
        self._snap = Snapshot()
        self._b = _Bounds()
        self._log: list[Entry] = []  # entry i at position i - base - 1

    def initial_state(self) -> HardState:
        return self._hs

    def first_index(self) -> int:
        return self._b.first()

    def last_index(self) -> int:
        return self._b.last()

    def term(self, index: int) -> int:
        return self._b.term(index)

    def entries(self, lo: int, hi: int) -> list[Entry]:
        self._b.check_range(lo, hi)
        return self._log[lo - self._b.base - 1 : hi - self._b.base - 1]

    def conf_entries(self) -> list[Entry]:
        """The configuration-change entries after the snapshot, in order (a restarting node's
        membership: the snapshot's configuration, then these)."""
        return [e for e in self._log if e.kind == EntryKind.CONF_CHANGE]

    def snapshot(self) -> Snapshot:
        return self._snap

    def save(
        self, hard_state: HardState | None, entries: Sequence[Entry], snapshot: Snapshot | None = None
    ) -> None:
        if snapshot is not None:
            if snapshot.index <= self._snap.index:
                raise ValueError(f"storage: snapshot {snapshot.index} is not newer than {self._snap.index}")
            self._snap = snapshot
            self._b = _Bounds(snapshot.index, snapshot.term)
            self._log = []
        b = self._b
        _check_contiguous(entries, b.base, b.last())
        if entries:
            cut = entries[0].index - b.base - 1
            del self._log[cut:]
            del b.terms[cut:]
            self._log.extend(entries)
            b.terms.extend(e.term for e in entries)
        if hard_state is not None:
            self._hs = hard_state

    def create_snapshot(
        self, index: int, data: bytes, compact_to: int | None = None, conf: ConfState | None = None
    ) -> Snapshot:
        """Record the state machine at ``index`` (applied there by the host) and the cluster's
        configuration there (``conf``: `RaftNode.conf_state_at(index)`; None: the bootstrap
        one); with ``compact_to``, drop the entries up to it in the same step."""
        self._b.check_snapshot(index, self._snap)
        self._snap = _snapshot(index, self._b.term(index), data, conf)
        if compact_to is not None:
            self.compact(compact_to)
        return self._snap

    def compact(self, index: int) -> None:
        """Drop the entries up to ``index`` (the host keeps it at or below its snapshot)."""
        b = self._b
        b.check_compact(index)
        term = b.term(index)
        cut = index - b.base
        del self._log[:cut]
        del b.terms[:cut]
        b.base, b.base_term = index, term


class SQLiteStorage:
    """Durable storage in one SQLite file (WAL, synchronous=FULL): a process killed with
    SIGKILL after ``save``, ``create_snapshot`` or ``compact`` returned restarts with that
    term, vote, snapshot and log. Tables: ``hard_state``, ``entries`` (after the compaction
    point only), ``snapshot`` (one row: index, term, data, voters and learners as JSON),
    ``log_start`` (one row: the compaction point's index and term). Memory holds the hard
    state, the snapshot and one term per stored entry (no entry before the compaction point).
    ``check_same_thread=False`` lets a host call it from more than one thread (one at a time:
    e.g. ``save`` in a worker thread so that an event loop does not wait on the disk);
    ``synchronous`` "OFF" is for benchmarks only (a power loss may lose what was saved)."""

    def __init__(
        self, path: str | Path, *, check_same_thread: bool = True, synchronous: str = "FULL"
    ) -> None:
        if synchronous not in ("FULL", "NORMAL", "OFF"):
            raise ValueError(f"SQLiteStorage: synchronous must be FULL, NORMAL or OFF, not {synchronous!r}")
        self.path = Path(path)
        self._db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=check_same_thread)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute(f"PRAGMA synchronous={synchronous}")
        for ddl in (
            "hard_state (id INTEGER PRIMARY KEY CHECK (id = 1), term INTEGER NOT NULL, vote INTEGER, "
            "commit_index INTEGER NOT NULL)",
            "entries (idx INTEGER PRIMARY KEY, term INTEGER NOT NULL, kind TEXT NOT NULL, "
            "data BLOB NOT NULL)",
            "snapshot (id INTEGER PRIMARY KEY CHECK (id = 1), idx INTEGER NOT NULL, term INTEGER NOT NULL, "
            "data BLOB NOT NULL, voters TEXT NOT NULL, learners TEXT NOT NULL)",
            "log_start (id INTEGER PRIMARY KEY CHECK (id = 1), idx INTEGER NOT NULL, term INTEGER NOT NULL)",
        ):
            self._db.execute(f"CREATE TABLE IF NOT EXISTS {ddl}")
        row = self._db.execute("SELECT term, vote, commit_index FROM hard_state").fetchone()
        self._hs = HardState(*row) if row else HardState()
        row = self._db.execute("SELECT idx, term, data, voters, learners FROM snapshot").fetchone()
        self._snap = (
            Snapshot(row[0], row[1], bytes(row[2]), tuple(json.loads(row[3])), tuple(json.loads(row[4])))
            if row
            else Snapshot()
        )
        base, base_term = self._db.execute("SELECT idx, term FROM log_start").fetchone() or (0, 0)
        rows = self._db.execute("SELECT term FROM entries WHERE idx > ? ORDER BY idx", (base,))
        terms = [t for (t,) in rows]
        self._b = _Bounds(base, base_term, terms)

    def close(self) -> None:
        self._db.close()

    def initial_state(self) -> HardState:
        return self._hs

    def first_index(self) -> int:
        return self._b.first()

    def last_index(self) -> int:
        return self._b.last()

    def term(self, index: int) -> int:
        return self._b.term(index)

    def entries(self, lo: int, hi: int) -> list[Entry]:
        self._b.check_range(lo, hi)
        rows = self._db.execute(
            "SELECT term, idx, data, kind FROM entries WHERE idx >= ? AND idx < ? ORDER BY idx", (lo, hi)
        )
        return [Entry(t, i, bytes(d), EntryKind(k)) for t, i, d, k in rows]

    def conf_entries(self) -> list[Entry]:
        """The configuration-change entries after the snapshot, in order (a restarting node's
        membership: the snapshot's configuration, then these)."""
        rows = self._db.execute(
            "SELECT term, idx, data, kind FROM entries WHERE kind = ? ORDER BY idx",
            (EntryKind.CONF_CHANGE.value,),
        )
        return [Entry(t, i, bytes(d), EntryKind(k)) for t, i, d, k in rows]

    def snapshot(self) -> Snapshot:
        return self._snap

    def _transaction(self, work) -> None:  # noqa: ANN001 (a callable taking the connection)
        db = self._db
        db.execute("BEGIN IMMEDIATE")
        try:
            work(db)
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise

    @staticmethod
    def _write_snapshot(db: sqlite3.Connection, s: Snapshot) -> None:
        db.execute(
            "INSERT OR REPLACE INTO snapshot (id, idx, term, data, voters, learners) "
            "VALUES (1, ?, ?, ?, ?, ?)",
            (s.index, s.term, s.data, json.dumps(list(s.voters)), json.dumps(list(s.learners))),
        )

    @staticmethod
    def _write_start(db: sqlite3.Connection, index: int, term: int) -> None:
        db.execute("DELETE FROM entries WHERE idx <= ?", (index,))
        db.execute("INSERT OR REPLACE INTO log_start (id, idx, term) VALUES (1, ?, ?)", (index, term))

    def save(
        self, hard_state: HardState | None, entries: Sequence[Entry], snapshot: Snapshot | None = None
    ) -> None:
        if snapshot is not None and snapshot.index <= self._snap.index:
            raise ValueError(f"storage: snapshot {snapshot.index} is not newer than {self._snap.index}")
        b = _Bounds(snapshot.index, snapshot.term) if snapshot is not None else self._b
        _check_contiguous(entries, b.base, b.last())
        if not entries and hard_state is None and snapshot is None:
            return

        def work(db: sqlite3.Connection) -> None:
            if snapshot is not None:
                db.execute("DELETE FROM entries")
                self._write_snapshot(db, snapshot)
                self._write_start(db, snapshot.index, snapshot.term)
            if entries:
                db.execute("DELETE FROM entries WHERE idx >= ?", (entries[0].index,))
                db.executemany(
                    "INSERT INTO entries (idx, term, kind, data) VALUES (?, ?, ?, ?)",
                    [(e.index, e.term, e.kind.value, e.data) for e in entries],
                )
            if hard_state is not None:
                db.execute(
                    "INSERT OR REPLACE INTO hard_state (id, term, vote, commit_index) VALUES (1, ?, ?, ?)",
                    (hard_state.term, hard_state.vote, hard_state.commit),
                )

        self._transaction(work)
        if snapshot is not None:
            self._snap, self._b = snapshot, b
        if entries:
            del b.terms[entries[0].index - b.base - 1 :]
            b.terms.extend(e.term for e in entries)
        if hard_state is not None:
            self._hs = hard_state

    def create_snapshot(
        self, index: int, data: bytes, compact_to: int | None = None, conf: ConfState | None = None
    ) -> Snapshot:
        """As `MemoryStorage.create_snapshot`, in one transaction."""
        b = self._b
        b.check_snapshot(index, self._snap)
        if compact_to is not None:
            b.check_compact(compact_to)
        snap = _snapshot(index, b.term(index), data, conf)
        start = (compact_to, b.term(compact_to)) if compact_to is not None else None

        def work(db: sqlite3.Connection) -> None:
            self._write_snapshot(db, snap)
            if start is not None:
                self._write_start(db, *start)

        self._transaction(work)
        self._snap = snap
        if start is not None:
            self._drop_terms(*start)
        return snap

    def compact(self, index: int) -> None:
        self._b.check_compact(index)
        start = (index, self._b.term(index))
        self._transaction(lambda db: self._write_start(db, *start))
        self._drop_terms(*start)

    def _drop_terms(self, index: int, term: int) -> None:
        b = self._b
        del b.terms[: index - b.base]
        b.base, b.base_term = index, term

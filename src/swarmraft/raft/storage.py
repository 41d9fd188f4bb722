"""Raft stable storage: hard state (term, vote, commit) and the log.

The host writes to storage (``save``) when it handles a `Ready`; the node only reads it.
`MemoryStorage` survives a simulated crash (it plays the disk); `SQLiteStorage` survives a
real one: WAL journal, synchronous writes, one transaction per `save`.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

from swarmraft.raft.types import Entry, EntryKind, HardState


class Storage(Protocol):
    def initial_state(self) -> HardState: ...
    def last_index(self) -> int: ...
    def term(self, index: int) -> int: ...
    def entries(self, lo: int, hi: int) -> list[Entry]: ...
    def save(self, hard_state: HardState | None, entries: Sequence[Entry]) -> None: ...
    def conf_entries(self) -> list[Entry]: ...


def _check_contiguous(entries: Sequence[Entry], last: int) -> None:
    if not entries:
        return
    first = entries[0].index
    if first < 1 or first > last + 1:
        raise ValueError(f"storage: entries start at {first}, the log ends at {last}")
    for a, b in zip(entries, entries[1:], strict=False):
        if b.index != a.index + 1:
            raise ValueError("storage: entries must have consecutive indexes")


class MemoryStorage:
    """In-memory storage (the simulator's disk)."""

    def __init__(self) -> None:
        self._hs = HardState()
        self._log: list[Entry] = []  # entry i at position i - 1

    def initial_state(self) -> HardState:
        return self._hs

    def last_index(self) -> int:
        return len(self._log)

    def term(self, index: int) -> int:
        if index == 0:
            return 0
        if not 1 <= index <= len(self._log):
            raise IndexError(f"storage: no entry {index} (last {len(self._log)})")
        return self._log[index - 1].term

    def entries(self, lo: int, hi: int) -> list[Entry]:
        if lo < 1 or hi > len(self._log) + 1 or lo > hi:
            raise IndexError(f"storage: entries [{lo}, {hi}) out of range (last {len(self._log)})")
        return self._log[lo - 1 : hi - 1]

    def conf_entries(self) -> list[Entry]:
        """The configuration-change entries, in order (a restarting node's membership)."""
        return [e for e in self._log if e.kind == EntryKind.CONF_CHANGE]

    def save(self, hard_state: HardState | None, entries: Sequence[Entry]) -> None:
        _check_contiguous(entries, len(self._log))
        if entries:
            del self._log[entries[0].index - 1 :]
            self._log.extend(entries)
        if hard_state is not None:
            self._hs = hard_state


class SQLiteStorage:
    """Durable storage in one SQLite file (WAL, synchronous=FULL): a process killed with
    SIGKILL after ``save`` returned restarts with that term, vote and log.
    ``check_same_thread=False`` lets a host call it from more than one thread (one at a time:
    e.g. ``save`` in a worker thread so that an event loop does not wait on the disk)."""

    def __init__(self, path: str | Path, *, check_same_thread: bool = True) -> None:
        self.path = Path(path)
        self._db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=check_same_thread)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS hard_state (id INTEGER PRIMARY KEY CHECK (id = 1), "
            "term INTEGER NOT NULL, vote INTEGER, commit_index INTEGER NOT NULL)"
        )
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS entries (idx INTEGER PRIMARY KEY, term INTEGER NOT NULL, "
            "kind TEXT NOT NULL, data BLOB NOT NULL)"
        )
        row = self._db.execute("SELECT term, vote, commit_index FROM hard_state").fetchone()
        self._hs = HardState(*row) if row else HardState()
        self._terms = [t for (t,) in self._db.execute("SELECT term FROM entries ORDER BY idx")]

    def close(self) -> None:
        self._db.close()

    def initial_state(self) -> HardState:
        return self._hs

    def last_index(self) -> int:
        return len(self._terms)

    def term(self, index: int) -> int:
        if index == 0:
            return 0
        if not 1 <= index <= len(self._terms):
            raise IndexError(f"storage: no entry {index} (last {len(self._terms)})")
        return self._terms[index - 1]

    def entries(self, lo: int, hi: int) -> list[Entry]:
        if lo < 1 or hi > len(self._terms) + 1 or lo > hi:
            raise IndexError(f"storage: entries [{lo}, {hi}) out of range (last {len(self._terms)})")
        rows = self._db.execute(
            "SELECT term, idx, data, kind FROM entries WHERE idx >= ? AND idx < ? ORDER BY idx", (lo, hi)
        )
        return [Entry(t, i, bytes(d), EntryKind(k)) for t, i, d, k in rows]

    def conf_entries(self) -> list[Entry]:
        """The configuration-change entries, in order (a restarting node's membership)."""
        rows = self._db.execute(
            "SELECT term, idx, data, kind FROM entries WHERE kind = ? ORDER BY idx",
            (EntryKind.CONF_CHANGE.value,),
        )
        return [Entry(t, i, bytes(d), EntryKind(k)) for t, i, d, k in rows]

    def save(self, hard_state: HardState | None, entries: Sequence[Entry]) -> None:
        _check_contiguous(entries, len(self._terms))
        if not entries and hard_state is None:
            return
        db = self._db
        db.execute("BEGIN IMMEDIATE")
        try:
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
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        if entries:
            del self._terms[entries[0].index - 1 :]
            self._terms.extend(e.term for e in entries)
        if hard_state is not None:
            self._hs = hard_state

"""When a host snapshots its state machine and how much log it keeps (`SnapshotPolicy`), and
an encoding of a list of entries for hosts whose state machine is the applied log itself
(the simulator's default `Cluster`).

The host calls ``policy.plan(applied, snapshot_index, first_index)`` after applying entries:
None, or the index to snapshot (the applied index) and the index to compact the log to (a
margin of ``keep`` entries below it stays, so a follower a little behind catches up with
appends, not a whole snapshot: etcd's SnapshotCatchUpEntries).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

from swarmraft.raft.types import Entry, EntryKind


@dataclass(frozen=True)
class SnapshotPolicy:
    """Snapshot every ``every`` applied entries (0: never) and keep ``keep`` entries below
    the snapshot."""

    every: int = 0
    keep: int = 0

    def __post_init__(self) -> None:
        if self.every < 0:
            raise ValueError("SnapshotPolicy: every must be >= 0")
        if self.keep < 0:
            raise ValueError("SnapshotPolicy: keep must be >= 0")

    def plan(self, applied: int, snapshot_index: int, first_index: int) -> tuple[int, int | None] | None:
        """(snapshot index, compact-to index or None) if a snapshot is due, else None."""
        if not self.every or applied - snapshot_index < self.every:
            return None
        compact_to = applied - self.keep
        return applied, compact_to if compact_to >= first_index else None


_COUNT = struct.Struct("<I")
_ENTRY = struct.Struct("<QQBI")  # term, index, kind (0 normal, 1 no-op, 2 conf change), data length
_KINDS = (EntryKind.NORMAL, EntryKind.NOOP, EntryKind.CONF_CHANGE)


def pack_entries(entries: Sequence[Entry]) -> bytes:
    """Entries as bytes: a u32 count, then per entry term, index, kind, length and data."""
    out = [_COUNT.pack(len(entries))]
    for e in entries:
        out.append(_ENTRY.pack(e.term, e.index, _KINDS.index(e.kind), len(e.data)))
        out.append(e.data)
    return b"".join(out)


def unpack_entries(data: bytes) -> list[Entry]:
    """The inverse of `pack_entries`; ValueError if ``data`` is not such bytes."""
    try:
        (count,) = _COUNT.unpack_from(data)
        off, out = _COUNT.size, []
        for _ in range(count):
            term, index, kind, size = _ENTRY.unpack_from(data, off)
            off += _ENTRY.size
            if off + size > len(data):
                raise ValueError("unpack_entries: entry data runs past the end")
            out.append(Entry(term, index, bytes(data[off : off + size]), _KINDS[kind]))
            off += size
    except (struct.error, IndexError) as exc:
        raise ValueError(f"unpack_entries: malformed entries: {exc}") from exc
    if off != len(data):
        raise ValueError(f"unpack_entries: {len(data) - off} bytes after the last entry")
    return out

"""The leader's view of one follower (`Progress`) and its window of appends in flight
(`Inflights`), after etcd-io/raft's tracker package.

A follower is probed (``probe``: one append at a time, ``paused`` until it is answered) until
it acknowledges an index; a follower that needs entries the leader has compacted gets the
leader's snapshot instead (``pending_snapshot``: nothing more is sent until it acknowledges
that index, or answers a heartbeat, when it is probed again); then appends are pipelined
(replicate state) up to a window of
``max_inflight_msgs`` messages and ``max_inflight_bytes`` bytes not yet acknowledged. A
rejection sends it back to probing. Rejections and acknowledgements that answer an append the
leader has moved past are stale and change nothing.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass


class Inflights:
    """Appends sent in the replicate state and not yet acknowledged, oldest first: the last
    index each carried and its payload bytes."""

    def __init__(self, max_msgs: int, max_bytes: int) -> None:
        self.max_msgs, self.max_bytes = max_msgs, max_bytes
        self._sent: deque[tuple[int, int]] = deque()
        self.bytes = 0

    def __len__(self) -> int:
        return len(self._sent)

    def full(self) -> bool:
        return len(self._sent) >= self.max_msgs or self.bytes >= self.max_bytes

    def add(self, last_index: int, size: int) -> None:
        self._sent.append((last_index, size))
        self.bytes += size

    def free_le(self, index: int) -> None:
        """Forget the appends an acknowledgement of ``index`` covers."""
        while self._sent and self._sent[0][0] <= index:
            self.bytes -= self._sent.popleft()[1]

    def free_first(self) -> None:
        """Forget the oldest append (its answer may be lost: a heartbeat's answer makes room
        for one more so a full window cannot stall the follower for good)."""
        if self._sent:
            self.bytes -= self._sent.popleft()[1]

    def reset(self) -> None:
        self._sent.clear()
        self.bytes = 0


@dataclass
class Progress:
    """The leader's view of one follower: the highest index it is known to hold (``match``),
    the next to send (``next``), its state (``probe``, ``paused`` while a probe is
    unanswered, else replicate with ``inflights``), whether it answered in the current
    check-quorum period (``recent_active``, one election timeout) and in the last one
    (``responsive``), and for heartbeats the ticks since the leader last sent it anything
    (``silent``) and whether that was an append in the replicate state (``flowing``)."""

    inflights: Inflights
    match: int = 0
    next: int = 1
    probe: bool = True
    paused: bool = False
    recent_active: bool = False
    responsive: bool = True
    silent: int = 0
    flowing: bool = False
    pending_snapshot: int = 0  # the index of the snapshot sent, while it is unacknowledged

    def become_probe(self) -> None:
        self.probe, self.paused, self.pending_snapshot = True, False, 0
        self.next = self.match + 1
        self.inflights.reset()

    def become_replicate(self) -> None:
        self.probe, self.paused, self.pending_snapshot = False, False, 0
        self.next = self.match + 1
        self.inflights.reset()

    def become_snapshot(self, index: int) -> None:
        self.probe, self.paused, self.pending_snapshot = True, True, index
        self.next = index + 1
        self.inflights.reset()

    def can_send(self) -> bool:
        if self.pending_snapshot:
            return False
        return not self.paused if self.probe else not self.inflights.full()

    def maybe_update(self, index: int) -> bool:
        """An acknowledgement of ``index``: whether it raised ``match``."""
        updated = index > self.match
        if updated:
            self.match = index
            self.paused = False
        self.next = max(self.next, index + 1)
        return updated

    def maybe_decrease(self, rejected: int, hint: int) -> bool:
        """A rejection of the append whose previous entry was ``rejected``, the follower
        suggesting ``hint`` as the next index to try. False if it is stale (etcd's
        maybeDecrTo): in the replicate state an index at or below ``match`` (the follower has
        since acknowledged more); when probing, any index but the one last probed."""
        if not self.probe:
            if rejected <= self.match:
                return False
            self.become_probe()
            return True
        if rejected != self.next - 1:
            return False
        self.next = max(self.match + 1, min(hint, rejected))
        self.paused = False
        return True

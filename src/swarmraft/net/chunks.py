"""Reassembly of Raft messages sent in pieces (`wire.Chunk`): a MsgSnap carrying a drone's
state is larger than one datagram once a swarm has more than a few drones.

Each piece is a datagram signed on its own, so a message put together here is as authentic
as any other. A receiver keeps, per sender, the pieces of that sender's newest message only:
a piece of a newer message discards the older one's (its sender moved on; Raft resends what
still matters), a piece of an older message is ignored. Memory is therefore bounded by one
message of at most `wire.MAX_MESSAGE` bytes per sender. A lost piece loses the message:
the leader sends its snapshot again when the follower's next answer shows it still behind
(`raft.progress`, ``pending_snapshot``).
"""

from __future__ import annotations

from swarmraft.net.wire import Chunk


class Reassembler:
    """The pieces received so far of each sender's newest message."""

    def __init__(self) -> None:
        self._open: dict[int, tuple[Chunk, dict[int, bytes]]] = {}

    def add(self, sender: int, piece: Chunk) -> bytes | None:
        """Take a piece; the whole message's bytes once its last missing piece arrives,
        else None. A piece whose header disagrees with the first piece of the same message
        (count or length) is ignored."""
        held = self._open.get(sender)
        if held is not None and piece.message < held[0].message:
            return None
        if held is None or piece.message > held[0].message:
            held = self._open[sender] = (piece, {})
        first, got = held
        if (piece.count, piece.length) != (first.count, first.length):
            return None
        got[piece.index] = piece.data
        if len(got) < first.count:
            return None
        del self._open[sender]
        return b"".join(got[i] for i in range(first.count))

    def held_bytes(self) -> int:
        """Bytes of pieces held (for status and tests of the bound)."""
        return sum(len(d) for _, got in self._open.values() for d in got.values())

"""Test helpers: Raft nodes wired together synchronously, as etcd-io/raft's paper tests do."""

from __future__ import annotations

import random
from collections.abc import Iterable

from swarmraft.raft import Entry, HardState, MemoryStorage, Message, MsgType, RaftConfig, RaftNode


def storage_with(terms: Iterable[int] = (), hard: HardState | None = None) -> MemoryStorage:
    """A storage holding entries with the given terms at indexes 1, 2, ..."""
    s = MemoryStorage()
    s.save(hard, [Entry(t, i + 1, f"e{i + 1}".encode()) for i, t in enumerate(terms)])
    return s


def make_node(
    nid: int,
    peers: Iterable[int],
    storage: MemoryStorage | None = None,
    *,
    election: int = 10,
    heartbeat: int = 1,
    pre_vote: bool = False,
    check_quorum: bool = False,
    seed: int = 0,
    **options: int,
) -> RaftNode:
    """A node with 10-tick election timeouts and 1-tick heartbeats; ``options`` are further
    `RaftConfig` fields (flow control limits)."""
    cfg = RaftConfig(
        id=nid,
        peers=tuple(p for p in peers if p != nid),
        election_tick=election,
        heartbeat_tick=heartbeat,
        pre_vote=pre_vote,
        check_quorum=check_quorum,
        **options,
    )
    return RaftNode(cfg, storage or MemoryStorage(), random.Random(seed + nid))


def flush(node: RaftNode) -> list[Message]:
    """Handle the node's Ready (persist, collect messages, apply, advance); repeat."""
    out: list[Message] = []
    while (rd := node.ready()) is not None:
        node.log.storage.save(rd.hard_state, rd.entries)
        out.extend(rd.messages)
        node.advance(rd)
    return out


def msgs_of(node: RaftNode, kind: MsgType | None = None) -> list[Message]:
    return [m for m in flush(node) if kind is None or m.type == kind]


class Net:
    """Delivers messages among nodes until quiet; ``drop`` holds (from, to) pairs cut."""

    def __init__(self, *nodes: RaftNode) -> None:
        self.nodes = {n.id: n for n in nodes}
        self.drop: set[tuple[int, int]] = set()

    def send(self, *msgs: Message) -> None:
        queue = list(msgs)
        for n in self.nodes.values():
            queue += flush(n)
        while queue:
            m = queue.pop(0)
            node = self.nodes.get(m.to)
            if node is None or (m.frm, m.to) in self.drop:
                continue
            node.step(m)
            queue += flush(node)

    def campaign(self, nid: int) -> None:
        self.nodes[nid].campaign()
        self.send()

    def propose(self, nid: int, data: bytes) -> None:
        self.nodes[nid].propose(data)
        self.send()

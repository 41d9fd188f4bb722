"""Raft safety invariants, checked by the simulator after every event.

Logs are compared through chain hashes: h[i] = hash(h[i-1], term_i, kind_i, data_i), so two
logs agree on every entry up to i exactly when their h[i] agree. Each event changes one node,
and only the part of its log written since the last check (`RaftLog.take_dirty`) is hashed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from swarmraft.raft import Entry, RaftNode, Role


class InvariantViolation(AssertionError):
    """A Raft safety property failed; the message names it, the seed and the time."""


@dataclass
class _NodeTrack:
    chain: list[int] = field(default_factory=lambda: [0])  # chain[i] for i = 0..last
    commit: int = 0
    leader_term: int | None = None
    leader_last: int = 0


def _chain_extend(chain: list[int], entries: list[Entry]) -> None:
    for e in entries:
        chain.append(hash((chain[-1], e.term, e.kind, e.data)))


@dataclass
class InvariantChecker:
    seed: int
    leaders: dict[int, int] = field(default_factory=dict)  # term -> leader id
    by_index_term: dict[tuple[int, int], int] = field(default_factory=dict)  # -> chain hash
    committed: list[int] = field(default_factory=lambda: [0])  # chain hash at committed index
    applied: dict[int, Entry] = field(default_factory=dict)
    hard: dict[int, tuple[int, int | None]] = field(default_factory=dict)  # persisted term, vote
    nodes: dict[int, _NodeTrack] = field(default_factory=dict)
    checks: int = 0

    def fail(self, now: float, what: str) -> None:
        raise InvariantViolation(f"seed {self.seed}, t = {now:.1f} ms: {what}")

    def restarted(self, node_id: int) -> None:
        """Forget a node's volatile tracking; its log is rehashed from index 1 next check."""
        self.nodes.pop(node_id, None)

    def check(self, now: float, node: RaftNode, hard_term: int, hard_vote: int | None) -> None:
        self.checks += 1
        nid = node.id
        track = self.nodes.get(nid)
        fresh = track is None
        if fresh:
            track = self.nodes[nid] = _NodeTrack(commit=0)
            node.log.take_dirty()
            dirty: int | None = 1
        else:
            dirty = node.log.take_dirty()
        last = node.log.last_index()

        # A leader never overwrites or deletes its own entries.
        if node.role == Role.LEADER and track.leader_term == node.term and dirty is not None:
            if dirty <= track.leader_last:
                self.fail(now, f"leader {nid} of term {node.term} rewrote its log from index {dirty}")

        # Log matching: entries with the same index and term have identical prefixes.
        if dirty is not None:
            del track.chain[dirty:]
            start = len(track.chain)
            _chain_extend(track.chain, node.log.slice(start, last + 1))
            for i in range(start, last + 1):
                key = (i, node.log.term(i) or 0)
                seen = self.by_index_term.setdefault(key, track.chain[i])
                if seen != track.chain[i]:
                    self.fail(
                        now,
                        f"log matching: node {nid} differs from another log before index {i} (term {key[1]})",
                    )

        # Election safety, and leader completeness on taking office.
        if node.role == Role.LEADER:
            other = self.leaders.setdefault(node.term, nid)
            if other != nid:
                self.fail(now, f"two leaders in term {node.term}: {other} and {nid}")
            if track.leader_term != node.term:
                c = len(self.committed) - 1
                if last < c or track.chain[c] != self.committed[c]:
                    self.fail(
                        now,
                        f"leader completeness: leader {nid} of term {node.term} lacks "
                        f"committed entries up to {c}",
                    )
                track.leader_term = node.term
            track.leader_last = last
        else:
            track.leader_term = None

        # Committed entries never change and are never lost.
        commit = node.log.committed
        if commit > last:
            self.fail(now, f"node {nid} commit {commit} beyond its last index {last}")
        if commit > track.commit or fresh:
            for i in range(track.commit + 1 if not fresh else 1, commit + 1):
                if i < len(self.committed):
                    if self.committed[i] != track.chain[i]:
                        self.fail(now, f"committed entry {i} differs on node {nid}")
                else:
                    self.committed.append(track.chain[i])
            track.commit = commit

        # Term and vote never go backwards, across restarts too.
        prev = self.hard.get(nid)
        if prev is not None:
            pt, pv = prev
            if hard_term < pt:
                self.fail(now, f"node {nid} persisted term went back from {pt} to {hard_term}")
            if hard_term == pt and pv is not None and hard_vote != pv:
                self.fail(now, f"node {nid} changed its vote in term {pt} from {pv} to {hard_vote}")
        self.hard[nid] = (hard_term, hard_vote)

    def applied_entry(self, now: float, node_id: int, entry: Entry) -> None:
        """State-machine safety: no two nodes apply different entries at one index."""
        seen = self.applied.setdefault(entry.index, entry)
        if seen != entry:
            self.fail(now, f"node {node_id} applied {entry} at index {entry.index}, another applied {seen}")

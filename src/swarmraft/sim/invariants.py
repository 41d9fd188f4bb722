"""Raft safety invariants, checked by the simulator after every event (liveness, which needs
the whole run, is checked by `sim.fuzz`).

Logs are compared through chain hashes: h[i] = hash(h[i-1], term_i, kind_i, data_i), so two
logs agree on every entry up to i exactly when their h[i] agree. Each event changes one node,
and only the part of its log written since the last check (`RaftLog.take_dirty`) is hashed.
A log that starts after a compaction point (a snapshot) takes the committed chain up to it:
what a snapshot covers must be committed, with the committed entry's term at its index.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from swarmraft.raft import Entry, HardState, Message, MsgType, RaftNode, Role, Snapshot, Storage

#: The invariants by name (``InvariantViolation.invariant``; ``raft-fuzz --without NAME``).
INVARIANTS = (
    "election-safety",  # at most one leader per term
    "leader-append-only",  # a leader never overwrites or deletes its own entries
    "log-matching",  # same index and term: same prefix
    "term-entries-kept",  # no node drops an entry of its current term
    "leader-completeness",  # a new leader holds every committed entry
    "commit-beyond-log",  # a node never commits past its last entry
    "committed-unchanged",  # a committed entry never changes, on any node
    "commit-monotonic",  # a node's commit index never goes back, across restarts too
    "leader-commit-rule",  # a leader moves its commit index only onto an entry of its own term
    "durable-term-vote",  # a persisted term never goes back; one persisted vote per term
    "durable-before-send",  # a granted vote, an acknowledged entry: on disk before the answer leaves
    "read-linearizable",  # a ReadIndex answer covers every commit made before the read began
    "transfer-caught-up",  # MsgTimeoutNow goes only to a node holding the leader's whole log
    "conf-change-rule",  # a leader appends a configuration change only with the previous one
    # committed and an entry of its own term committed (single-server changes, thesis 4.1)
    "state-machine-safety",  # every node applies the same entry at each index (no two nodes apply
    # different entries at one index), each index once, in order
    "snapshot-committed",  # a snapshot or a compacted log covers only committed entries, with their terms
)


class InvariantViolation(AssertionError):
    """A Raft safety property failed; the message names it, the seed and the time, and
    ``invariant`` is its name in `INVARIANTS`."""

    def __init__(self, message: str, invariant: str = "") -> None:
        super().__init__(message)
        self.invariant = invariant


@dataclass
class _NodeTrack:
    chain: list[int] = field(default_factory=lambda: [0])  # chain[i] for i = 0..last
    terms: list[int] = field(default_factory=lambda: [0])  # the term of entry i
    commit: int = 0  # highest commit index seen in this incarnation
    leader_term: int | None = None
    leader_last: int = 0


def _chain_extend(track: _NodeTrack, entries: list[Entry]) -> None:
    chain = track.chain
    for e in entries:
        chain.append(hash((chain[-1], e.term, e.kind, e.data)))
        track.terms.append(e.term)


@dataclass
class InvariantChecker:
    seed: int
    leaders: dict[int, int] = field(default_factory=dict)  # term -> leader id
    by_index_term: dict[tuple[int, int], int] = field(default_factory=dict)  # -> chain hash
    committed: list[int] = field(default_factory=lambda: [0])  # chain hash at committed index
    # the lowest term of a node seen holding each index committed: the term it was committed in
    # (its leader learns first); a leader of term L must hold those committed before L
    committed_term: list[int] = field(default_factory=lambda: [0])
    applied: dict[int, int] = field(default_factory=dict)  # index -> hash of the entry applied there
    node_applied: dict[int, int] = field(default_factory=dict)  # node -> its state machine's index
    hard: dict[int, HardState] = field(default_factory=dict)  # last persisted hard state seen
    nodes: dict[int, _NodeTrack] = field(default_factory=dict)
    checks: int = 0
    without: frozenset[str] = frozenset()  # invariants not checked (to test the checker itself)

    def fail(self, now: float, invariant: str, what: str) -> None:
        if invariant not in self.without:
            raise InvariantViolation(f"seed {self.seed}, t = {now:.1f} ms: {invariant}: {what}", invariant)

    def restarted(self, node_id: int) -> None:
        """Forget a node's volatile tracking; its log is rehashed from index 1 next check, and
        its state machine starts empty (until a snapshot is restored)."""
        self.nodes.pop(node_id, None)
        self.node_applied[node_id] = 0

    def check(self, now: float, node: RaftNode, hard: HardState) -> None:
        """Check node's state after an event; ``hard`` is what its storage holds."""
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
                self.fail(
                    now,
                    "leader-append-only",
                    f"leader {nid} of term {node.term} rewrote its log from index {dirty}",
                )

        # Log matching: entries with the same index and term have identical prefixes.
        if dirty is not None:
            first = node.log.first_index()
            # Only the leader of a term writes entries of that term and it never takes one back,
            # so no node drops an entry of its current term (a snapshot holds what it covers).
            for i in range(max(dirty, first - 1), len(track.terms) if not fresh else 0):
                if track.terms[i] == node.term and (i > last or node.log.term(i) != node.term):
                    self.fail(
                        now,
                        "term-entries-kept",
                        f"node {nid} dropped entry {i} of its current term {node.term}",
                    )
                    break
            del track.chain[dirty:]
            del track.terms[dirty:]
            start = len(track.chain)
            if start < first:
                self._compacted_prefix(now, nid, node, track, start, first - 1)
            _chain_extend(track, node.log.slice(max(start, first), last + 1))
            for i in range(max(start, first), last + 1):
                key = (i, node.log.term(i) or 0)
                seen = self.by_index_term.setdefault(key, track.chain[i])
                if seen != track.chain[i]:
                    self.fail(
                        now,
                        "log-matching",
                        f"node {nid} differs from another log before index {i} (term {key[1]})",
                    )

        # Election safety, and leader completeness on taking office.
        if node.role == Role.LEADER:
            other = self.leaders.setdefault(node.term, nid)
            if other != nid:
                self.fail(now, "election-safety", f"two leaders in term {node.term}: {other} and {nid}")
            if track.leader_term != node.term:
                c = len(self.committed) - 1
                while c > 0 and self.committed_term[c] >= node.term:
                    c -= 1  # committed in this term or later: not a new leader's to hold
                if last < c or track.chain[c] != self.committed[c]:
                    self.fail(
                        now,
                        "leader-completeness",
                        f"leader {nid} of term {node.term} lacks committed entries up to {c}",
                    )
                track.leader_term = node.term
            if dirty is not None and node.confs.last_index >= max(dirty, track.leader_last + 1):
                self._check_conf_rule(now, node, max(dirty, track.leader_last + 1))
            track.leader_last = last
        else:
            track.leader_term = None

        # Committed entries never change and are never lost; a commit index never goes back.
        commit = node.log.committed
        if commit > last:
            self.fail(now, "commit-beyond-log", f"node {nid} commit {commit} beyond its last index {last}")
        if (
            commit > track.commit
            and not fresh
            and node.role == Role.LEADER
            and node.log.term(commit) != node.term
        ):
            self.fail(
                now,
                "leader-commit-rule",
                f"leader {nid} of term {node.term} moved its commit index to {commit}, an entry of term "
                f"{node.log.term(commit)}",
            )
        if commit < track.commit and not fresh:
            self.fail(
                now, "commit-monotonic", f"node {nid} commit index went back from {track.commit} to {commit}"
            )
        if commit > track.commit or fresh:
            for i in range(track.commit + 1 if not fresh else 1, commit + 1):
                if i < len(self.committed):
                    if self.committed[i] != track.chain[i]:
                        self.fail(now, "committed-unchanged", f"committed entry {i} differs on node {nid}")
                    self.committed_term[i] = min(self.committed_term[i], node.term)
                else:
                    self.committed.append(track.chain[i])
                    self.committed_term.append(node.term)
            track.commit = commit

        # Term, vote and commit index on disk never go backwards, across restarts too.
        prev = self.hard.get(nid)
        if prev is not None:
            if hard.term < prev.term:
                self.fail(
                    now,
                    "durable-term-vote",
                    f"node {nid} persisted term went back from {prev.term} to {hard.term}",
                )
            if hard.term == prev.term and prev.vote is not None and hard.vote != prev.vote:
                self.fail(
                    now,
                    "durable-term-vote",
                    f"node {nid} changed its vote in term {prev.term} from {prev.vote} to {hard.vote}",
                )
            if hard.commit < prev.commit:
                self.fail(
                    now,
                    "commit-monotonic",
                    f"node {nid} persisted commit index went back from {prev.commit} to {hard.commit}",
                )
        self.hard[nid] = hard

    def _check_conf_rule(self, now: float, node: RaftNode, first_new: int) -> None:
        """The leader appended entries from ``first_new`` on, configuration changes among them:
        each needs the configuration entry before it committed, and an entry of the leader's
        term committed (one change at a time; Ongaro's fix to single-server changes)."""
        changes = [i for i, _, _ in node.confs.changes]
        commit = node.log.committed
        for k, i in enumerate(changes):
            if i < first_new:
                continue
            prev = changes[k - 1] if k > 0 else node.confs.base_index
            if prev > commit:
                self.fail(
                    now,
                    "conf-change-rule",
                    f"leader {node.id} appended a configuration change at {i} while the one at {prev} "
                    f"is not committed (commit {commit})",
                )
            if node.log.term(commit) != node.term:
                self.fail(
                    now,
                    "conf-change-rule",
                    f"leader {node.id} of term {node.term} appended a configuration change at {i} before "
                    f"committing an entry of its term (commit {commit}, of term {node.log.term(commit)})",
                )

    def _compacted_prefix(
        self, now: float, nid: int, node: RaftNode, track: _NodeTrack, start: int, base: int
    ) -> None:
        """Entries start..base of node's log are in its snapshot: they take the committed
        chain, after checking that base is committed and its term is the committed entry's."""
        known = len(self.committed) - 1
        if base > known:
            self.fail(
                now,
                "snapshot-committed",
                f"node {nid}'s log starts after index {base}, beyond the highest committed index {known}",
            )
        term = node.log.term(base) or 0
        if base <= known and self.by_index_term.get((base, term)) != self.committed[base]:
            self.fail(
                now,
                "snapshot-committed",
                f"node {nid}'s snapshot at index {base} has term {term}, not the committed entry's",
            )
        for i in range(start, base + 1):
            track.chain.append(self.committed[i] if i <= known else 0)
            track.terms.append(term if i == base else -1)

    def snapshot_restored(
        self, now: float, node_id: int, snap: Snapshot, entries: list[Entry] | None
    ) -> None:
        """Node ``node_id``'s state machine was restored from ``snap``: it jumps to its index
        (never back); with ``entries`` (a state machine that is the applied log), each must be
        the entry applied at its index."""
        before = self.node_applied.get(node_id, 0)
        if snap.index < before:
            self.fail(
                now,
                "state-machine-safety",
                f"node {node_id} restored a snapshot at {snap.index} over a state machine at {before}",
            )
        if entries is not None:
            if [e.index for e in entries] != list(range(1, len(entries) + 1)) or len(entries) != snap.index:
                self.fail(
                    now,
                    "state-machine-safety",
                    f"node {node_id}'s snapshot at {snap.index} holds {len(entries)} entries, "
                    f"not 1..{snap.index}",
                )
            for e in entries:
                self._same_as_applied(now, node_id, e)
        self.node_applied[node_id] = snap.index

    def _same_as_applied(self, now: float, node_id: int, entry: Entry) -> None:
        h = hash((entry.term, entry.kind, entry.data))
        if self.applied.setdefault(entry.index, h) != h:
            self.fail(
                now,
                "state-machine-safety",
                f"node {node_id} applied {entry} at index {entry.index}, another node applied another entry",
            )

    def sending(self, now: float, m: Message, storage: Storage) -> None:
        """Durable before sent: a granted vote is on disk (that term, that candidate) before the
        answer leaves, and so is every entry an append answer acknowledges."""
        if m.reject:
            return
        if m.type == MsgType.VOTE_RESP:
            hs = storage.initial_state()
            if hs.term != m.term or hs.vote != m.to:
                self.fail(
                    now,
                    "durable-before-send",
                    f"node {m.frm} grants its vote to {m.to} in term {m.term} with term {hs.term} and "
                    f"vote {hs.vote} on disk",
                )
        elif m.type == MsgType.APP_RESP and m.index > storage.last_index():
            self.fail(
                now,
                "durable-before-send",
                f"node {m.frm} acknowledges index {m.index} with {storage.last_index()} entries on disk",
            )

    def read_answered(self, now: float, node_id: int, ctx: int, index: int, floor: int, applied: int) -> None:
        """Linearizable reads: the read index of an answer is at least the highest index any
        node had committed when the read was asked (``floor``), and the answering node has
        applied up to it."""
        if index < floor:
            self.fail(
                now,
                "read-linearizable",
                f"node {node_id} answered read {ctx} at index {index}, but index {floor} was committed "
                "before the read began",
            )
        if applied < index:
            self.fail(
                now,
                "read-linearizable",
                f"node {node_id} answered read {ctx} at index {index} having applied only {applied}",
            )

    def timeout_now(self, now: float, m: Message, target: Storage) -> None:
        """A leader transfer's MsgTimeoutNow goes only to a node that holds (on disk) the
        leader's last entry (``m.index``, ``m.log_term``): one that does not would start an
        election it cannot win while the leader refuses proposals."""
        if target.initial_state().term > m.term:
            return  # the target moved on to a later term: the message is stale and ignored
        last = target.last_index()
        if m.index > last or target.term(m.index) != m.log_term:
            self.fail(
                now,
                "transfer-caught-up",
                f"leader {m.frm} sent MsgTimeoutNow to node {m.to}, whose log ends at {last}, before it "
                f"held the leader's last entry {m.index} (term {m.log_term})",
            )

    def applied_entry(self, now: float, node_id: int, entry: Entry) -> None:
        """State-machine safety: no two nodes apply different entries at one index, and each
        node applies every index once, in order, after its snapshot's."""
        at = self.node_applied.get(node_id, 0)
        if entry.index != at + 1:
            self.fail(
                now,
                "state-machine-safety",
                f"node {node_id} applied entry {entry.index} after its state machine reached {at}",
            )
        self.node_applied[node_id] = entry.index
        self._same_as_applied(now, node_id, entry)

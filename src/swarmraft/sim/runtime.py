"""A deterministic discrete-event runtime for Raft nodes, and `Cluster`, the scenario API.

One event queue ordered by (virtual time in ms, insertion sequence): the same seed and the
same calls give the same run, event for event. Every ``tick_ms`` one event ticks each live
node in id order (election timeouts are randomised per node, so lockstep ticks do not
synchronise elections), messages cross the `Network` model, a crash drops the node's volatile state
(its storage, the "disk", survives) and a restart rebuilds the node from storage. After
every event the `InvariantChecker` verifies Raft's safety properties.

Snapshots: with a `SnapshotPolicy` each node snapshots its state machine every ``every``
applied entries and compacts its log (keeping ``keep`` entries); a restarted node restores
the snapshot and applies the tail only. The state machine is the list of applied entries
(`applied`) unless the host brings its own (``app_snapshot`` and ``app_restore``: then the
Cluster keeps no applied entries, so a long run stays bounded).

Example::

    from swarmraft.sim import Cluster

    c = Cluster(5, seed=1)
    c.run_until(lambda: c.leader() is not None, timeout_ms=2000)
    c.propose(b"hello")
    c.crash(c.leader())
    c.run(1000)
    assert all(c.applied(i) == [b"hello"] for i in c.alive_ids())
"""

from __future__ import annotations

import heapq
import random
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from functools import partial
from typing import Any

from swarmraft.raft import (
    ConfChange,
    ConfState,
    Entry,
    EntryKind,
    MemoryStorage,
    Message,
    MsgType,
    NotLeader,
    ProposalDropped,
    RaftConfig,
    RaftNode,
    Ready,
    Snapshot,
    SnapshotPolicy,
    Status,
    Storage,
    pack_entries,
    unpack_entries,
)
from swarmraft.sim.invariants import InvariantChecker
from swarmraft.sim.network import LinkModel, Network

# answers that promise something the sender must have saved first
_PROMISES = frozenset({MsgType.VOTE_RESP, MsgType.APP_RESP})


class EventLoop:
    """Virtual clock and event queue with deterministic tie-breaks (insertion order)."""

    def __init__(self) -> None:
        self.now = 0.0
        self._queue: list[tuple[float, int, Callable[..., None], tuple[Any, ...]]] = []
        self._seq = 0
        self.events = 0

    def at(self, time: float, action: Callable[..., None], *args: Any) -> None:
        self._seq += 1
        heapq.heappush(self._queue, (time, self._seq, action, args))

    def after(self, delay: float, action: Callable[..., None], *args: Any) -> None:
        self._seq += 1
        heapq.heappush(self._queue, (self.now + delay, self._seq, action, args))

    def step(self) -> bool:
        if not self._queue:
            return False
        self.now, _, action, args = heapq.heappop(self._queue)
        self.events += 1
        action(*args)
        return True

    def next_time(self) -> float | None:
        return self._queue[0][0] if self._queue else None


class Cluster:
    """n Raft nodes (ids 1..n) in the simulator.

    ``tick_ms`` 10 with ``election_tick`` 15 and ``heartbeat_tick`` 5 gives 150-300 ms
    election timeouts and 50 ms heartbeats (the Raft paper; docs/protocol.md); the default network
    has 1-3 ms one-way delay and no loss. ``raft_options`` sets further `RaftConfig` fields on
    every node (flow control limits, ``max_entries_per_msg``); ``without`` names invariants not
    checked. ``snapshots``: when nodes snapshot and compact (None: never); ``app_snapshot(i)``
    and ``app_restore(i, snapshot)``: the host's state machine of node i (its encoding at the
    node's applied index, and its restoration); ``storage``: node i's storage (a
    `MemoryStorage` when None); ``validate(node, entry)``: every node's validator of new
    entries, ``validate_snapshot(node, snapshot)`` of a leader's snapshot (`RaftNode`).
    """

    def __init__(
        self,
        n: int,
        seed: int = 0,
        tick_ms: float = 10.0,
        election_tick: int = 15,
        heartbeat_tick: int = 5,
        network: Network | LinkModel | None = None,
        pre_vote: bool = True,
        check_quorum: bool = True,
        check_invariants: bool = True,
        on_apply: Callable[[int, Entry], None] | None = None,
        raft_options: Mapping[str, Any] | None = None,
        without: frozenset[str] = frozenset(),
        snapshots: SnapshotPolicy | None = None,
        app_snapshot: Callable[[int], bytes] | None = None,
        app_restore: Callable[[int, Snapshot], None] | None = None,
        storage: Callable[[int], Storage] | None = None,
        validate: Callable[[int, Entry], bool] | None = None,
        validate_snapshot: Callable[[int, Snapshot], bool] | None = None,
    ) -> None:
        if n < 1:
            raise ValueError("Cluster: n must be >= 1")
        if tick_ms <= 0:
            raise ValueError("Cluster: tick_ms must be > 0")
        self.n, self.seed, self.tick_ms = n, seed, tick_ms
        self.ids = tuple(range(1, n + 1))
        self.network = network if isinstance(network, Network) else Network(network or LinkModel())
        self.loop = EventLoop()
        self.rng = random.Random(seed)
        self._raft_kw: dict[str, Any] = dict(
            election_tick=election_tick,
            heartbeat_tick=heartbeat_tick,
            pre_vote=pre_vote,
            check_quorum=check_quorum,
            **(raft_options or {}),
        )
        self.configs = {
            i: RaftConfig(id=i, peers=tuple(p for p in self.ids if p != i), **self._raft_kw) for i in self.ids
        }
        self._boot = self.ids  # the bootstrap voters
        self._reads: dict[int, tuple[float, int]] = {}  # ctx -> (asked at, highest commit then)
        self.read_states: dict[int, tuple[int, int, float]] = {}  # ctx -> (node, index, answered at)
        if (app_snapshot is None) != (app_restore is None):
            raise ValueError("Cluster: give both app_snapshot and app_restore, or neither")
        self.snapshots = snapshots or SnapshotPolicy()
        self.app_snapshot, self.app_restore = app_snapshot, app_restore
        self.snapshots_taken = 0
        self.snapshots_installed = 0  # by followers, from a leader's MsgSnap
        self.storage: dict[int, Storage] = {i: storage(i) if storage else MemoryStorage() for i in self.ids}
        self.nodes: dict[int, RaftNode | None] = {}
        self._incarnation = dict.fromkeys(self.ids, 0)
        self._applied: dict[int, list[Entry]] = {i: [] for i in self.ids}
        self._held: dict[int, list[Callable[[], None]]] = {}  # paused node -> deliveries waiting
        self.checker = InvariantChecker(seed, without=without) if check_invariants else None
        self._armed: dict[int, tuple[str, frozenset[str] | None, float | None]] = {}  # crash_in_ready
        self.sent: Counter[str] = Counter()
        self.app_sent = 0
        self.refused = 0  # proposals a leader refused (ProposalDropped)
        self.delivered: Counter[str] = Counter()
        self.on_apply = on_apply
        self.validate = validate
        self.validate_snapshot = validate_snapshot
        for i in self.ids:
            self._start(i)
        self.loop.after(tick_ms, self._tick_all)

    # -- node lifecycle -------------------------------------------------------------------
    def _start(self, i: int) -> None:
        self._incarnation[i] += 1
        node_rng = random.Random(self.seed * 1_000_003 + i * 10_007 + self._incarnation[i])
        check = partial(self.validate, i) if self.validate is not None else None
        check_snap = partial(self.validate_snapshot, i) if self.validate_snapshot is not None else None
        self.nodes[i] = RaftNode(
            self.configs[i], self.storage[i], node_rng, validate=check, validate_snapshot=check_snap
        )
        self._applied[i] = []  # the state machine is volatile: restored from the snapshot, then re-applied
        if self.checker:
            self.checker.restarted(i)
        snap = self.storage[i].snapshot()
        if snap.index:
            self._restore(i, snap)
        self._process(i)

    def _restore(self, i: int, snap: Snapshot) -> None:
        """Node i's state machine from a snapshot (its own on restart, or a leader's)."""
        if self.app_restore is not None:
            self.app_restore(i, snap)
            entries = None
        else:
            entries = self._applied[i] = unpack_entries(snap.data)
        if self.checker:
            self.checker.snapshot_restored(self.loop.now, i, snap, entries)

    def _maybe_snapshot(self, i: int, node: RaftNode) -> None:
        st = self.storage[i]
        plan = self.snapshots.plan(node.log.applied, st.snapshot().index, st.first_index())
        if plan is None:
            return
        index, compact_to = plan
        data = self.app_snapshot(i) if self.app_snapshot is not None else pack_entries(self._applied[i])
        st.create_snapshot(index, data, compact_to, node.conf_state_at(index))
        self.snapshots_taken += 1

    def _tick_all(self) -> None:
        """One clock tick for every live node, in id order (one event, not n)."""
        for i in self.ids:
            node = self.nodes.get(i)
            if node is not None and i not in self._held:
                node.tick()
                if node.has_ready():
                    self._process(i)
        self.loop.after(self.tick_ms, self._tick_all)

    def _deliver(self, m: Message) -> None:
        node = self.nodes.get(m.to)
        if node is None:
            return
        if m.to in self._held:
            self._held[m.to].append(lambda: self._deliver(m))
            return
        self.delivered[m.type] += 1
        node.step(m)
        self._process(m.to)

    def _process(self, i: int) -> None:
        """Handle every Ready: persist, then send, then apply, then advance."""
        node = self.nodes[i]
        assert node is not None
        changed = False
        while node.has_ready():
            rd = node._ready()
            if rd.hard_state is not None or rd.entries or rd.committed:
                changed = True
                self.storage[i].save(rd.hard_state, rd.entries, rd.snapshot)
            if self._armed and self._crash_point(i, rd, "persisted"):
                return
            for m in rd.messages:
                if self.checker and m.type in _PROMISES:
                    self.checker.sending(self.loop.now, m, self.storage[i])
                elif self.checker and m.type == MsgType.TIMEOUT_NOW:
                    self.checker.timeout_now(self.loop.now, m, self.storage[m.to])
                self.sent[m.type] += 1  # StrEnum: counts are looked up by "MsgApp" too
                for d in self.network.delays(self.rng, m.frm, m.to):
                    self.loop.after(d, self._deliver, m)
            if self._armed and self._crash_point(i, rd, "sent"):
                return
            if rd.snapshot is not None:
                self.snapshots_installed += 1
                self._restore(i, rd.snapshot)
            keep = self.app_snapshot is None
            for e in rd.committed:
                if keep:
                    self._applied[i].append(e)
                if self.checker:
                    self.checker.applied_entry(self.loop.now, i, e)
                if self.on_apply:
                    self.on_apply(i, e)
            for rs in rd.read_states:
                self._read_answered(i, node, rs.index, rs.ctx)
            node.advance(rd)
            if rd.committed and self.snapshots.every:
                self._maybe_snapshot(i, node)
        # Without state in a Ready nothing persistent changed (at most a leader stepped
        # down, or messages went out), so there is nothing new for the invariants to see.
        if self.checker and (changed or i not in self.checker.nodes):
            self.checker.check(self.loop.now, node, self.storage[i].initial_state())

    # -- running --------------------------------------------------------------------------
    @property
    def now(self) -> float:
        return self.loop.now

    def run(self, ms: float) -> None:
        """Advance virtual time by ``ms``."""
        end = self.loop.now + ms
        while (t := self.loop.next_time()) is not None and t <= end:
            self.loop.step()
        self.loop.now = end

    def run_until(self, predicate: Callable[[], bool], timeout_ms: float) -> bool:
        """Run until ``predicate()`` holds (checked after every event) or the timeout;
        returns whether it held."""
        end = self.loop.now + timeout_ms
        if predicate():
            return True
        while (t := self.loop.next_time()) is not None and t <= end:
            self.loop.step()
            if predicate():
                return True
        self.loop.now = end
        return False

    # -- membership, transfer, reads ------------------------------------------------------
    def add_node(self) -> int:
        """Start a new node (id: one above the highest) that knows the bootstrap voters and is
        not a member: it takes part once a leader adds it (``propose_conf_change`` with
        ``ConfChange(ConfChangeType.ADD_LEARNER, id)``) and it receives the log. Returns its id."""
        k = max(self.ids) + 1
        self.ids = (*self.ids, k)
        self.n = len(self.ids)
        self.configs[k] = RaftConfig(
            id=k, peers=tuple(p for p in self.ids if p != k), voters=self._boot, **self._raft_kw
        )
        self.storage[k] = MemoryStorage()
        self._incarnation[k] = 0
        self._applied[k] = []
        self._start(k)
        return k

    def conf_state(self, i: int) -> ConfState:
        """Node i's configuration (from its storage if it is down)."""
        self._check_id(i)
        node = self.nodes.get(i)
        if node is not None:
            return node.conf_state
        return RaftNode(self.configs[i], self.storage[i], random.Random(0)).conf_state

    def propose_conf_change(self, cc: ConfChange, via: int | None = None) -> int:
        """Propose a configuration change at the leader (or node ``via``); returns its index.
        Raises as `RaftNode.propose_conf_change` does (`NotLeader` if there is no leader)."""
        target = self.leader() if via is None else via
        node = self.nodes.get(target) if target is not None else None
        if node is None:
            raise NotLeader(target or 0, None)
        index = node.propose_conf_change(cc)
        self._process(target)  # type: ignore[arg-type]
        return index

    def transfer_leader(self, to: int) -> None:
        """The current leader hands over to ``to`` (`RaftNode.transfer_leader`)."""
        self._check_id(to)
        lead = self.leader()
        if lead is None:
            raise NotLeader(0, None)
        self.nodes[lead].transfer_leader(to)  # type: ignore[union-attr]
        self._process(lead)

    def read_index(self, via: int) -> int | None:
        """A linearizable read at node ``via``; returns its ctx (the answer appears in
        ``read_states[ctx]``: node, read index, time), or None if ``via`` is down or knows no
        leader. The invariant checker verifies the answer covers every commit made before."""
        self._check_id(via)
        node = self.nodes.get(via)
        if node is None or via in self._held:
            return None
        ctx = len(self._reads) + 1
        try:
            node.read_index(ctx)
        except NotLeader:
            return None
        self._reads[ctx] = (self.loop.now, len(self.checker.committed) - 1 if self.checker else 0)
        self._process(via)
        return ctx

    def _read_answered(self, i: int, node: RaftNode, index: int, ctx: int) -> None:
        asked = self._reads.get(ctx)
        if asked is None or ctx in self.read_states:
            return
        self.read_states[ctx] = (i, index, self.loop.now)
        if self.checker:
            self.checker.read_answered(self.loop.now, i, ctx, index, asked[1], node.log.applied)

    # -- faults ---------------------------------------------------------------------------
    def _check_id(self, i: int) -> None:
        if i not in self.configs:
            raise ValueError(f"no node {i}; ids are 1..{self.n}")

    def crash(self, i: int) -> None:
        """Stop node i: its volatile state is lost, its storage keeps what was persisted."""
        self._check_id(i)
        self.nodes[i] = None
        self._held.pop(i, None)
        self._armed.pop(i, None)

    def crash_in_ready(
        self, i: int, point: str, on: Iterable[str] | None = None, restart_ms: float | None = None
    ) -> None:
        """Crash node i in the middle of handling its next `Ready` that sends a message (of a
        type in ``on``, e.g. ``{"MsgVoteResp"}``; any type if None): ``point`` "persisted"
        crashes after that Ready is saved and before its messages leave, "sent" after they
        leave and before anything later is saved. With ``restart_ms`` the node restarts that
        long after (0: as the next event). Replaces an earlier arming of node i; `disarm`
        cancels it."""
        self._check_id(i)
        if point not in ("persisted", "sent"):
            raise ValueError('crash_in_ready: point must be "persisted" or "sent"')
        self._armed[i] = (point, frozenset(on) if on is not None else None, restart_ms)

    def disarm(self) -> None:
        """Cancel every pending `crash_in_ready`."""
        self._armed.clear()

    def _crash_point(self, i: int, rd: Ready, point: str) -> bool:
        """Crash node i here if it is armed for this point and this Ready; returns whether it did."""
        arm = self._armed.get(i)
        if arm is None or arm[0] != point or not rd.messages:
            return False
        if arm[1] is not None and not any(m.type in arm[1] for m in rd.messages):
            return False
        node = self.nodes[i]
        if self.checker and node is not None:  # what it saved is checked before it goes
            self.checker.check(self.loop.now, node, self.storage[i].initial_state())
        self.crash(i)
        if arm[2] is not None:
            self.loop.after(arm[2], self._restart_if_down, i, self._incarnation[i])
        return True

    def _restart_if_down(self, i: int, incarnation: int) -> None:
        if self.nodes.get(i) is None and self._incarnation[i] == incarnation:
            self._start(i)

    def pause(self, i: int, ms: float) -> None:
        """Freeze node i for ``ms`` (a SIGSTOPped process): it keeps its state but gets no
        ticks, and what is delivered to it waits, to be handled in arrival order when it
        resumes (as a socket buffer holds datagrams). Its missed ticks are not replayed.
        Pausing a crashed or paused node does nothing."""
        self._check_id(i)
        if ms <= 0:
            raise ValueError("pause: ms must be > 0")
        if self.nodes.get(i) is None or i in self._held:
            return
        self._held[i] = held = []
        self.loop.after(ms, self._resume, i, held)

    def _resume(self, i: int, held: list[Callable[[], None]]) -> None:
        if self._held.get(i) is not held:  # crashed meanwhile (and perhaps paused again)
            return
        del self._held[i]
        for deliver in held:
            deliver()

    def paused(self, i: int) -> bool:
        self._check_id(i)
        return i in self._held

    def restart(self, i: int) -> None:
        """Restart a crashed node from its storage."""
        self._check_id(i)
        if self.nodes.get(i) is not None:
            raise ValueError(f"node {i} is running; crash it first")
        self._start(i)

    def alive(self, i: int) -> bool:
        self._check_id(i)
        return self.nodes.get(i) is not None

    def alive_ids(self) -> list[int]:
        return [i for i in self.ids if self.nodes.get(i) is not None]

    def partition(self, *groups: Iterable[int]) -> None:
        """Split the network: nodes talk only within their group; nodes in no group are
        isolated."""
        gs = [frozenset(g) for g in groups]
        for g in gs:
            for i in g:
                self._check_id(i)
        self.network.groups = gs

    def isolate(self, i: int) -> None:
        self._check_id(i)
        self.partition([i], [p for p in self.ids if p != i])

    def cut(self, a: int, b: int) -> None:
        """Drop every message from a to b (one way)."""
        self._check_id(a), self._check_id(b)
        self.network.cuts.add((a, b))

    def heal(self) -> None:
        """Remove partitions and cuts (link loss and delay settings stay)."""
        self.network.groups = []
        self.network.cuts.clear()

    def set_link(self, a: int, b: int, **changes: Any) -> None:
        """Change both directions of link a-b: loss=, delay_ms=(lo, hi), duplicate=, reorder=."""
        self._check_id(a), self._check_id(b)
        if "delay_ms" in changes and isinstance(changes["delay_ms"], int | float):
            changes["delay_ms"] = (float(changes["delay_ms"]), float(changes["delay_ms"]))
        self.network.set_link(a, b, **changes)

    def set_loss(self, p: float) -> None:
        """Loss probability p on every link."""
        self.network.set_all(loss=p)

    # -- application messages -------------------------------------------------------------
    def send_app(
        self,
        frm: int,
        to: int,
        handler: Callable[[int, Any], None],
        payload: Any,
        rng: random.Random | None = None,
    ) -> None:
        """Send an application message (e.g. a drone's report) over the same network model;
        ``handler(to, payload)`` runs on delivery if node ``to`` is up. ``rng``: another
        generator for this message's loss and delay (traffic that must not shift the draws of
        the rest of the run, e.g. the report fan-out; not counted in ``app_sent``)."""
        if rng is None:
            self.app_sent += 1
        for d in self.network.delays(rng or self.rng, frm, to):
            self.loop.after(d, self._deliver_app, to, handler, payload)

    def _deliver_app(self, to: int, handler: Callable[[int, Any], None], payload: Any) -> None:
        if to in self._held:
            self._held[to].append(lambda: self._deliver_app(to, handler, payload))
        elif self.nodes.get(to) is not None:
            handler(to, payload)

    # -- client side ----------------------------------------------------------------------
    def propose_batch(self, datas: list[bytes], via: int | None = None) -> bool:
        """Propose several entries in one `MsgProp` (one append for the leader to send, as a
        client batching its writes); ``via`` and the result as in `propose`."""
        target = self.leader() if via is None else via
        if target is None or not datas:
            return False
        self._check_id(target)
        node = self.nodes.get(target)
        if node is None:
            return False
        was_leader = node.role == "leader"
        node.step(Message(MsgType.PROP, target, target, 0, entries=tuple(Entry(0, 0, d) for d in datas)))
        self._process(target)
        return was_leader

    def propose(self, data: bytes, via: int | None = None) -> bool:
        """Propose ``data``. With ``via`` None, at the current leader; otherwise at node
        ``via`` (a follower forwards it to the leader it knows). Returns True if a leader
        accepted it into its log now (a forwarded proposal returns False: it is in flight; a
        refused one, beyond the leader's cap on uncommitted bytes, returns False and is counted
        in ``refused``)."""
        target = self.leader() if via is None else via
        if target is None:
            return False
        self._check_id(target)
        node = self.nodes.get(target)
        if node is None:
            return False
        try:
            index = node.propose(data)
        except NotLeader:
            return False
        except ProposalDropped:
            self.refused += 1
            return False
        self._process(target)
        return index is not None

    def campaign(self, i: int, force: bool = False) -> None:
        """Node i starts an election now (`RaftNode.campaign`), if it is up and not paused."""
        node = self.nodes.get(i)
        if node is None or i in self._held:
            return
        node.campaign(force)
        self._process(i)

    def depose(self, i: int, leader: int | None, term: int | None = None) -> None:
        """Node i found ``leader`` faulty (`RaftNode.depose`), if it is up and not paused."""
        node = self.nodes.get(i)
        if node is None or i in self._held:
            return
        node.depose(leader, term)
        self._process(i)

    def leader(self) -> int | None:
        """The live, running (not paused) leader of the highest term, or None."""
        best = None
        for i in self.alive_ids():
            if i in self._held:
                continue
            node = self.nodes[i]
            assert node is not None
            if node.role == "leader" and (best is None or node.term > self.nodes[best].term):  # type: ignore[union-attr]
                best = i
        return best

    def status(self, i: int) -> Status:
        self._check_id(i)
        node = self.nodes.get(i)
        if node is None:
            raise ValueError(f"node {i} is crashed")
        return node.status

    def log(self, i: int) -> list[Entry]:
        """Node i's log (persisted and unstable), from its first entry held (1 unless it was
        compacted)."""
        self._check_id(i)
        node = self.nodes.get(i)
        if node is None:
            st = self.storage[i]
            return st.entries(st.first_index(), st.last_index() + 1)
        return node.log.slice(node.log.first_index(), node.log.last_index() + 1)

    def last_index(self, i: int) -> int:
        """Node i's last log index (its storage's, if it is down)."""
        self._check_id(i)
        node = self.nodes.get(i)
        return node.log.last_index() if node is not None else self.storage[i].last_index()

    def applied(self, i: int) -> list[bytes]:
        """Payloads node i applied, in order, without the leaders' no-op entries (its
        snapshot's included). Not kept when the host brings its own state machine."""
        self._check_id(i)
        if self.app_snapshot is not None:
            raise ValueError("Cluster.applied: the host's state machine holds what was applied")
        return [e.data for e in self._applied[i] if e.kind != EntryKind.NOOP]

    @property
    def messages(self) -> Counter[str]:
        """Messages sent, by type name ("MsgApp", "MsgVote", ...)."""
        return Counter({k.value if hasattr(k, "value") else k: v for k, v in self.sent.items()})

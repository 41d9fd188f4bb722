"""Randomised fault runs that try to break Raft: crashes (some mid-Ready, some restarted at
once), partitions, one-way cuts, loss, duplication and deep reordering, on 3-7 nodes with
PreVote and CheckQuorum drawn per seed, appends of 1-4 entries and, in some seeds, logs of
thousands of entries, and snapshots with log compaction every few entries (so crashed and
lagging followers catch up by InstallSnapshot). In a fraction of the seeds
(``FuzzConfig.membership``) membership moves too: nodes join as learners, learners are
promoted, voters (the leader too) and learners are removed, leadership is transferred, and
linearizable reads are asked at any node. Every safety invariant is checked after every event;
once the faults stop, liveness (a leader within two election timeouts, then no term change) and
convergence (every committed entry on every member) are checked.

A run is fully determined by its seed: a failing seed replays exactly
(``swarmraft raft-fuzz --seed-start S --seeds 1``).
"""

from __future__ import annotations

import random
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from swarmraft.raft import (
    ConfChange,
    ConfChangeRefused,
    ConfChangeType,
    NotLeader,
    RaftSafetyError,
    SnapshotPolicy,
)
from swarmraft.sim.invariants import InvariantViolation
from swarmraft.sim.network import LinkModel
from swarmraft.sim.runtime import Cluster

# what a crash mid-Ready waits for: any message, a vote answer, an append answer, an append
# (a leader that has just advanced its commit index, or taken office)
_CRASH_ON: tuple[frozenset[str] | None, ...] = (
    None,
    frozenset({"MsgVoteResp", "MsgPreVoteResp"}),
    frozenset({"MsgAppResp"}),
    frozenset({"MsgApp"}),
)


@dataclass(frozen=True)
class FuzzConfig:
    """A field left None is drawn per seed: ``nodes`` 3-7, ``loss`` 0-30 %,
    ``max_entries_per_msg`` 1-4 (64, the core's default, in one seed in five), ``pre_vote`` and
    ``check_quorum`` each on or off. Per seed, too: duplication 0-10 %, reordering of 0-30 % of
    messages by up to 20, 100 or 400 ms (deeper than an election timeout). In a fraction
    ``heavy`` of the seeds proposals come in batches of 100-500 entries until 1000-3000 are
    proposed, so followers back from a crash or a cut catch up on a long log 1-4 entries per
    append; those seeds have 3-5 nodes and no reordering (the core has no in-flight window
    yet: a leader answers every acknowledgement with another append, and reordered rejections
    of appends in flight multiply them into hundreds of thousands of messages per seed).

    Faults are drawn every ``step_ms`` for ``fault_ms`` of virtual time; then the network heals
    for good and every node restarts; liveness and convergence as in `_settle`, convergence
    within ``settle_ms``. ``without``: invariants not checked (names in
    `sim.invariants.INVARIANTS`, and "liveness"), to show what each one alone catches.

    Membership: in a fraction ``membership`` of the seeds (drawn from a generator of its own,
    so the other seeds run exactly as without it), every ``step_ms`` a membership operation
    with probability ``p_member`` (a node joins as a learner (a new one, up to 9 nodes, or one
    removed earlier), a learner is promoted, a voter (the leader in a third of the removals)
    or a learner removed, leadership transferred) and with probability ``p_read`` a
    linearizable read: at a random node, or (half the time) at every node that believes it
    leads, a deposed one too."""

    nodes: int | None = None
    fault_ms: float = 3000.0
    settle_ms: float = 30_000.0
    step_ms: float = 50.0
    loss: float | None = None
    max_entries_per_msg: int | None = None
    pre_vote: bool | None = None
    check_quorum: bool | None = None
    heavy: float = 0.1
    # the fraction of seeds whose nodes snapshot and compact: every 2-20 entries (50-500 in
    # heavy seeds), keeping up to a quarter of that many entries below the snapshot
    snapshots: float = 0.8
    p_batch: float = 0.15  # a heavy seed's batch of 100-500 entries, until it has proposed 1000-3000
    p_crash: float = 0.05
    p_bounce: float = 0.04  # crash and restart at the same instant
    p_crash_in_ready: float = 0.08  # between persisting and sending, or right after sending
    p_doomed: float = 0.03  # every node crashes the next time it sends appends
    p_partition: float = 0.04
    p_cut: float = 0.05  # one-way cuts
    p_heal: float = 0.08
    p_propose: float = 0.6
    max_events: int = 2_000_000  # a seed over this many events fails as "budget" (a message storm)
    without: frozenset[str] = frozenset()
    membership: float = 0.5
    p_member: float = 0.3
    p_read: float = 0.5
    max_nodes: int = 9


class _OverBudget(Exception):
    """A seed ran more than ``FuzzConfig.max_events`` events."""


@dataclass(frozen=True)
class FuzzResult:
    seed: int
    events: int
    proposals: int
    committed: int
    crashes: int
    partitions: int
    converged: bool
    error: str | None = None
    invariant: str | None = None  # what failed: an invariant's name, "liveness", "convergence", ...
    nodes: int = 0
    pre_vote: bool = False
    check_quorum: bool = False
    max_entries_per_msg: int = 0
    last_index: int = 0  # the longest log at the end
    conf_changes: int = 0  # configuration changes a leader accepted
    reads: int = 0  # linearizable reads answered
    snapshot_every: int = 0  # 0: no snapshots in this seed
    snapshots_installed: int = 0  # by followers, from a leader

    @property
    def ok(self) -> bool:
        return self.error is None and self.converged


def election_timeout_ms(c: Cluster) -> float:
    """The longest randomised election timeout of the cluster's nodes."""
    return 2 * c.configs[c.ids[0]].election_tick * c.tick_ms


def run_seed(seed: int, cfg: FuzzConfig | None = None) -> FuzzResult:
    """One randomised run. Violations (and any exception from the core) are caught and
    reported in ``error`` and ``invariant``."""
    cfg = cfg or FuzzConfig()
    rng = random.Random(seed * 7919 + 17)
    heavy = rng.random() < cfg.heavy
    target = rng.randint(1000, 3000) if heavy else 0  # entries to propose
    n = cfg.nodes if cfg.nodes is not None else rng.randint(3, 5 if heavy else 7)
    loss = cfg.loss if cfg.loss is not None else rng.uniform(0.0, 0.3)
    per_msg = cfg.max_entries_per_msg or (rng.randint(1, 4) if rng.random() < 0.8 else 64)
    # half the two-entry seeds send one entry per append (own generator: other draws as before)
    if not cfg.max_entries_per_msg and per_msg == 2 and random.Random(seed * 7919 + 41).random() < 0.5:
        per_msg = 1
    inflight = rng.choice((1, 2, 8)) if rng.random() < 0.5 else 256
    pre_vote = cfg.pre_vote if cfg.pre_vote is not None else rng.random() < 0.5
    check_quorum = cfg.check_quorum if cfg.check_quorum is not None else rng.random() < 0.5
    # drawn from their own generator so that the seeds' other draws stay as they were
    srng = random.Random(seed * 104_729 + 3)
    every = (srng.randint(50, 500) if heavy else srng.randint(2, 20)) if srng.random() < cfg.snapshots else 0
    policy = SnapshotPolicy(every, srng.randint(0, every // 4)) if every else None
    link = LinkModel(
        loss=loss,
        duplicate=rng.uniform(0.0, 0.1),
        reorder=rng.uniform(0.0, 0.3) * (0 if heavy else 1),
        reorder_ms=rng.choice((20.0, 100.0, 400.0)),
    )
    mrng = random.Random(seed * 7919 + 29)  # membership draws: other seeds run as before
    member = mrng.random() < cfg.membership
    committed: set[bytes] = set()
    c = Cluster(
        n,
        seed=seed,
        network=link,
        pre_vote=pre_vote,
        check_quorum=check_quorum,
        raft_options={
            "max_entries_per_msg": per_msg,
            # flow control: windows of 1 to 8 appends in half the seeds, the default otherwise
            "max_inflight_msgs": inflight,
        },
        without=cfg.without,
        snapshots=policy,
        on_apply=lambda _i, e: committed.add(e.data) if e.data else None,
    )
    stats = {"proposals": 0, "crashes": 0, "partitions": 0, "conf_changes": 0}

    def result(ok: bool, error: str | None = None, invariant: str | None = None) -> FuzzResult:
        last = max(c.last_index(i) for i in c.ids)
        return FuzzResult(
            seed,
            c.loop.events,
            stats["proposals"],
            len(committed),
            stats["crashes"],
            stats["partitions"],
            ok,
            error,
            invariant,
            n,
            pre_vote,
            check_quorum,
            per_msg,
            last,
            stats["conf_changes"],
            len(c.read_states),
            every,
            c.snapshots_installed,
        )

    try:
        _faults(c, rng, cfg, target, stats, mrng if member else None)
        return _settle(c, cfg, committed, result, liveness=pre_vote and "liveness" not in cfg.without)
    except InvariantViolation as exc:
        return result(False, str(exc), exc.invariant or "invariant")
    except _OverBudget:
        return result(
            False,
            f"seed {seed}: over {cfg.max_events} events by t = {c.now:.1f} ms (messages multiply: "
            f"{dict(c.messages)})",
            "budget",
        )
    except RaftSafetyError as exc:
        return result(False, f"the core's own check: {exc}", "core-check")
    except Exception as exc:  # a crash of the core is a failure of the seed too
        return result(False, f"{type(exc).__name__}: {exc}", "exception")


def _faults(
    c: Cluster,
    rng: random.Random,
    cfg: FuzzConfig,
    target: int,
    stats: dict[str, int],
    mrng: random.Random | None = None,
) -> None:
    """The fault phase: every ``step_ms`` at most one fault, and proposals; with ``mrng``,
    membership operations and reads too."""
    down_until: dict[int, float] = {}
    t_end = c.now + cfg.fault_ms
    while c.now < t_end:
        c.run(cfg.step_ms)
        if c.loop.events > cfg.max_events:
            raise _OverBudget
        for i in [i for i, t in down_until.items() if t <= c.now]:
            del down_until[i]
            if not c.alive(i):
                c.restart(i)
        alive = c.alive_ids()
        r = rng.random()
        for name in ("p_crash", "p_bounce", "p_crash_in_ready", "p_doomed", "p_partition", "p_cut", "p_heal"):
            p = getattr(cfg, name)
            if r < p:
                break
            r -= p
        else:
            name = ""
        if name == "p_crash" and alive:
            i = _victim(c, rng, alive)
            c.crash(i)
            # most come back within a few heartbeats; one in four stays down long enough to
            # fall thousands of entries behind in a heavy seed
            down_until[i] = c.now + (
                rng.uniform(1000, 2500) if rng.random() < 0.25 else rng.expovariate(1 / 300)
            )
            stats["crashes"] += 1
        elif name == "p_bounce" and alive:
            i = _victim(c, rng, alive)
            c.crash(i)
            c.restart(i)
            stats["crashes"] += 1
        elif name == "p_crash_in_ready" and alive:
            i = _victim(c, rng, alive)
            restart_ms = rng.choice((0.0, 0.0, rng.uniform(1, 300)))
            c.crash_in_ready(i, rng.choice(("persisted", "sent")), rng.choice(_CRASH_ON), restart_ms)
            stats["crashes"] += 1
        elif name == "p_doomed":
            # each node dies the next time it sends appends, right after saving: a leader just
            # in office with its first entry, or one that just advanced its commit index
            for i in alive:
                c.crash_in_ready(i, "persisted", {"MsgApp"}, rng.uniform(0, 300))
        elif name == "p_partition":
            ids = list(c.ids)
            rng.shuffle(ids)
            cut = rng.randrange(1, len(ids))
            lead = c.leader()
            if lead is not None and rng.random() < 0.5:  # the leader cut off in a minority
                ids.remove(lead)
                ids.insert(0, lead)
                cut = rng.randrange(1, (len(ids) + 1) // 2)
            c.partition(ids[:cut], ids[cut:])
            stats["partitions"] += 1
        elif name == "p_cut":
            for _ in range(rng.randint(1, len(c.ids))):
                a, b = rng.sample(c.ids, 2)
                c.cut(a, b)
            stats["partitions"] += 1
        elif name == "p_heal":
            c.heal()
        if target and stats["proposals"] < target and rng.random() < cfg.p_batch:
            size = min(rng.randint(100, 500), target - stats["proposals"])
            datas = [f"s{c.seed}-p{stats['proposals'] + k}".encode() for k in range(size)]
            c.propose_batch(datas, via=rng.choice([None, *c.alive_ids()]))
            stats["proposals"] += len(datas)
        elif rng.random() < cfg.p_propose:
            # a burst of several entries now and then leaves uncommitted tails longer than one
            # append when the leader goes
            size = rng.randint(2, 10) if rng.random() < 0.3 else 1
            datas = [f"s{c.seed}-p{stats['proposals'] + k}".encode() for k in range(size)]
            via = rng.choice([None, *c.alive_ids()])
            c.propose(datas[0], via=via) if size == 1 else c.propose_batch(datas, via=via)
            stats["proposals"] += size
        if mrng is not None:
            _membership(c, mrng, cfg, stats)


def _membership(c: Cluster, rng: random.Random, cfg: FuzzConfig, stats: dict[str, int]) -> None:
    """At most one membership operation and one read; refused ones (no leader, a change
    pending, a learner not caught up, ...) are part of the test."""
    if rng.random() < cfg.p_read:
        if rng.random() < 0.5:
            c.read_index(rng.choice(c.ids))
        else:  # at every node that believes it leads: a deposed leader must not answer
            for i in c.alive_ids():
                if c.nodes[i].role == "leader":  # type: ignore[union-attr]
                    c.read_index(i)
    if rng.random() < cfg.p_member:
        # now and then two at once: the second must be refused while the first is pending
        for _ in range(2 if rng.random() < 0.3 else 1):
            _member_op(c, rng, cfg, stats)


def _member_op(c: Cluster, rng: random.Random, cfg: FuzzConfig, stats: dict[str, int]) -> None:
    lead = c.leader()
    if lead is None:
        return
    conf = c.conf_state(lead)
    op = rng.choice(("add", "add", "promote", "promote", "remove", "transfer"))
    try:
        if op == "add":
            outside = [i for i in c.ids if i not in conf.members]
            if len(c.ids) < cfg.max_nodes and (not outside or rng.random() < 0.5):
                k = c.add_node()
            elif outside:
                k = rng.choice(outside)
            else:
                return
            c.propose_conf_change(ConfChange(ConfChangeType.ADD_LEARNER, k))
        elif op == "promote" and conf.learners:
            c.propose_conf_change(ConfChange(ConfChangeType.PROMOTE, rng.choice(conf.learners)))
        elif op == "remove":
            if conf.learners and rng.random() < 0.3:
                k = rng.choice(conf.learners)
            elif len(conf.voters) > 2:
                k = lead if rng.random() < 1 / 3 else rng.choice(conf.voters)
            else:
                return
            c.propose_conf_change(ConfChange(ConfChangeType.REMOVE, k))
        elif op == "transfer" and len(conf.voters) > 1:
            c.transfer_leader(rng.choice([v for v in conf.voters if v != lead]))
            return
        else:
            return
        stats["conf_changes"] += 1
    except (NotLeader, ConfChangeRefused):
        pass


def _victim(c: Cluster, rng: random.Random, alive: list[int]) -> int:
    """The node a fault hits: the leader half the time (if there is one), else any live node."""
    lead = c.leader()
    return lead if lead is not None and rng.random() < 0.5 else rng.choice(alive)


def _settle(
    c: Cluster, cfg: FuzzConfig, committed: set[bytes], result: Callable[..., FuzzResult], liveness: bool
) -> FuzzResult:
    """Faults stop: the network heals for good and every node restarts. Then liveness, with
    PreVote (without it a node whose log is too old to win may rightly start election after
    election, each of a higher term, for as long as its timeout comes first: Raft thesis
    section 9.6), and convergence.

    Liveness counts from the moment the healed network is all there is: every message sent
    before the heal has arrived (deep reordering holds some back by up to 400 ms) and a
    CheckQuorum leader has judged a whole period after the heal. From then on, within two
    of the longest election timeouts, a leader that every node follows in its term; after
    that, no node's term changes and the leader stays, until every node has applied its log
    and for one more election timeout."""
    c.heal()
    c.disarm()
    link = c.network.default
    c.network.set_all(loss=0.0, duplicate=0.0, reorder=0.0)
    for i in c.ids:
        if not c.alive(i):
            c.restart(i)
    et = election_timeout_ms(c)
    c.run(max(et / 2, link.delay_ms[1] + link.reorder_ms))
    healed = c.now

    def members() -> list[int]:
        lead = c.leader()
        return list(c.conf_state(lead).members) if lead is not None else list(c.ids)

    def top_term() -> int:
        return max(c.nodes[i].term for i in members())  # type: ignore[union-attr]

    def stable() -> bool:
        # a leader among its voters (one that appended its own removal is not: it steps down
        # once that commits), no transfer under way, every member following it in its term.
        # Its configuration need not be committed yet: on a long log caught up one entry per
        # append that can take longer than the window
        lead = c.leader()
        if lead is None:
            return False
        node = c.nodes[lead]
        assert node is not None
        if lead not in node.conf_state.voters:
            return False
        if node.lead_transferee is not None:  # a transfer from the fault phase still runs
            return False
        return all(
            (m := c.nodes[i]) is not None and m.term == node.term and m.lead == lead
            for i in node.conf_state.members
        )

    window = 2 * et if liveness else cfg.settle_ms
    if not c.run_until(stable, window):
        return result(
            False,
            f"seed {c.seed}: no leader followed by every node within {window:.0f} ms of t = {healed:.1f} ms "
            "(the network healed, every message from before delivered)",
            "liveness" if liveness else "convergence",
        )
    lead, term, elected = c.leader(), top_term(), c.now
    live = members()

    def converged() -> bool:
        if c.loop.events > cfg.max_events:
            raise _OverBudget
        leader = c.nodes[lead]  # type: ignore[index]
        last = leader.log.last_index() if leader is not None else -1
        return all((node := c.nodes[i]) is not None and node.log.applied == last for i in live)

    done = c.run_until(converged, cfg.settle_ms)
    c.run(et)  # and stays so: no election starts
    if liveness and (top_term() != term or c.leader() != lead):
        return result(
            False,
            f"seed {c.seed}: every node followed leader {lead} of term {term} at t = {elected:.1f} ms, yet "
            f"by t = {c.now:.1f} ms the term is {top_term()} and the leader {c.leader()}",
            "liveness",
        )
    first = c.applied(live[0])
    if not (done and set(first) >= committed and all(c.applied(i) == first for i in live)):
        return result(
            False,
            f"seed {c.seed}: did not converge: some committed entry is missing on a node",
            "convergence",
        )
    return result(True)


def run_seeds(
    start: int, count: int, cfg: FuzzConfig | None = None, stop_at_first: bool = False
) -> Iterator[FuzzResult]:
    """Seeds start..start+count-1 in order; with ``stop_at_first``, up to the first failing one."""
    for s in range(start, start + count):
        r = run_seed(s, cfg)
        yield r
        if stop_at_first and not r.ok:
            return

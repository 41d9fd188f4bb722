"""Randomised fault runs that try to break Raft: crashes, restarts, partitions, loss,
duplication and reordering, with every invariant checked after every event.

A run is fully determined by its seed: a failing seed replays exactly
(``swarmraft raft-fuzz --seed-start S --seeds 1``).
"""

from __future__ import annotations

import random
from dataclasses import dataclass

from swarmraft.sim.network import LinkModel
from swarmraft.sim.runtime import Cluster


@dataclass(frozen=True)
class FuzzConfig:
    """Defaults: 5 nodes, 20 % loss, 5 % duplication, 10 % reordering, faults for 3 s of
    virtual time, then up to 10 s with the faults removed to converge."""

    nodes: int = 5
    fault_ms: float = 3000.0
    settle_ms: float = 10_000.0
    step_ms: float = 50.0
    loss: float = 0.2
    duplicate: float = 0.05
    reorder: float = 0.1
    p_crash: float = 0.06
    p_restart: float = 0.15
    p_partition: float = 0.05
    p_heal: float = 0.08
    p_propose: float = 0.6


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

    @property
    def ok(self) -> bool:
        return self.error is None and self.converged


def run_seed(seed: int, cfg: FuzzConfig | None = None) -> FuzzResult:
    """One randomised run. Invariant violations are caught and reported in ``error``."""
    cfg = cfg or FuzzConfig()
    rng = random.Random(seed * 7919 + 17)
    link = LinkModel(loss=cfg.loss, duplicate=cfg.duplicate, reorder=cfg.reorder)
    committed: set[bytes] = set()
    c = Cluster(
        cfg.nodes, seed=seed, network=link, on_apply=lambda _i, e: committed.add(e.data) if e.data else None
    )
    proposals = crashes = partitions = 0
    try:
        t_end = c.now + cfg.fault_ms
        while c.now < t_end:
            c.run(cfg.step_ms)
            r = rng.random()
            alive, down = c.alive_ids(), [i for i in c.ids if not c.alive(i)]
            if r < cfg.p_crash and alive:
                c.crash(rng.choice(alive))
                crashes += 1
            elif r < cfg.p_crash + cfg.p_restart and down:
                c.restart(rng.choice(down))
            elif r < cfg.p_crash + cfg.p_restart + cfg.p_partition:
                ids = list(c.ids)
                rng.shuffle(ids)
                cut = rng.randrange(1, len(ids))
                c.partition(ids[:cut], ids[cut:])
                partitions += 1
            elif r < cfg.p_crash + cfg.p_restart + cfg.p_partition + cfg.p_heal:
                c.heal()
            if rng.random() < cfg.p_propose:
                via = rng.choice([None, *c.alive_ids()])
                if c.propose(f"s{seed}-p{proposals}".encode(), via=via):
                    pass
                proposals += 1
        # Faults stop: heal, restart everyone, no loss; everything committed must reach all.
        c.heal()
        c.set_loss(0.0)
        for i in c.ids:
            if not c.alive(i):
                c.restart(i)

        def converged() -> bool:
            first = c.applied(c.ids[0])
            return set(first) >= committed and all(c.applied(i) == first for i in c.ids)

        # a leader's no-op must commit too, so propose once more through whoever leads
        c.run_until(lambda: c.leader() is not None, cfg.settle_ms)
        ok = c.run_until(converged, cfg.settle_ms)
        return FuzzResult(
            seed,
            c.loop.events,
            proposals,
            len(committed),
            crashes,
            partitions,
            ok,
            None if ok else "did not converge: some committed entry is missing on a node",
        )
    except AssertionError as exc:
        return FuzzResult(
            seed, c.loop.events, proposals, len(committed), crashes, partitions, False, str(exc)
        )

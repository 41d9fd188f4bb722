"""The radio network model of the simulator: per-link delay, loss, duplication, reordering,
one-way cuts and partitions. All draws come from the `random.Random` passed in."""

from __future__ import annotations

import random
from dataclasses import dataclass, field, replace
from typing import Any


@dataclass(frozen=True)
class LinkModel:
    """One direction of one link. Delay uniform in ``delay_ms`` (default 1-3 ms one way);
    each copy is lost with probability ``loss``; a message is sent twice with probability
    ``duplicate``; with probability ``reorder`` a copy is held back by up to
    ``reorder_ms`` more, so later messages overtake it."""

    delay_ms: tuple[float, float] = (1.0, 3.0)
    loss: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    reorder_ms: float = 20.0

    def __post_init__(self) -> None:
        lo, hi = self.delay_ms
        if lo < 0 or hi < lo:
            raise ValueError("LinkModel: delay_ms must be (low, high) with 0 <= low <= high")
        for name in ("loss", "duplicate", "reorder"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"LinkModel: {name} must be in [0, 1]")
        if self.reorder_ms < 0:
            raise ValueError("LinkModel: reorder_ms must be >= 0")

    @classmethod
    def of(cls, config: Any) -> LinkModel:
        """The link model of a scenario's ``[network]`` (`sim.scenario.NetworkConfig`)."""
        return cls(tuple(config.delay_ms), config.loss, config.duplicate, config.reorder)

    def delays(self, rng: random.Random) -> list[float]:
        """Delivery delays of the copies that arrive (empty: lost)."""
        if not (self.loss or self.duplicate or self.reorder):  # the common, clean link
            return [rng.uniform(*self.delay_ms)]
        copies = 2 if self.duplicate and rng.random() < self.duplicate else 1
        out = []
        for _ in range(copies):
            if self.loss and rng.random() < self.loss:
                continue
            d = rng.uniform(*self.delay_ms)
            if self.reorder and rng.random() < self.reorder:
                d += rng.uniform(0, self.reorder_ms)
            out.append(d)
        return out


@dataclass
class Network:
    """Link models by direction, plus cuts and partitions."""

    default: LinkModel = field(default_factory=LinkModel)
    links: dict[tuple[int, int], LinkModel] = field(default_factory=dict)
    cuts: set[tuple[int, int]] = field(default_factory=set)  # one-way: (from, to)
    groups: list[frozenset[int]] = field(default_factory=list)  # partition, empty = none

    def link(self, a: int, b: int) -> LinkModel:
        return self.links.get((a, b), self.default)

    def set_link(self, a: int, b: int, **changes: object) -> None:
        """Change both directions of link a-b (e.g. loss=0.5, delay_ms=(5, 10))."""
        for x, y in ((a, b), (b, a)):
            self.links[(x, y)] = replace(self.link(x, y), **changes)

    def set_all(self, **changes: object) -> None:
        self.default = replace(self.default, **changes)
        for k, v in list(self.links.items()):
            self.links[k] = replace(v, **changes)

    def connected(self, a: int, b: int) -> bool:
        if (a, b) in self.cuts:
            return False
        if self.groups:
            return any(a in g and b in g for g in self.groups)
        return True

    def delays(self, rng: random.Random, a: int, b: int) -> list[float]:
        if (self.cuts or self.groups) and not self.connected(a, b):
            return []
        link = self.links.get((a, b), self.default) if self.links else self.default
        return link.delays(rng)

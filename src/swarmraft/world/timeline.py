"""Attacks and GNSS outages over time: what each drone's GNSS receiver outputs at time t.

Spoofs change a victim's GNSS fix from ``start`` to ``end`` (seconds; None = to the end):
``jump`` (a fixed offset of ``magnitude`` m in a random direction), ``drag`` (an offset
growing at ``rate`` m/s in a random horizontal direction: covert drag-off), ``area`` (every
victim reports the same point, ``magnitude`` m from the swarm centre at the start),
``collusion`` (victims report a rigid rotation of their true positions about ``pivots`` honest
drones), and ``enlarge`` (GNSS left honest). ``tamper_ranges`` makes the victims report their
own ranges consistent with the fake positions; ``enlarge`` (m, with any kind) lengthens every
range a victim takes part in by that much (distance enlargement: a delayed ranging reply).
An outage (jamming) removes the fix of its drones from ``start`` to ``end``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from swarmraft.world.attacks import random_directions, rigid_motions


@dataclass(frozen=True)
class Spoof:
    kind: Literal["jump", "drag", "area", "collusion", "enlarge"]
    drones: tuple[int, ...]  # 0-based indexes
    start: float
    end: float | None = None
    magnitude: float = 30.0
    rate: float = 0.5
    pivots: tuple[int, ...] = ()
    angle_deg: float = 45.0
    tamper_ranges: bool = False
    enlarge: float = 0.0
    same_direction: bool = False  # drag: all victims in the first one's direction (coordinated)

    def active(self, t: float) -> bool:
        return t >= self.start and (self.end is None or t < self.end)


@dataclass(frozen=True)
class Outage:
    drones: tuple[int, ...]
    start: float
    end: float | None = None

    def active(self, t: float) -> bool:
        return t >= self.start and (self.end is None or t < self.end)


@dataclass
class AttackTimeline:
    """Spoofs and outages with their random directions drawn once, up front."""

    spoofs: list[Spoof] = field(default_factory=list)
    outages: list[Outage] = field(default_factory=list)
    directions: list[np.ndarray] = field(default_factory=list)
    anchors: list[np.ndarray | None] = field(default_factory=list)
    # per collusion spoof, the seed of its rigid motion's draws (axis, angle's sign), from the
    # attack generator; the same each step, so the motion stays rigid over time
    motion_seeds: list[int | None] = field(default_factory=list)

    @classmethod
    def build(cls, rng: np.random.Generator, spoofs: list[Spoof], outages: list[Outage]) -> AttackTimeline:
        dirs = []
        for s in spoofs:
            d = random_directions(rng, len(s.drones))
            if s.kind == "drag":
                d[:, 2] = 0.0
                d /= np.linalg.norm(d, axis=1, keepdims=True)
                if s.same_direction:  # drawn as before, so other draws do not shift
                    d[:] = d[0]
            dirs.append(d)
        # a child generator per collusion (spawning draws nothing from rng: the other spoofs'
        # directions, and everything drawn from rng after this, stay as they were)
        seeds = [int(rng.spawn(1)[0].integers(2**62)) if s.kind == "collusion" else None for s in spoofs]
        return cls(list(spoofs), list(outages), dirs, [None] * len(spoofs), seeds)

    def gnss(self, t: float, truth: np.ndarray, fix: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Receiver output at time t from true positions (n, 3) and honest fixes (n, 3):
        (fix, has_fix (n,), spoofed (n,))."""
        n = truth.shape[0]
        out = fix.copy()
        spoofed = np.zeros(n, dtype=bool)
        for k, s in enumerate(self.spoofs):
            if not s.active(t):
                continue
            idx = np.array(s.drones)
            spoofed[idx] = True
            if s.kind == "jump":
                out[idx] = fix[idx] + self.directions[k] * s.magnitude
            elif s.kind == "drag":
                out[idx] = fix[idx] + self.directions[k] * s.rate * (t - s.start)
            elif s.kind == "enlarge":
                continue  # GNSS honest: only its ranges read long (`enlargement`)
            elif s.kind == "area":
                if self.anchors[k] is None:
                    self.anchors[k] = truth.mean(axis=0) + self.directions[k][0] * s.magnitude
                out[idx] = self.anchors[k]
            else:
                piv = truth[np.array(s.pivots)][None]
                if len(s.pivots) == 3:
                    a, b = piv[0, 1] - piv[0, 0], piv[0, 2] - piv[0, 0]
                    if np.linalg.norm(np.cross(a, b)) <= 1e-9 * np.linalg.norm(a) * np.linalg.norm(b):
                        ids = ", ".join(str(p + 1) for p in s.pivots)
                        raise ValueError(
                            f"collusion: pivots {ids} are collinear at t = {t:g} s: they fix no plane "
                            "to reflect in (choose pivots not on one line)"
                        )
                theta = (s.angle_deg, s.angle_deg)
                R, shift = rigid_motions(np.random.default_rng(self.motion_seeds[k]), piv, theta)
                out[idx] = truth[idx] @ R[0].T + shift[0]
        has_fix = np.ones(n, dtype=bool)
        for o in self.outages:
            if o.active(t):
                has_fix[np.array(o.drones)] = False
        return out, has_fix, spoofed

    def enlargement(self, t: float, n: int) -> np.ndarray:
        """(n,) m by which the ranges each drone takes part in read long at time t."""
        out = np.zeros(n)
        for s in self.spoofs:
            if s.active(t) and s.enlarge > 0:
                out[np.array(s.drones)] += s.enlarge
        return out

    def tampering(self, t: float) -> np.ndarray:
        """(n_spoofs) drones that tamper with their ranges at time t (indexes)."""
        ids = [d for s in self.spoofs if s.active(t) and s.tamper_ranges for d in s.drones]
        return np.array(sorted(set(ids)), dtype=int)

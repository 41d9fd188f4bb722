"""Attacks on a snapshot batch.

A position attack returns the reports (T, n, 3) the attackers send instead of their honest
ones; a range attack rewrites ranges (T, n, n). `Attack` combines one of each and is what
sweeps apply: ``attack.apply(rng, truth, reported, ranges, attackers)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Protocol

import numpy as np

from swarmraft.world.geometry import true_distances


def choose_attackers(rng: np.random.Generator, trials: int, n: int, f: int) -> np.ndarray:
    """(T, n) bool with exactly f attackers per trial, chosen uniformly."""
    if not 0 <= f <= n:
        raise ValueError(f"f must be in [0, n={n}], got {f}")
    order = np.argsort(rng.random((trials, n)), axis=1)[:, :f]
    out = np.zeros((trials, n), dtype=bool)
    np.put_along_axis(out, order, True, axis=1)
    return out


def random_directions(rng: np.random.Generator, count: int) -> np.ndarray:
    """Unit vectors uniform on the sphere, (count, 3)."""
    v = rng.standard_normal((count, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


class PositionAttack(Protocol):
    def reports(
        self,
        rng: np.random.Generator,
        truth: np.ndarray,
        reported: np.ndarray,
        attackers: np.ndarray,
    ) -> np.ndarray: ...


@dataclass(frozen=True)
class Jump:
    """Independent position jumps. ``box``: offset uniform in [-half_width, half_width] per
    axis (the paper: 30 m; mean norm about 28.8 m). ``shell``: uniform direction, magnitude
    uniform in [low, high] (realistic: 10-100 m, docs/models.md)."""

    kind: Literal["box", "shell"] = "box"
    half_width: float = 30.0
    low: float = 10.0
    high: float = 100.0

    def __post_init__(self) -> None:
        if self.half_width < 0 or self.low < 0 or self.high < self.low:
            raise ValueError("Jump: need half_width >= 0 and 0 <= low <= high")

    def offsets(self, rng: np.random.Generator, count: int) -> np.ndarray:
        if self.kind == "box":
            return rng.uniform(-self.half_width, self.half_width, size=(count, 3))
        mags = rng.uniform(self.low, self.high, size=count)
        return random_directions(rng, count) * mags[:, None]

    def reports(self, rng, truth, reported, attackers):
        out = reported.copy()
        out[attackers] = truth[attackers] + self.offsets(rng, int(attackers.sum()))
        return out


def rigid_motions(
    rng: np.random.Generator, pivots: np.ndarray, angle_deg: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Rigid motions (T, 3, 3) and translations (T, 3) fixing k = 1, 2 or 3 pivot points
    (T, k, 3): a rotation about a random axis through one pivot, a rotation about the axis
    through two pivots, or the reflection in the plane of three (the only non-identity
    isometry fixing three non-collinear points)."""
    T, k, _ = pivots.shape
    if k == 3:
        nrm = np.cross(pivots[:, 1] - pivots[:, 0], pivots[:, 2] - pivots[:, 0])
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        R = np.eye(3) - 2 * np.einsum("ti,tj->tij", nrm, nrm)
    else:
        if k == 1:
            axis = random_directions(rng, T)
        else:
            axis = pivots[:, 1] - pivots[:, 0]
            axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        theta = np.deg2rad(rng.uniform(*angle_deg, size=T)) * rng.choice([-1, 1], size=T)
        K = np.zeros((T, 3, 3))
        K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
        K -= np.swapaxes(K, 1, 2)
        s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
        R = np.eye(3) + s * K + (1 - c) * (K @ K)
    shift = pivots[:, 0] - np.einsum("tij,tj->ti", R, pivots[:, 0])
    return R, shift


@dataclass(frozen=True)
class RigidCollusion:
    """The attackers report a rigid motion of their true positions that keeps k honest pivot
    drones fixed (k = 1, 2, 3), so every range among attackers and to the pivots stays
    consistent. Rotation angle uniform in ``angle_deg`` with a random sign.

    ``min_move`` (m): a trial whose motion moves some attacker less than this is drawn again
    (pivots, axis, angle and sign), up to ``MOVE_DRAWS`` times; a trial no draw satisfies (its
    attackers all near every pivot axis or plane) keeps its last draw, for the caller to
    redraw the whole trial (`experiments.trials.draw` does). 0 (the default) draws once.
    """

    pivots: Literal[1, 2, 3] = 1
    angle_deg: tuple[float, float] = (20.0, 90.0)
    min_move: float = 0.0

    MOVE_DRAWS = 50

    def __post_init__(self) -> None:
        if self.pivots not in (1, 2, 3):
            raise ValueError("RigidCollusion: pivots must be 1, 2 or 3")
        lo, hi = self.angle_deg
        if not 0 <= lo <= hi <= 180:
            raise ValueError("RigidCollusion: angle_deg must satisfy 0 <= low <= high <= 180")
        if not self.min_move >= 0:
            raise ValueError("RigidCollusion: min_move must be >= 0 m")

    def _moved(self, rng, truth, honest):
        """One draw of pivots and motion per trial: the moved positions (T, n, 3)."""
        T, n, _ = truth.shape
        keys = np.where(honest, rng.random((T, n)), np.inf)
        pivot_idx = np.argsort(keys, axis=1)[:, : self.pivots]
        pivots = np.take_along_axis(truth, pivot_idx[..., None], axis=1)
        R, shift = rigid_motions(rng, pivots, self.angle_deg)
        return np.einsum("tij,tnj->tni", R, truth) + shift[:, None, :]

    def reports(self, rng, truth, reported, attackers):
        honest = ~attackers
        if (honest.sum(axis=1) < self.pivots).any():
            raise ValueError(f"RigidCollusion: needs at least {self.pivots} honest drones")
        moved = self._moved(rng, truth, honest)
        if self.min_move > 0:
            for _ in range(self.MOVE_DRAWS):
                dist = np.linalg.norm(moved - truth, axis=2)
                short = np.flatnonzero((attackers & (dist < self.min_move)).any(axis=1))
                if not short.size:
                    break
                moved[short] = self._moved(rng, truth[short], honest[short])
        return np.where(attackers[..., None], moved, reported)


@dataclass(frozen=True)
class AreaSpoof:
    """Every victim reports the same point: the swarm centroid plus an offset of uniform
    direction and magnitude uniform in [low, high] m, drawn per trial."""

    low: float = 10.0
    high: float = 100.0

    def reports(self, rng, truth, reported, attackers):
        T = truth.shape[0]
        mags = rng.uniform(self.low, self.high, size=T)
        point = truth.mean(axis=1) + random_directions(rng, T) * mags[:, None]
        return np.where(attackers[..., None], point[:, None, :], reported)


@dataclass(frozen=True)
class RangeTamper:
    """Range tampering. ``consistent``: each attacker reports, as its own ranges, the
    distances from its fake report to the others' reports, so its row of the range matrix
    agrees with what it claims. ``bias``: add ``bias`` m to the attackers' own ranges (rows),
    or to the listed ordered ``pairs`` (i, j) when given."""

    mode: Literal["none", "consistent", "bias"] = "none"
    bias: float = 5.0
    pairs: tuple[tuple[int, int], ...] = ()

    def ranges(self, reported: np.ndarray, ranges: np.ndarray, attackers: np.ndarray) -> np.ndarray:
        if self.mode == "none":
            return ranges
        n = ranges.shape[1]
        if self.mode == "consistent":
            rows = np.broadcast_to(attackers[:, :, None], ranges.shape) & ~np.eye(n, dtype=bool)
            fake = true_distances(reported)
            return np.where(rows & ~np.isnan(ranges), fake, ranges)
        out = ranges.copy()
        if self.pairs:
            for i, j in self.pairs:
                if not (0 <= i < n and 0 <= j < n) or i == j:
                    raise ValueError(f"RangeTamper: pair ({i}, {j}) is not a pair of drones")
                out[:, i, j] += self.bias
        else:
            rows = attackers[:, :, None] & ~np.eye(n, dtype=bool)
            out = np.where(rows, out + self.bias, out)
        return out


@dataclass(frozen=True)
class DistanceEnlargement:
    """Distance enlargement: each attacker delays its ranging replies (or its own timestamps),
    so every range it takes part in reads long, in both directions of each of its links, as
    two-way ranging does: by its enlargement, uniform in [low, high] m and drawn per attacker
    and trial; a link between two attackers by the sum of theirs. Without secure ranging
    (IEEE 802.15.4z STS) nothing in a range shows the delay; a range can be lengthened this
    way but never shortened (the reply cannot come before the request)."""

    low: float = 2.0
    high: float = 10.0

    def __post_init__(self) -> None:
        if not 0 <= self.low <= self.high:
            raise ValueError("DistanceEnlargement: need 0 <= low <= high")

    def ranges(self, rng: np.random.Generator, ranges: np.ndarray, attackers: np.ndarray) -> np.ndarray:
        delta = np.where(attackers, rng.uniform(self.low, self.high, size=attackers.shape), 0.0)
        return enlarge(ranges, delta)


def enlarge(ranges: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Ranges (..., n, n) with every range drone k takes part in lengthened by delta[..., k] m
    (both directions; a link of two enlargers by both); the diagonal and nan stay as they are."""
    n = ranges.shape[-1]
    out = ranges + delta[..., :, None] + delta[..., None, :]
    return np.where(np.eye(n, dtype=bool), ranges, out)


@dataclass(frozen=True)
class Attack:
    """A position attack (or none) plus range tampering, plus distance enlargement (or none)."""

    position: PositionAttack | None = field(default_factory=Jump)
    range_tamper: RangeTamper = field(default_factory=RangeTamper)
    enlargement: DistanceEnlargement | None = None

    def apply(
        self,
        rng: np.random.Generator,
        truth: np.ndarray,
        reported: np.ndarray,
        ranges: np.ndarray,
        attackers: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        if self.position is not None:
            reported = self.position.reports(rng, truth, reported, attackers)
        ranges = self.range_tamper.ranges(reported, ranges, attackers)
        if self.enlargement is not None:
            ranges = self.enlargement.ranges(rng, ranges, attackers)
        return reported, ranges

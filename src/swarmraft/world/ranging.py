"""Inter-drone ranging models. ``measure(rng, truth)`` returns ranges (T, n, n) with
``ranges[t, i, j]`` measured by drone i to drone j, ``nan`` where unmeasured, 0 on the diagonal.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from swarmraft.world.geometry import true_distances

NLOS_MODES = ("link", "direction")


def _finish(d: np.ndarray, true: np.ndarray, max_range: float | None) -> np.ndarray:
    d = np.maximum(d, 0.0)
    if max_range is not None:
        d = np.where(true > max_range, np.nan, d)
    n = d.shape[1]
    d[:, np.arange(n), np.arange(n)] = 0.0
    return d


def _pair_noise(rng: np.random.Generator, shape: tuple[int, ...], symmetric: bool) -> np.ndarray:
    """Standard normal per ordered pair, or mirrored across the diagonal when symmetric."""
    z = rng.standard_normal(shape)
    if symmetric:
        upper = np.triu(z, 1)
        z = upper + np.swapaxes(upper, 1, 2)
    return z


@dataclass(frozen=True)
class ExactRanging:
    """True distances, symmetric, every pair: the reference code (docs/models.md)."""

    max_range: float | None = None

    def measure(self, rng: np.random.Generator, truth: np.ndarray) -> np.ndarray:
        true = true_distances(truth)
        return _finish(true.copy(), true, self.max_range)


@dataclass(frozen=True)
class UWBRanging:
    """UWB two-way ranging: Gaussian noise sigma (default 0.10 m, docs/models.md; 0.05-0.15 m),
    with probability ``nlos_prob`` a positive NLOS bias uniform in ``nlos_bias`` (default
    +0.3 to +1 m), nothing beyond ``max_range`` (reliable to 50-100 m). ``symmetric``: i and j
    share one measurement; otherwise each direction is measured independently (its own
    Gaussian noise).

    ``nlos_mode``: ``"link"`` (default) draws the NLOS bias once per link and snapshot and adds
    it to both directions, since it comes from the propagation path both directions of a
    two-way range share; ``"direction"`` draws it per ordered pair (the model before links).
    Each call (one snapshot, or each step of a mission) draws afresh: nothing persists."""

    sigma: float = 0.10
    max_range: float | None = None
    nlos_prob: float = 0.0
    nlos_bias: tuple[float, float] = (0.3, 1.0)
    symmetric: bool = False
    nlos_mode: Literal["link", "direction"] = "link"

    def __post_init__(self) -> None:
        if self.sigma < 0:
            raise ValueError("UWB sigma must be >= 0")
        if self.nlos_mode not in NLOS_MODES:
            raise ValueError(f"UWB nlos_mode must be one of {', '.join(NLOS_MODES)}, got {self.nlos_mode!r}")
        if not 0 <= self.nlos_prob <= 1:
            raise ValueError("UWB nlos_prob must be in [0, 1]")
        lo, hi = self.nlos_bias
        if lo < 0 or hi < lo:
            raise ValueError("UWB nlos_bias must be (low, high) with 0 <= low <= high")
        if self.max_range is not None and not self.max_range > 0:
            raise ValueError("UWB max_range must be > 0")

    def measure(self, rng: np.random.Generator, truth: np.ndarray) -> np.ndarray:
        true = true_distances(truth)
        d = true + self.sigma * _pair_noise(rng, true.shape, self.symmetric)
        if self.nlos_prob > 0:
            hit = rng.random(true.shape) < self.nlos_prob
            bias = np.where(hit, rng.uniform(*self.nlos_bias, size=true.shape), 0.0)
            if self.nlos_mode == "link":  # the upper triangle's draw, mirrored: one per link
                bias = np.triu(bias, 1)
                bias = bias + np.swapaxes(bias, 1, 2)
            d = d + bias
        return _finish(d, true, self.max_range)

    def measure_steps(self, rng: np.random.Generator, positions: np.ndarray) -> np.ndarray:
        """Ranges (S, n, n) of each step's positions (S, n, 3) in turn: exactly what calling
        `measure` step by step gives, draws included. Without NLOS a call draws only its
        Gaussian noise, in order, so many steps are measured in one call (a long mission's
        world took minutes step by step); with NLOS the draws interleave and each step is
        measured alone."""
        S, n, _ = positions.shape
        out = np.empty((S, n, n))
        chunk = max(1, _CHUNK_FLOATS // (3 * n * n)) if self.nlos_prob == 0 else 1
        for lo in range(0, S, chunk):
            out[lo : lo + chunk] = self.measure(rng, positions[lo : lo + chunk])
        return out


_CHUNK_FLOATS = 2_000_000  # per call of `UWBRanging.measure_steps` (its (T, n, n, 3) differences)


@dataclass(frozen=True)
class RSSIRanging:
    """RSSI ranging under log-normal shadowing: the received power has Gaussian shadowing of
    ``shadowing_db`` dB (docs/models.md: 4-8 dB) and path-loss exponent ``exponent`` (2-4), so the
    inverted distance is d * 10^(X / (10 exponent)), X ~ N(0, shadowing_db^2)."""

    shadowing_db: float = 6.0
    exponent: float = 2.5
    max_range: float | None = None
    symmetric: bool = False

    def __post_init__(self) -> None:
        if self.shadowing_db < 0 or not self.exponent > 0:
            raise ValueError("RSSI needs shadowing_db >= 0 and exponent > 0")

    def measure(self, rng: np.random.Generator, truth: np.ndarray) -> np.ndarray:
        true = true_distances(truth)
        x = self.shadowing_db * _pair_noise(rng, true.shape, self.symmetric)
        return _finish(true * 10.0 ** (x / (10 * self.exponent)), true, self.max_range)

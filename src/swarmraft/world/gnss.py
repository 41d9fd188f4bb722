"""GNSS error models: white Gaussian per axis, first-order Gauss-Markov over time, and a
component common to all drones. Sigmas are per axis: horizontal (E, N) and vertical (U).

Defaults: 1.5 m horizontal, 3 m vertical, Gauss-Markov tau 60-300 s (docs/models.md, realistic).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _axis_sigma(sigma_h: float, sigma_v: float) -> np.ndarray:
    if sigma_h < 0 or sigma_v < 0:
        raise ValueError("GNSS sigma must be >= 0")
    return np.array([sigma_h, sigma_h, sigma_v], dtype=float)


@dataclass(frozen=True)
class GNSSModel:
    """Per-drone white error (sigma_h, sigma_v) plus a common-mode error shared by all drones
    of a trial (common_h, common_v). For a snapshot a Gauss-Markov error is stationary
    Gaussian with the same sigma, so snapshots use this model; `GaussMarkov` gives the
    time-correlated sequence."""

    sigma_h: float = 1.5
    sigma_v: float = 3.0
    common_h: float = 0.0
    common_v: float = 0.0

    def __post_init__(self) -> None:
        _axis_sigma(self.sigma_h, self.sigma_v)
        _axis_sigma(self.common_h, self.common_v)

    def errors(self, rng: np.random.Generator, trials: int, n: int) -> np.ndarray:
        """GNSS errors (T, n, 3)."""
        own = rng.standard_normal((trials, n, 3)) * _axis_sigma(self.sigma_h, self.sigma_v)
        if self.common_h == 0 and self.common_v == 0:
            return own
        common = rng.standard_normal((trials, 1, 3)) * _axis_sigma(self.common_h, self.common_v)
        return own + common

    @property
    def total_sigma(self) -> tuple[float, float]:
        """Per-axis sigma of one drone's error (horizontal, vertical)."""
        return (
            float(np.hypot(self.sigma_h, self.common_h)),
            float(np.hypot(self.sigma_v, self.common_v)),
        )


@dataclass(frozen=True)
class GaussMarkov:
    """First-order Gauss-Markov error per drone and axis: e_{k+1} = phi e_k + w_k with
    phi = exp(-dt / tau) and Var(w) = sigma^2 (1 - phi^2), started stationary."""

    sigma_h: float = 1.5
    sigma_v: float = 3.0
    tau: float = 120.0
    dt: float = 0.1

    def __post_init__(self) -> None:
        _axis_sigma(self.sigma_h, self.sigma_v)
        if not self.tau > 0 or not self.dt > 0:
            raise ValueError("GaussMarkov: tau and dt must be > 0")

    def sequence(self, rng: np.random.Generator, steps: int, n: int) -> np.ndarray:
        """Errors (steps, n, 3)."""
        sig = _axis_sigma(self.sigma_h, self.sigma_v)
        phi = float(np.exp(-self.dt / self.tau))
        q = sig * np.sqrt(1 - phi**2)
        out = np.empty((steps, n, 3))
        e = rng.standard_normal((n, 3)) * sig
        for k in range(steps):
            out[k] = e
            e = phi * e + rng.standard_normal((n, 3)) * q
        return out

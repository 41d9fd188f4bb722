"""Threshold calibration, as the paper's section III.E: from honest-only snapshots, the
residual statistics mu_e and sigma_e give the threshold T = mu_e + 3 sigma_e.

Two residuals are calibrated:

- ``tau``: the pairwise vote residual | ||z_A - z_B|| - d_AB | over measured pairs (what the
  vote of Algorithm 1 compares with tau);
- ``epsilon``: the distance between an honest drone's report and its multilateration from all
  the others (what the re-marking rule compares with epsilon).

This module gets the honest snapshots from its caller; simulating them from a noise model is
the experiments layer's job (``swarmraft.experiments.calibration``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from swarmraft.estimation.pairwise import report_distances
from swarmraft.estimation.paper import PaperParams, anchor_distances, recover
from swarmraft.estimation.snapshot import SnapshotBatch


@dataclass(frozen=True)
class Calibration:
    tau: float
    epsilon: float
    pair_mean: float
    pair_std: float
    recovery_mean: float
    recovery_std: float
    samples: int

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def three_sigma(values: np.ndarray) -> tuple[float, float, float]:
    """(mu + 3 sigma, mu, sigma) of the finite values."""
    v = values[np.isfinite(values)]
    if v.size < 2:
        raise ValueError("calibration needs at least 2 residuals (n >= 2 drones with ranges)")
    mu, sd = float(v.mean()), float(v.std(ddof=1))
    return mu + 3 * sd, mu, sd


def pair_residuals(reported: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """| ||z_A - z_B|| - d_AB | for every measured ordered pair, flattened."""
    off = ~np.eye(reported.shape[1], dtype=bool)
    e = np.abs(report_distances(reported) - ranges)[:, off]
    return e[~np.isnan(e)]


def recovery_residuals(
    reported: np.ndarray, ranges: np.ndarray, params: PaperParams | None = None
) -> np.ndarray:
    """||z_A - multilateration of A from all other drones||, for every drone, flattened."""
    p = params or PaperParams()
    T, n = reported.shape[:2]
    dists = anchor_distances(ranges)
    t_idx, a_idx = np.divmod(np.arange(T * n), n)
    mask = ~np.isnan(dists[t_idx, a_idx]) & (np.arange(n)[None, :] != a_idx[:, None])
    est = recover(reported[t_idx], dists[t_idx, a_idx], mask, reported[t_idx, a_idx], p)
    ok = mask.sum(axis=1) >= min(3, n - 1)  # small swarms: as many anchors as there are
    return np.linalg.norm(est - reported[t_idx, a_idx], axis=1)[ok]


def calibrate(honest: SnapshotBatch, params: PaperParams | None = None) -> Calibration:
    """Calibrate tau and epsilon (each mu_e + 3 sigma_e) from honest-only snapshots."""
    rep, rng_ = np.asarray(honest.reported, float), np.asarray(honest.ranges, float)
    tau, pm, ps = three_sigma(pair_residuals(rep, rng_))
    rec = recovery_residuals(rep, rng_, params)
    eps, rm, rs = three_sigma(rec)
    return Calibration(
        tau=tau,
        epsilon=eps,
        pair_mean=pm,
        pair_std=ps,
        recovery_mean=rm,
        recovery_std=rs,
        samples=int(rep.shape[0]),
    )

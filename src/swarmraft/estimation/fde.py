"""The `fde` detector: fault detection and exclusion as in GNSS receiver integrity monitoring
(RAIM). Estimate all positions jointly from every trusted report and range; if the weighted
sum of squared residuals fails a chi-square test at false-alarm probability ``p_fa``, or the
largest GNSS residual block fails its own 3-dof test at ``p_fa / n``, exclude the drone with
the largest residual contribution (its GNSS report and its own ranges), together with any
drone whose contribution is gross (above the local test and half the largest), and
repeat, until the tests pass, ``f_max`` drones are excluded or ``min_trusted`` remain."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from swarmraft.estimation.joint import (
    chi2_quantile,
    joint_estimate,
    residual_statistics,
    tests_pass,
    trusted_estimate,
)
from swarmraft.estimation.noise import NoiseModel, NoiseParams
from swarmraft.estimation.registry import register
from swarmraft.estimation.snapshot import SnapshotBatch, VerdictBatch

GROSS = 1.0  # contributions above this share of the worst are excluded together with it


class FDEParams(NoiseParams):
    p_fa: float = Field(1e-3, gt=0, lt=1, description="false-alarm probability of the test")
    min_trusted: int = Field(4, ge=1, description="stop excluding below this many drones")
    f_max: int | None = Field(None, ge=0, description="exclude at most this many; None: (n - 1) // 2")


@register("fde", FDEParams, "chi-square residual test with greedy exclusion (RAIM-style FDE)")
def fde_detector(batch: SnapshotBatch, p: FDEParams) -> VerdictBatch:
    reported = np.asarray(batch.reported, float)
    ranges = np.asarray(batch.ranges, float)
    T, n, _ = reported.shape
    noise = NoiseModel.of(batch, p, "fde")
    trusted = np.ones((T, n), dtype=bool)
    active = np.arange(T)
    stat = np.zeros(T)
    x_all = None
    while active.size:
        tr = trusted[active]
        # after an exclusion the previous solution is a close start: a few iterations do
        start = None if x_all is None else x_all[active]
        x = joint_estimate(
            reported[active],
            ranges[active],
            tr,
            noise.gnss_cov,
            noise.range_sigma,
            iters=8,
            x0=start,
        )
        x_all = np.zeros_like(reported) if x_all is None else x_all
        x_all[active] = x
        per, gnss_q, total, dof = residual_statistics(x, reported[active], ranges[active], tr, noise)
        stat[active] = total
        failed = ~tests_pass(gnss_q, total, dof, tr, p.p_fa)
        f_max = (n - 1) // 2 if p.f_max is None else p.f_max
        can = (tr.sum(axis=1) > p.min_trusted) & ((~tr).sum(axis=1) < f_max)
        go = failed & can
        score = np.where(tr, per, -np.inf)
        worst = np.argmax(score, axis=1)
        # Gross faults need not wait their turn: with the worst, exclude every drone whose
        # contribution is above both the local test and half the worst, up to f_max.
        gross = tr & (per > np.maximum(chi2_quantile(1 - p.p_fa / n, 3), GROSS * score.max(axis=1))[:, None])
        gross[np.arange(len(worst)), worst] = True
        room = f_max - (~tr).sum(axis=1)
        rank = np.argsort(np.argsort(-score, axis=1), axis=1)
        gross &= rank < room[:, None]
        gross &= go[:, None]
        trusted[active] &= ~gross
        active = active[go]
    positions, status = trusted_estimate(
        reported,
        ranges,
        trusted,
        noise.gnss_cov,
        noise.range_sigma,
        x0=x_all,
        prior=batch.prior,
        prior_sigma=batch.prior_sigma,
    )
    return VerdictBatch(
        positions=positions, faulty=~trusted, status=status, diagnostics={"chi2": stat, "trusted": trusted}
    )

"""The `fde` detector: fault detection and exclusion as in GNSS receiver integrity monitoring
(RAIM). Drones most of whose two-way ranges disagree (`two_way_outliers`: range tampering)
are excluded first. Then estimate all positions jointly from every trusted report and range;
if the weighted sum of squared residuals fails a chi-square test at false-alarm probability
``p_fa``, or the largest GNSS residual block fails its own 3-dof test at ``p_fa / n``,
exclude the drone with the largest residual contribution (its GNSS report and its own
ranges), one drone a round (each re-solve starts from the last solution), and repeat, until
the tests pass, ``f_max`` drones are excluded or ``min_trusted`` remain. The final trusted
set goes through `integrity.finish` (robust estimate, statuses, protection levels): if its
tests still fail, exclusion is exhausted and the status is ``alarm``. The rounds' solves only
feed the tests and a start of that robust estimate, so they take the reduced solve
(`joint.weighted_gauss_newton`: the excluded drones' blocks eliminated)."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from swarmraft.estimation.integrity import IntegrityParams, finish, resolve_f_max
from swarmraft.estimation.joint import joint_estimate, residual_statistics, tests_pass
from swarmraft.estimation.noise import NoiseModel
from swarmraft.estimation.registry import register
from swarmraft.estimation.snapshot import SnapshotBatch, VerdictBatch


class FDEParams(IntegrityParams):
    min_trusted: int = Field(4, ge=1, description="stop excluding below this many drones")
    k_pair: float = Field(4.0, gt=0, description="two-way range check: d_ij and d_ji agree within, sigmas")


def two_way_outliers(ranges: np.ndarray, range_sigma: float, k: float) -> np.ndarray:
    """Drones (T, n) most of whose two-way links disagree: |d_ij - d_ji| > k sqrt(2) sigma on
    more than half the links measured both ways. A drone that tampers with the ranges it
    measures disagrees with every honest drone's measurement of the same distance; an honest
    drone disagrees only with the tamperers."""
    back = np.swapaxes(ranges, 1, 2)
    both = ~np.isnan(ranges) & ~np.isnan(back)
    with np.errstate(invalid="ignore"):
        bad = both & (np.abs(ranges - back) > k * np.sqrt(2) * range_sigma)
    return bad.sum(axis=2) > 0.5 * both.sum(axis=2)


@register("fde", FDEParams, "chi-square residual test with greedy exclusion (RAIM-style FDE)")
def fde_detector(batch: SnapshotBatch, p: FDEParams) -> VerdictBatch:
    reported = np.asarray(batch.reported, float)
    ranges = np.asarray(batch.ranges, float)
    T, n, _ = reported.shape
    noise = NoiseModel.of(batch, p, "fde")
    f_max = resolve_f_max(p, n, "fde")
    # Tampered ranges first (they would spread their residuals over the honest drones that
    # measured them), at most f_max, the most inconsistent first.
    tampered = two_way_outliers(ranges, noise.range_sigma, p.k_pair)
    too_many = tampered.sum(axis=1) > f_max
    trusted = ~np.where(too_many[:, None], False, tampered)
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
            reduced=True,  # these solves only feed the test: see the module's docstring
        )
        x_all = np.zeros_like(reported) if x_all is None else x_all
        x_all[active] = x
        per, gnss_q, total, dof = residual_statistics(x, reported[active], ranges[active], tr, noise)
        stat[active] = total
        failed = ~tests_pass(gnss_q, total, dof, tr, p.p_fa)
        can = (tr.sum(axis=1) > p.min_trusted) & ((~tr).sum(axis=1) < f_max)
        go = failed & can
        worst = np.argmax(np.where(tr, per, -np.inf), axis=1)
        trusted[active[go], worst[go]] = False
        active = active[go]
    return finish(batch, p, noise, trusted, starts=(x_all,), diagnostics={"chi2": stat})

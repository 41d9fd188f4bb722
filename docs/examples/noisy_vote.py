"""A detector written outside SwarmRaft, as docs/detectors.md ("Writing a detector") shows:
a noise-aware pairwise vote decides the trusted set, and `integrity.finish` does the rest (the
robust estimate, statuses, protection levels, the repair and rival checks every statistical
detector ends with).

Use it from Python after ``import noisy_vote`` (then ``verify(snapshot, "noisy_vote")``,
``run_sweep``), or from the command line once a package declares it as an entry point:

    [project.entry-points."swarmraft.detectors"]
    noisy_vote = "noisy_vote"
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from swarmraft.estimation import SnapshotBatch, VerdictBatch, register
from swarmraft.estimation.integrity import IntegrityParams, finish, resolve_f_max
from swarmraft.estimation.noise import NoiseModel


class VoteParams(IntegrityParams):  # p_fa, f_max, noise and range screening come with it
    k: float = Field(3.0, gt=0, description="a range disagrees beyond k sigma of its report distance")


@register("noisy_vote", VoteParams, "noise-aware pairwise vote, then the robust joint estimate")
def noisy_vote(batch: SnapshotBatch, p: VoteParams) -> VerdictBatch:
    noise = NoiseModel.of(batch, p, "noisy_vote")  # the snapshot's sigmas, or the parameters'
    reported = np.asarray(batch.reported, float)  # (T, n, 3)
    ranges = np.asarray(batch.ranges, float)  # (T, n, n), nan where not measured
    n = reported.shape[1]
    apart = np.linalg.norm(reported[:, :, None] - reported[:, None], axis=3)
    # the sigma of a report distance: two GNSS errors on the worst axis, and the range's
    sigma = np.sqrt(2 * np.diag(noise.gnss_cov).max() + noise.range_sigma**2)
    measured = ~np.isnan(ranges) & ~np.eye(n, dtype=bool)
    with np.errstate(invalid="ignore"):
        against = measured & (np.abs(apart - ranges) > p.k * sigma)
    flagged = 2 * against.sum(axis=2) > measured.sum(axis=2)  # most of its ranges disagree
    # more drones flagged than tolerated: exclusion is exhausted, an alarm
    status = np.where(flagged.sum(axis=1) > resolve_f_max(p, n, "noisy_vote"), "alarm", "ok")
    return finish(batch, p, noise, ~flagged, status=status)

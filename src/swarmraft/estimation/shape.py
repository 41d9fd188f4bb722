"""The `shape` detector: the swarm's shape from its ranges, registered to the GNSS reports.

UWB ranges (0.10 m) are about 30 times more precise than GNSS (1.5 m / 3 m per axis), so the
ranges alone fix the swarm's shape up to a rigid motion (`links.range_shape`: classical MDS,
then a least-squares fit of every range). The honest drones' reports are that shape moved
into place, plus GNSS noise: one rigid registration. Colluders that report a rigid motion of
their true positions about up to 3 honest pivots (the attack that defeats pairwise tests:
every range among them and to the pivots stays consistent) are a second, smaller rigid
registration of the same shape, through the pivots. So the candidates for the honest set are
the inlier sets of the rigid registrations of the shape to the reports:

1. Hypotheses: every triple of placed drones (at most ``max_triples``, a fixed quasi-random
   choice beyond) whose three pairs are consistent (`clique.consistency_graph` at ``k``
   sigma), each with both handednesses (the shape from ranges is known up to a reflection,
   and three points cannot tell one from the other) unless a set found so far with that
   handedness holds it, registered by orthogonal Procrustes (Kabsch, with the determinant
   fixed to +1 or -1).
2. Inliers: the drones whose report lies within the chi-square 3-dof ``1 - p_fa / n``
   quantile of the registered shape (whitened by the GNSS covariance plus the shape's own
   error), refitted on its inliers ``refits`` times, keeping the handedness.
3. Candidates: the distinct inlier sets that leave at most ``f_max`` drones out (by default
   an honest majority, (n - 1) // 2). Each is tested like `clique`'s candidates: a joint
   estimate trusting it (`joint.joint_estimate`) and the residual tests at ``p_fa``
   (`joint.tests_pass`). A passing set inside another passing set whose estimate places
   every drone where it does (within the inlier quantile) is the same explanation with
   drones left out, and is dropped; one that places some drone elsewhere is another.
4. One set left: it is trusted. Two or more: two trusted sets with at most ``f_max``
   attackers each explain the data, and the status is ``unidentifiable``; only the drones
   outside every such set are flagged, and the positions come from the drones inside all of
   them. None passes: the largest candidate with the smallest chi-square is taken, an
   ``alarm`` (its tests fail); no candidate at all: ``alarm`` (more than ``f_max`` drones
   fit no registration with the others).

The chosen set goes through `integrity.finish` (robust estimate, statuses, protection levels,
rival check), as every statistical detector's does. Identifiability (docs/models.md): f
colluders about k pivots form a registration of f + k drones, so the honest one is the only
candidate when n - (f + k) > f_max; with f_max = f that is n >= 2f + 4 for any k <= 3, and
at n = 2f + 1 both registrations are candidates: ``unidentifiable``, not a guess.

Ranges a drone reports about its own links are taken into the shape only where they agree
with the other direction of the link; a drone that disagrees with most of its links (range
tampering) is placed by the others' ranges to it. A drone the ranges do not place (fewer
than 4 placed drones to range with) joins a candidate where its report agrees with every
member's within ``k`` sigma on the ranges it has (`clique.consistency_graph`), and the
residual tests judge it.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from swarmraft.estimation.integrity import IntegrityParams, finish, resolve_f_max
from swarmraft.estimation.noise import NoiseModel
from swarmraft.estimation.registrations import (
    MAX_SETS,
    MAX_TRIPLES,
    PAIR_K,
    REFITS,
    candidates,
    distinct_explanations,
)
from swarmraft.estimation.registry import register
from swarmraft.estimation.snapshot import SnapshotBatch, VerdictBatch


class ShapeParams(IntegrityParams):
    max_triples: int = Field(
        MAX_TRIPLES,
        ge=1,
        description="registration seeds: every triple of drones up to this many, else a fixed choice",
    )
    max_sets: int = Field(
        MAX_SETS, ge=2, description="distinct registrations per snapshot; beyond: unidentifiable"
    )
    refits: int = Field(REFITS, ge=1, le=50, description="refits of each registration on its inliers at most")
    k: float = Field(
        PAIR_K, gt=0, description="pairwise consistency (seed triangles) and two-way agreement, sigmas"
    )


@register("shape", ShapeParams, "rigid registrations of the range-fixed shape to the reports")
def shape_detector(batch: SnapshotBatch, p: ShapeParams) -> VerdictBatch:
    reported = np.asarray(batch.reported, float)
    ranges = np.asarray(batch.ranges, float)
    T, n, _ = reported.shape
    noise = NoiseModel.of(batch, p, "shape")
    f_max = resolve_f_max(p, n, "shape")
    c = candidates(reported, ranges, noise, f_max, p.p_fa, p.k, p.max_triples, p.refits, p.max_sets)
    masks, x, passed, total = c.masks, c.x, c.passed, c.total
    counts = np.bincount(c.owner, minlength=T)
    trusted = np.ones((T, n), dtype=bool)
    suspects = np.zeros((T, n), dtype=bool)
    start = np.full((T, n, 3), np.nan)
    status = np.full(T, "ok", dtype=object)
    support = np.zeros((T, n), dtype=int)
    k = 0
    for t in range(T):
        ks = np.arange(k, k + counts[t])
        k += counts[t]
        if not ks.size:  # more than f_max drones fit no registration with the others
            status[t] = "alarm"
            continue
        plausible = ks[passed[ks]]
        if plausible.size:
            plausible = plausible[distinct_explanations(masks[plausible], x[plausible], c.Winv, c.threshold)]
        support[t] = masks[plausible].sum(axis=0)
        if c.capped[t]:  # the search stopped before it saw every registration
            status[t] = "unidentifiable"
        if plausible.size >= 2:
            status[t] = "unidentifiable"
            trusted[t] = np.logical_and.reduce(masks[plausible])  # what every explanation trusts
            suspects[t] = ~np.logical_or.reduce(masks[plausible])  # what none trusts
            continue
        top = ks[masks[ks].sum(axis=1) == masks[ks[0]].sum()]
        pick = plausible[0] if plausible.size else top[np.argmin(total[top])]
        trusted[t] = masks[pick]
        suspects[t] = ~masks[pick]
        start[t] = x[pick]
    v = finish(batch, p, noise, trusted, (start,), status, suspects, diagnostics={"explanations": support})
    # `finish` may repair a trusted set that fails its tests by a swap and flag what the swap
    # leaves out; the common part of two explanations can fail (e.g. the pivots of a
    # reflection and the drones near their plane: coplanar anchors). An unidentifiable
    # verdict flags only the drones outside every explanation, whatever set placed them.
    unid = status == "unidentifiable"
    v.faulty[unid] = suspects[unid]
    return v

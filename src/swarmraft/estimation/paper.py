"""The paper's detector: Algorithm 1 (pairwise consistency vote, then multilateration of the
flagged drones from the unflagged ones), with every parameter exposed.

The defaults are the ``reference`` settings: the paper's public code as docs/models.md describes it
(tau 0.01 m, epsilon 3 m, start at the drone's own report, soft_l1 loss with f_scale 5 m,
up to 3 restarts stopping when a restart moves < 1e-3 m, all other drones as anchors when
fewer than 3 unflagged remain, a tie counts as honest). Flagged drones are processed in index
order and a drone re-marked honest becomes an anchor for the drones after it, as there.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import ConfigDict, Field

from swarmraft.estimation.integrity import IntegrityParams, finish
from swarmraft.estimation.link_params import LinkParams
from swarmraft.estimation.noise import NoiseModel
from swarmraft.estimation.pairwise import report_distances
from swarmraft.estimation.registry import register
from swarmraft.estimation.snapshot import SnapshotBatch, VerdictBatch
from swarmraft.estimation.trust_region import linear_multilateration, solve_ranges


class PaperParams(LinkParams):
    """Parameters of Algorithm 1. Defaults: the reference code (docs/models.md); the range
    screening (`links`) is off, as Algorithm 1 has none (``links = "screen"`` turns it on)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    tau: float = Field(0.01, gt=0, description="vote threshold on | ||z_A - z_B|| - d_AB |, m")
    epsilon: float = Field(3.0, ge=0, description="re-mark honest if recovery is within, m")
    restarts: int = Field(3, ge=1, le=100, description="least-squares solves per drone")
    restart_tol: float = Field(1e-3, ge=0, description="stop restarting below this move, m")
    loss: Literal["linear", "soft_l1", "huber", "cauchy"] = "soft_l1"
    f_scale: float = Field(5.0, gt=0, description="robust loss scale, m")
    initial: Literal["report", "centroid", "linear"] = Field(
        "report", description="start: own report (code), anchor centroid (paper text), closed form"
    )
    fallback: Literal["all", "skip"] = Field(
        "all", description="< min_anchors unflagged: use all drones (code) or keep the report"
    )
    tie: Literal["honest", "faulty"] = Field("honest", description="a zero vote sum counts as")
    min_anchors: int = Field(3, ge=1)
    links: Literal["screen", "off"] = Field(
        "off", description="screen the ranges first (links.screen): needs the snapshot's range_sigma"
    )
    recovery: Literal["reference", "joint"] = Field(
        "reference",
        description="stage 2: the reference code's solver, or the joint estimate (closed-form "
        "start, Gauss-Newton, noise weights, geometry check; no re-marking)",
    )


def pairwise_votes(reported: np.ndarray, ranges: np.ndarray, tau: float) -> np.ndarray:
    """Stage 1 vote sums (T, n): +1 per measured neighbour B with
    | ||z_A - z_B|| - ranges[A, B] | < tau, -1 otherwise; unmeasured pairs abstain."""
    dhat = report_distances(reported)
    n = reported.shape[1]
    measured = ~np.isnan(ranges) & ~np.eye(n, dtype=bool)
    with np.errstate(invalid="ignore"):
        ok = np.abs(dhat - ranges) < tau
    return np.where(measured, np.where(ok, 1, -1), 0).sum(axis=2)


def anchor_distances(ranges: np.ndarray) -> np.ndarray:
    """Distance from each anchor j to drone A, (T, A, j): the anchor's own measurement
    ranges[j, A] (as the reference code), else the drone's ranges[A, j]."""
    towards = np.swapaxes(ranges, 1, 2)
    return np.where(np.isnan(towards), ranges, towards)


def recover(
    reported: np.ndarray,
    dists: np.ndarray,
    anchor_mask: np.ndarray,
    start: np.ndarray,
    p: PaperParams,
) -> np.ndarray:
    """Multilaterate B drones: anchors (B, n, 3), dists (B, n), mask (B, n), report (B, 3)."""
    if p.initial == "report":
        x0 = start.copy()
    elif p.initial == "centroid":
        w = anchor_mask.astype(float)
        x0 = np.einsum("bm,bmk->bk", w, reported) / np.maximum(w.sum(axis=1), 1)[:, None]
    else:
        x0 = linear_multilateration(reported, dists, anchor_mask)
    est = x0
    active = np.arange(len(est))
    for _ in range(p.restarts):
        if not active.size:
            break
        sol = solve_ranges(
            reported[active],
            dists[active],
            anchor_mask[active],
            est[active],
            loss=p.loss,
            f_scale=p.f_scale,
        )
        moved = np.linalg.norm(sol.x - est[active], axis=1) >= p.restart_tol
        est[active[moved]] = sol.x[moved]
        active = active[moved]
    return est


def _stage2(
    reported: np.ndarray,
    dists: np.ndarray,
    measured: np.ndarray,
    flags: np.ndarray,
    t_idx: np.ndarray,
    a_idx: np.ndarray,
    p: PaperParams,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Recover the flagged drones (t_idx, a_idx) against the flags given; returns the
    estimates (B, 3), anchors used (B,) and whether a solve ran (B,)."""
    B = len(t_idx)
    others = measured[t_idx, a_idx]  # (B, n): anchors with a range to the drone
    trusted = others & ~flags[t_idx]
    few = trusted.sum(axis=1) < p.min_anchors
    mask = np.where(few[:, None], others, trusted) if p.fallback == "all" else trusted
    solve = ~few if p.fallback == "skip" else np.ones(B, dtype=bool)
    solve &= mask.any(axis=1)
    est = reported[t_idx, a_idx].copy()
    if solve.any():
        s = np.flatnonzero(solve)
        est[s] = recover(reported[t_idx[s]], dists[t_idx[s], a_idx[s]], mask[s], est[s], p)
    used = np.where(solve, mask.sum(axis=1), 0)
    return est, used, solve


@register("paper", PaperParams, "Algorithm 1 of the paper: pairwise vote + multilateration")
def paper_detector(batch: SnapshotBatch, p: PaperParams) -> VerdictBatch:
    reported = np.asarray(batch.reported, dtype=float)
    ranges = np.asarray(batch.ranges, dtype=float)
    T, n = reported.shape[:2]
    votes = pairwise_votes(reported, ranges, p.tau)
    flagged0 = votes < 0 if p.tie == "honest" else votes <= 0
    if p.recovery == "joint":
        q = IntegrityParams()
        noise = NoiseModel.of(batch, q, "paper")
        # the paper's recovery made exact: a flagged drone placed by anchors whose faults could
        # not be detected keeps its estimate (degenerate, levels inf), as Algorithm 1 keeps its
        # multilateration; the statistical detectors withhold it (`integrity._verdicts`)
        return finish(
            batch,
            q,
            noise,
            ~flagged0,
            diagnostics={"votes": votes, "flagged_by_vote": flagged0},
            keep_unverified=True,
        )
    dists = anchor_distances(ranges)
    measured = ~np.isnan(dists) & ~np.eye(n, dtype=bool)

    positions = reported.copy()
    flags = flagged0.copy()
    anchors = np.zeros((T, n), dtype=int)
    deviation = np.full((T, n), np.nan)

    def settle(
        t_idx: np.ndarray, a_idx: np.ndarray, est: np.ndarray, used: np.ndarray, solved: np.ndarray
    ) -> np.ndarray:
        dev = np.linalg.norm(reported[t_idx, a_idx] - est, axis=1)
        replace = solved & (dev > p.epsilon)
        remark = solved & ~replace
        positions[t_idx[replace], a_idx[replace]] = est[replace]
        flags[t_idx[remark], a_idx[remark]] = False
        anchors[t_idx, a_idx] = used
        deviation[t_idx[solved], a_idx[solved]] = dev[solved]
        return remark

    # All flagged drones at once against the stage-1 flags ...
    t_idx, a_idx = np.nonzero(flagged0)
    est, used, solved = _stage2(reported, dists, measured, flagged0, t_idx, a_idx, p)
    remark = settle(t_idx, a_idx, est, used, solved)
    # ... then, in the rare trials where a drone was re-marked honest while a later flagged
    # drone exists, redo that trial in index order so the re-marked drone anchors the rest.
    later = np.zeros(T, dtype=bool)
    for t, a in zip(t_idx[remark], a_idx[remark], strict=True):
        later[t] |= bool(flagged0[t, a + 1 :].any())
    for t in np.flatnonzero(later):
        flags[t] = flagged0[t]
        positions[t] = reported[t]
        for a in np.flatnonzero(flagged0[t]):
            ti, ai = np.array([t]), np.array([a])
            settle(ti, ai, *_stage2(reported, dists, measured, flags, ti, ai, p))

    thin = flags & (anchors < 3)
    # a drone that measured no range has no vote (every pair abstains): nothing checked the
    # report the verdict passes through, so it is not `ok` (9 drones with no range at all
    # were `ok`, a spoofed one 27 m off among them)
    voters = (~np.isnan(ranges) & ~np.eye(n, dtype=bool)).sum(axis=2)
    thin |= ~flags & (voters == 0)
    # The vote's own consistency test, applied to the answer: a recovered drone whose anchors
    # would still vote against it (a wrong local minimum of the solver) is an alarm.
    after = pairwise_votes(positions, np.where(flags[:, None, :], np.nan, ranges), p.tau)
    revote = after < 0 if p.tie == "honest" else after <= 0
    alarm = (flags & ~thin & revote).any(axis=1)
    status = np.where(alarm, "alarm", np.where(thin.any(axis=1), "degenerate", "ok"))
    return VerdictBatch(
        positions=positions,
        faulty=flags,
        status=status,
        diagnostics={
            "votes": votes,
            "flagged_by_vote": flagged0,
            "anchors": anchors,
            "deviation": deviation,
        },
        drone_status=np.where(alarm[:, None], "alarm", np.where(thin, "degenerate", "ok")),
    )

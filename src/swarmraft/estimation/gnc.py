"""The `joint` detector: a robust joint estimate of every position from all GNSS reports and
all ranges by graduated non-convexity (GNC) with the Geman-McClure loss (Yang, Antonante,
Tzoumas, Carlone, "Graduated Non-Convexity for Robust Spatial Perception", RA-L 2020). The
weights start nearly quadratic and are tightened step by step, so spoofed reports and tampered
ranges lose their weight without an explicit search over subsets. Drones whose GNSS residual
stays beyond the chi-square 3-dof 0.999 quantile (or most of whose own ranges are outliers)
are flagged, flagged drones whose reports agree with the others' ranges are re-included, and
all positions are re-estimated with the rest trusted, which also brings the honest drones
below their raw GNSS error. The final set goes through `integrity.finish` (robust estimate
from several starts including the GNC estimate, statuses, protection levels); flagging more
than ``f_max`` drones is an ``alarm``. Where the answer is an alarm (GNC settled on a wrong
partition, about 1 % of trials with 8 of 17 drones spoofed), the clique detector's answer is
used if its status is better."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from swarmraft.estimation.bounds import CHI2_3DOF_999
from swarmraft.estimation.clique import CliqueParams, clique_detector
from swarmraft.estimation.integrity import IntegrityParams, finish, resolve_f_max, status_rank
from swarmraft.estimation.joint import joint_estimate, residuals, weighted_gauss_newton
from swarmraft.estimation.noise import NoiseModel
from swarmraft.estimation.registry import register
from swarmraft.estimation.snapshot import SnapshotBatch, VerdictBatch


def geman_mcclure_weights(r2: np.ndarray, c2: float, mu: float) -> np.ndarray:
    """GNC Geman-McClure weights for squared whitened residuals r2 (Yang et al. 2020)."""
    return (mu * c2 / (r2 + mu * c2)) ** 2


def gnc_estimate(
    reported: np.ndarray,
    ranges: np.ndarray,
    gnss_cov: np.ndarray,
    range_sigma: float,
    c_gnss: float = 4.0,
    c_range: float = 4.0,
    mu_factor: float = 2.0,
    max_outer: int = 60,
    inner: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust joint estimate by graduated non-convexity: all GNSS reports and all ranges,
    Geman-McClure weights relaxed from nearly quadratic (large mu) to the true robust loss
    (mu = 1). ``c_gnss`` is the inlier bound on the whitened 3-D GNSS residual norm,
    ``c_range`` on the whitened range residual. Returns positions (T, n, 3), GNSS weights
    (T, n) and range weights (T, n, n).

    Every trial has its own mu, started from its own largest residual, divided by
    ``mu_factor`` each round down to 1; a trial stops (its positions, weights and residuals
    no longer change) after its round at mu = 1, or after ``max_outer`` rounds. A trial's
    answer therefore does not depend on the other trials of its batch: run alone (a leader
    step) or in a sweep chunk of any size, it is the same bit for bit."""
    T, n, _ = reported.shape
    G_half = np.linalg.cholesky(np.linalg.inv(np.asarray(gnss_cov, float))).T
    meas = ~np.isnan(ranges) & ~np.eye(n, dtype=bool)
    gnss_w = np.ones((T, n))
    range_w = meas.astype(float)
    x = weighted_gauss_newton(
        reported, reported, ranges, gnss_w, range_w, gnss_cov, range_sigma, iters=inner + 2
    )
    rg, rr = residuals(x, reported, ranges, G_half, range_sigma)
    r2g, r2r = np.einsum("tni,tni->tn", rg, rg), np.where(meas, rr**2, 0.0)
    worst_g, worst_r = r2g.max(axis=1) / c_gnss**2, r2r.max(axis=(1, 2)) / c_range**2
    # np.where(b > a, b, a) and np.where(1 > m, 1, m): Python's max, nan included, per trial
    mu = np.maximum(2 * np.where(worst_r > worst_g, worst_r, worst_g), 1.0)
    active = np.arange(T)
    for _ in range(max_outer):
        # while every trial is active (always, for a single snapshot), views instead of copies
        sel = slice(None) if active.size == T else active
        m = mu[sel]
        gw = geman_mcclure_weights(r2g[sel], c_gnss**2, m[:, None])
        rw = np.where(meas[sel], geman_mcclure_weights(r2r[sel], c_range**2, m[:, None, None]), 0.0)
        rep, rng_ = reported[sel], ranges[sel]
        xa = weighted_gauss_newton(x[sel], rep, rng_, gw, rw, gnss_cov, range_sigma, iters=inner)
        rg, rr = residuals(xa, rep, rng_, G_half, range_sigma)
        x[sel] = xa
        r2g[sel] = np.einsum("tni,tni->tn", rg, rg)
        r2r[sel] = np.where(meas[sel], rr**2, 0.0)
        settled = m <= 1.0
        m = m / mu_factor
        mu[sel] = np.where(1.0 > m, 1.0, m)
        active = active[~settled]
        if not active.size:
            break
    gnss_w = geman_mcclure_weights(r2g, c_gnss**2, 1.0)
    range_w = np.where(meas, geman_mcclure_weights(r2r, c_range**2, 1.0), 0.0)
    return x, gnss_w, range_w


class JointParams(IntegrityParams):
    c_gnss: float = Field(4.0, gt=0, description="GNC inlier bound, whitened GNSS residual")
    c_range: float = Field(4.0, gt=0, description="GNC inlier bound, whitened range residual")
    mu_factor: float = Field(2.0, gt=1, description="GNC: divide mu by this each round (1.4 in Yang et al.)")
    inner: int = Field(1, ge=1, description="GNC: Gauss-Newton iterations per round")
    flag_chi2: float = Field(CHI2_3DOF_999, gt=0, description="flag GNSS residual^2 above")


@register("joint", JointParams, "robust joint estimate (GNC, Geman-McClure) of all positions")
def joint_detector(batch: SnapshotBatch, p: JointParams) -> VerdictBatch:
    reported = np.asarray(batch.reported, float)
    ranges = np.asarray(batch.ranges, float)
    n = reported.shape[1]
    noise = NoiseModel.of(batch, p, "joint")
    f_max = resolve_f_max(p, n, "joint")
    x, gnss_w, range_w = gnc_estimate(
        reported,
        ranges,
        noise.gnss_cov,
        noise.range_sigma,
        p.c_gnss,
        p.c_range,
        p.mu_factor,
        max_outer=60,
        inner=p.inner,
    )
    G_half = noise.whitener
    rg, _ = residuals(x, reported, ranges, G_half, noise.range_sigma)
    own = ~np.isnan(ranges) & ~np.eye(n, dtype=bool)
    bad_ranges = ((range_w < 0.5) & own).sum(axis=2) > 0.5 * own.sum(axis=2)
    faulty = (np.einsum("tni,tni->tn", rg, rg) > p.flag_chi2) | bad_ranges
    # Re-inclusion: estimate with the flagged drones distrusted; a flagged drone whose report
    # agrees with where the others' ranges put it was flagged wrongly (GNC can settle on a
    # wrong partition when many reports are spoofed).
    for _ in range(2):
        x = joint_estimate(reported, ranges, ~faulty, noise.gnss_cov, noise.range_sigma)
        rg, _ = residuals(x, reported, ranges, G_half, noise.range_sigma)
        back = faulty & ~bad_ranges & (np.einsum("tni,tni->tn", rg, rg) <= p.flag_chi2)
        if not back.any():
            break
        faulty &= ~back
    too_many = np.where(faulty.sum(axis=1) > f_max, "alarm", "ok")
    v = finish(batch, p, noise, ~faulty, (x,), too_many, diagnostics={"gnss_weight": gnss_w})
    # GNC can settle on a wrong partition: where its answer is an alarm, the clique
    # detector's answer is taken if its status is better.
    bad = v.status == "alarm"
    if bad.any():
        shared = p.model_dump(exclude=set(JointParams.model_fields) - set(IntegrityParams.model_fields))
        alt = clique_detector(batch.subset(bad), CliqueParams(**{**shared, "f_max": f_max}))
        better = status_rank(alt.status) < status_rank(v.status[bad])
        idx = np.flatnonzero(bad)[better]
        for name in ("positions", "faulty", "status", "drone_status", "hpl", "vpl"):
            getattr(v, name)[idx] = getattr(alt, name)[better]
    return v

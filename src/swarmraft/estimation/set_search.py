"""Every trusted set, for a verdict that ended in ``alarm``: smallest exclusion first.

A detector's alarm says its chosen set fails its tests and exclusion is exhausted. Where the
swarm is small, every set that leaves out at most ``f_max`` drones can be tried instead, as
RAIM's exhaustive fault detection and exclusion does: for k = 0, 1, ..., ``f_max`` drones
left out, each of the C(n, k) sets is given to the estimator (`integrity.given_set`); a set
explains the data where it passes its tests (status ``ok``, or ``degenerate`` where the
geometry leaves a drone unfixed). At the smallest k with an explanation, one explanation is
the answer (judged again by `integrity.finish`, rivals and all), several are
``unidentifiable`` (estimated from the drones all of them trust, only the drones outside
all of them flagged), and where no set explains the data up to ``f_max`` the alarm stands.
An ``ok`` answer becomes ``unidentifiable`` where any other explanation (more drones left
out included: no margin) places some drone beyond its protection levels: at (9, 4) trial
9,147 the smallest explanation left out 3 drones, trusted 2 spoofers and placed drones 66 m
off, and the true set (4 out, ``degenerate``) was the rival that showed it. The search runs
only where all its sets, the sum of C(n, k) for k up to ``f_max``, are at most ``cap``: 256
at n = 9, 4,096 at 13, 65,536 at 17. A set that no estimate could pass (`cannot_pass`: most of
them) is not estimated, which leaves every verdict as it was (a verdict does not depend on
the others in its batch) and an alarm step at 14-49 ms at n = 9 (`benchmarks/bench_set_search.py`).

At (9, 4) (realistic, jumps of 10-100 m) `joint`'s alarms are 4 % of the trials and 65 % of
the attacked drones' squared error: `benchmarks/alarm_sets.py`, and README, "Integrity,
measured"."""

from __future__ import annotations

import itertools
import math

import numpy as np

from swarmraft.estimation.integrity import IntegrityParams, finish, given_set, status_rank
from swarmraft.estimation.joint import chi2_quantile
from swarmraft.estimation.noise import NoiseModel, gnss_information
from swarmraft.estimation.snapshot import SnapshotBatch, VerdictBatch


def sets_leaving_out(n: int, k: int) -> np.ndarray:
    """Every trusted set (C(n, k), n) of n drones with exactly k left out, in
    lexicographic order of the drones left out."""
    out = np.ones((math.comb(n, k), n), dtype=bool)
    for row, left in enumerate(itertools.combinations(range(n), k)):
        out[row, list(left)] = False
    return out


def search_alarms(
    batch: SnapshotBatch, p: IntegrityParams, noise: NoiseModel, v: VerdictBatch, f_max: int, cap: int
) -> VerdictBatch:
    """``v`` with each ``alarm`` verdict replaced by the exhaustive search's answer where it
    is better (see the module docstring); ``cap`` sets at most per trial (0: no search)."""
    rows = np.flatnonzero(v.status == "alarm")
    n = v.faulty.shape[1]
    if not rows.size or sum(math.comb(n, k) for k in range(f_max + 1)) > cap:
        return v
    sets = np.concatenate([sets_leaving_out(n, k) for k in range(f_max + 1)])
    for t in rows:
        w = _search(batch, p, noise, t, sets)
        if w is not None and status_rank(w.status)[0] < status_rank(v.status[t : t + 1])[0]:
            v = v.with_rows(np.array([t]), w, np.array([0]))
    return v


def _search(
    batch: SnapshotBatch, p: IntegrityParams, noise: NoiseModel, t: int, sets: np.ndarray
) -> VerdictBatch | None:
    """The search's verdict for trial t over ``sets`` (S, n), or None where no set passes."""
    n = sets.shape[1]
    one = batch.subset(np.array([t]))
    # a set explains the data when it passes its tests: `ok`, or `degenerate` where the
    # geometry leaves some drone unfixed (an explanation all the same); a set that no estimate
    # could pass is not estimated (a verdict does not depend on the others in its batch)
    live = ~cannot_pass(one, p, noise, sets)
    explains = np.zeros(len(sets), dtype=bool)
    positions = np.full((len(sets), n, 3), np.nan)
    if live.any():
        g = given_set(batch.subset(np.full(int(live.sum()), t)), p, sets[live])
        explains[live] = g.status != "alarm"
        positions[live] = g.positions
    if not explains.any():
        return None
    left_out = (~sets).sum(axis=1)
    first = explains & (left_out == left_out[explains].min())
    if first.sum() > 1:
        return _unidentifiable(one, p, noise, sets[first])
    w = finish(one, p, noise, sets[first])
    if w.status[0] != "ok":
        return w
    # every other explanation is a rival where it places some drone beyond the answer's
    # levels: two explanations with at most f_max attackers (a set with more drones left
    # out is one too: no margin here, the search answers alarms only)
    d = positions[explains] - w.positions[0]
    with np.errstate(invalid="ignore"):
        beyond = (np.hypot(d[..., 0], d[..., 1]) > w.hpl[0]) | (np.abs(d[..., 2]) > w.vpl[0])
    rivals = sets[explains][beyond.any(axis=1)]
    if len(rivals):
        return _unidentifiable(one, p, noise, np.concatenate([sets[first], rivals]))
    return w


def cannot_pass(one: SnapshotBatch, p: IntegrityParams, noise: NoiseModel, sets: np.ndarray) -> np.ndarray:
    """Sets (S, n) of the one-trial batch ``one`` whose residual tests (`joint.tests_pass`) fail
    whatever the estimate (S,). Two trusted drones i, j with a range d_ij that i measured: the
    local test bounds each one's GNSS residual by r = sqrt(L / lambda_min) (L its 3-dof
    quantile at p_fa / n, lambda_min the GNSS information's smallest eigenvalue) and the global
    test bounds the range residual by range_sigma sqrt(G) (G its quantile at p_fa with the
    set's degrees of freedom), so |(|z_i - z_j|) - d_ij| <= 2 r + range_sigma sqrt(G) for
    their reports z in any passing estimate. A set with a pair beyond it fails; a set with no
    degrees of freedom (the global test then passes) is never ruled out here."""
    z = np.asarray(one.reported, float)[0]
    ranges = np.asarray(one.ranges, float)[0]
    n = z.shape[0]
    lam = float(np.linalg.eigvalsh(gnss_information(noise.gnss_cov))[0])
    reach = 2.0 * np.sqrt(chi2_quantile(1 - p.p_fa / n, 3) / lam)
    measured = ~np.isnan(ranges) & ~np.eye(n, dtype=bool)
    with np.errstate(invalid="ignore"):
        gap = np.where(measured, np.abs(np.linalg.norm(z[:, None] - z[None], axis=2) - ranges), 0.0)
    own = (measured[None] & sets[:, :, None]).sum(axis=(1, 2))
    dof = 3 * sets.sum(axis=1) + own - 3 * n
    limit = reach + noise.range_sigma * np.sqrt(chi2_quantile(1 - p.p_fa, np.maximum(dof, 1)))
    limit = limit * (1 + 1e-9)  # rounding in the bound's own arithmetic never rules out a set
    both = sets[:, :, None] & sets[:, None, :]
    beyond = (both & (gap[None] > limit[:, None, None])).any(axis=(1, 2))
    return beyond & (dof > 0) & np.isfinite(z).all()


def _unidentifiable(
    one: SnapshotBatch, p: IntegrityParams, noise: NoiseModel, sets: np.ndarray
) -> VerdictBatch:
    """Several trusted sets explain trial ``one``: estimated from the drones all of them
    trust, only the drones outside all of them flagged."""
    common = sets.all(axis=0)[None]
    outside = ~sets.any(axis=0)[None]
    return finish(one, p, noise, common, status=np.array(["unidentifiable"]), faulty=outside)

"""Every trusted set, for a verdict that ended in ``alarm`` or in a ``degenerate`` one that
accuses drones: smallest exclusion first.

A detector's alarm says its chosen set fails its tests and exclusion is exhausted. Where the
swarm is small, every set that leaves out at most ``f_max`` drones can be tried instead, as
RAIM's exhaustive fault detection and exclusion does: for k = 0, 1, ..., ``f_max`` drones
left out, each of the C(n, k) sets is given to the estimator (`integrity.given_set`); a set
explains the data where it passes its tests (status ``ok``, or ``degenerate`` where the
geometry leaves a drone unfixed or its level is above the alert limits). At the smallest k
with an explanation, one explanation is the answer (judged again by `integrity.finish`,
rivals and all), several are ``unidentifiable`` (estimated from the drones all of them
trust, only the drones outside all of them flagged), and where no set explains the data up
to ``f_max`` the alarm stands, with the positions and flags of the likeliest set that passes
its residual tests and fails only its separation test (`_likeliest_alarm`), where there is
one. An ``ok`` answer becomes ``unidentifiable`` where any other explanation (more drones
left out included: no margin) places some drone beyond its protection levels: at (9, 4)
trial 9,147 the smallest explanation left out 3 drones, trusted 2 spoofers and placed drones
66 m off, and the true set (4 out, ``degenerate``) was the rival that showed it.

A ``degenerate`` verdict that accuses k drones is searched too, and replaced where a set
leaving out fewer than k drones explains the data and the search's answer is ``ok`` or
``unidentifiable`` (its drones fixed, or the doubt said): the detector's set was not the
smallest explanation. At (7, 1) trials 3,972 and 7,014 `joint` left 3 honest drones out and
trusted 4 drones, the spoofer among them, on the mirror side of the plane of the other three
(a reflection keeps every range): ``degenerate``, the spoofer 94 m off. The true set, 1 out,
passes; the mirror set is its rival: ``unidentifiable``, nobody accused. The search runs
only where all its sets, the sum of C(n, k) for k up to ``f_max``, are at most ``cap``: 256
at n = 9, 4,096 at 13, 65,536 at 17. A set that no estimate could pass (`joint.cannot_pass`: most of
them) is not estimated, which leaves every verdict as it was (a verdict does not depend on
the others in its batch) and an alarm step at 14-49 ms at n = 9 (`benchmarks/bench_set_search.py`).
The sets are estimated a block of equal size at a time and the search stops once its answer is
known (`_search`); ``budget`` (`joint`'s ``search_budget``) bounds the sets estimated for one
verdict, a verdict whose search needs more standing as it is.

At (9, 4) (realistic, jumps of 10-100 m) `joint`'s alarms are 4 % of the trials and 65 % of
the attacked drones' squared error: `benchmarks/alarm_sets.py`, and docs/integrity.md,
"Where the efficiency goes"."""

from __future__ import annotations

import functools
import itertools
import math

import numpy as np

from swarmraft.estimation.integrity import IntegrityParams, finish, given_set, status_rank
from swarmraft.estimation.joint import cannot_pass, residual_statistics
from swarmraft.estimation.noise import NoiseModel
from swarmraft.estimation.snapshot import SnapshotBatch, VerdictBatch

# sets estimated together: how many drones each leaves out, their rows in the search's sets,
# and their verdicts
Block = tuple[int, np.ndarray, VerdictBatch]


@functools.lru_cache(maxsize=64)
def sets_leaving_out(n: int, k: int) -> np.ndarray:
    """Every trusted set (C(n, k), n) of n drones with exactly k left out, in
    lexicographic order of the drones left out (read-only: built once per (n, k), 18 ms of
    a step at n = 13 when it was built on every search)."""
    out = np.ones((math.comb(n, k), n), dtype=bool)
    for row, left in enumerate(itertools.combinations(range(n), k)):
        out[row, list(left)] = False
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=16)
def _every_set(n: int, f_max: int) -> np.ndarray:
    """Every set leaving out at most ``f_max`` of n drones, by how many it leaves out
    (read-only)."""
    out = np.concatenate([sets_leaving_out(n, k) for k in range(f_max + 1)])
    out.flags.writeable = False
    return out


def search_sets(
    batch: SnapshotBatch,
    p: IntegrityParams,
    noise: NoiseModel,
    v: VerdictBatch,
    f_max: int,
    cap: int,
    budget: int | None = None,
) -> VerdictBatch:
    """``v`` with each ``alarm`` verdict, and each ``degenerate`` one that accuses drones,
    replaced by the exhaustive search's answer where it is better (see the module docstring);
    ``cap`` sets at most per trial (0: no search); ``budget``: sets estimated at most per
    verdict (None: no limit), a verdict whose search would need more stands as it is."""
    accused = v.faulty.sum(axis=1)
    status = decided(v)
    rows = np.flatnonzero((status == "alarm") | ((status == "degenerate") & (accused > 0)))
    n = v.faulty.shape[1]
    if not rows.size or sum(math.comb(n, k) for k in range(f_max + 1)) > cap:
        return v
    sets = _every_set(n, f_max)
    for t in rows:
        # a degenerate verdict is replaced only by an answer leaving out fewer drones
        below = None if status[t] == "alarm" else int(accused[t])
        found = _search(batch, p, noise, t, sets, below, budget)
        if found is None:
            continue
        w, k, explained = found
        answer = decided(w)[0]
        if status[t] == "alarm":
            # an explanation where it is better; else the likeliest set that passes its
            # residual tests (an alarm still, its positions those of that set)
            better = not explained or status_rank(np.array([answer]))[0] < status_rank(status[t : t + 1])[0]
        else:
            better = explained and k < accused[t] and answer in ("ok", "unidentifiable")
        if better:
            v = v.with_rows(np.array([t]), w, np.array([0]))
    return v


def decided(v: VerdictBatch) -> np.ndarray:
    """The statuses the search decides on: the verdicts' own without the alert limits (a
    drone withheld for its level changes the label, not what the data explain)."""
    return np.asarray(v.diagnostics.get("status_without_limits", v.status)).astype(str)


def _search(
    batch: SnapshotBatch,
    p: IntegrityParams,
    noise: NoiseModel,
    t: int,
    sets: np.ndarray,
    below: int | None = None,
    budget: int | None = None,
) -> tuple[VerdictBatch, int, bool] | None:
    """The search's verdict for trial t over ``sets`` (S, n; ordered by how many drones each
    leaves out), the fewest drones an explanation leaves out, and True; where no set passes,
    the `alarm` verdict of the set that passes its residual tests (only its separation test
    fails) leaving out fewest drones, with the lowest chi-square, that number and False; None
    where there is none either, or where ``below`` is given and no set leaving out fewer than
    ``below`` drones explains the data (the caller would not use the answer), or where the
    answer needs more than ``budget`` sets estimated (the verdict then stands: a search cut
    short could miss the explanation, or the rival, that decides it).

    The sets are estimated a block of equal size at a time, smallest exclusion first, and the
    search stops as soon as its answer is known: at the first block with an explanation
    unless its answer is ``ok`` (then every explanation may be a rival, and every set is
    estimated), and at ``below``. The answer is the one estimating every set would give (a
    verdict does not depend on the others in its batch), for a fraction of the cost where a
    flat layer makes most verdicts ``degenerate``: at (13, 6) in a flat layer a verdict
    accusing 6 drones had 1-121 live sets, of which 0-28 leave out fewer."""
    n = sets.shape[1]
    one = batch.subset(np.array([t]))
    # a set explains the data when it passes its tests: `ok`, or `degenerate` where the
    # geometry leaves some drone unfixed or above the alert limits (an explanation all the
    # same); a set that no estimate could pass is not estimated
    # (checked a block at a time, where the block is estimated: a set's check is its own)
    reported, ranges = np.asarray(one.reported, float), np.asarray(one.ranges, float)
    left_out = (~sets).sum(axis=1)
    edges = np.searchsorted(left_out, np.arange(int(left_out.max()) + 2))  # blocks: sets by k
    explains = np.zeros(len(sets), dtype=bool)
    positions = np.full((len(sets), n, 3), np.nan)
    withheld = np.zeros((len(sets), n), dtype=bool)  # placed, but beyond the alert limits
    blocks: list[Block] = []

    spent = 0

    def estimate(k: int) -> bool:
        """Estimates the live sets leaving out k drones; False where the budget cannot."""
        nonlocal spent
        block = np.arange(edges[k], edges[k + 1])
        owner, sigma = np.zeros(block.size, dtype=int), noise.range_sigma
        # the wider band (`joint.cannot_pass`): ``budget`` counts the sets estimated, and the
        # verdicts of searches that reach it stay those measured with it
        args = (reported, ranges, sets[block], owner, noise.gnss_cov, sigma, p.p_fa)
        ruled = cannot_pass(*args, along_line=False)
        rows = block[~ruled]
        spent += rows.size
        if budget is not None and spent > budget:
            return False
        if rows.size:
            g = given_set(batch.subset(np.full(rows.size, t)), p, sets[rows], keep_unverified=True)
            explains[rows] = g.status != "alarm"
            positions[rows] = g.positions
            withheld[rows] = g.diagnostics["beyond_alert_limit"]
            blocks.append((k, rows, g))
        return True

    sizes = range(int(left_out.max()) + 1)
    for k in sizes:
        if below is not None and k >= below:
            return None
        if not estimate(k):
            return None
        if explains.any():
            break
    if not explains.any():
        return _likeliest_alarm(one, noise, blocks, sets)
    first = explains & (left_out == k)
    if first.sum() > 1:
        return _unidentifiable(one, p, noise, sets[first]), k, True
    w = finish(one, p, noise, sets[first])
    if decided(w)[0] != "ok":
        return w, k, True
    for rest in sizes[k + 1 :]:
        if not estimate(rest):
            return None
    # every other explanation is a rival where it places some drone beyond the answer's
    # levels: two explanations with at most f_max attackers (a set with more drones left
    # out is one too: no margin here, the search answers alarms only)
    d = positions[explains] - w.positions[0]
    with np.errstate(invalid="ignore"):
        beyond = (np.hypot(d[..., 0], d[..., 1]) > w.hpl[0]) | (np.abs(d[..., 2]) > w.vpl[0])
    # a drone the answer places and another explanation leaves undetermined (nan: a mirror
    # image fits as well) is placed only if that explanation is wrong: a rival too. In a flat
    # layer (7, 3), trial 539: the answer trusted a spoofer whose report lifted the anchors
    # out of their plane and placed a drone 48 m below its level of 15 m; the true set,
    # `degenerate`, could not place it. (A drone withheld for a level above the alert limits
    # is placed, only not well enough to use: no rival for that; at (7, 3), realistic cube,
    # trial 26 of seed 7 was a right `ok` verdict turned `unidentifiable` by one.)
    unplaced = np.isnan(positions[explains]).any(axis=2) & ~withheld[explains]
    beyond |= unplaced & np.isfinite(w.positions[0]).all(axis=1)
    rivals = sets[explains][beyond.any(axis=1)]
    if len(rivals):
        return _unidentifiable(one, p, noise, np.concatenate([sets[first], rivals])), k, True
    return w, k, True


def _likeliest_alarm(
    one: SnapshotBatch, noise: NoiseModel, blocks: list[Block], sets: np.ndarray
) -> tuple[VerdictBatch, int, bool] | None:
    """No set explains trial ``one``: of the sets estimated, ``blocks`` (each: how many
    drones its sets leave out, smallest first, their rows in ``sets`` (S, n) and their
    verdicts), those whose verdicts fail only the separation test (the fit passes its
    residual tests), the one leaving out fewest drones with the lowest chi-square: its `alarm`
    verdict, how many it leaves out, and False; None where every set fails its residual
    tests. At (9, 4) (realistic, 10,000 trials) the true honest set fails its own separation
    test in 67 of the search's 104 alarms."""
    for k, rows, g in blocks:
        pick = np.flatnonzero(np.asarray(g.diagnostics["alarm_cause"]).astype(str) == "separation test")
        if not pick.size:
            continue
        reported = np.repeat(np.asarray(one.reported, float), len(pick), axis=0)
        ranges = np.repeat(np.asarray(one.ranges, float), len(pick), axis=0)
        _, _, cost, _ = residual_statistics(g.positions[pick], reported, ranges, sets[rows[pick]], noise)
        best = pick[np.argmin(np.where(np.isfinite(cost), cost, np.inf))]
        return g.subset(np.array([best])), k, False
    return None


def _unidentifiable(
    one: SnapshotBatch, p: IntegrityParams, noise: NoiseModel, sets: np.ndarray
) -> VerdictBatch:
    """Several trusted sets explain trial ``one``: estimated from the drones all of them
    trust, only the drones outside all of them flagged."""
    common = sets.all(axis=0)[None]
    outside = ~sets.any(axis=0)[None]
    return finish(one, p, noise, common, status=np.array(["unidentifiable"]), faulty=outside)

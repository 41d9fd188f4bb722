"""The rigid registrations of the range-fixed shape to the GNSS reports: the candidates for
the honest set of the `shape` detector, and the rivals every statistical detector's verdict
can be checked against (`IntegrityParams.registration_rivals`).

UWB ranges (0.10 m) are about 30 times more precise than GNSS (1.5 m / 3 m per axis), so the
ranges alone fix the swarm's shape up to a rigid motion (`links.range_shape`). The honest
drones' reports are that shape moved into place, plus GNSS noise: one rigid registration.
Colluders that report a rigid motion of their true positions about up to 3 honest pivots are
a second, smaller one through the pivots. `candidates` finds the distinct inlier sets of the
registrations grown from consistent triples of drones (each handedness), keeps those leaving
at most ``f_max`` drones out, and solves and tests each (a joint estimate started from its
registration, the residual tests at ``p_fa``): see `shape` for the whole rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from itertools import combinations

import numpy as np
from numba import njit

from swarmraft.estimation.joint import chi2_quantile, joint_estimate, residual_statistics, tests_pass
from swarmraft.estimation.links import TAMPER_SHARE, range_shape
from swarmraft.estimation.noise import NoiseModel
from swarmraft.estimation.pairwise import consistency_graph
from swarmraft.estimation.rivals import Rivals

# the defaults of `shape.ShapeParams`, which the rival check uses as they are
MAX_TRIPLES = 6000  # registration seeds: every triple up to this many, else a fixed choice
MAX_SETS = 32  # distinct registrations per snapshot; beyond: the search was cut short
REFITS = 5  # refits of each registration on its inliers at most
PAIR_K = 5.0  # pairwise consistency (seed triangles) and two-way agreement, sigmas
COVER_PARTITIONS = 3  # the rival check's seed triples: splits of the drones (`covering_triples`)

_GOLDEN = (0.7548776662466927, 0.5698402909980532)  # the R2 sequence (Roberts 2018)


@lru_cache(maxsize=16)
def triples(n: int, cap: int) -> np.ndarray:
    """Triples of drone indices (m, 3): all of them if there are at most ``cap``, else ``cap``
    distinct ones from a fixed low-discrepancy sequence (the same for every call). Read-only,
    and kept: the sequence's de-duplication was 18 ms of a 65-drone step."""
    t = _triples(n, cap)
    t.flags.writeable = False
    return t


def _triples(n: int, cap: int) -> np.ndarray:
    if n < 3:
        return np.zeros((0, 3), dtype=int)
    if math.comb(n, 3) <= cap:
        return np.array(list(combinations(range(n), 3)), dtype=int)
    m = np.arange(4 * cap)
    i = m % n
    j = (i + 1 + (np.floor((m * _GOLDEN[0]) % 1 * (n - 1))).astype(int)) % n
    k = (i + 1 + (np.floor((m * _GOLDEN[1]) % 1 * (n - 1))).astype(int)) % n
    t = np.sort(np.stack([i, j, k], axis=1), axis=1)
    t = t[(t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2])]
    _, first = np.unique(t, axis=0, return_index=True)
    return t[np.sort(first)[:cap]]


@lru_cache(maxsize=64)
def covering_triples(n: int, m: int, cap: int, partitions: int = COVER_PARTITIONS) -> np.ndarray:
    """Seed triples (k, 3) for the sets of at least ``m`` of n drones: every triple where
    there are at most ``cap`` (`triples`), else enough to reach every such set, where a cap
    would sample: the drones are split into g = (m - 1) // 2 groups, and a set of m drones
    has 3 in some group (2 in each of g groups is fewer than m: Turan's construction), so the
    triples inside the groups hold a seed of every such set; ``partitions`` splits (each
    drone's group by index, then by index times a stride coprime to n whose square is not 1
    mod n; none such at n = 6, 8, 12, 24) give most sets several (their triples can
    coincide). A set that holds a seed is not always found from it (the seed may grow into
    another set). Where the Turan triples are not fewer than the cap's sample, the sample.
    At n = 65 with the default f_max, 209 triples where the cap samples 6,000 (60 ms of
    registrations a step). Read-only, and kept."""
    every = triples(n, cap)
    if math.comb(n, 3) <= cap:
        return every
    t = turan_triples(n, m, partitions)
    if not len(t) or len(t) >= len(every):
        return every
    t.flags.writeable = False
    return t


@lru_cache(maxsize=64)
def rival_seeds(n: int, m: int, cap: int) -> tuple[np.ndarray, np.ndarray]:
    """The rival check's seed triples (k, 3) for sets of at least m of n drones, and which of
    them (k,) are also tried with a handedness whose triple lies inside a set found with the
    other one: `covering_triples`, and of those, where they are every triple, the ones of
    `turan_triples` (every set of m drones still holds one, or all where that is empty). A
    flat formation's honest set holds most triples, each tried mirrored in vain: at n = 17
    two SVDs each, 2.6 ms of a 6.6 ms audit re-run. This search is not the whole one: a set
    the Turan seeds do not grow into, whose other seeds lie inside a set of the other
    handedness, is lost (a review's synthetic collusion at n = 9-13: 9 of 380 sets; the
    README's collusion table moved by 2 of 24,000 trials). Read-only, and kept."""
    tri = covering_triples(n, m, cap)
    inside = np.ones(len(tri), dtype=np.bool_)
    if math.comb(n, 3) <= cap:
        t = turan_triples(n, m, COVER_PARTITIONS)
        if len(t):
            inside = (tri[:, None, :] == t[None, :, :]).all(axis=2).any(axis=1)
    inside.flags.writeable = False
    return tri, inside


def turan_triples(n: int, m: int, partitions: int) -> np.ndarray:
    """Triples (k, 3) of n drones such that every set of at least m drones holds one from each
    of ``partitions`` splits into g = (m - 1) // 2 groups (`covering_triples`); none where
    g < 2 (a group would hold every drone)."""
    g = (m - 1) // 2
    if g < 2 or n < 3:
        return np.zeros((0, 3), dtype=int)
    chosen: set[tuple[int, int, int]] = set()
    strides = [s for s in range(2, n) if math.gcd(s, n) == 1 and s * s % n != 1][: partitions - 1]
    for stride in [1, *strides]:
        order = (np.arange(n) * stride) % n
        for group in np.array_split(order, g):
            chosen.update(tuple(sorted(int(v) for v in c)) for c in combinations(group, 3))
    return np.array(sorted(chosen), dtype=int).reshape(-1, 3)


def shape_ranges(ranges: np.ndarray, sigma: float, k: float) -> np.ndarray:
    """Which ranges (T, n, n) the shape is fitted to: every measured one, except where the two
    ways of a link disagree beyond ``k`` sqrt(2) sigma: then the way measured by a drone that
    disagrees with more than half of its two-way links (it tampers with its own ranges) is
    dropped and the other kept, or both are dropped if neither drone does."""
    n = ranges.shape[1]
    meas = ~np.isnan(ranges) & ~np.eye(n, dtype=bool)
    both = meas & np.swapaxes(meas, 1, 2)
    with np.errstate(invalid="ignore"):
        disagree = both & (np.abs(ranges - np.swapaxes(ranges, 1, 2)) > k * np.sqrt(2) * sigma)
    tamper = disagree.sum(axis=2) > TAMPER_SHARE * np.maximum(both.sum(axis=2), 1)
    keep_way = ~tamper[:, :, None] & tamper[:, None, :]  # i honest about a link to tamperer j
    return meas & ~tamper[:, :, None] & (~disagree | keep_way)


@njit(cache=True)
def _cross(y, z, w, yc, zc):  # pragma: no cover - compiled
    """The weighted centroids of points y, z (n, 3) (into yc, zc) and the SVD (U, Vt) of their
    weighted cross-covariance: what `_procrustes` needs of them whatever the handedness."""
    n = y.shape[0]
    sw = 0.0
    yc[:] = 0.0
    zc[:] = 0.0
    for i in range(n):
        sw += w[i]
        for a in range(3):
            yc[a] += w[i] * y[i, a]
            zc[a] += w[i] * z[i, a]
    for a in range(3):
        yc[a] /= sw
        zc[a] /= sw
    C = np.zeros((3, 3))
    for i in range(n):
        if w[i] > 0:
            for a in range(3):
                for b in range(3):
                    C[a, b] += w[i] * (z[i, a] - zc[a]) * (y[i, b] - yc[b])
    U, _, Vt = np.linalg.svd(C)
    return U, Vt


@njit(cache=True)
def _det3(A):  # pragma: no cover - compiled
    return (
        A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1])
        - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
        + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0])
    )


@njit(cache=True)
def _rotation(U, Vt, yc, zc, hand, R, tr):  # pragma: no cover - compiled
    """R with det R = ``hand`` and tr from `_cross`'s parts, in place. U and Vt are
    orthogonal (determinant +-1), so the sign of their determinants by cofactors is the sign
    LAPACK's LU would give."""
    d = hand * np.sign(_det3(U) * _det3(Vt))
    for a in range(3):
        for b in range(3):
            R[a, b] = U[a, 0] * Vt[0, b] + U[a, 1] * Vt[1, b] + d * U[a, 2] * Vt[2, b]
    for a in range(3):
        tr[a] = zc[a]
        for b in range(3):
            tr[a] -= R[a, b] * yc[b]


@njit(cache=True)
def _procrustes(y, z, w, hand, R, tr):  # pragma: no cover - compiled
    """Weighted orthogonal Procrustes (Kabsch): R (3, 3) with det R = ``hand`` (+1 or -1) and
    tr (3,) minimising sum_i w_i |z_i - R y_i - tr|^2 over points y, z (n, 3), in place."""
    yc = np.zeros(3)
    zc = np.zeros(3)
    U, Vt = _cross(y, z, w, yc, zc)
    _rotation(U, Vt, yc, zc, hand, R, tr)


def procrustes_fit(y: np.ndarray, z: np.ndarray, w: np.ndarray, hand: float) -> tuple[np.ndarray, np.ndarray]:
    """The rigid motion (R (3, 3) with det R = ``hand``, t (3,)) that best carries points y
    (n, 3) onto z (n, 3) in weighted least squares (weights w (n,)): z ~ R y + t."""
    R, t = np.zeros((3, 3)), np.zeros(3)
    _procrustes(
        np.ascontiguousarray(y, float), np.ascontiguousarray(z, float), np.asarray(w, float), hand, R, t
    )
    return R, t


@njit(cache=True)
def _inliers(y, z, Winv, threshold, placed, inl, R, tr):  # pragma: no cover - compiled
    """The placed drones within ``threshold`` of the registration R, tr of shape y (n, 3) to
    reports z (whitened by Winv) into ``inl`` (n,); returns how many."""
    cnt = 0
    e = np.zeros(3)
    for i in range(y.shape[0]):
        for a in range(3):
            e[a] = z[i, a] - tr[a]
            for b in range(3):
                e[a] -= R[a, b] * y[i, b]
        q = 0.0
        for a in range(3):
            for b in range(3):
                q += e[a] * Winv[a, b] * e[b]
        inl[i] = placed[i] and q <= threshold
        if inl[i]:
            cnt += 1
    return cnt


@njit(cache=True)
def _registration_kernel(
    shape, reported, placed, adj, tri, inside, Winv, threshold, refits, min_size, sets, hands, count
):  # pragma: no cover - compiled
    """Per trial, the distinct inlier sets of at least ``min_size`` drones of the rigid
    registrations grown from the triples ``tri`` that are triangles of the consistency graph
    ``adj``, each with both handednesses unless a set found with that handedness holds it;
    at most sets.shape[1] of them (count[t] one more than that when the cap cut the search
    short). A triangle inside a registration of the other handedness is tried where
    ``inside`` (per triple) says so: colluders reflected about three pivots with every honest
    drone near the pivots' plane make one registration of all the drones, and the honest
    drones' own one lies inside it."""
    T, n, _ = shape.shape
    M = sets.shape[1]
    w = np.zeros(n)
    inl = np.zeros(n, dtype=np.bool_)
    R = np.zeros((3, 3))
    tr = np.zeros(3)
    yc = np.zeros(3)
    zc = np.zeros(3)
    U = np.zeros((3, 3))
    Vt = np.zeros((3, 3))
    for t in range(T):
        c = 0
        for m in range(tri.shape[0]):
            i, j, k = tri[m, 0], tri[m, 1], tri[m, 2]
            if not (placed[t, i] and placed[t, j] and placed[t, k]):
                continue
            if not (adj[t, i, j] and adj[t, i, k] and adj[t, j, k]):
                continue
            seeded = False  # the triple's own SVD, the same for both handednesses
            for hi in range(2):
                hand = 1.0 - 2.0 * hi
                covered = False
                for s in range(min(c, M)):
                    if (
                        (hands[t, s] == hand or not inside[m])
                        and sets[t, s, i]
                        and sets[t, s, j]
                        and sets[t, s, k]
                    ):
                        covered = True
                        break
                if covered:
                    continue
                w[:] = 0.0
                w[i] = w[j] = w[k] = 1.0
                ok = False
                for it in range(refits + 1):
                    if it == 0:
                        if not seeded:
                            U, Vt = _cross(shape[t], reported[t], w, yc, zc)
                            seeded = True
                        _rotation(U, Vt, yc, zc, hand, R, tr)
                        got = _inliers(shape[t], reported[t], Winv, threshold, placed[t], inl, R, tr)
                    else:
                        _procrustes(shape[t], reported[t], w, hand, R, tr)
                        got = _inliers(shape[t], reported[t], Winv, threshold, placed[t], inl, R, tr)
                    if got < 3:
                        ok = False
                        break
                    ok = True
                    same = True
                    for a in range(n):
                        if (w[a] > 0) != inl[a]:
                            same = False
                        w[a] = 1.0 if inl[a] else 0.0
                    if same:
                        break
                if not ok or inl.sum() < min_size:
                    continue
                dup = False
                for s in range(min(c, M)):
                    eq = True
                    for a in range(n):
                        if sets[t, s, a] != inl[a]:
                            eq = False
                            break
                    if eq:
                        dup = True
                        break
                if dup:
                    continue
                if c < M:
                    sets[t, c, :] = inl
                    hands[t, c] = hand
                c += 1
                if c > M:
                    break
            if c > M:
                break
        count[t] = c


@njit(cache=True)
def _registered_kernel(shape, reported, masks, hands, placed, out):  # pragma: no cover - compiled
    """For each candidate b: the shape registered (`_procrustes`) to the reports of its placed
    members with its handedness, every placed drone at its registered position and the others
    at their reports, into out[b] (n, 3); the reports where fewer than 3 members are placed."""
    B, n, _ = shape.shape
    R = np.zeros((3, 3))
    tr = np.zeros(3)
    w = np.zeros(n)
    for b in range(B):
        cnt = 0
        for i in range(n):
            w[i] = 1.0 if masks[b, i] and placed[b, i] else 0.0
            cnt += masks[b, i] and placed[b, i]
        out[b] = reported[b]
        if cnt < 3:
            continue
        _procrustes(shape[b], reported[b], w, hands[b], R, tr)
        for i in range(n):
            if placed[b, i]:
                for a in range(3):
                    out[b, i, a] = (
                        tr[a] + R[a, 0] * shape[b, i, 0] + R[a, 1] * shape[b, i, 1] + R[a, 2] * shape[b, i, 2]
                    )


def registered(
    shape: np.ndarray, reported: np.ndarray, masks: np.ndarray, hands: np.ndarray, placed: np.ndarray
) -> np.ndarray:
    """Positions (B, n, 3): each candidate's registration of the shape (B, n, 3) to the
    reports of its members ``masks`` (B, n) with handedness ``hands`` (B,) (unplaced drones
    at their reports): the start of its joint estimate, every drone already where the
    ranges put it relative to the trusted ones."""
    out = np.empty_like(np.asarray(reported, float))
    _registered_kernel(
        np.ascontiguousarray(shape, float),
        np.ascontiguousarray(reported, float),
        np.ascontiguousarray(masks, np.bool_),
        np.ascontiguousarray(hands, float),
        np.ascontiguousarray(placed, np.bool_),
        out,
    )
    return out


def registration_sets(
    shape: np.ndarray,
    reported: np.ndarray,
    placed: np.ndarray,
    adj: np.ndarray,
    cov: np.ndarray,
    threshold: float,
    cap: int,
    refits: int,
    max_sets: int,
    min_size: int,
    covering: bool = False,
) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Per trial, the distinct inlier sets (m, n) and their handednesses (m,) of the rigid
    registrations of the shape (T, n, 3) to the reports (module docstring), grown from
    triangles of the consistency graph ``adj`` (T, n, n) of ``placed`` drones; inliers:
    whitened squared residual (covariance ``cov``) <= ``threshold``; only sets of
    ``min_size`` drones or more (a candidate for the honest set leaves at most f_max out),
    seeded by every triple (at most ``cap``) or, with ``covering``, as `rival_seeds` says.
    Also whether each trial's search stopped at ``max_sets`` sets (T,)."""
    T, n, _ = shape.shape
    if covering:
        tri, inside = rival_seeds(n, min_size, cap)
    else:
        tri = triples(n, cap)
        inside = np.ones(len(tri), dtype=np.bool_)
    sets = np.zeros((T, max_sets, n), dtype=np.bool_)
    hands = np.zeros((T, max_sets))
    count = np.zeros(T, dtype=np.int64)
    _registration_kernel(
        np.ascontiguousarray(shape, float),
        np.ascontiguousarray(reported, float),
        np.ascontiguousarray(placed, np.bool_),
        np.ascontiguousarray(adj, np.bool_),
        np.ascontiguousarray(tri, np.int64),
        inside,
        np.linalg.inv(cov),
        float(threshold),
        int(refits),
        int(min_size),
        sets,
        hands,
        count,
    )
    kept = np.minimum(count, max_sets)
    return [sets[t, : kept[t]] for t in range(T)], [hands[t, : kept[t]] for t in range(T)], count > max_sets


def distinct_explanations(masks: np.ndarray, x: np.ndarray, Winv: np.ndarray, threshold: float) -> np.ndarray:
    """Which of the passing sets (m, n), with their joint estimates x (m, n, 3), are explanations
    of their own (m,): a set inside a larger one whose estimate places every drone within
    ``threshold`` (whitened by Winv) of it is the same explanation with drones left out; a
    set inside a larger one that places some drone further away is another (e.g. colluders
    reflected about three pivots with every honest drone near the pivots' plane: all the
    drones fit the reflection, and the honest ones the truth)."""
    inside = (masks[:, None, :] <= masks[None, :, :]).all(axis=2)  # a within b
    strict = inside & ~inside.T
    d = x[:, None] - x[None, :]
    apart = (np.einsum("abni,ij,abnj->abn", d, Winv, d) > threshold).any(axis=2)
    return ~(strict & ~apart).any(axis=1)


@dataclass(frozen=True)
class Candidates:
    """The registrations' candidate sets of a batch of T trials, B in all, by trial: each
    one's trial ``owner`` (B,), set ``masks`` (B, n, largest first within a trial),
    handedness ``hands`` (B,), joint estimate ``x`` (B, n, 3), chi-square ``total`` (B,) and
    whether it passes the residual tests ``passed`` (B,); per trial, whether the search
    stopped at ``max_sets`` registrations ``capped`` (T,); and the inlier test (whitening
    ``Winv`` (3, 3), chi-square ``threshold``) that `distinct_explanations` reuses."""

    owner: np.ndarray
    masks: np.ndarray
    hands: np.ndarray
    x: np.ndarray
    total: np.ndarray
    passed: np.ndarray
    capped: np.ndarray
    Winv: np.ndarray
    threshold: float

    def rivals(self, rows: np.ndarray) -> Rivals:
        """The candidate sets of the trials ``rows`` as rivals of their verdicts
        (`integrity.finish`'s rival check, `IntegrityParams.registration_rivals`): each with
        its trial, set, whether it passes the residual tests, estimate and chi-square."""
        return Rivals(self.owner, self.masks, self.passed, self.x, self.total).of_trials(rows)


def candidates(
    reported: np.ndarray,
    ranges: np.ndarray,
    noise: NoiseModel,
    f_max: int,
    p_fa: float,
    k: float = PAIR_K,
    max_triples: int = MAX_TRIPLES,
    refits: int = REFITS,
    max_sets: int = MAX_SETS,
    verdict: tuple[np.ndarray, np.ndarray] | None = None,
) -> Candidates:
    """The candidate sets of the trials (reported (T, n, 3), ranges (T, n, n)): the distinct
    inlier sets of the rigid registrations leaving at most ``f_max`` drones out, largest
    first, each solved and tested at ``p_fa`` (module docstring; `shape` for the rule). A
    trial without a registration has one candidate, the drones the shape does not place
    (none: nobody trusted). ``verdict``: the rival check's call, with each trial's trusted set
    (T, n) and whether its verdict is not an alarm (T,): the seeds are `rival_seeds` instead
    of `shape`'s (every triple, or the cap's sample), and a candidate equal to a non-alarm
    verdict's own set, never its rival, is not solved (x and chi-square nan, not passed)."""
    T, n, _ = reported.shape
    use = shape_ranges(ranges, noise.range_sigma, k)
    shape = range_shape(ranges, use, noise.range_sigma)
    linked = use | np.swapaxes(use, 1, 2)
    placed = linked.sum(axis=2) >= 4
    # the shape's own error (a few range sigmas per axis) beside each drone's GNSS error
    cov = noise.gnss_cov + (2 * noise.range_sigma) ** 2 * np.eye(3)
    threshold = float(chi2_quantile(1 - p_fa / n, 3))
    Winv = np.linalg.inv(cov)
    adj = consistency_graph(reported, ranges, noise, k)
    adj[:, np.arange(n), np.arange(n)] = True
    found, handed, capped = registration_sets(
        shape,
        reported,
        placed,
        adj,
        cov,
        threshold,
        max_triples,
        refits,
        max_sets,
        n - f_max,
        verdict is not None,
    )
    cands, hands = [], []
    for t, (sets, hs) in enumerate(zip(found, handed, strict=True)):
        if not len(sets):  # no registration: the drones the shape does not place, if any
            sets, hs = np.zeros((1, n), dtype=bool), np.ones(1)
        # a drone the shape does not place joins a set if its report agrees pairwise with
        # every member's report it has a range to (the residual tests then judge it)
        loose = ~placed[t][None, :] & (adj[t][None, :, :] | ~sets[:, None, :]).all(axis=2)
        sets = sets | loose
        keep = (n - sets.sum(axis=1)) <= f_max
        order = np.argsort(-sets[keep].sum(axis=1), kind="stable")
        cands.append(sets[keep][order])
        hands.append(hs[keep][order])
    owner = np.array([t for t, cs in enumerate(cands) for _ in cs], dtype=int)
    masks = np.concatenate(cands) if owner.size else np.zeros((0, n), dtype=bool)
    all_hands = np.concatenate(hands) if owner.size else np.zeros(0)
    passed, total = np.zeros(owner.size, dtype=bool), np.full(owner.size, np.nan)
    x = np.full((owner.size, n, 3), np.nan)
    solve = np.ones(owner.size, dtype=bool)
    if verdict is not None and owner.size:
        own, settled = verdict
        solve = ~settled[owner] | (masks != own[owner]).any(axis=1)
    if solve.any():
        # each candidate's joint estimate starts from its registration: with few trusted
        # drones (n near 2f+1) closed-form multilateration from them can start in a mirror
        o, ms = owner[solve], masks[solve]
        x0 = registered(shape[o], reported[o], ms, all_hands[solve], placed[o])
        x[solve] = joint_estimate(
            reported[o], ranges[o], ms, noise.gnss_cov, noise.range_sigma, iters=20, x0=x0
        )
        _, gnss_q, total[solve], dof = residual_statistics(x[solve], reported[o], ranges[o], ms, noise)
        passed[solve] = tests_pass(gnss_q, total[solve], dof, ms, p_fa)
    return Candidates(owner, masks, all_hands, x, total, passed, capped, Winv, threshold)

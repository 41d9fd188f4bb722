"""The joint estimate of a decided trusted set, robust to where the solver starts.

`robust_estimate` runs Levenberg-Marquardt with step acceptance from several starts
(closed-form multilateration, its mirror image across the anchors' best-fit plane, the
reports, the prior, and any start the caller brings) and keeps the lowest converged cost.
Converged starts that fit equally well but place a drone apart (a mirror of near-coplanar
anchors) leave that drone ambiguous; `integrity.assess` then calls it undetermined.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from swarmraft.estimation.envelope import SPARSE_SHARE
from swarmraft.estimation.joint import initial_positions, norm_apart, pair_distance, weighted_gauss_newton
from swarmraft.estimation.links import linked_share
from swarmraft.estimation.noise import NoiseModel


@dataclass(frozen=True)
class Estimate:
    """A joint estimate with its trusted set: positions (T, n, 3), cost (T,), converged (T,),
    ambiguous (T, n): drones placed apart by two equally good minima."""

    x: np.ndarray
    cost: np.ndarray
    converged: np.ndarray
    ambiguous: np.ndarray


def _trusted_weights(trusted: np.ndarray, prior: np.ndarray | None, shape: tuple[int, ...]):
    gnss_w = trusted.astype(float)
    range_w = np.broadcast_to(trusted[:, :, None], shape).astype(float)
    if prior is not None:
        prior = np.where(trusted[..., None], np.nan, prior)
    return gnss_w, range_w, prior


def robust_estimate(
    reported: np.ndarray,
    ranges: np.ndarray,
    trusted: np.ndarray,
    noise: NoiseModel,
    prior: np.ndarray | None = None,
    prior_sigma: float | None = None,
    starts: tuple[np.ndarray, ...] = (),
    iters: int = 50,
    window: float = 10.83,
) -> Estimate:
    """The joint estimate with a trusted set, from several starts (closed form, its mirror
    image, the reports, the prior, and ``starts``): GNSS of trusted drones, ranges measured
    by trusted drones, priors (nan rows = none) of untrusted drones. Converged minima whose
    cost is within ``window`` (default: chi-square 1 dof, 0.999) of the best and that place
    an untrusted drone further apart than its GNSS error could explain are ambiguous."""
    T, n, _ = reported.shape
    if not (prior is not None and prior_sigma):
        prior = None
    gnss_w, range_w, pr = _trusted_weights(trusted, prior, ranges.shape)
    closed = initial_positions(reported, ranges, trusted, pr)
    x0 = [closed, mirrored(closed, ranges, trusted), reported]
    if pr is not None:
        x0.append(np.where(np.isnan(pr), reported, pr))
    x0 += [np.where(np.isfinite(s), s, reported) for s in starts]
    S = len(x0)
    # a start identical to an earlier one of its trial (bit for bit: with every drone trusted
    # the closed form, its mirror image and the reports are one point) is solved once; the
    # solver treats each problem alone, so the copy is what solving it again would give
    # on a sparse range graph every start but the closed form first has its untrusted drones
    # settled into their own minima (`settled`); the closed form is left as it is
    sparse = linked_share(ranges) <= SPARSE_SHARE

    def settle(x0: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """`settled` on x0 (len(rows), n, 3) of the trials ``rows`` (x0 itself, nothing copied,
        where none of them is sparse: every dense batch)."""
        if not sparse[rows].any():
            return x0
        pr_rows = None if pr is None else pr[rows]
        return settled(x0, ranges[rows], trusted[rows], sparse[rows], noise.range_sigma, pr_rows, prior_sigma)

    t = np.arange(T)
    x0[1:] = [settle(v, t) for v in x0[1:]]
    X0 = np.concatenate(x0)
    source = _first_copy(X0.reshape(S, T, 3 * n))
    rows = np.flatnonzero(source == np.arange(S * T))
    r_t = rows % T

    def solve(x0: np.ndarray, rows: np.ndarray, reduced: bool = False) -> tuple[np.ndarray, ...]:
        """The solver from x0 (len(rows), n, 3) for the trials ``rows``."""
        return weighted_gauss_newton(
            x0,
            reported[rows],
            ranges[rows],
            gnss_w[rows],
            range_w[rows],
            noise.gnss_cov,
            noise.range_sigma,
            iters,
            prior=None if pr is None else pr[rows],
            prior_sigma=prior_sigma,
            full=True,
            reduced=reduced,
        )

    # Every start by the reduced solver (`joint.weighted_gauss_newton`: the same steps, not the
    # same bits; 1.7x faster a solve with 8 of 17 drones untrusted), then the start that won
    # solved again by the full one (and again, should another start then lead), so that the
    # estimate a verdict reports is the full solver's from its start, bit for bit. Trials
    # where the two are one solver (every drone trusted: none is free; a sparse range graph:
    # the envelope solve) are not solved again. The other starts' minima, which only decide
    # ambiguity, keep the reduced solver's bits (verdicts against the full solver everywhere:
    # flags and statuses the same, positions within 1e-6 m but near a line:
    # benchmarks/verdict_equivalence.py).
    twice = ~trusted.all(axis=1) & ~sparse
    X = np.empty((S * T, n, 3))
    cost, conv = np.empty(S * T), np.empty(S * T, dtype=bool)
    X[rows], cost[rows], conv[rows] = solve(X0[rows], r_t, reduced=True)
    X, cost, conv = X[source], cost[source], conv[source]
    X, cost, conv = X.reshape(S, T, n, 3), cost.reshape(S, T), conv.reshape(S, T)
    X0 = X0.reshape(S, T, n, 3)
    full = np.zeros((S, T), dtype=bool)  # which starts hold the full solver's minimum

    def solved_again() -> np.ndarray:
        """The best start of each trial, solved again by the full solver where it was not
        (in place on X, cost, conv and full), until the best is one so solved: the full
        solve moves a cost in its last bits, which can hand the lead to another start."""
        while True:
            best = _best(cost, conv)
            k = np.flatnonzero(twice & ~full[best, t])
            if not k.size:
                return best
            X[best[k], k], cost[best[k], k], conv[best[k], k] = solve(X0[best[k], k], k)
            full[best[k], k] = True

    best = solved_again()
    # one more start: the best with every untrusted drone reflected across its anchors'
    # best-fit plane, where near-coplanar anchors leave each drone a second minimum
    flip0 = settle(mirrored(X[best, t], ranges, trusted), t)
    flip = solve(flip0, t, reduced=True)
    X0 = np.concatenate([X0, flip0[None]])
    X = np.concatenate([X, flip[0][None]])
    cost, conv = np.concatenate([cost, flip[1][None]]), np.concatenate([conv, flip[2][None]])
    full = np.concatenate([full, np.zeros((1, T), dtype=bool)])
    S += 1
    best = solved_again()
    x, c, ok = X[best, t], cost[best, t], conv[best, t]
    # An untrusted drone's position changes only the ranges trusted drones measured to it (and
    # its prior), so each can sit in its own minimum: near-coplanar anchors leave two, and a
    # start reaches the combination some drones need on one side and others on the other
    # only by chance. The drone-by-drone best of all starts is one more start.
    # each drone's own cost with the anchors where the best start put them: the same frame
    # for every start (a start that moved the whole swarm is not a second minimum of one drone)
    anchors = X[best, t]
    # every start at once: (S, T, ...) as (S T, ...)
    q = _own_cost(anchors, X, ranges, trusted, noise.range_sigma, pr, prior_sigma)
    q = np.where(conv[..., None], q, np.inf)
    pick = np.argmin(q, axis=0)  # (T, n)
    mixed = np.flatnonzero(((pick != best[:, None]) & ~trusted).any(axis=1))

    def appended(rows: np.ndarray, Xr: np.ndarray, cr: np.ndarray, okr: np.ndarray) -> None:
        """Those trials' minima as one more row of every start's X, cost, conv and q."""
        nonlocal X, conv, cost, q
        X = np.concatenate([X, np.full((1, T, n, 3), np.nan)])
        X[-1, rows] = Xr
        conv = np.concatenate([conv, np.isin(t, rows[okr])[None]])
        cost = np.concatenate([cost, np.full((1, T), np.inf)])
        cost[-1, rows] = cr
        q = np.concatenate([q, np.full((1, T, n), np.inf)])
        q[-1, rows] = np.where(
            okr[:, None],
            _own_cost(
                anchors[rows],
                Xr[None],
                ranges[rows],
                trusted[rows],
                noise.range_sigma,
                None if pr is None else pr[rows],
                prior_sigma,
            )[0],
            np.inf,
        )

    if mixed.size:
        x_mix = x[mixed].copy()
        untrusted = ~trusted[mixed]
        x_mix[untrusted] = X[pick[mixed], mixed[:, None], np.arange(n)[None, :]][untrusted]
        Xm, cm, okm = solve(x_mix, mixed)
        better = okm & (cm < c[mixed])
        rows = mixed[better]
        x[rows], c[rows], ok[rows] = Xm[better], cm[better], True
        appended(mixed, Xm, cm, okm)
        if rows.size:
            # the mixed answer's own reflection, every untrusted drone across its anchors'
            # plane at once: when no start reached either side cleanly, the other side of the
            # plane is among no start's minima, and two equally good minima apart would pass
            # for one
            Xf, cf, okf = solve(settle(mirrored(x[rows], ranges[rows], trusted[rows]), rows), rows)
            appended(rows, Xf, cf, okf)
            won = okf & (cf < c[rows])
            x[rows[won]], c[rows[won]], ok[rows[won]] = Xf[won], cf[won], True
    far = max(10 * noise.range_sigma, float(np.sqrt(np.trace(noise.gnss_cov))))
    # ambiguous: another converged minimum places the drone apart and fits as well, judged by
    # the whole cost or by the drone's own part of it
    own = _own_cost(anchors, x[None], ranges, trusted, noise.range_sigma, pr, prior_sigma)[0]
    ambiguous = np.empty((T, n), dtype=bool)
    _ambiguous_kernel(X, x, cost, c, conv, q, own, np.ascontiguousarray(trusted), far, window, ambiguous)
    return Estimate(x, c, ok, ambiguous)


@njit(cache=True)
def _ambiguous_kernel(X, x, cost, c, conv, q, own, trusted, far, window, out):  # pragma: no cover
    """`robust_estimate`'s ambiguity in place on out (T, n): an untrusted drone that some
    start's minimum X (S, T, n, 3) places further than ``far`` from x (the distance summed as
    np.linalg.norm sums) while fitting within ``window`` of the best, by its converged whole
    cost (cost (S, T) against c (T,)) or by the drone's own part (q (S, T, n) against own
    (T, n))."""
    S, T, n, _ = X.shape
    for t in range(T):
        for i in range(n):
            out[t, i] = False
            if trusted[t, i]:
                continue
            for s in range(S):
                if not norm_apart(X[s, t, i], x[t, i]) > far:
                    continue
                near = conv[s, t] and cost[s, t] <= c[t] + window
                if near or q[s, t, i] <= own[t, i] + window:
                    out[t, i] = True
                    break


def _best(cost: np.ndarray, conv: np.ndarray) -> np.ndarray:
    """Per trial (T,), the start (of S) with the lowest converged cost, or the lowest cost
    where none converged."""
    out = np.empty(cost.shape[1], dtype=np.int64)
    _best_kernel(np.ascontiguousarray(cost, float), np.ascontiguousarray(conv, np.bool_), out)
    return out


@njit(cache=True)
def _argmin(v):  # pragma: no cover - compiled
    """np.argmin of v (S,): the first minimum, or the first nan if there is one."""
    best = 0
    for s in range(v.size):
        if np.isnan(v[s]):
            return s
        if v[s] < v[best]:
            best = s
    return best


@njit(cache=True)
def _best_kernel(cost, conv, out):  # pragma: no cover - compiled
    """`_best` in place on out (T,), as np.argmin decides (its nan rule included)."""
    S, T = cost.shape
    score = np.empty(S)
    for t in range(T):
        some = False
        for s in range(S):
            some = some or conv[s, t]
            score[s] = cost[s, t] if conv[s, t] else np.inf
        out[t] = _argmin(score) if some else _argmin(cost[:, t].copy())


def _first_copy(starts: np.ndarray) -> np.ndarray:
    """For starts (S, T, m), the flat index s T + t of each one's first bit-for-bit copy
    among the starts of its trial t (itself where none comes before it)."""
    S, T, _ = starts.shape
    source = np.arange(S * T).reshape(S, T)
    _first_copy_kernel(np.ascontiguousarray(starts, float).view(np.uint64), source)
    return source.ravel()


@njit(cache=True)
def _first_copy_kernel(bits, source):  # pragma: no cover - compiled
    """`_first_copy` in place on source (S, T), each start's own flat index on entry: start s
    of trial t takes the source of the first earlier start e whose bits are all equal (an
    earlier start that is itself a copy passes its source on)."""
    S, T, m = bits.shape
    for s in range(1, S):
        for e in range(s):
            for t in range(T):
                if source[s, t] != s * T + t:
                    continue
                same = True
                for k in range(m):
                    if bits[s, t, k] != bits[e, t, k]:
                        same = False
                        break
                if same:
                    source[s, t] = source[e, t]


def _own_cost(
    anchors: np.ndarray,
    X: np.ndarray,
    ranges: np.ndarray,
    trusted: np.ndarray,
    range_sigma: float,
    prior: np.ndarray | None,
    prior_sigma: float | None,
) -> np.ndarray:
    """Per start s and untrusted drone j (S, T, n; 0 for trusted ones), with the trusted
    drones at ``anchors`` (T, n, 3) and the untrusted ones where start s put them (X
    (S, T, n, 3)): the chi-square of the ranges trusted drones measured to it, and of its
    prior: the part of the joint cost only x_j changes."""
    S, T, n, _ = X.shape
    has_prior = prior is not None and bool(prior_sigma)
    out = np.empty((S, T, n))
    _own_cost_kernel(
        np.ascontiguousarray(anchors, float),
        np.ascontiguousarray(X, float),
        np.ascontiguousarray(ranges, float),
        np.ascontiguousarray(trusted, np.bool_),
        float(range_sigma) ** 2,
        np.ascontiguousarray(prior, float) if has_prior else anchors,
        float(prior_sigma) ** 2 if has_prior else 0.0,
        has_prior,
        out,
    )
    return out


@njit(cache=True)
def _own_cost_kernel(anchors, X, ranges, trusted, s2, prior, p2, has_prior, out):  # pragma: no cover
    """`_own_cost` in place on out (S, T, n), in the order of operations of the numpy
    expression it replaced (a sum over the measuring drones i in order; an infinite range as
    +-DBL_MAX, as nan_to_num made it), so bit for bit the same; ``prior`` is read only with
    ``has_prior``."""
    S, T, n, _ = X.shape
    big = np.finfo(np.float64).max
    col = np.empty(n)
    x = np.empty((n, 3))
    for s in range(S):
        for t in range(T):
            for i in range(n):
                src = anchors[t, i] if trusted[t, i] else X[s, t, i]
                for a in range(3):
                    x[i, a] = src[a]
            for j in range(n):
                col[j] = 0.0
            for i in range(n):
                for j in range(n):
                    d = ranges[t, i, j]
                    v = 0.0
                    if trusted[t, i] and not np.isnan(d):
                        if np.isinf(d):
                            d = big if d > 0 else -big
                        r = pair_distance(x, i, j) - d
                        v = r * r
                    col[j] = v if i == 0 else col[j] + v
            for j in range(n):
                r2 = col[j] / s2
                if has_prior and np.isfinite(prior[t, j]).all():
                    e0 = x[j, 0] - prior[t, j, 0]
                    e1 = x[j, 1] - prior[t, j, 1]
                    e2 = x[j, 2] - prior[t, j, 2]
                    r2 = r2 + ((e0 * e0 + e1 * e1) + e2 * e2) / p2
                out[s, t, j] = 0.0 if trusted[t, j] else r2


def anchor_planes(
    x: np.ndarray, ranges: np.ndarray, trusted: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For every drone i, its anchors (T, i, k): trusted drones k that measured a range to
    it; their count (T, i), centroid (T, i, 3) and principal axes (T, i, 3, 3), columns in
    ascending order of spread (column 0: the normal of their best-fit plane). One compiled
    kernel (numpy's per-call overhead on 17-drone arrays was most of its time)."""
    return anchor_planes_of(x, ranges, trusted, np.ones(np.shape(trusted), dtype=bool))


def anchor_planes_of(
    x: np.ndarray, ranges: np.ndarray, trusted: np.ndarray, which: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`anchor_planes`, the count, centroid and axes computed only for the drones ``which``
    (T, n) marks (0 elsewhere); the anchors of every drone."""
    T, n, _ = x.shape
    anchors = ~np.isnan(np.swapaxes(ranges, 1, 2)) & trusted[:, None, :] & ~np.eye(n, dtype=bool)
    cnt, mean, vec = np.zeros((T, n)), np.zeros((T, n, 3)), np.zeros((T, n, 3, 3))
    _anchor_planes_kernel(
        np.ascontiguousarray(x, float),
        np.ascontiguousarray(anchors),
        np.ascontiguousarray(which),
        cnt,
        mean,
        vec,
    )
    return anchors, cnt, mean, vec


@njit(cache=True)
def _anchor_planes_kernel(x, anchors, which, cnt, mean, vec):  # pragma: no cover - compiled
    """`anchor_planes`' count, centroid and axes of the drones ``which`` marks, in the order
    of operations of the numpy expressions it replaced (einsum's sums over the anchors in
    order, then np.linalg.eigh, the same LAPACK routine), so bit for bit the same."""
    T, n, _ = x.shape
    for t in range(T):
        for i in range(n):
            if which[t, i]:
                cnt[t, i] = _plane(x[t], anchors[t, i], mean[t, i], vec[t, i])


@njit(cache=True)
def _plane(xt, anchors, mean, vec):  # pragma: no cover - compiled
    """One drone's anchors (n,) at xt (n, 3): their count (returned), centroid (in place on
    mean (3,)) and principal axes (on vec (3, 3)), as `_anchor_planes_kernel` computes them."""
    n = xt.shape[0]
    S = np.empty((3, 3))
    c = 0.0
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    for k in range(n):
        w = 1.0 if anchors[k] else 0.0
        c += w
        m0 += w * xt[k, 0]
        m1 += w * xt[k, 1]
        m2 += w * xt[k, 2]
    div = max(c, 1.0)
    mean[0] = m0 / div
    mean[1] = m1 / div
    mean[2] = m2 / div
    for a in range(3):
        for b in range(3):
            S[a, b] = 0.0
    for k in range(n):
        w = 1.0 if anchors[k] else 0.0
        for a in range(3):
            da = xt[k, a] - mean[a]
            for b in range(3):
                S[a, b] += w * da * (xt[k, b] - mean[b])
    _, v = np.linalg.eigh(S)
    vec[:, :] = v
    return c


@njit(cache=True)
def _mirrored_kernel(x, ranges, trusted, out):  # pragma: no cover - compiled
    """`mirrored` into out (T, n, 3): each untrusted drone's anchors' plane by `_plane` (the
    same bits as `anchor_planes`), its height above it summed as numpy's einsum sums a
    strided operand (in order), and the reflection x - 2 h normal; trusted drones as x."""
    T, n, _ = x.shape
    anchors = np.zeros(n, dtype=np.bool_)
    mean = np.empty(3)
    vec = np.empty((3, 3))
    for t in range(T):
        for i in range(n):
            for a in range(3):
                out[t, i, a] = x[t, i, a]
            if trusted[t, i]:
                continue
            for k in range(n):
                anchors[k] = not np.isnan(ranges[t, k, i]) and trusted[t, k] and k != i
            _plane(x[t], anchors, mean, vec)
            h = ((x[t, i, 0] - mean[0]) * vec[0, 0] + (x[t, i, 1] - mean[1]) * vec[1, 0]) + (
                x[t, i, 2] - mean[2]
            ) * vec[2, 0]
            for a in range(3):
                out[t, i, a] = x[t, i, a] - 2 * h * vec[a, 0]


#: Levenberg-Marquardt steps of one untrusted drone's own problem in `settled`
SETTLE_ITERS = 30


def settled(
    x0: np.ndarray,
    ranges: np.ndarray,
    trusted: np.ndarray,
    sparse: np.ndarray,
    range_sigma: float,
    prior: np.ndarray | None = None,
    prior_sigma: float | None = None,
) -> np.ndarray:
    """A start x0 (T, n, 3) whose untrusted drones, in the trials ``sparse`` (T,) marks, sit
    at the minimum of their own part of the cost (`_own_cost`: the ranges trusted drones
    measured to the drone, its prior where it has one) with the trusted drones where x0 has
    them; a drone that fewer than 3 trusted drones range and without a prior stays (as does
    one with an infinite range, or whose own cost at the start is not finite: a start or an
    anchor at nan). The other trials are x0 itself.

    Given the trusted drones, each untrusted drone's position changes only its own part of
    the cost, so these are 3-dof problems solved one drone at a time. Solved jointly from a
    start that places some of them far off (reflected across their anchors' plane, at their
    spoofed reports), one damping factor for the whole swarm held every drone's step to the
    worst drone's: at n = 65 on a sparse range graph (`benchmarks/bench_sparse.py`) those
    starts crawled 10-50 iterations of a 195-coordinate solve where the closed form took 4;
    settled first, most take 1-15 (the robust estimate's solves 6.8 -> 4.1 ms of a step).
    The closed-form start is never settled: with half the swarm untrusted (`shape`, trial 7
    there) its settled image led the joint solve into a minimum a thousand times the best.
    Dense graphs are left alone, their verdicts as before bit for bit."""
    if not np.asarray(sparse).any():
        return x0
    out = np.array(x0, dtype=float, copy=True)
    has_prior = prior is not None and bool(prior_sigma)
    _settle_kernel(
        out,
        np.ascontiguousarray(ranges, float),
        np.ascontiguousarray(trusted, np.bool_),
        np.ascontiguousarray(sparse, np.bool_),
        1.0 / range_sigma**2,
        np.ascontiguousarray(prior, float) if has_prior else out,
        1.0 / prior_sigma**2 if has_prior else 0.0,
        SETTLE_ITERS,
    )
    return out


@njit(cache=True)
def _drone_cost(x, ranges, trusted, t, i, p, w_r, prior, w_p):  # pragma: no cover - compiled
    """Untrusted drone i's own part of trial t's cost with it at p (3,) and the others at x."""
    c = 0.0
    n = x.shape[1]
    for k in range(n):
        d = ranges[t, k, i]
        if k != i and trusted[t, k] and not np.isnan(d):
            e = norm_apart(p, x[t, k]) - d
            c += w_r * e * e
    if w_p > 0.0:
        for a in range(3):
            c += w_p * (p[a] - prior[t, i, a]) ** 2
    return c


@njit(cache=True)
def _settle_kernel(x, ranges, trusted, sparse, w_r, prior, prior_w, iters):  # pragma: no cover
    """`settled` in place on x (T, n, 3): per untrusted drone of a sparse trial, Levenberg-
    Marquardt with step acceptance on its own cost (weights w_r per range, prior_w on its
    prior where that has no nan; ``prior`` read only where prior_w > 0), stopping as
    `joint.levenberg_marquardt_kernel` does (a step below 1e-7 m, a decrease of at most 1e-3,
    or no step that lowers the cost)."""
    T, n, _ = x.shape
    H = np.zeros((3, 3))
    A = np.zeros((3, 3))
    g = np.zeros(3)
    p = np.zeros(3)
    pn = np.zeros(3)
    for t in range(T):
        if not sparse[t]:
            continue
        for i in range(n):
            if trusted[t, i]:
                continue
            anchors = 0
            for k in range(n):
                d = ranges[t, k, i]
                if k != i and trusted[t, k] and not np.isnan(d):
                    anchors += 1 if np.isfinite(d) else n  # an infinite range: left alone
            w_p = prior_w if prior_w > 0.0 and not np.isnan(prior[t, i]).any() else 0.0
            if (anchors < 3 and w_p == 0.0) or anchors >= n:
                continue
            for a in range(3):
                p[a] = x[t, i, a]
            cost = _drone_cost(x, ranges, trusted, t, i, p, w_r, prior, w_p)
            if not np.isfinite(cost):  # a start or an anchor at nan: left as it is
                continue
            lam = 1e-6
            for _ in range(iters):
                H[:, :] = 0.0
                g[:] = 0.0
                for k in range(n):
                    d = ranges[t, k, i]
                    if k == i or not trusted[t, k] or np.isnan(d):
                        continue
                    r = norm_apart(p, x[t, k])
                    if not r > 0.0:
                        continue
                    u0 = (p[0] - x[t, k, 0]) / r
                    u1 = (p[1] - x[t, k, 1]) / r
                    u2 = (p[2] - x[t, k, 2]) / r
                    e = w_r * (r - d)
                    g[0] += u0 * e
                    g[1] += u1 * e
                    g[2] += u2 * e
                    H[0, 0] += w_r * u0 * u0
                    H[0, 1] += w_r * u0 * u1
                    H[0, 2] += w_r * u0 * u2
                    H[1, 1] += w_r * u1 * u1
                    H[1, 2] += w_r * u1 * u2
                    H[2, 2] += w_r * u2 * u2
                H[1, 0], H[2, 0], H[2, 1] = H[0, 1], H[0, 2], H[1, 2]
                for a in range(3):
                    g[a] += w_p * (p[a] - prior[t, i, a]) if w_p > 0.0 else 0.0
                    H[a, a] += w_p
                accepted = False
                big = 0.0
                new_cost = cost
                for _attempt in range(16):
                    for a in range(3):
                        for b in range(3):
                            A[a, b] = H[a, b]
                        A[a, a] += lam * H[a, a] + 1e-12
                    step = np.linalg.solve(A, -g)
                    big = 0.0
                    for a in range(3):
                        pn[a] = p[a] + step[a]
                        big = max(big, abs(step[a]))
                    new_cost = _drone_cost(x, ranges, trusted, t, i, pn, w_r, prior, w_p)
                    if new_cost <= cost:
                        accepted = True
                        break
                    lam *= 10.0
                    if big < 1e-7:
                        break
                if not accepted:
                    break
                decrease = cost - new_cost
                for a in range(3):
                    p[a] = pn[a]
                cost = new_cost
                lam = max(lam * 0.3, 1e-12)
                if big < 1e-7 or decrease <= 1e-3 + 1e-12 * cost:
                    break
            for a in range(3):
                x[t, i, a] = p[a]


def mirrored(x: np.ndarray, ranges: np.ndarray, trusted: np.ndarray) -> np.ndarray:
    """x with every untrusted drone reflected across the best-fit plane of its anchors: a
    start that reaches the other minimum of a near-coplanar geometry. One compiled kernel
    (`_mirrored_kernel`: the planes of the untrusted drones only)."""
    out = np.empty(np.shape(x))
    _mirrored_kernel(
        np.ascontiguousarray(x, float),
        np.ascontiguousarray(ranges, float),
        np.ascontiguousarray(trusted, np.bool_),
        out,
    )
    return out

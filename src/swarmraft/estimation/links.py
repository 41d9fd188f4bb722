"""Range faults of links, not drones: a screening every detector's ranges go through first.

UWB two-way ranges fail by links: a blocked path (NLOS) lengthens a range by 0.3-1 m, in both
directions of the link (the path is shared) or, with a per-direction fault, in one. A detector
that reads such a range as a drone's fault flags an honest drone. `screen` finds bad links from
the ranges alone, without any GNSS report (so no position spoof can steer it), and drops them:

1. Directions. A link measured both ways whose two ranges disagree beyond ``k`` sqrt(2) sigma
   loses both directions, unless one of its drones disagrees with more than half of the
   drones it ranges both ways, one of them at least by more than an NLOS bias can
   (``nlos_max``, 2 m): that drone tampers with the ranges it reports, and its links are left
   for the detector to see (`fde.two_way_outliers`, the `clique` two-way check).
2. Links. The swarm's shape from the ranges alone: classical MDS of the largest set of drones
   with every pair measured, the others placed by closed-form multilateration, then
   Levenberg-Marquardt on every range measured by a drone that step 1 did not single out.
   Where nothing reads long beyond ``k`` sigma and step 1 dropped nothing, the screening
   stops here and changes nothing. Otherwise the links whose two ways disagree beyond
   ``K_LOW`` sqrt(2) sigma are dropped too and, as range faults only lengthen (NLOS, a
   delayed reply), the shape is fitted again by graduated non-convexity with a one-sided
   Geman-McClure loss (a range reading short is noise; one reading long loses its weight);
   the ranges still reading long beyond ``K_LOW`` = 3 sigma (the range itself, or its
   link's mean of both directions) are dropped.
3. Distance enlargement. A drone that delays its replies lengthens all its links by one
   amount delta. For each drone, its position and a common delta are fitted to its links
   with the other drones where step 2 put them (the pseudorange problem: position and clock
   bias); a drone whose delta is significant (``k`` standard errors and ``k`` sigma) and
   which fits 3 (and a quarter) more of its links with delta than without is enlarged: the
   most significant one per round, its ranges corrected by delta, and step 2 again, until
   none is left. Links still reading long after the correction are NLOS and stay dropped.
   NLOS on some links of an honest drone lengthens them unequally: no common delta fits.
   A drone on the edge of the swarm can move outwards instead of delaying (every drone it
   ranges on one side): ranges alone cannot tell, and it goes unflagged here (README,
   "Distance enlargement").

`run_screened` wraps a detector: it runs on the screened ranges (the original batch, bit for
bit, where nothing was found) and the enlarged drones are flagged in its verdict.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numba import njit
from pydantic import BaseModel

from swarmraft.estimation.envelope import SPARSE_SHARE, range_share
from swarmraft.estimation.joint import levenberg_marquardt_kernel, pair_distance, weighted_gauss_newton
from swarmraft.estimation.snapshot import SnapshotBatch, VerdictBatch
from swarmraft.estimation.trust_region import linear_multilateration

K_LOW = 3.0  # once a link reads long beyond k, the links beyond this many sigmas are dropped
TAMPER_SHARE = 0.5  # a drone disagreeing with more than this share of its links (one grossly) tampers
_LOOSE = 1e8  # m^2: the variance of the pseudo-report that only fixes the fitted shape's gauge
#: sigmas below ``k`` that `_quiet` needs before it calls a trial quiet: its own fit is not
#: the bits of `screen`'s (its classical MDS start is summed in another order), and the two
#: stop within the solver's tolerance of one minimum: up to 0.1 sigma apart in 1.4 million
#: random 3-D swarms (a review's fuzzing, 2026-12-05)
QUIET_MARGIN = 0.5
#: `_quiet` only where the swarm's shape has one minimum: at least QUIET_DRONES drones whose
#: classical MDS spreads the third axis at least QUIET_SHAPE of the first (in variance). On a
#: near-flat or near-collinear swarm the two fits can stop in different minima (a review found
#: 3.4 sigma apart at n = 4 and 6): there the numpy screening decides
QUIET_DRONES = 7
QUIET_SHAPE = 0.05


@dataclass(frozen=True)
class Screen:
    """What `screen` found: the ranges with bad links nan (T, n, n), the links dropped (T, n, n,
    both directions), drones single out as range tamperers (T, n), enlarged drones (T, n) and
    their enlargement (T, n) in m (0 elsewhere)."""

    ranges: np.ndarray
    dropped: np.ndarray
    tampering: np.ndarray
    enlarged: np.ndarray
    delta: np.ndarray

    @property
    def changed(self) -> bool:
        return bool(self.dropped.any() or self.enlarged.any())


def _both_ways(ranges: np.ndarray) -> np.ndarray:
    """The mean of d_ij and d_ji where measured (T, n, n), nan where neither is."""
    meas = ~np.isnan(ranges)
    back = np.swapaxes(meas, 1, 2)
    cnt = meas.astype(float) + back
    total = np.nan_to_num(ranges) + np.swapaxes(np.nan_to_num(ranges), 1, 2)
    return np.where(cnt > 0, total / np.maximum(cnt, 1), np.nan)


def _classical_mds(d: np.ndarray) -> np.ndarray:
    """Points (m, 3) whose distances best match the complete distance matrix d (m, m)."""
    m = len(d)
    J = np.eye(m) - 1.0 / m
    w, v = np.linalg.eigh(-0.5 * J @ (d**2) @ J)
    top = np.argsort(w)[::-1][: min(3, m)]
    out = np.zeros((m, 3))
    out[:, : top.size] = v[:, top] * np.sqrt(np.maximum(w[top], 0.0))
    return out


def sparse_graph(ranges: np.ndarray) -> np.ndarray:
    """Per trial (T,), whether the range graph is sparse: two drones that each range with
    someone have no range between them either way (out of each other's range). A drone with
    no range at all (outside the swarm) does not make it sparse."""
    n = ranges.shape[1]
    meas = ~np.isnan(ranges) & ~np.eye(n, dtype=bool)
    linked = meas | np.swapaxes(meas, 1, 2)
    some = linked.any(axis=2)
    gap = ~linked & some[:, :, None] & some[:, None, :] & ~np.eye(n, dtype=bool)
    return gap.any(axis=(1, 2))


def linked_share(ranges: np.ndarray) -> np.ndarray:
    """Per trial (T,), the share of pairs of drones with a range either way, among the drones
    that range with someone (1 where fewer than two do): `envelope.range_share` of each."""
    return np.array([range_share(np.ascontiguousarray(r, float)) for r in ranges], dtype=float)


def _geodesic(d: np.ndarray) -> np.ndarray:
    """d (n, n) with each unmeasured pair (nan) filled by its shortest path through measured
    ones (nan where none): on a sparse range graph, a complete matrix for classical MDS whose
    error (paths bend round) the fit then removes. Dijkstra from every drone, compiled
    (`_dijkstra`): scipy's `shortest_path` gives the same bits at 3-4x the cost (its checks and
    its conversion to a sparse matrix were most of a 65-drone step's 0.9 ms), except for a
    measured range of 1e-8 m or less, which scipy's dense input drops as no link: here it is a
    link, so a pair is finite exactly when measured links join it (scipy left such a pair
    finite but unjoined, and the MDS of its component failed on the gap)."""
    g = np.empty_like(d, dtype=float)
    _dijkstra(np.ascontiguousarray(d, float), g)
    return np.where(np.isnan(d), np.where(np.isfinite(g), g, np.nan), d)


@njit(cache=True)
def _dijkstra(d, out):  # pragma: no cover - compiled
    """Shortest path lengths (n, n) into ``out`` (inf where none) over the links of d (n, n,
    symmetric; nan: no link, a zero length is a link), Dijkstra from each drone with a binary
    heap. A length is
    the sum along its path from the source, each relaxation dist[u] + d[u, v] kept only if
    strictly shorter: the bits do not depend on the order in which equally distant drones
    are taken (scipy's `shortest_path(method="D")` agrees bit for bit)."""
    n = d.shape[0]
    start = np.zeros(n + 1, dtype=np.int64)
    for i in range(n):
        c = 0
        for j in range(n):
            if j != i and d[i, j] == d[i, j]:
                c += 1
        start[i + 1] = start[i] + c
    nbr = np.empty(start[n], dtype=np.int64)
    for i in range(n):
        c = start[i]
        for j in range(n):
            if j != i and d[i, j] == d[i, j]:
                nbr[c] = j
                c += 1
    m = start[n] + n + 1
    hk = np.empty(m)  # heap keys (distances) and drones, stale entries skipped
    hv = np.empty(m, dtype=np.int64)
    done = np.zeros(n, dtype=np.bool_)
    for s in range(n):
        dist = out[s]
        dist[:] = np.inf
        done[:] = False
        dist[s] = 0.0
        size = 1
        hk[0] = 0.0
        hv[0] = s
        while size > 0:
            key, u = hk[0], hv[0]
            size -= 1
            if size > 0:  # sift the last entry down from the root
                k, kv = hk[size], hv[size]
                i = 0
                while True:
                    c = 2 * i + 1
                    if c >= size:
                        break
                    if c + 1 < size and hk[c + 1] < hk[c]:
                        c += 1
                    if hk[c] < k:
                        hk[i], hv[i] = hk[c], hv[c]
                        i = c
                    else:
                        break
                hk[i], hv[i] = k, kv
            if done[u] or key > dist[u]:
                continue
            done[u] = True
            for e in range(start[u], start[u + 1]):
                v = nbr[e]
                alt = dist[u] + d[u, v]
                if not done[v] and alt < dist[v]:
                    dist[v] = alt
                    i = size  # sift up
                    size += 1
                    while i > 0:
                        p = (i - 1) // 2
                        if hk[p] > alt:
                            hk[i], hv[i] = hk[p], hv[p]
                            i = p
                        else:
                            break
                    hk[i], hv[i] = alt, v


_APART = 1e4  # m between the starts of range-graph components that no range connects


def _components_mds(g: np.ndarray) -> np.ndarray:
    """Points (n, 3) from shortest-path distances g (n, n; nan between components): classical
    MDS of each connected component on its own, the components set `_APART` apart along x
    (nothing fixes where one lies relative to another; placed on top of each other, the fit
    pulled them into each other and 110 honest links of two 12-drone clusters read long)."""
    n = len(g)
    out = np.zeros((n, 3))
    label = components(g)
    for k in range(label.max() + 1 if n else 0):
        idx = np.flatnonzero(label == k)
        out[idx] = _classical_mds(g[np.ix_(idx, idx)])
        out[idx, 0] += k * _APART
    return out


def components(g: np.ndarray) -> np.ndarray:
    """Each drone's connected component (n,) of the graph whose edges are the finite entries
    of g (n, n), numbered in the order of their first drones (as scipy's connected_components
    numbers them). From `_geodesic` (a finite entry for every pair measured links join) a
    drone's component is the row's finite entries; searched breadth first all the same."""
    n = len(g)
    linked = np.isfinite(g) | np.isfinite(g.T)
    label = np.full(n, -1)
    k = 0
    for i in range(n):
        if label[i] >= 0:
            continue
        label[i] = k
        front = [i]
        while front:
            reach = linked[front].any(axis=0) & (label < 0)
            label[reach] = k
            front = list(np.flatnonzero(reach))
        k += 1
    return label


def _mds(ranges: np.ndarray, geodesic: np.ndarray | None = None) -> np.ndarray:
    """A start for the shape (T, n, 3): classical MDS of the symmetrised ranges of the largest
    set of drones found (greedily) with every pair measured, then the others one by one by
    closed-form multilateration from 4 or more placed drones they range with (those that
    never have 4 stay at the origin). Trials that ``geodesic`` (T,) marks (a sparse range
    graph, `sparse_graph`) instead fill unmeasured pairs by shortest paths (`_geodesic`) and
    take each connected component's MDS (`_components_mds`): from the few drones that all
    range each other, multilateration strays into folds."""
    T, n, _ = ranges.shape
    sym = _both_ways(ranges)
    sym[:, np.arange(n), np.arange(n)] = 0.0
    x = np.zeros((T, n, 3))
    for t in range(T):
        d = sym[t]
        if geodesic is not None and geodesic[t]:
            x[t] = _components_mds(_geodesic(d))
            continue
        gaps = np.isnan(d)
        np.fill_diagonal(gaps, False)
        core = np.ones(n, dtype=bool)
        while (gaps & core[:, None] & core[None, :]).any():
            core[np.argmax((gaps & core[None, :]).sum(axis=1) * core)] = False
        idx = np.flatnonzero(core)
        x[t, idx] = _classical_mds(d[np.ix_(idx, idx)])
        placed = core.copy()
        while not placed.all():
            links = ~gaps & placed[None, :]
            np.fill_diagonal(links, False)
            ready = ~placed & (links.sum(axis=1) >= 4)
            if not ready.any():
                break
            for i in np.flatnonzero(ready):
                x[t, i] = linear_multilateration(x[t][None], d[i][None], links[i][None])[0]
            placed |= ready
    return x


def _fit(x: np.ndarray, ranges: np.ndarray, weight: np.ndarray, sigma: float) -> np.ndarray:
    """The shape (T, n, 3) fitting the weighted ranges, from x (its gauge held by x itself)."""
    T, n, _ = x.shape
    return weighted_gauss_newton(
        x, x, ranges, np.ones((T, n)), weight, _LOOSE * np.eye(3), sigma, iters=30, tol=1e-5
    )


#: `fitted_shape` remembers its last answer for inputs up to this many bytes (a leader's step)
_MEMO_BYTES = 2**21
_last_shape: tuple[bytes, np.ndarray] | None = None


def fitted_shape(ranges: np.ndarray, weight: np.ndarray, sigma: float, geodesic: np.ndarray) -> np.ndarray:
    """The shape (T, n, 3) fitting the ranges of ``weight`` > 0 (`_fit`), from the classical
    MDS start of those ranges (`_mds`; ``geodesic`` (T,): the sparse graph's start).

    The screening fits it first (step 2) and `range_shape` fits it again for the detector's
    registrations, from the same inputs wherever the screening changed nothing (every
    snapshot of `benchmarks/bench_sparse.py`: 1.6 ms of a 65-drone step). The last answer is
    kept for inputs equal bit for bit (a copy is returned: the caller owns it); the same
    inputs give the same bits either way, so nothing depends on whether it was kept. One
    entry, swapped whole, so threads sharing the module see either answer or none."""
    global _last_shape
    ranges, weight = np.asarray(ranges, float), np.asarray(weight, float)
    geodesic = np.asarray(geodesic, bool)
    small = ranges.nbytes + weight.nbytes <= _MEMO_BYTES
    if small:
        head = str((ranges.shape, float(sigma))).encode()
        key = b"".join([head, ranges.tobytes(), weight.tobytes(), geodesic.tobytes()])
        last = _last_shape
        if last is not None and last[0] == key:
            return last[1].copy()
    x = _fit(_mds(np.where(weight > 0, ranges, np.nan), geodesic), ranges, weight, sigma)
    if small:
        _last_shape = (key, x.copy())
    return x


def _link_residuals(x: np.ndarray, ranges: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Per link (T, n, n, symmetric): the mean of its weighted measured ranges minus the fitted
    distance; nan where neither direction is used."""
    diff = x[:, :, None, :] - x[:, None, :, :]
    dist = np.sqrt(np.einsum("tijk,tijk->tij", diff, diff))
    use = weight > 0
    r = np.where(use, np.nan_to_num(ranges) - dist, 0.0)
    cnt = use.astype(float) + np.swapaxes(use, 1, 2)
    with np.errstate(invalid="ignore"):
        return np.where(cnt > 0, (r + np.swapaxes(r, 1, 2)) / cnt, np.nan)


def _long_z(x: np.ndarray, ranges: np.ndarray, weight: np.ndarray, sigma: float) -> np.ndarray:
    """How long each used direction reads (T, n, n), in sigmas: the larger of its own residual
    (a fault of one direction) and its link's mean residual in sigmas of that mean (a fault
    both directions share); -inf where unused."""
    diff = x[:, :, None, :] - x[:, None, :, :]
    dist = np.sqrt(np.einsum("tijk,tijk->tij", diff, diff))
    use = weight > 0
    own = np.where(use, (np.nan_to_num(ranges) - dist) / sigma, -np.inf)
    r = _link_residuals(x, ranges, weight)
    cnt = use.astype(float) + np.swapaxes(use, 1, 2)
    with np.errstate(invalid="ignore"):
        link = r / (sigma / np.sqrt(np.maximum(cnt, 1)))
    return np.where(use, np.fmax(own, np.nan_to_num(link, nan=-np.inf)), -np.inf)


def _one_sided(
    x: np.ndarray, ranges: np.ndarray, base: np.ndarray, z: np.ndarray, sigma: float, rounds: int
) -> tuple[np.ndarray, np.ndarray]:
    """Graduated non-convexity (Yang et al. 2020) with a one-sided Geman-McClure loss: a range
    reading short is Gaussian noise (weight 1), one reading long (`_long_z`) loses its weight
    as it reads longer, the loss tightened from nearly quadratic to its bound ``K_LOW`` sigmas.
    Returns the shape fitted without the ranges still reading long beyond ``K_LOW`` (T, n, 3)
    and those ranges (T, n, n)."""
    c2 = K_LOW**2
    mu = np.maximum(2 * z.max(axis=(1, 2)) ** 2 / c2, 1.0)[:, None, None]
    for _ in range(rounds):
        zz = np.maximum(z, 0.0) ** 2
        w = base * np.where(z > 0, (mu * c2 / (zz + mu * c2)) ** 2, 1.0)
        x = _fit(x, ranges, w, sigma)
        z = _long_z(x, ranges, base, sigma)
        if (mu <= 1).all():
            break
        mu = np.maximum(mu / 2, 1.0)
    long_ = z > K_LOW
    return _fit(x, ranges, np.where(long_, 0.0, base), sigma), long_


def _enlargement(
    start: np.ndarray,
    x: np.ndarray,
    ranges: np.ndarray,
    others: np.ndarray,
    sigma: float,
    offset: bool = True,
    trims: int = 3,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each of B drones placed by its links, with a common enlargement delta of them
    (``offset``: |p - x_j| + delta = d_j, the pseudorange problem of position and clock bias)
    or without (delta = 0): d (B, n) the mean of both directions of each link to the drones
    at x (B, n, 3) where ``others`` (B, n). Gauss-Newton from ``start`` (B, 3), then ``trims``
    times again without the links reading long beyond ``K_LOW`` sigmas (NLOS; at least 5
    kept). Returns delta (B,), its standard error (B,) and the inliers (B,): links of
    ``others`` within ``K_LOW`` sigmas of the fit, either way."""
    p = np.array(start, dtype=float, copy=True)
    delta = np.zeros(len(x))
    d = np.where(others, ranges, 0.0)
    use = others.copy()
    s_link = sigma / np.sqrt(2)
    k_off = 1.0 if offset else 0.0
    H = np.tile(np.eye(4), (len(x), 1, 1))
    for trim in range(trims + 1):
        for _ in range(6):
            diff = p[:, None, :] - x
            dist = np.linalg.norm(diff, axis=2)
            u = diff / np.where(dist > 0, dist, 1.0)[..., None]
            r = np.where(use, dist + delta[:, None] - d, 0.0)
            J = np.concatenate([u, np.full(u.shape[:2] + (1,), k_off)], axis=2) * use[..., None]
            H = np.einsum("bmi,bmj->bij", J, J) + 1e-9 * np.eye(4)
            step = np.linalg.solve(H, -np.einsum("bmi,bm->bi", J, r)[..., None])[..., 0]
            p += step[:, :3]
            delta += step[:, 3]
        long_ = use & (d - np.linalg.norm(p[:, None, :] - x, axis=2) - delta[:, None] > K_LOW * s_link)
        if trim == trims or not long_.any():
            break
        use &= ~long_ | (use.sum(axis=1) - long_.sum(axis=1) < 5)[:, None]
    se = s_link * np.sqrt(np.linalg.inv(H)[:, 3, 3]) if offset else np.zeros(len(x))
    r = np.linalg.norm(p[:, None, :] - x, axis=2) + delta[:, None] - d
    return delta, se, (others & (np.abs(r) <= K_LOW * s_link)).sum(axis=1)


def _corrected(ranges: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Ranges (T, n, n) with each drone's enlargement delta (T, n) taken off its links."""
    n = ranges.shape[1]
    out = ranges - delta[:, :, None] - delta[:, None, :]
    return np.where(np.eye(n, dtype=bool), ranges, out)


def _most_enlarged(
    x: np.ndarray,
    ranges: np.ndarray,
    base: np.ndarray,
    linked: np.ndarray,
    enlarged: np.ndarray,
    sigma: float,
    k: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Per trial (T,), the drone not yet ``enlarged`` whose links a common enlargement explains
    best (-1 if none does) and that enlargement (T,), m: significant (``k`` standard errors
    and ``k`` sigmas), and fitting 3 or more (and a quarter) more of its links than no
    enlargement (`_enlargement`). One delay lengthens every link alike; NLOS lengthens some
    links of a drone, unequally."""
    T, n, _ = x.shape
    t_idx, s_idx = np.nonzero(~enlarged)
    sym = _both_ways(np.where(base > 0, ranges, np.nan))[t_idx, s_idx]  # (B, n)
    others = linked[t_idx, s_idx] & ~np.isnan(sym)
    dl, se, fit1 = _enlargement(x[t_idx, s_idx], x[t_idx], sym, others, sigma)
    _, _, fit0 = _enlargement(x[t_idx, s_idx], x[t_idx], sym, others, sigma, offset=False)
    m = others.sum(axis=1)
    real = (dl > k * se) & (dl > k * sigma) & (fit1 - fit0 >= np.maximum(3, 0.25 * m)) & (m >= 5)
    score = np.full((T, n), -np.inf)
    score[t_idx, s_idx] = np.where(real, dl / np.maximum(se, 1e-12), -np.inf)
    best = np.argmax(score, axis=1)
    found = np.isfinite(score[np.arange(T), best])
    size = np.zeros((T, n))
    size[t_idx, s_idx] = dl
    return np.where(found, best, -1), size[np.arange(T), best]


@njit(cache=True)
def _quiet(ranges, sigma, k, out):  # pragma: no cover - compiled
    """Per trial, in place on out (T,): True where `screen` finds nothing: at least
    `QUIET_DRONES` drones, every pair ranged at least one way, no link's two ways disagreeing
    beyond ``k`` sqrt(2) sigma, a shape with one minimum (its classical MDS's third variance
    at least `QUIET_SHAPE` of its first), and the shape fitted to every range (that MDS of the
    mean of both ways, then Levenberg-Marquardt, as step 2 of the module docstring) reading no
    range or link long beyond ``k`` - `QUIET_MARGIN` sigmas. Its own fit, not the bits of
    `screen`'s: the margin covers the difference where the shape has one minimum, and a trial
    it does not call quiet is screened in full. One compiled pass: a 17-drone step's
    screening took 0.5 ms of numpy calls, and almost every step finds nothing."""
    T, n, _ = ranges.shape
    two = k * np.sqrt(2.0) * sigma
    limit = k - QUIET_MARGIN
    d = np.zeros((n, n))
    w = np.zeros((1, n, n))
    for t in range(T):
        out[t] = False
        r = ranges[t]
        whole = n >= QUIET_DRONES
        for i in range(n):
            for j in range(n):
                w[0, i, j] = 1.0 if i != j and not np.isnan(r[i, j]) else 0.0
        for i in range(n):
            d[i, i] = 0.0
            for j in range(i):
                a, b = w[0, i, j] > 0, w[0, j, i] > 0
                if a and b:
                    if abs(r[i, j] - r[j, i]) > two:
                        whole = False
                    d[i, j] = 0.5 * (r[i, j] + r[j, i])
                elif a:
                    d[i, j] = r[i, j]
                elif b:
                    d[i, j] = r[j, i]
                else:
                    whole = False
                d[j, i] = d[i, j]
        if not whole:
            continue
        # classical MDS: the top 3 eigenvectors of the double-centred squared distances
        sq = d * d
        row = np.zeros(n)
        for i in range(n):
            row[i] = sq[i].mean()
        total = row.mean()
        B = np.empty((n, n))
        for i in range(n):
            for j in range(n):
                B[i, j] = -0.5 * (sq[i, j] - row[i] - row[j] + total)
        vals, vecs = np.linalg.eigh(B)
        if not vals[n - 3] >= QUIET_SHAPE * vals[n - 1]:  # near-flat or near-collinear
            continue
        x = np.zeros((1, n, 3))
        for a in range(min(3, n)):
            c = n - 1 - a
            s = np.sqrt(max(vals[c], 0.0))
            for i in range(n):
                x[0, i, a] = vecs[i, c] * s
        rep = x.copy()
        cost = np.zeros(1)
        conv = np.zeros(1, dtype=np.bool_)
        G = np.eye(3) / _LOOSE
        gw = np.ones((1, n))
        levenberg_marquardt_kernel(
            x, rep, ranges[t : t + 1], gw, w, G, 1.0 / sigma**2, 30, 1e-5, x, 0.0, cost, conv, False
        )
        quiet = True
        for i in range(n):
            for j in range(i):
                dist = pair_distance(x[0], i, j)
                cnt = 0.0
                res = 0.0
                if w[0, i, j] > 0:
                    cnt += 1.0
                    res += r[i, j] - dist
                    quiet = quiet and (r[i, j] - dist) / sigma <= limit
                if w[0, j, i] > 0:
                    cnt += 1.0
                    res += r[j, i] - dist
                    quiet = quiet and (r[j, i] - dist) / sigma <= limit
                quiet = quiet and res / cnt / (sigma / np.sqrt(cnt)) <= limit
        out[t] = quiet


def screen(
    ranges: np.ndarray, sigma: float, k: float = 5.0, rounds: int = 20, nlos_max: float = 2.0
) -> Screen:
    """Screen ranges (T, n, n) of noise ``sigma`` (m) for bad links (module docstring). The
    trials `_quiet` finds nothing in are left as they are without the numpy passes (the
    same answer: `_screen` would find nothing in them); the others are screened in full."""
    ranges = np.asarray(ranges, float)
    T, n, _ = ranges.shape
    quiet = np.zeros(T, dtype=bool)
    if T and n:
        _quiet(np.ascontiguousarray(ranges), float(sigma), float(k), quiet)
    if not quiet.any():
        return _screen(ranges, sigma, k, rounds, nlos_max)
    none = np.zeros((T, n), dtype=bool)
    out = Screen(ranges.copy(), np.zeros((T, n, n), dtype=bool), none, none.copy(), np.zeros((T, n)))
    rows = np.flatnonzero(~quiet)
    if rows.size:
        s = _screen(ranges[rows], sigma, k, rounds, nlos_max)
        for name in Screen.__dataclass_fields__:
            getattr(out, name)[rows] = getattr(s, name)
    return out


def _screen(ranges: np.ndarray, sigma: float, k: float, rounds: int, nlos_max: float) -> Screen:
    """`screen` in numpy, every trial."""
    T, n, _ = ranges.shape
    off = ~np.eye(n, dtype=bool)
    meas = ~np.isnan(ranges) & off
    if not meas.any():  # nothing to screen
        none = np.zeros((T, n), dtype=bool)
        return Screen(ranges, np.zeros((T, n, n), dtype=bool), none, none, np.zeros((T, n)))
    back = np.swapaxes(ranges, 1, 2)
    both = meas & np.swapaxes(meas, 1, 2)
    with np.errstate(invalid="ignore"):
        gap = np.abs(ranges - back)
    disagree = both & (gap > k * np.sqrt(2) * sigma)
    most = disagree.sum(axis=2) > TAMPER_SHARE * both.sum(axis=2)
    tampering = most & (disagree & (gap > nlos_max)).any(axis=2)
    culprit = tampering[:, :, None] | tampering[:, None, :]
    dropped = disagree & ~culprit
    # step 2: fit the shape to the ranges the screening trusts; where a link reads long (or
    # two ways disagree), drop the two-way disagreements beyond K_LOW too, fit again with a
    # one-sided robust loss and drop the ranges reading long
    base = (meas & ~dropped & ~tampering[:, :, None]).astype(float)
    linked = (base > 0) | (np.swapaxes(base, 1, 2) > 0)
    sparse = sparse_graph(ranges)
    x = fitted_shape(ranges, base, sigma, sparse)
    z = _long_z(x, ranges, base, sigma)
    long_ = np.zeros((T, n, n), dtype=bool)
    enlarged = np.zeros((T, n), dtype=bool)
    delta = np.zeros((T, n))
    rows = np.flatnonzero((z.max(axis=(1, 2)) > k) | dropped.any(axis=(1, 2)))
    if rows.size:
        loose = both[rows] & (gap[rows] > min(k, K_LOW) * np.sqrt(2) * sigma) & ~culprit[rows]
        dropped[rows] |= loose
        base[rows] = np.where(loose, 0.0, base[rows])
        z = _long_z(x[rows], ranges[rows], base[rows], sigma)
        x[rows], long_[rows] = _one_sided(x[rows], ranges[rows], base[rows], z, sigma, rounds)
    # step 3: where something reads long, the drone whose links a common enlargement explains
    # best is taken as enlarged, its ranges corrected, the shape fitted again, and so on
    go = rows
    for _ in range(n // 2):
        if not go.size:
            break
        cur = _corrected(ranges[go], delta[go])
        best, dl = _most_enlarged(x[go], cur, base[go], linked[go], enlarged[go], sigma, k)
        go, best, dl = go[best >= 0], best[best >= 0], dl[best >= 0]
        enlarged[go, best] = True
        delta[go, best] = dl
        cur = _corrected(ranges[go], delta[go])
        z = _long_z(x[go], cur, base[go], sigma)
        x[go], long_[go] = _one_sided(x[go], cur, base[go], z, sigma, rounds)
    out = np.where(dropped, np.nan, ranges)
    if enlarged.any():
        out = _corrected(out, delta)
    out = np.where(long_, np.nan, out)
    return Screen(out, (dropped | long_) & meas, tampering, enlarged, delta)


def run_screened(run, batch: SnapshotBatch, p: BaseModel, sigma_floor: float = 1e-3) -> VerdictBatch:
    """A detector ``run(batch, p)`` on the screened ranges (the batch itself where the screening
    finds nothing, so its verdict is bit for bit the unscreened one), enlarged drones flagged.
    Diagnostics: ``range_dropped`` (T, n) links each drone lost, ``enlargement`` (T, n) m."""
    if getattr(p, "links", "off") == "off":
        return run(batch, p)
    rs = getattr(p, "range_sigma", None)
    rs = rs if rs is not None else batch.range_sigma
    if rs is None and hasattr(p, "min_sigma"):
        return run(batch, p)  # a statistical detector: it says itself that it needs the noise
    if rs is None:
        raise ValueError(
            "links: screening ranges needs the ranging noise: give the snapshot range_sigma, or "
            "set links = 'off'"
        )
    floor = getattr(p, "min_sigma", sigma_floor)
    s = screen(batch.ranges, max(float(rs), floor), p.link_k, p.link_rounds, p.link_nlos_max)
    if not s.changed:
        return run(batch, p)
    v = run(replace(batch, ranges=s.ranges), p)
    diag = {**v.diagnostics, "range_dropped": s.dropped.sum(axis=2), "enlargement": s.delta}
    return replace(v, faulty=v.faulty | s.enlarged, diagnostics=diag)


def range_shape(ranges: np.ndarray, use: np.ndarray, sigma: float) -> np.ndarray:
    """The swarm's shape (T, n, 3) from its ranges alone, up to a rigid motion and a
    reflection: classical MDS of the largest fully measured set, the others by closed-form
    multilateration, then Levenberg-Marquardt on the ranges ``use`` (T, n, n) marks, each
    with noise ``sigma`` (m) (the fit `screen` makes). A drone with fewer than 4 placed
    drones to range with stays at the origin."""
    # the ranges a detector sees are screened already: a graph the screening left gaps in
    # (NLOS) keeps its start; only a sparse one (at most SPARSE_SHARE of its pairs ranged)
    # takes the shortest-path start
    return fitted_shape(ranges, use.astype(float), sigma, linked_share(ranges) <= SPARSE_SHARE)

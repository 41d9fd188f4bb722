"""Joint estimation of all drone positions from GNSS reports and every measured range.

The state is the 3n positions. Residuals: each trusted GNSS report, whitened by its
covariance, and each measured range (drone i's measurement d_ij of drone j), divided by the
range sigma. `weighted_gauss_newton` minimises the weighted sum of squares with a
Levenberg-Marquardt step and an analytic Jacobian, batched over trials; `joint_estimate` uses
it with a known trusted set (`trusted_estimate` adds the geometry check); `swarmraft.estimation.gnc`
uses it with robust weights.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit
from scipy.special import chdtri

from swarmraft.estimation.envelope import (
    SPARSE_SHARE,
    coupling_order,
    envelope_cholesky,
    envelope_solve,
    range_share,
)
from swarmraft.estimation.noise import NoiseModel, gnss_information, smallest_information
from swarmraft.estimation.trust_region import _multilateration_kernel


def _geometry(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    diff = x[:, :, None, :] - x[:, None, :, :]
    dist = np.sqrt(np.einsum("tijk,tijk->tij", diff, diff))
    u = diff / np.where(dist > 0, dist, 1.0)[..., None]
    return dist, u


def residuals(
    x: np.ndarray, reported: np.ndarray, ranges: np.ndarray, G_half: np.ndarray, range_sigma: float
) -> tuple[np.ndarray, np.ndarray]:
    """Whitened GNSS residuals (T, n, 3) and range residuals (T, n, n) at positions x (0 where
    a range is nan). One compiled kernel: it is called a dozen times per leader step, where
    numpy's per-call overhead on these small arrays was most of its time."""
    T, n, _ = x.shape
    rg = np.empty((T, n, 3))
    rr = np.empty((T, n, n))
    residuals_kernel(
        np.ascontiguousarray(x, float),
        np.ascontiguousarray(reported, float),
        np.ascontiguousarray(ranges, float),
        np.ascontiguousarray(G_half, float),
        float(range_sigma),
        rg,
        rr,
    )
    return rg, rr


@njit(cache=True)
def residuals_kernel(x, reported, ranges, G_half, range_sigma, rg, rr):  # pragma: no cover
    """`residuals` in place on rg, rr, in numpy's order of operations (bit for bit the
    einsum and nan_to_num expression it replaced: an infinite range counts as +-DBL_MAX)."""
    T, n, _ = x.shape
    big = np.finfo(np.float64).max
    for t in range(T):
        for i in range(n):
            e0 = x[t, i, 0] - reported[t, i, 0]
            e1 = x[t, i, 1] - reported[t, i, 1]
            e2 = x[t, i, 2] - reported[t, i, 2]
            for a in range(3):
                rg[t, i, a] = G_half[a, 0] * e0 + G_half[a, 1] * e1 + G_half[a, 2] * e2
            for j in range(n):
                d = ranges[t, i, j]
                if np.isnan(d):
                    rr[t, i, j] = 0.0
                    continue
                if np.isinf(d):
                    d = big if d > 0 else -big
                rr[t, i, j] = (pair_distance(x[t], i, j) - d) / range_sigma


@njit(cache=True)
def pair_distance(xt, i, j):  # pragma: no cover - compiled
    """|x_i - x_j| (compiled) summed as numpy's einsum sums three squares, (d0^2 + d2^2) + d1^2
    (its two-lane loop), so a kernel gives the bits of ``np.sqrt(np.einsum("tijk,tijk->tij",
    diff, diff))``, the expression the kernels replaced."""
    d0 = xt[i, 0] - xt[j, 0]
    d1 = xt[i, 1] - xt[j, 1]
    d2 = xt[i, 2] - xt[j, 2]
    return np.sqrt((d0 * d0 + d2 * d2) + d1 * d1)


@njit(cache=True)
def norm_apart(p, q):  # pragma: no cover - compiled
    """|p - q| of two 3-vectors summed as np.linalg.norm sums three squares, in order:
    (d0^2 + d1^2) + d2^2 (einsum's order is `pair_distance`'s)."""
    d0 = p[0] - q[0]
    d1 = p[1] - q[1]
    d2 = p[2] - q[2]
    return np.sqrt((d0 * d0 + d1 * d1) + d2 * d2)


@njit(cache=True)
def _separation(xt, i, j):  # pragma: no cover - compiled
    """Distance between drones i and j at positions xt, and the vector x_i - x_j."""
    d0 = xt[i, 0] - xt[j, 0]
    d1 = xt[i, 1] - xt[j, 1]
    d2 = xt[i, 2] - xt[j, 2]
    return np.sqrt(d0 * d0 + d1 * d1 + d2 * d2), d0, d1, d2


@njit(cache=True)
def _ranged_pairs(rng_, rw, pi, pj):  # pragma: no cover - compiled
    """The ranges a problem uses, in place on pi, pj (n * n,): each (i, j), i != j, with a
    positive weight and a measured range, in row-major order (the order `_cost` and
    `_normal_equations` add them in, and the couplings of `envelope.coupling_order`; a nan
    weight is no range). Returns how many there are."""
    n = rng_.shape[0]
    k = 0
    for i in range(n):
        for j in range(n):
            if i != j and rw[i, j] > 0 and not np.isnan(rng_[i, j]):
                pi[k] = i
                pj[k] = j
                k += 1
    return k


@njit(cache=True)
def _cost(xt, rep, rng_, gw, rw, G, inv_s2, pr, prior_w, pi, pj, E):  # pragma: no cover - compiled
    """Weighted sum of squared whitened residuals of one problem at positions xt (n, 3), with
    the ranges (pi[k], pj[k]), k < E, of `_ranged_pairs`."""
    n = xt.shape[0]
    c = 0.0
    for i in range(n):
        w = gw[i]
        if w > 0:
            e0 = xt[i, 0] - rep[i, 0]
            e1 = xt[i, 1] - rep[i, 1]
            e2 = xt[i, 2] - rep[i, 2]
            e = (e0, e1, e2)
            for a in range(3):
                for b in range(3):
                    c += w * e[a] * G[a, b] * e[b]
        if prior_w > 0 and np.isfinite(pr[i, 0]):
            for a in range(3):
                c += prior_w * (xt[i, a] - pr[i, a]) ** 2
    for k in range(E):
        i, j = pi[k], pj[k]
        r = _separation(xt, i, j)[0] - rng_[i, j]
        c += rw[i, j] * inv_s2 * r * r
    return c


@njit(cache=True)
def _normal_equations(
    xt, rep, rng_, gw, rw, G, inv_s2, pr, prior_w, H, g, lower, pos, first, pi, pj, E
):  # pragma: no cover - compiled
    """Gauss-Newton normal equations H, g (in place) of one problem at xt, drone i's
    coordinates in rows (and columns) 3 pos[i] to 3 pos[i] + 2 of H (``pos`` the identity:
    the drones' own order). With ``lower``, of H only the lower triangle (H[p, q], p >= q;
    the rest is left as it was), all `_reduced_solve` and `_envelope_step` read: 21 entries
    per range instead of 36, and of that only each block row's part from its first block
    column ``first`` (by place; zeros: the whole triangle) is cleared: the envelope of
    `envelope.coupling_order`, where every range falls. Not the same bits as the full
    matrix's lower triangle (an off-diagonal block takes u_a u_b where the full matrix's
    transpose has u_b u_a). g is in the drones' own order."""
    n = xt.shape[0]
    if lower:
        for p in range(n):
            for r in range(3 * p, 3 * p + 3):
                for q in range(3 * first[p], r + 1):
                    H[r, q] = 0.0
    else:
        H[:, :] = 0.0
    g[:] = 0.0
    for i in range(n):
        o = 3 * pos[i]
        w = gw[i]
        if w > 0:
            for a in range(3):
                for b in range(3):
                    if not lower or b <= a:
                        H[o + a, o + b] += w * G[a, b]
                    g[3 * i + a] += w * G[a, b] * (xt[i, b] - rep[i, b])
        if prior_w > 0 and np.isfinite(pr[i, 0]):
            for a in range(3):
                H[o + a, o + a] += prior_w
                g[3 * i + a] += prior_w * (xt[i, a] - pr[i, a])
    for k in range(E):
        i, j = pi[k], pj[k]
        dist, d0, d1, d2 = _separation(xt, i, j)
        if dist == 0:
            continue
        u = (d0 / dist, d1 / dist, d2 / dist)
        wr = rw[i, j] * inv_s2
        r = dist - rng_[i, j]
        oi, oj = 3 * pos[i], 3 * pos[j]
        lo, hi = (oi, oj) if oi > oj else (oj, oi)
        for a in range(3):
            g[3 * i + a] += wr * r * u[a]
            g[3 * j + a] -= wr * r * u[a]
            for b in range(3):
                v = wr * u[a] * u[b]
                if not lower or b <= a:
                    H[oi + a, oi + b] += v
                    H[oj + a, oj + b] += v
                if lower:
                    H[lo + a, hi + b] -= v
                else:
                    H[oi + a, oj + b] -= v
                    H[oj + a, oi + b] -= v


PIVOT_FLOOR = 1e-8


@njit(cache=True)
def _lower(H, p, q):  # pragma: no cover - compiled
    """H[p, q] of a symmetric matrix of which only the lower triangle is set."""
    return H[p, q] if p >= q else H[q, p]


@njit(cache=True)
def _free_drones(rng_, gw, rw, free):  # pragma: no cover - compiled
    """Mark (in place on ``free`` (n,)) the drones with no GNSS weight and no weighted range of
    their own: their positions enter only through the ranges others measured to them (and a
    prior), so no two of them are coupled and their blocks of the normal equations are 3x3
    blocks on the diagonal. Returns how many there are."""
    n = gw.shape[0]
    count = 0
    for i in range(n):
        own = gw[i] > 0
        if not own:
            for j in range(n):
                if j != i and rw[i, j] > 0 and not np.isnan(rng_[i, j]):
                    own = True
                    break
        free[i] = not own
        if not own:
            count += 1
    return count


@njit(cache=True)
def _cholesky(S, m):  # pragma: no cover - compiled
    """In place, the lower Cholesky factor of S[:m, :m] (only its lower triangle is read).
    Returns the smallest pivot relative to its diagonal entry, d_j / S_jj (1 for a perfectly
    conditioned matrix, near 0 for a nearly singular one), or 0 if a pivot is not positive
    (then S is spoilt)."""
    worst = 1.0
    for j in range(m):
        d = S[j, j]
        diag = d
        for p in range(j):
            d -= S[j, p] * S[j, p]
        if not d > 0:
            return 0.0
        worst = min(worst, d / diag)
        d = np.sqrt(d)
        S[j, j] = d
        for i in range(j + 1, m):
            v = S[i, j]
            for p in range(j):
                v -= S[i, p] * S[j, p]
            S[i, j] = v / d
    return worst


@njit(cache=True)
def _cholesky_solve_columns(L, m, B):  # pragma: no cover - compiled
    """B[:m] <- (L L')^-1 B[:m] for every column of B (m or more rows, R columns), with L from
    `_cholesky`; row by row, so the columns go through the cache together."""
    R = B.shape[1]
    for i in range(m):
        for p in range(i):
            f = L[i, p]
            for q in range(R):
                B[i, q] -= f * B[p, q]
        d = L[i, i]
        for q in range(R):
            B[i, q] /= d
    for i in range(m - 1, -1, -1):
        for p in range(i + 1, m):
            f = L[p, i]
            for q in range(R):
                B[i, q] -= f * B[p, q]
        d = L[i, i]
        for q in range(R):
            B[i, q] /= d


@njit(cache=True)
def _cholesky_solve(L, m, y):  # pragma: no cover - compiled
    """y[:m] <- (L L')^-1 y[:m] with L from `_cholesky`: `_cholesky_solve_columns` for one
    column, the same operations in the same order (the same bits), each row's sum kept in a
    register (3x faster at m = 27)."""
    for i in range(m):
        v = y[i]
        for p in range(i):
            v -= L[i, p] * y[p]
        y[i] = v / L[i, i]
    for i in range(m - 1, -1, -1):
        v = y[i]
        for p in range(i + 1, m):
            v -= L[p, i] * y[p]
        y[i] = v / L[i, i]


@njit(cache=True)
def _reduced_solve(H, g, lam, ridge, idx, loose, S, rhs, Y, D, F, step):  # pragma: no cover
    """step = -A^-1 g for the damped normal equations A = H + diag(lam H_kk + ridge) when the
    drones ``loose`` are free (`_free_drones`: coupled only to the kept ones, whose
    coordinates are ``idx``): each free drone's 3x3 block is eliminated (Schur complement),
    the kept drones' system (len(idx) square) is solved by Cholesky, and the free drones are
    substituted back. The same step as solving A in exact arithmetic (A is symmetric positive
    definite: a Gauss-Newton matrix plus a positive damping), not the same bits. False if a
    pivot is not positive or below ``PIVOT_FLOOR`` of its diagonal (the caller then solves A
    in full). Only H's lower triangle is read, and H is not changed; F (n, 3, 3) keeps the
    free drones' factors."""
    m = idx.size
    for a in range(m):
        pa = idx[a]
        rhs[a] = -g[pa]
        for b in range(a):
            S[a, b] = H[pa, idx[b]]
        S[a, a] = H[pa, pa] + (lam * H[pa, pa] + ridge)
    for u in loose:
        o = 3 * u
        for a in range(3):
            for b in range(3):
                D[a, b] = H[o + a, o + b]
            D[a, a] += lam * H[o + a, o + a] + ridge
        if _cholesky(D, 3) < PIVOT_FLOOR:
            return False
        F[u] = D
        # Y = D^-1 [A[u, kept], -g_u] (3 x (m + 1))
        for b in range(m):
            pb = idx[b]
            for a in range(3):
                Y[a, b] = _lower(H, o + a, pb)
        for a in range(3):
            Y[a, m] = -g[o + a]
        # the two triangular solves with D, a pass over the m + 1 columns per row (each
        # column's operations as one column at a time would do them, in the same order: the
        # same bits; the passes vectorise, a third of the solve's time at n = 17)
        d00, d10, d11, d20, d21, d22 = D[0, 0], D[1, 0], D[1, 1], D[2, 0], D[2, 1], D[2, 2]
        Y0, Y1, Y2 = Y[0], Y[1], Y[2]
        for b in range(m + 1):
            Y0[b] = Y0[b] / d00
        for b in range(m + 1):
            Y1[b] = (Y1[b] - d10 * Y0[b]) / d11
        for b in range(m + 1):
            Y2[b] = (Y2[b] - d20 * Y0[b] - d21 * Y1[b]) / d22
        for b in range(m + 1):
            Y2[b] = Y2[b] / d22
        for b in range(m + 1):
            Y1[b] = (Y1[b] - d21 * Y2[b]) / d11
        for b in range(m + 1):
            Y0[b] = (Y0[b] - d10 * Y1[b] - d20 * Y2[b]) / d00
        for a in range(m):
            pa = idx[a]
            c0, c1, c2 = _lower(H, pa, o), _lower(H, pa, o + 1), _lower(H, pa, o + 2)
            if c0 == 0.0 and c1 == 0.0 and c2 == 0.0:
                continue  # no range between this coordinate's drone and u
            for b in range(a + 1):
                S[a, b] -= c0 * Y[0, b] + c1 * Y[1, b] + c2 * Y[2, b]
            rhs[a] -= c0 * Y[0, m] + c1 * Y[1, m] + c2 * Y[2, m]
    if m:
        if _cholesky(S, m) < PIVOT_FLOOR:
            return False
        _cholesky_solve(S, m, rhs)
    for a in range(m):
        step[idx[a]] = rhs[a]
    for u in loose:
        o = 3 * u
        r0 = -g[o]
        r1 = -g[o + 1]
        r2 = -g[o + 2]
        for b in range(m):
            pb = idx[b]
            r0 -= _lower(H, o, pb) * rhs[b]
            r1 -= _lower(H, o + 1, pb) * rhs[b]
            r2 -= _lower(H, o + 2, pb) * rhs[b]
        L = F[u]
        y0 = r0 / L[0, 0]
        y1 = (r1 - L[1, 0] * y0) / L[1, 1]
        y2 = (r2 - L[2, 0] * y0 - L[2, 1] * y1) / L[2, 2]
        y2 = y2 / L[2, 2]
        y1 = (y1 - L[2, 1] * y2) / L[1, 1]
        y0 = (y0 - L[1, 0] * y1 - L[2, 0] * y2) / L[0, 0]
        step[o] = y0
        step[o + 1] = y1
        step[o + 2] = y2
    return True


@njit(cache=True)
def _envelope_step(Hp, g, lam, ridge, order, first, L, rhs, step):  # pragma: no cover - compiled
    """step = -A^-1 g for the damped normal equations A = H + diag(lam H_kk + ridge) of a
    sparse range graph, from H's envelope in the drones' envelope order (`_normal_equations`
    with ``lower``, ``pos`` and ``first``): copied into L and factorised there
    (`envelope.envelope_cholesky`). The same step as solving A in exact arithmetic, not the
    same bits. False if a pivot is not positive or below ``PIVOT_FLOOR`` of its diagonal (the
    caller then solves A in full)."""
    nb = first.size
    for p in range(3 * nb):
        for q in range(3 * first[p // 3], p):
            L[p, q] = Hp[p, q]
        L[p, p] = Hp[p, p] + (lam * Hp[p, p] + ridge)
        rhs[p] = -g[3 * order[p // 3] + p % 3]
    if envelope_cholesky(L, first, nb) < PIVOT_FLOOR:
        return False
    envelope_solve(L, first, nb, rhs)
    for p in range(3 * nb):
        step[3 * order[p // 3] + p % 3] = rhs[p]
    return True


@njit(cache=True)
def levenberg_marquardt_kernel(
    x, reported, ranges, gnss_w, range_w, G, inv_s2, iters, tol, prior, prior_w, cost_out, conv_out, reduced
):  # pragma: no cover - compiled
    """Problem by problem, in place on x (T, n, 3): Levenberg-Marquardt with step acceptance.
    A step is taken only if it lowers the cost; otherwise the damping grows tenfold and the
    step is tried again. Converged: an accepted step below ``tol`` m, a cost decrease below
    1e-3 (the cost is a chi-square: statistically nothing; a crawl along a curved valley of
    near-collinear anchors stops there), or no step that lowers it.

    Each step solves the damped normal equations with LAPACK's LU (np.linalg.solve); on a
    sparse range graph (`envelope.range_share` at most SPARSE_SHARE) by an
    envelope Cholesky in reverse Cuthill-McKee order (`_envelope_step`: a solve 3x faster at
    n = 65 with each drone ranging 7-21 others, 12x at n = 256: benchmarks/bench_envelope.py);
    otherwise with ``reduced`` by
    `_reduced_solve` where some drones are free (2-3x faster at n = 17 with 8 drones free).
    Both are the same step as LU's in exact arithmetic, not the same bits, and fall back to LU
    where a pivot is small."""
    T, n, _ = x.shape
    N = 3 * n
    # every entry of H, A and S that a solver uses is written before it is read (each reads
    # only what its own normal equations wrote; `envelope.envelope_cholesky` reads and throws
    # away a diagonal block's upper entries): left unset, a large swarm's pages are not
    # zeroed on every call
    H = np.empty((N, N))
    g = np.zeros(N)
    A = np.empty((N, N))
    xn = np.zeros((n, 3))
    free = np.zeros(n, dtype=np.bool_)
    S = np.empty((N, N))
    rhs = np.zeros(N)
    Y = np.zeros((3, N + 1))
    D = np.zeros((3, 3))
    F = np.zeros((n, 3, 3))
    idx = np.zeros(N, dtype=np.int64)
    step = np.zeros(N)
    order = np.zeros(n, dtype=np.int64)
    pos = np.zeros(n, dtype=np.int64)
    first = np.zeros(n, dtype=np.int64)
    own = np.arange(n)  # the drones' own order, and no envelope: for the dense solvers
    none = np.zeros(n, dtype=np.int64)
    pi = np.zeros(n * n, dtype=np.int64)
    pj = np.zeros(n * n, dtype=np.int64)
    for t in range(T):
        xt = x[t]
        rep, rng_, gw, rw, pr = reported[t], ranges[t], gnss_w[t], range_w[t], prior[t]
        E = _ranged_pairs(rng_, rw, pi, pj)
        sparse = range_share(rng_) <= SPARSE_SHARE
        if sparse:  # the envelope's order, only where it is used
            coupling_order(n, pi, pj, E, order, pos, first)
        if reduced and not sparse:
            loose_count = _free_drones(rng_, gw, rw, free)
        else:
            loose_count = 0
            free[:] = False  # nothing left over from the problem before
        loose = np.flatnonzero(free)
        m = 0
        for i in range(n):
            if not free[i]:
                for a in range(3):
                    idx[m] = 3 * i + a
                    m += 1
        cost = _cost(xt, rep, rng_, gw, rw, G, inv_s2, pr, prior_w, pi, pj, E)
        lam = 1e-6
        conv = False
        for _ in range(iters):
            full = loose_count == 0 and not sparse  # H whole (else its lower triangle)
            if full:
                _normal_equations(
                    xt, rep, rng_, gw, rw, G, inv_s2, pr, prior_w, H, g, False, own, none, pi, pj, E
                )
            elif sparse:
                _normal_equations(
                    xt, rep, rng_, gw, rw, G, inv_s2, pr, prior_w, S, g, True, pos, first, pi, pj, E
                )
            else:
                _normal_equations(
                    xt, rep, rng_, gw, rw, G, inv_s2, pr, prior_w, H, g, True, own, none, pi, pj, E
                )
            diag = S if sparse else H  # the same diagonal, in the envelope order
            scale = 1.0
            for k in range(N):
                scale = max(scale, abs(diag[k, k]))
            accepted = False
            big = 0.0
            new_cost = cost
            for _attempt in range(16):
                ridge = 1e-12 * scale
                if full:
                    done = False
                elif sparse:
                    done = _envelope_step(S, g, lam, ridge, order, first, A, rhs, step)
                else:
                    done = _reduced_solve(H, g, lam, ridge, idx[:m], loose, S, rhs, Y, D, F, step)
                if not done:
                    if not full:  # the whole matrix for LU, from here on in this iteration
                        _normal_equations(
                            xt, rep, rng_, gw, rw, G, inv_s2, pr, prior_w, H, g, False, own, none, pi, pj, E
                        )
                        full = True
                    for a in range(N):
                        for b in range(N):
                            A[a, b] = H[a, b]
                        A[a, a] += lam * H[a, a] + ridge
                    step[:] = np.linalg.solve(A, -g)
                big = 0.0
                for i in range(n):
                    for a in range(3):
                        xn[i, a] = xt[i, a] + step[3 * i + a]
                        big = max(big, abs(step[3 * i + a]))
                new_cost = _cost(xn, rep, rng_, gw, rw, G, inv_s2, pr, prior_w, pi, pj, E)
                if new_cost <= cost:
                    accepted = True
                    break
                lam *= 10.0
                if big < tol:
                    break
            if not accepted:
                # no step lowers the cost even with damping 1e10 times larger: a minimum
                conv = True
                break
            decrease = cost - new_cost
            for i in range(n):
                for a in range(3):
                    xt[i, a] = xn[i, a]
            cost = new_cost
            lam = max(lam * 0.3, 1e-12)
            if big < tol or decrease <= 1e-3 + 1e-12 * cost:
                conv = True
                break
        cost_out[t] = cost
        conv_out[t] = conv


def _dense(w: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Weights ``w`` as a C-contiguous float array of ``shape`` (broadcast only if needed)."""
    w = np.asarray(w)
    if w.shape != shape:
        w = np.broadcast_to(w, shape)
    return np.ascontiguousarray(w, float)


def weighted_gauss_newton(
    x0: np.ndarray,
    reported: np.ndarray,
    ranges: np.ndarray,
    gnss_w: np.ndarray,
    range_w: np.ndarray,
    gnss_cov: np.ndarray,
    range_sigma: float,
    iters: int = 50,
    tol: float = 1e-7,
    prior: np.ndarray | None = None,
    prior_sigma: float | None = None,
    full: bool = False,
    reduced: bool = False,
):
    """Minimise sum_i gnss_w_i |G^1/2 (x_i - z_i)|^2 + sum_ij range_w_ij ((|x_i - x_j| - d_ij)/s)^2
    (+ sum_i |x_i - p_i|^2 / prior_sigma^2 over drones with a prior p_i, nan = none) over
    x (T, n, 3), starting at x0: Levenberg-Marquardt with the analytic Jacobian and step
    acceptance (a step is taken only if it lowers the cost), each problem until it converges
    or ``iters`` steps (a numba kernel: the normal equations of 17 drones are 51 x 51, small
    enough that numpy's per-call overhead dominated). With ``full``, also returns the final
    cost (T,) and whether each problem converged (T,). ``reduced``: solve each step by
    eliminating the free drones (see `levenberg_marquardt_kernel`): faster, not the same bits;
    for solves that only feed a test, not for an estimate a verdict reports. On a sparse range
    graph every solve, ``reduced`` or not, goes by the envelope Cholesky: LU's step in exact
    arithmetic, not its bits (deterministic all the same)."""
    x = np.array(x0, dtype=float, copy=True)
    T, n, _ = x.shape
    G = gnss_information(gnss_cov)
    has_prior = prior is not None and prior_sigma is not None and prior_sigma > 0
    # without a prior the kernel never reads it (its weight is 0)
    prior_arr = np.ascontiguousarray(prior, float) if has_prior else np.empty((T, n, 3))
    cost = np.zeros(T)
    conv = np.zeros(T, dtype=np.bool_)
    levenberg_marquardt_kernel(
        x,
        np.ascontiguousarray(reported, float),
        np.ascontiguousarray(ranges, float),
        _dense(gnss_w, (T, n)),
        _dense(range_w, (T, n, n)),
        G,
        1.0 / range_sigma**2,
        int(iters),
        float(tol),
        prior_arr,
        1.0 / prior_sigma**2 if has_prior else 0.0,
        cost,
        conv,
        bool(reduced),
    )
    return (x, cost, conv) if full else x


def initial_positions(
    reported: np.ndarray,
    ranges: np.ndarray,
    trusted: np.ndarray,
    prior: np.ndarray | None = None,
    fast: bool = False,
) -> np.ndarray:
    """Start for the joint solve: trusted drones at their reports; the others by closed-form
    multilateration from the trusted ones they have ranges with, or, with fewer than 4 such
    anchors, at their prior if they have one (which picks the right one of the two mirror
    solutions that 3 anchors leave), else at their report. ``fast``: see
    `trust_region.linear_multilateration`."""
    x = np.array(reported, dtype=float, copy=True)
    has_prior = prior is not None
    _initial_kernel(
        x,
        np.ascontiguousarray(ranges, float),
        np.ascontiguousarray(trusted, np.bool_),
        np.ascontiguousarray(prior, float) if has_prior else x,
        has_prior,
        bool(fast),
    )
    return x


@njit(cache=True)
def _initial_kernel(x, ranges, trusted, prior, has_prior, fast):  # pragma: no cover - compiled
    """`initial_positions` in place on x (T, n, 3), the reports on entry: each untrusted drone
    a at its prior (where ``has_prior`` and its row has no nan), then, with 4 or more trusted
    anchors k that have a range with it (the anchor's own d_ka first, else d_ak), by
    `trust_region._multilateration_kernel` on that problem alone (the same inputs as the
    numpy selection that fed it, so the same bits)."""
    T, n, _ = x.shape
    anchors = np.empty((1, n, 3))
    dists = np.zeros((1, n))
    mask = np.zeros((1, n), dtype=np.bool_)
    out = np.empty((1, 3))
    for t in range(T):
        for i in range(n):
            for c in range(3):
                anchors[0, i, c] = x[t, i, c]  # the reports: no drone moved yet
        for a in range(n):
            if trusted[t, a]:
                continue
            if has_prior and not np.isnan(prior[t, a]).any():
                for c in range(3):
                    x[t, a, c] = prior[t, a, c]
            cnt = 0
            for k in range(n):
                d = ranges[t, k, a]
                if np.isnan(d):
                    d = ranges[t, a, k]
                dists[0, k] = d
                mask[0, k] = trusted[t, k] and k != a and not np.isnan(d)
                if mask[0, k]:
                    cnt += 1
            if cnt >= 4:
                _multilateration_kernel(anchors, dists, mask, out, fast)
                for c in range(3):
                    x[t, a, c] = out[0, c]


def joint_estimate(
    reported: np.ndarray,
    ranges: np.ndarray,
    trusted: np.ndarray,
    gnss_cov: np.ndarray,
    range_sigma: float,
    iters: int = 8,
    x0: np.ndarray | None = None,
    prior: np.ndarray | None = None,
    prior_sigma: float | None = None,
    reduced: bool = False,
) -> np.ndarray:
    """All positions (T, n, 3) with the trusted set known: GNSS of trusted drones, ranges
    measured by trusted drones (an untrusted drone's own ranges may be tampered), ranges
    measured by others to the untrusted ones, and priors (T, n, 3; nan = none) where given.
    ``x0``: a start (e.g. the previous solution when the trusted set shrinks by one); by
    default closed-form multilateration. ``reduced``: see `weighted_gauss_newton` (and the
    start by `initial_positions` with ``fast``)."""
    if prior is not None:
        # a prior only where the position must come from ranges (a trusted drone has its GNSS),
        # so a stale or wrong prior cannot pull the trusted geometry
        prior = np.where(trusted[..., None], np.nan, prior)
    if x0 is None:
        x0 = initial_positions(reported, ranges, trusted, prior, fast=reduced)
    gnss_w = trusted.astype(float)
    range_w = np.broadcast_to(trusted[:, :, None], ranges.shape).astype(float)
    return weighted_gauss_newton(
        x0,
        reported,
        ranges,
        gnss_w,
        range_w,
        gnss_cov,
        range_sigma,
        iters,
        prior=prior,
        prior_sigma=prior_sigma,
        reduced=reduced,
    )


def anchor_counts(ranges: np.ndarray, trusted: np.ndarray) -> np.ndarray:
    """For each drone, how many trusted other drones share a range with it (T, n)."""
    n = ranges.shape[1]
    linked = (~np.isnan(ranges) | ~np.isnan(np.swapaxes(ranges, 1, 2))) & ~np.eye(n, dtype=bool)
    return (linked & trusted[:, None, :]).sum(axis=2)


def trusted_estimate(
    reported: np.ndarray,
    ranges: np.ndarray,
    trusted: np.ndarray,
    gnss_cov: np.ndarray,
    range_sigma: float,
    x0: np.ndarray | None = None,
    prior: np.ndarray | None = None,
    prior_sigma: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Joint estimate with a decided trusted set, and the status per trial: ``degenerate``
    when an untrusted drone has fewer than 4 trusted drones to range with (3 spheres leave a
    mirror ambiguity, fewer a continuum), or fewer than 3 if it has a prior (previous verified
    position or INS) that resolves the mirror; its report is then kept rather than guessed."""
    positions = joint_estimate(
        reported,
        ranges,
        trusted,
        gnss_cov,
        range_sigma,
        iters=8 if x0 is None else 4,
        x0=x0,
        prior=prior,
        prior_sigma=prior_sigma,
    )
    need = np.full(trusted.shape, 4)
    if prior is not None and prior_sigma:
        need = np.where(np.isnan(prior).any(axis=2), 4, 3)
    thin = ~trusted & (anchor_counts(ranges, trusted) < need)
    positions = np.where(thin[..., None], reported, positions)
    return positions, np.where(thin.any(axis=1), "degenerate", "ok")


def residual_statistics(
    x: np.ndarray, reported: np.ndarray, ranges: np.ndarray, trusted: np.ndarray, noise: NoiseModel
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-drone chi-square contributions (T, n) of trusted drones (GNSS block + own ranges),
    the GNSS blocks alone (T, n), the total (T,) and its degrees of freedom (T,). One kernel
    (`_statistics_kernel`) after `residuals`, in the order numpy's expressions summed."""
    rg, rr = residuals(x, reported, ranges, noise.whitener, noise.range_sigma)
    T, n, _ = rg.shape
    if n > PAIRWISE_MAX:  # beyond the kernel's sums: numpy's expressions
        own = ~np.isnan(ranges) & ~np.eye(n, dtype=bool) & trusted[:, :, None]
        gnss_q = np.where(trusted, np.einsum("tni,tni->tn", rg, rg), 0.0)
        per = gnss_q + np.where(own, rr**2, 0.0).sum(axis=2)
        return per, gnss_q, per.sum(axis=1), 3 * trusted.sum(axis=1) + own.sum(axis=(1, 2)) - 3 * n
    per, gnss_q, total = np.empty((T, n)), np.empty((T, n)), np.empty(T)
    dof = np.empty(T, dtype=np.int64)
    _statistics_kernel(
        rg,
        rr,
        np.ascontiguousarray(ranges, float),
        np.ascontiguousarray(trusted, np.bool_),
        per,
        gnss_q,
        total,
        dof,
    )
    return per, gnss_q, total, dof


@njit(cache=True)
def _pairwise_block(a, lo, n):  # pragma: no cover - compiled
    """numpy's pairwise sum of a[lo : lo + n], n <= 128 (its unrolled block)."""
    if n < 8:
        r = -0.0
        for i in range(lo, lo + n):
            r += a[i]
        return r
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - (n % 8):
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True)
def _half(n):  # pragma: no cover - compiled
    """Where numpy's pairwise sum splits a run of n > 128: half of it, a multiple of 8 below."""
    n2 = n // 2
    return n2 - n2 % 8


@njit(cache=True)
def _pairwise_2(a, lo, n):  # pragma: no cover - compiled
    """`pairwise_sum` of a run whose halves are blocks (n <= 256)."""
    if n <= 128:
        return _pairwise_block(a, lo, n)
    h = _half(n)
    return _pairwise_block(a, lo, h) + _pairwise_block(a, lo + h, n - h)


@njit(cache=True)
def _pairwise_3(a, lo, n):  # pragma: no cover - compiled
    """`pairwise_sum` of a run whose quarters are blocks (n <= 512)."""
    if n <= 128:
        return _pairwise_block(a, lo, n)
    h = _half(n)
    return _pairwise_2(a, lo, h) + _pairwise_2(a, lo + h, n - h)


@njit(cache=True)
def pairwise_sum(a, lo, n):  # pragma: no cover - compiled
    """a[lo : lo + n].sum() as numpy sums a contiguous axis (pairwise: blocks of at most 128
    in eight lanes, halves of longer runs summed apart), so a kernel gives its bits, for
    n up to PAIRWISE_MAX (numpy's recursion unrolled three levels deep: numba's cache
    cannot hold a recursive function)."""
    if n <= 128:
        return _pairwise_block(a, lo, n)
    h = _half(n)
    return _pairwise_3(a, lo, h) + _pairwise_3(a, lo + h, n - h)


#: the longest run `pairwise_sum` sums as numpy does (every length up to it tested against np.sum)
PAIRWISE_MAX = 960


@njit(cache=True)
def _statistics_kernel(rg, rr, ranges, trusted, per, gnss_q, total, dof):  # pragma: no cover
    """`residual_statistics` from the residuals rg (T, n, 3), rr (T, n, n), in place: each
    trusted drone's |rg|^2 (einsum's three squares) plus the sum of its measured ranges'
    rr^2 (numpy's pairwise sum of the row, unmeasured as 0), the total of those, and the
    degrees of freedom 3 (trusted) + (ranges trusted drones measured) - 3 n."""
    T, n, _ = rg.shape
    row = np.empty(n)
    for t in range(T):
        count = 0
        for i in range(n):
            q = 0.0
            if trusted[t, i]:
                q = (rg[t, i, 0] * rg[t, i, 0] + rg[t, i, 2] * rg[t, i, 2]) + rg[t, i, 1] * rg[t, i, 1]
                count += 3
            gnss_q[t, i] = q
            for j in range(n):
                row[j] = 0.0
                if trusted[t, i] and j != i and not np.isnan(ranges[t, i, j]):
                    row[j] = rr[t, i, j] * rr[t, i, j]
                    count += 1
            per[t, i] = q + pairwise_sum(row, 0, n)
        total[t] = pairwise_sum(per[t], 0, n)
        dof[t] = count - 3 * n


def chi2_quantile(q: float, dof: np.ndarray | int) -> np.ndarray:
    """Chi-square quantile (scipy.special.chdtri: the ufunc behind chi2.ppf, without its
    per-call argument checking, which dominated the detectors' step time). An integer dof's
    quantile is remembered (a step asks for the same few, eight times)."""
    if isinstance(dof, int | np.integer):
        return _chi2_scalar(float(q), int(dof))
    return chdtri(dof, 1 - q)


@lru_cache(maxsize=256)
def _chi2_scalar(q: float, dof: int) -> np.float64:
    return chdtri(dof, 1 - q)


def tests_pass(
    gnss_q: np.ndarray, total: np.ndarray, dof: np.ndarray, trusted: np.ndarray, p_fa: float
) -> np.ndarray:
    """The residual tests on `residual_statistics` (T,): the global chi-square test of all
    residuals at ``p_fa``, and the local 3-dof test of the worst trusted GNSS report at
    ``p_fa / n`` (its power does not drown in the many range residuals)."""
    n = trusted.shape[1]
    local_ok = np.where(trusted, gnss_q, 0.0).max(axis=1) <= chi2_quantile(1 - p_fa / n, 3)
    dof = np.asarray(dof)
    if dof.size <= 16:  # a step's few: each quantile remembered (`chi2_quantile`)
        limit = np.array([chi2_quantile(1 - p_fa, max(int(d), 1)) for d in dof.ravel()]).reshape(dof.shape)
    else:
        limit = chi2_quantile(1 - p_fa, np.maximum(dof, 1))
    global_ok = (dof <= 0) | (total <= limit)
    return local_ok & global_ok


#: rounding in `cannot_pass`'s own arithmetic never rules out a set: its band is widened by this
_BAND_ROUNDING = 1e-9


def cannot_pass(
    reported: np.ndarray,
    ranges: np.ndarray,
    sets: np.ndarray,
    owner: np.ndarray,
    gnss_cov: np.ndarray,
    range_sigma: float,
    p_fa: float,
    along_line: bool = True,
) -> np.ndarray:
    """Trusted sets (B, n) of the trials ``owner`` (B,) of ``reported`` (T, n, 3) and
    ``ranges`` (T, n, n) whose residual tests (`tests_pass`) fail whatever the estimate (B,).

    Two trusted drones i, j with a range d_ij that i measured: in a passing estimate x the
    local test holds each one's GNSS error e = z - x inside the ellipsoid e^T C^-1 e <= L (C
    the GNSS covariance, L its 3-dof quantile at p_fa / n), so w = e_i - e_j lies in the
    ellipsoid of radius R = 2 sqrt(L), and the global test bounds the range residual by
    s = range_sigma sqrt(G) (G its quantile at p_fa with the set's degrees of freedom). With
    z = z_i - z_j and u = z / |z|, |x_i - x_j| = |z - w| lies between |z| - R sqrt(u^T C u)
    (w's reach along the line of sight) and sqrt(|z|^2 + 2 |z| R sqrt(u^T C u) + R^2
    lambda_max(C)); a set with a pair whose range d_ij is beyond that band by more than s
    fails. Without ``along_line`` the band is the wider |z| -+ R sqrt(lambda_max(C)) (its
    rule before 2026-12-05), where a horizontal link with a vertical GNSS error twice the
    horizontal has twice the slack it needs: at n = 17 in `bench_audit.py` the band along the
    line rules out every swap of the rival check, the wider one half of them; at n = 65 in
    `bench_sparse.py` 1,075 of 1,282 against 893. (`set_search` keeps the wider band: its
    budget counts the sets it estimates, and with fewer to estimate some searches that stop
    at the budget today would finish, changing their verdicts.) A set with no degrees of
    freedom (the global test then passes) is never ruled out here. Exact either way: a set
    ruled out is one no solver could make pass, so it need not be solved."""
    n = reported.shape[1]
    C = np.ascontiguousarray(gnss_cov, float)
    lam = smallest_information(gnss_cov)  # 1 / lambda_max(C)
    # R, or (without along_line) the band's half-width R sqrt(lambda_max(C)), as before
    reach = 2.0 * np.sqrt(chi2_quantile(1 - p_fa / n, 3) / (1.0 if along_line else lam))
    measured = ~np.isnan(ranges) & ~np.eye(n, dtype=bool)
    own = (measured.sum(axis=2)[owner] * sets).sum(axis=1)
    dof = 3 * sets.sum(axis=1) + own - 3 * n
    # the quantile of each distinct dof once (a search's thousands of sets share a few); a
    # few sets (the rival check's swaps) each their own: the same values, without np.unique
    if len(sets) > 64:
        dofs, which = np.unique(np.maximum(dof, 1), return_inverse=True)
        slack = range_sigma * np.sqrt(chi2_quantile(1 - p_fa, dofs))[which]
    else:
        slack = range_sigma * np.sqrt(chi2_quantile(1 - p_fa, np.maximum(dof, 1)))
    slack = np.ascontiguousarray(slack, float)
    beyond = np.zeros(len(sets), dtype=bool)
    _pair_beyond(
        np.ascontiguousarray(reported, float),
        np.ascontiguousarray(ranges, float),
        np.ascontiguousarray(owner, np.int64),
        np.ascontiguousarray(sets, bool),
        C,
        float(reach),
        1.0 / lam,
        slack if along_line else (reach + slack) * (1 + _BAND_ROUNDING),
        along_line,
        beyond,
    )
    return beyond & (dof > 0) & np.isfinite(reported).all(axis=(1, 2))[owner]


@njit(cache=True)
def _pair_beyond(reported, ranges, owner, sets, C, reach, widest, slack, along_line, out):  # pragma: no cover
    """out[b]: some two drones i, j of set b have a range d_ij of trial owner[b] outside the
    band `cannot_pass` gives |x_i - x_j| from their reports z, widened by slack[b] (an
    unmeasured range is never outside it, an infinite one always); without ``along_line``
    outside |z| -+ slack[b] (the caller's whole half-width). |z| summed in order, as
    np.linalg.norm sums. A loop that stops at the first such pair, where numpy built three
    (B, n, n) arrays: 3.7 ms of a search's step at n = 13, 5,812 sets."""
    n = sets.shape[1]
    grow = 1.0 + _BAND_ROUNDING
    for b in range(sets.shape[0]):
        z = reported[owner[b]]
        r = ranges[owner[b]]
        s = slack[b]
        for i in range(n):
            if out[b]:
                break
            if not sets[b, i]:
                continue
            for j in range(n):
                if j == i or not sets[b, j] or np.isnan(r[i, j]):
                    continue
                m = norm_apart(z[i], z[j])
                if not along_line:
                    if abs(m - r[i, j]) > s:
                        out[b] = True
                        break
                    continue
                w0 = z[i, 0] - z[j, 0]
                w1 = z[i, 1] - z[j, 1]
                w2 = z[i, 2] - z[j, 2]
                if m > 0.0:
                    q = (
                        w0 * (C[0, 0] * w0 + C[0, 1] * w1 + C[0, 2] * w2)
                        + w1 * (C[1, 0] * w0 + C[1, 1] * w1 + C[1, 2] * w2)
                        + w2 * (C[2, 0] * w0 + C[2, 1] * w1 + C[2, 2] * w2)
                    )
                    along = reach * np.sqrt(max(q, 0.0)) / m  # R sqrt(u^T C u)
                else:
                    along = reach * np.sqrt(widest)
                far = np.sqrt(m * m + 2.0 * m * along + reach * reach * widest)
                if m - r[i, j] > (along + s) * grow or r[i, j] - s > far * grow:
                    out[b] = True
                    break


def passes_residual_tests(
    x: np.ndarray,
    reported: np.ndarray,
    ranges: np.ndarray,
    trusted: np.ndarray,
    noise: NoiseModel,
    p_fa: float,
) -> np.ndarray:
    """Whether a joint estimate with this trusted set explains the data (T,); see
    `tests_pass`."""
    _, gnss_q, total, dof = residual_statistics(x, reported, ranges, trusted, noise)
    return tests_pass(gnss_q, total, dof, trusted, p_fa)

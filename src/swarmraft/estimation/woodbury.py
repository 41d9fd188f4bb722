"""Every fault hypothesis of the protection levels from the all-in-view covariance, by the
Woodbury identity (the numerical core of `integrity.assess`).

Hypothesis j ("trusted drone j is faulty") leaves out drone j's GNSS report and the ranges
it measured. Its information is A_j = U_j U_j' with 3 GNSS columns (G^1/2 on drone j's
coordinates) and one column per range j measured to k (sqrt(w_jk) u_jk on drone j's
coordinates, -sqrt(w_jk) u_jk on drone k's). With P0 = J^-1, the subset covariance is
P_j = (J - A_j)^-1 = P0 + X_j S_j^-1 X_j' where X_j = P0 U_j (N x m, m = 3 + K) and
S_j = I - U_j' X_j (m x m): one m x m system per hypothesis instead of inverting a 3n x 3n
matrix. Only the 3x3 diagonal blocks of P_j and the step P_j b_j are kept.

`without_each` is a numba kernel, trial by trial and hypothesis by hypothesis (S_j by
`joint`'s Cholesky, which the reduced Levenberg-Marquardt solve uses too): the numpy
version it replaced built every hypothesis' X at once (tens of MB at n = 64) and its many
small array operations were most of the protection levels' time at n = 17 (1.0 ms of a
5 ms step). A zero column (a range not measured) adds an identity row to S_j and nothing
to P_j, so each hypothesis takes its own K (the ranges its drone measured) and a verdict's
bits do not depend on the other trials of its batch.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from swarmraft.estimation.joint import PIVOT_FLOOR, _cholesky, _cholesky_solve_columns, pair_distance


@njit(cache=True)
def _kernel(P0, b, gnss, Gh, u, w, nb, K_t, Cj, dj):  # pragma: no cover - compiled
    """`without_each` into Cj (T, n, n, 3, 3) and dj (T, n, 3n): hypothesis j's columns are
    its GNSS (Gh = G^1/2, weight gnss[t, j]) and its ranges to the drones nb[t, j, :K_t[t]]."""
    T, N, _ = P0.shape
    n = N // 3
    Kmax = nb.shape[2]
    X = np.zeros((N, 3 + Kmax))
    S = np.zeros((3 + Kmax, 3 + Kmax))
    Z = np.zeros((3 + Kmax, N))
    sw = np.zeros(Kmax)
    P0b = np.zeros(N)
    bq = np.zeros(N, dtype=np.int64)
    for t in range(T):
        finite = True  # P0 without inf or nan: its zero products add nothing to a sum
        for r in range(N):
            for q in range(N):
                if not np.isfinite(P0[t, r, q]):
                    finite = False
        for j in range(n):
            g = gnss[t, j]
            o = 3 * j
            if g == 0.0 and not (w[t, j] > 0).any():
                # an untrusted drone's hypothesis leaves nothing out: the all-in-view blocks,
                # and no step (what the identity gives with its columns all zero)
                for i in range(n):
                    for a in range(3):
                        for c in range(3):
                            Cj[t, j, i, a, c] = P0[t, 3 * i + a, 3 * i + c]
                for r in range(N):
                    dj[t, j, r] = 0.0
                continue
            # the ranges j measured (first in nb): the trial's other columns would be zero,
            # each an identity row of S_j that adds nothing (the same values with fewer of
            # them: at n = 65 a drone ranges 7-21 others, and every hypothesis took 21)
            K = 0
            while K < K_t[t] and w[t, j, nb[t, j, K]] > 0:
                K += 1
            m = 3 + K
            # X = P0 U_j: GNSS columns P0[:, j] Gh g, range columns sqrt(w) (P0[:, j] - P0[:, k]) u
            for c in range(K):
                sw[c] = np.sqrt(w[t, j, nb[t, j, c]])
            for r in range(N):
                for a in range(3):
                    v = 0.0
                    for q in range(3):
                        v += P0[t, r, o + q] * Gh[q, a]
                    X[r, a] = v * g
                for c in range(K):
                    k = nb[t, j, c]
                    ok = 3 * k
                    v = 0.0
                    for q in range(3):
                        v += (P0[t, r, o + q] - P0[t, r, ok + q]) * u[t, j, k, q]
                    X[r, 3 + c] = sw[c] * v
            # S = I - U_j' X (symmetrised)
            for col in range(m):
                for a in range(3):
                    v = 0.0
                    for q in range(3):
                        v += Gh[q, a] * X[o + q, col]
                    S[a, col] = -v * g
                for c in range(K):
                    k = nb[t, j, c]
                    ok = 3 * k
                    v = 0.0
                    for q in range(3):
                        v += u[t, j, k, q] * (X[o + q, col] - X[ok + q, col])
                    S[3 + c, col] = -sw[c] * v
            for a in range(m):
                S[a, a] += 1.0
                for c in range(a):
                    s = 0.5 * (S[a, c] + S[c, a])
                    S[a, c] = s
                    S[c, a] = s
            # Z = S^-1 X' (m, N) by Cholesky (S is symmetric positive definite where the
            # hypothesis leaves every position fixed; elsewhere, or nearly so, nan: the
            # hypothesis is left to `integrity.assess`, which inverts it directly)
            if _cholesky(S, m) < PIVOT_FLOOR:
                for i in range(n):
                    Cj[t, j, i] = np.nan
                for r in range(N):
                    dj[t, j, r] = np.nan
                continue
            for q in range(m):
                for r in range(N):
                    Z[q, r] = X[r, q]
            _cholesky_solve_columns(S, m, Z)
            # blocks of P_j: P0's plus X_i Z_i
            for i in range(n):
                for a in range(3):
                    for c in range(3):
                        v = P0[t, 3 * i + a, 3 * i + c]
                        for q in range(m):
                            v += X[3 * i + a, q] * Z[q, 3 * i + c]
                        Cj[t, j, i, a, c] = v
            # step: P0 b_j + X (Z b_j); b_j is zero but on drone j and the drones it ranges
            # (a sparse range graph: 3 (K + 1) of 3n coordinates), and with P0 finite a zero
            # term adds nothing to the sum, so only the others are summed, in the same order
            nz = 0
            for q in range(N):
                if b[t, j, q] != 0.0 or not finite:
                    bq[nz] = q
                    nz += 1
            for r in range(N):
                v = 0.0
                for e in range(nz):
                    q = bq[e]
                    v += P0[t, r, q] * b[t, j, q]
                P0b[r] = v
            for q in range(m):
                v = 0.0
                for r in range(N):
                    v += Z[q, r] * b[t, j, r]
                for r in range(N):
                    P0b[r] += X[r, q] * v
            for r in range(N):
                dj[t, j, r] = P0b[r]


def without_each(
    P0: np.ndarray, b: np.ndarray, gnss: np.ndarray, G: np.ndarray, u: np.ndarray, w: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """For every hypothesis j, the 3x3 diagonal blocks (T, j, n, 3, 3) of P_j = (J - A_j)^-1
    and the step P_j b_j (T, j, n, 3), from P0 = J^-1 (T, 3n, 3n), the gradients b (T, n, 3n)
    of what each hypothesis leaves out, and its terms: GNSS weight ``gnss`` (T, n) of
    information ``G`` (3, 3), unit vectors ``u`` (T, j, k, 3) and weights ``w`` (T, j, k)
    of its ranges (0: not measured). Where S_j is nearly singular (drone j's measurements
    fix something nothing else does) the identity loses precision; `integrity.assess`
    recomputes those hypotheses exactly."""
    T, N, _ = P0.shape
    n = N // 3
    measured = w > 0
    K_t = np.maximum(measured.sum(axis=2).max(axis=1), 1).astype(np.int64)  # (T,)
    # each hypothesis' ranges, measured ones first (stable: in order of k)
    nb = np.ascontiguousarray(np.argsort(~measured, axis=2, kind="stable")[..., : int(K_t.max())])
    Cj = np.empty((T, n, n, 3, 3))
    dj = np.empty((T, n, N))
    _kernel(
        np.ascontiguousarray(P0, float),
        np.ascontiguousarray(b, float),
        np.ascontiguousarray(gnss, float),
        np.linalg.cholesky(G),
        np.ascontiguousarray(u, float),
        np.ascontiguousarray(w, float),
        nb.astype(np.int64),
        K_t,
        Cj,
        dj,
    )
    return Cj, dj.reshape(T, n, n, 3)


@njit(cache=True)
def _finite(d):  # pragma: no cover - compiled
    """d with an infinite value as +-DBL_MAX, as np.nan_to_num makes it."""
    if np.isinf(d):
        big = np.finfo(np.float64).max
        return big if d > 0 else -big
    return d


@njit(cache=True)
def hypotheses_kernel(x, reported, ranges, trusted, keep, G, w_r, J, b, gnss, u, w):  # pragma: no cover
    """`integrity._hypothesis_information` in place on J (T, 3n, 3n), b (T, n, 3n), and the
    terms gnss (T, n), u (T, j, k, 3), w (T, j, k), in the order of operations of the numpy
    expressions it replaced (see there: J's diagonal blocks summed over j in order, each
    hypothesis' own block its GNSS plus its ranges summed over k in order)."""
    T, n, _ = x.shape
    uu = np.empty((n, n, 3, 3))  # hypothesis j's range terms w u u' to each k (k = j: none)
    own = np.empty((n, 3, 3))  # hypothesis j's own block
    for t in range(T):
        for j in range(n):
            gnss[t, j] = 1.0 if trusted[t, j] else 0.0
            for k in range(n):
                d = pair_distance(x[t], j, k)
                s = d if d > 0 else 1.0
                for a in range(3):
                    u[t, j, k, a] = (x[t, j, a] - x[t, k, a]) / s
                m = j != k and not np.isnan(ranges[t, j, k]) and trusted[t, j] and keep[t, j] and keep[t, k]
                w[t, j, k] = w_r if m else 0.0
        for j in range(n):
            for k in range(n):
                for a in range(3):
                    for c in range(3):
                        # einsum adds each product to a zeroed output: a zero is +0.0
                        uu[j, k, a, c] = 0.0 + w[t, j, k] * u[t, j, k, a] * u[t, j, k, c]
            for a in range(3):
                for c in range(3):
                    acc = uu[j, 0, a, c]
                    for k in range(1, n):
                        acc += uu[j, k, a, c]
                    own[j, a, c] = (G[a, c] if trusted[t, j] else 0.0) + acc
        for p in range(n):
            for q in range(n):
                for a in range(3):
                    for c in range(3):
                        if p != q:  # -(uu[p, q] + uu[q, p]), its sign of zero as numpy's
                            J[t, 3 * p + a, 3 * q + c] = -(uu[p, q, a, c] + uu[q, p, a, c])
                        else:  # block p sums over j of (own if j = p else uu[j, p]), j in order
                            v = own[p, a, c] if p == 0 else uu[0, p, a, c]
                            for j in range(1, n):
                                v += own[p, a, c] if j == p else uu[j, p, a, c]
                            J[t, 3 * p + a, 3 * p + c] = v
        b[t] = 0.0
        for j in range(n):
            # b_j: GNSS and range gradients on drone j, minus the range terms on each k
            for a in range(3):
                e = 0.0
                if trusted[t, j]:  # einsum's order: (G_a0 d0 + G_a2 d2) + G_a1 d1
                    d0 = x[t, j, 0] - reported[t, j, 0]
                    d1 = x[t, j, 1] - reported[t, j, 1]
                    d2 = x[t, j, 2] - reported[t, j, 2]
                    e = (G[a, 0] * d0 + G[a, 2] * d2) + G[a, 1] * d1
                acc = 0.0
                for k in range(n):
                    r = 0.0
                    if w[t, j, k] > 0:
                        r = pair_distance(x[t], j, k) - _finite(ranges[t, j, k])
                    acc += (w_r * r) * u[t, j, k, a]
                b[t, j, 3 * j + a] = e + acc
                for k in range(n):
                    r = 0.0
                    if w[t, j, k] > 0:
                        r = pair_distance(x[t], j, k) - _finite(ranges[t, j, k])
                    b[t, j, 3 * k + a] -= 0.0 + (w_r * r) * u[t, j, k, a]

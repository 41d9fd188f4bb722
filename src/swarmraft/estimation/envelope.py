"""Envelope (skyline) Cholesky for the normal equations of a sparse range graph.

On a sparse range graph (each drone ranges only its neighbours) a drone's 3x3 block of the
Gauss-Newton matrix couples only to the drones it has a range with. Ordered by reverse
Cuthill-McKee, the coupled coordinates sit near the diagonal; the Cholesky factor of a
symmetric positive definite matrix keeps its nonzeros inside the envelope (from each row's
first nonzero column to the diagonal), so factorising only the envelope costs about
``N * b^2 / 2`` multiply-adds for a mean row width ``b`` instead of LU's ``2 N^3 / 3``:
65 drones ranging up to 60 m in a 150 m formation have b of about 45 (a reach of about 14
drones) of N = 195 (benchmarks/bench_envelope.py).

`range_share` says whether a problem's graph is sparse, `coupling_order` orders its
drones, `envelope_cholesky` factorises (by 3x3 blocks,
a drone's coordinates together) and `envelope_solve` solves. Compiled, every sum in a fixed
order (the partial sums are not left to the compiler or a BLAS to group); the bits are not
those of the dense LU they replace.
"""

from __future__ import annotations

import numpy as np
from numba import njit

SPARSE_SHARE = 0.5  # a range graph with at most this share of its pairs ranged is sparse


@njit(cache=True)
def range_share(rng_):  # pragma: no cover - compiled
    """The density of one problem's range graph ``rng_`` (n, n; nan = not measured): the share
    of pairs with a range measured either way among the drones that have any (1 for a
    complete graph, and where fewer than 2 drones range), so that drones outside the swarm
    (no range at all) do not make a dense swarm sparse. At most SPARSE_SHARE: sparse."""
    n = rng_.shape[0]
    pairs = 0
    some = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        for j in range(i):
            if not np.isnan(rng_[i, j]) or not np.isnan(rng_[j, i]):
                pairs += 1
                some[i] = True
                some[j] = True
    m = some.sum()
    return 1.0 if m < 2 else pairs / (m * (m - 1) / 2)


@njit(cache=True)
def coupling_order(n, pi, pj, E, order, pos, first):  # pragma: no cover - compiled
    """Reverse Cuthill-McKee order (in place on ``order`` (n,), and each drone's place in it on
    ``pos`` (n,)) of n drones coupled by the ranges (pi[k], pj[k]), k < E (either direction:
    `joint._ranged_pairs`), and for each drone in that order the first (lowest-placed) drone
    it is coupled with or itself (in place on ``first`` (n,)): its block row's envelope.

    The search starts, in each connected part, from a drone of least degree and visits
    neighbours by increasing degree, ties by index: the same order for the same graph."""
    adj = np.zeros((n, n), dtype=np.bool_)
    for k in range(E):
        adj[pi[k], pj[k]] = True
        adj[pj[k], pi[k]] = True
    deg = np.zeros(n, dtype=np.int64)
    for i in range(n):
        for j in range(n):
            if adj[i, j]:
                deg[i] += 1
    seen = np.zeros(n, dtype=np.bool_)
    cm = np.empty(n, dtype=np.int64)
    count = 0
    nbr = np.empty(n, dtype=np.int64)
    while count < n:
        root = -1
        for i in range(n):  # least degree among those not yet placed
            if not seen[i] and (root < 0 or deg[i] < deg[root]):
                root = i
        seen[root] = True
        cm[count] = root
        head = count
        count += 1
        while head < count:
            v = cm[head]
            head += 1
            k = 0
            for u in range(n):
                if adj[v, u] and not seen[u]:
                    nbr[k] = u
                    k += 1
            # insertion sort by (degree, index): k is a drone's neighbour count
            for a in range(1, k):
                u = nbr[a]
                b = a - 1
                while b >= 0 and (deg[nbr[b]] > deg[u] or (deg[nbr[b]] == deg[u] and nbr[b] > u)):
                    nbr[b + 1] = nbr[b]
                    b -= 1
                nbr[b + 1] = u
            for a in range(k):
                seen[nbr[a]] = True
                cm[count] = nbr[a]
                count += 1
    for p in range(n):
        order[p] = cm[n - 1 - p]
        pos[order[p]] = p
    for p in range(n):
        lo = p
        v = order[p]
        for u in range(n):
            if adj[v, u] and pos[u] < lo:
                lo = pos[u]
        first[p] = lo


@njit(cache=True)
def envelope_cholesky(L, first, nb):  # pragma: no cover - compiled
    """In place, the lower Cholesky factor of L[:3 nb, :3 nb], by 3x3 blocks: block row I
    starts at block column first[I] <= I (`coupling_order`); only the blocks from there to
    the diagonal are used (those left of it are taken as zero and never touched; a diagonal
    block's entries above its diagonal are read into sums that are thrown away, whatever
    they hold). Nine running sums per pair of blocks, each in a fixed order. Returns the
    smallest pivot relative to its diagonal entry (as `joint._cholesky`), or 0 if a pivot is
    not positive or a row's ``first`` lies past its diagonal (then L is spoilt)."""
    worst = 1.0
    for bi in range(nb):
        i = 3 * bi
        fi = first[bi]
        if fi > bi:
            return 0.0
        for bj in range(fi, bi + 1):
            j = 3 * bj
            s00 = L[i, j]
            s01 = L[i, j + 1]
            s02 = L[i, j + 2]
            s10 = L[i + 1, j]
            s11 = L[i + 1, j + 1]
            s12 = L[i + 1, j + 2]
            s20 = L[i + 2, j]
            s21 = L[i + 2, j + 1]
            s22 = L[i + 2, j + 2]
            for k in range(3 * max(fi, first[bj]), j):
                a0 = L[i, k]
                a1 = L[i + 1, k]
                a2 = L[i + 2, k]
                b0 = L[j, k]
                b1 = L[j + 1, k]
                b2 = L[j + 2, k]
                s00 -= a0 * b0
                s01 -= a0 * b1
                s02 -= a0 * b2
                s10 -= a1 * b0
                s11 -= a1 * b1
                s12 -= a1 * b2
                s20 -= a2 * b0
                s21 -= a2 * b1
                s22 -= a2 * b2
            if bj < bi:  # L_IJ = S L_JJ^-T, row by row
                d0 = L[j, j]
                d1 = L[j + 1, j + 1]
                d2 = L[j + 2, j + 2]
                c10 = L[j + 1, j]
                c20 = L[j + 2, j]
                c21 = L[j + 2, j + 1]
                x0 = s00 / d0
                x1 = (s01 - x0 * c10) / d1
                L[i, j] = x0
                L[i, j + 1] = x1
                L[i, j + 2] = (s02 - x0 * c20 - x1 * c21) / d2
                x0 = s10 / d0
                x1 = (s11 - x0 * c10) / d1
                L[i + 1, j] = x0
                L[i + 1, j + 1] = x1
                L[i + 1, j + 2] = (s12 - x0 * c20 - x1 * c21) / d2
                x0 = s20 / d0
                x1 = (s21 - x0 * c10) / d1
                L[i + 2, j] = x0
                L[i + 2, j + 1] = x1
                L[i + 2, j + 2] = (s22 - x0 * c20 - x1 * c21) / d2
            else:  # the diagonal block: a 3x3 Cholesky of S's lower triangle
                if not s00 > 0:
                    return 0.0
                worst = min(worst, s00 / L[i, i])
                d0 = np.sqrt(s00)
                l10 = s10 / d0
                l20 = s20 / d0
                q = s11 - l10 * l10
                if not q > 0:
                    return 0.0
                worst = min(worst, q / L[i + 1, i + 1])
                d1 = np.sqrt(q)
                l21 = (s21 - l20 * l10) / d1
                q = s22 - l20 * l20 - l21 * l21
                if not q > 0:
                    return 0.0
                worst = min(worst, q / L[i + 2, i + 2])
                L[i, i] = d0
                L[i + 1, i] = l10
                L[i + 1, i + 1] = d1
                L[i + 2, i] = l20
                L[i + 2, i + 1] = l21
                L[i + 2, i + 2] = np.sqrt(q)
    return worst


@njit(cache=True)
def envelope_solve(L, first, nb, y):  # pragma: no cover - compiled
    """y[:3 nb] <- (L L')^-1 y[:3 nb] with L from `envelope_cholesky` (the same ``first``)."""
    m = 3 * nb
    for i in range(m):
        fi = 3 * first[i // 3]
        s = y[i]
        for k in range(fi, i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    for i in range(m - 1, -1, -1):
        v = y[i] / L[i, i]
        y[i] = v
        for k in range(3 * first[i // 3], i):
            y[k] -= L[i, k] * v

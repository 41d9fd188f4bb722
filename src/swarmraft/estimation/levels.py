"""The end of `integrity.assess` in one compiled pass: from the all-in-view covariance blocks
C0 and each fault hypothesis' blocks Cj and separations dj (`woodbury.without_each`), the
per-axis sigma, the separation test, the protection levels and the hypotheses that leave a
drone unfixed. The numpy expressions it replaced cost about 0.25 ms of a 17-drone step in
their calls alone; `levels_kernel` computes what they computed, in their order of operations
(elementwise, so bit for bit), with numpy's nan rules (a nan level stays nan, a maximum with
a nan is nan); tests/test_estimation_kernels.py keeps those expressions as its reference."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _nanmax(a, b):  # pragma: no cover - compiled
    """np.maximum's rule: nan if either is nan."""
    if np.isnan(a) or np.isnan(b):
        return np.nan
    return a if a >= b else b


@njit(cache=True)
def unfixed_block(C, largest0, max_condition):  # pragma: no cover - compiled
    """Whether a 3x3 covariance block C does not fix a position: largest over smallest
    eigenvalue above ``max_condition``, or largest eigenvalue above 1e6 times ``largest0``
    (the all-in-view block's), from its lower triangle (as LAPACK reads it); any non-finite
    entry is unfixed. Eigenvalues are computed only where a bound cannot decide: a block that
    is clearly positive definite (leading minors positive by a margin far above rounding)
    with largest/smallest <= F^3 / det <= max_condition / 2 and largest <= F <= 5e5 largest0
    (F its Frobenius norm, which bounds every eigenvalue; the smallest is >= det / F^2) is
    fixed. Most blocks are, and 3x3 eigenvalue problems were most of this test's time."""
    a, b, c = C[0, 0], C[1, 1], C[2, 2]
    d, e, f = C[1, 0], C[2, 0], C[2, 1]
    finite = True
    for p in range(3):
        for q in range(3):
            finite = finite and np.isfinite(C[p, q])
    if not finite:
        return True
    F = np.sqrt(((a * a + b * b) + c * c) + 2 * ((d * d + e * e) + f * f))
    minor2 = a * b - d * d
    det = (a * (b * c - f * f) - d * (d * c - f * e)) + e * (d * f - b * e)
    if (
        a > 0
        and minor2 > 1e-10 * F * F
        and det >= 2 * F**3 / max_condition
        and F <= 5e5 * max(largest0, 1e-300)
    ):
        return False
    S = np.empty((3, 3))
    for p in range(3):
        for q in range(p + 1):
            S[p, q] = C[p, q]
            S[q, p] = C[p, q]
    ev = np.linalg.eigvalsh(S)
    return ev[2] > max_condition * max(ev[0], 1e-300) or ev[2] > 1e6 * max(largest0, 1e-300)


@njit(cache=True)
def levels_kernel(
    C0,
    Cj,
    dj,
    exact,
    trusted,
    undetermined,
    largest0,
    common,
    k_fa,
    k_md,
    max_condition,
    sigma,
    hpl,
    vpl,
    separated,
    ill,
):  # pragma: no cover - compiled
    """In place on sigma (T, n, 3), hpl and vpl (T, n), separated (T,) and ill (T, n), from
    C0 (T, n, 3, 3), Cj (T, j, n, 3, 3), dj (T, j, n, 3) (the exact separations ``exact``
    instead where finite), the trusted set and the undetermined drones (T, n), each drone's
    largest all-in-view eigenvalue ``largest0`` (T, n), ``common`` (3,) and the quantile
    factors k_fa, k_md (T,): `integrity.assess`'s lines from var0 to the levels. ``ill``:
    some trusted drone's hypothesis leaves the drone unfixed."""
    T, n = trusted.shape
    pl = np.empty(3)
    for t in range(T):
        separated[t] = False
        for i in range(n):
            ill[t, i] = False
            for a in range(3):
                var0 = C0[t, i, a, a] + common[a]
                sigma[t, i, a] = np.sqrt(var0)
                pl[a] = k_md[t] * np.sqrt(var0)  # fault-free
            fixed = not undetermined[t, i]
            for a in range(3):
                worst = 0.0  # the maximum over j of the live hypotheses' levels (0: none)
                for j in range(n):
                    if not trusted[t, j]:
                        worst = _nanmax(worst, 0.0)
                        continue
                    var_j = Cj[t, j, i, a, a]
                    var_ss = _nanmax(var_j - C0[t, i, a, a], 0.0)
                    thr = k_fa[t] * np.sqrt(var_ss)
                    d = exact[t, j, i, a]
                    if not np.isfinite(d):
                        d = dj[t, j, i, a]
                    if fixed and abs(d) > thr + 1e-9:
                        separated[t] = True
                    worst = _nanmax(worst, thr + k_md[t] * np.sqrt(var_j + common[a]))
                pl[a] = _nanmax(pl[a], worst)
            hpl[t, i] = np.hypot(pl[0], pl[1])
            vpl[t, i] = pl[2]
            for j in range(n):
                if trusted[t, j] and not ill[t, i]:
                    ill[t, i] = unfixed_block(Cj[t, j, i], largest0[t, i], max_condition)


@njit(cache=True)
def blocks_kernel(P, out):  # pragma: no cover - compiled
    """The 3x3 diagonal blocks of matrices P (B, 3n, 3n) into out (B, n, 3, 3) (copies)."""
    B, N, _ = P.shape
    for b in range(B):
        for i in range(N // 3):
            for a in range(3):
                for c in range(3):
                    out[b, i, a, c] = P[b, 3 * i + a, 3 * i + c]


@njit(cache=True)
def eigenvalues_kernel(C, out):  # pragma: no cover - compiled
    """Ascending eigenvalues of symmetric 3x3 blocks C (B, 3, 3) into out (B, 3), from each
    block's lower triangle; 0, inf, inf where a block is not finite. np.linalg.eigvalsh's
    LAPACK routine, from scipy's OpenBLAS (numba) where numpy calls its own: the same bits
    with this project's wheels (numpy 2.4, scipy 1.17: 100,000 random blocks of condition up
    to e^40 compared; tests/test_estimation_kernels.py checks 4,000), not a promise of every
    build."""
    S = np.empty((3, 3))
    for b in range(C.shape[0]):
        finite = True
        for p in range(3):
            for q in range(3):
                finite = finite and np.isfinite(C[b, p, q])
        if not finite:
            out[b, 0] = 0.0
            out[b, 1] = np.inf
            out[b, 2] = np.inf
            continue
        for p in range(3):
            for q in range(p + 1):
                S[p, q] = C[b, p, q]
                S[q, p] = C[b, p, q]
        out[b] = np.linalg.eigvalsh(S)

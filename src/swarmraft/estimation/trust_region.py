"""Trust-region least squares for many small multilateration problems.

Each problem b finds a point x_b in R^3 minimising a robust cost of the range residuals

    r_bj(x) = ||x - a_bj|| - d_bj     for the anchors j with mask[b, j] true.

The iteration is the trust-region reflective method of SciPy's ``least_squares(method="trf")``
without bounds: the trust region is solved exactly through an SVD of the scaled Jacobian, with
Moré's root finding for the Levenberg-Marquardt parameter, the same radius update and
termination tests, and the same robust-loss rescaling. Run on one problem with the same
settings it follows SciPy's iterates, given an analytic Jacobian; that is what lets the
``reference`` preset reproduce the paper's code (docs/models.md). Here the problems of a batch are
solved one after another in a kernel compiled by numba (a leader step at n = 17 has 8 of
them, a sweep chunk thousands): SciPy's Python-level loop costs about 1 ms per problem, and a
numpy version vectorised across the batch still paid about 0.4 ms of interpreter overhead per
iteration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

EPS = float(np.finfo(float).eps)
LOSSES = ("linear", "soft_l1", "huber", "cauchy")


@dataclass(frozen=True)
class SolveResult:
    """Solutions of a batch: ``x`` (B, 3), final robust ``cost`` (B,), ``nfev`` (B,) and the
    SciPy termination ``status`` (B,): 1 gtol, 2 ftol, 3 xtol, 4 ftol and xtol, 0 max_nfev."""

    x: np.ndarray
    cost: np.ndarray
    nfev: np.ndarray
    status: np.ndarray


@njit(cache=True)
def _residuals(x, anchors, dists, f, J):  # pragma: no cover - compiled
    """f = ||x - a_j|| - d_j and its Jacobian, in place."""
    for j in range(anchors.shape[0]):
        d0 = x[0] - anchors[j, 0]
        d1 = x[1] - anchors[j, 1]
        d2 = x[2] - anchors[j, 2]
        nrm = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        f[j] = nrm - dists[j]
        if nrm > 0:
            J[j, 0] = d0 / nrm
            J[j, 1] = d1 / nrm
            J[j, 2] = d2 / nrm
        else:
            J[j, 0] = 0.0
            J[j, 1] = 0.0
            J[j, 2] = 0.0


@njit(cache=True)
def _loss(f, loss_id, f_scale, rho0, rho1, rho2):  # pragma: no cover - compiled
    """rho(z), rho'(z), rho''(z) at z = (f / C)^2, scaled as SciPy (rho0 C^2, rho2 / C^2).
    loss_id: 0 linear, 1 soft_l1, 2 huber, 3 cauchy. Returns the cost 0.5 sum rho0."""
    c2 = f_scale * f_scale
    cost = 0.0
    for j in range(f.shape[0]):
        z = (f[j] / f_scale) ** 2
        if loss_id == 0:
            r0, r1, r2 = z, 1.0, 0.0
        elif loss_id == 1:
            t = 1.0 + z
            r0, r1, r2 = 2.0 * (math.sqrt(t) - 1.0), t**-0.5, -0.5 * t**-1.5
        elif loss_id == 2:
            if z <= 1.0:
                r0, r1, r2 = z, 1.0, 0.0
            else:
                sq = math.sqrt(z)
                r0, r1, r2 = 2.0 * sq - 1.0, 1.0 / sq, -0.5 / (sq * sq * sq)
        else:
            t = 1.0 + z
            r0, r1, r2 = math.log1p(z), 1.0 / t, -1.0 / (t * t)
        rho0[j] = r0 * c2
        rho1[j] = r1
        rho2[j] = r2 / c2
        cost += rho0[j]
    return 0.5 * cost


@njit(cache=True)
def _scale(f, J, rho1, rho2, fs, Js):  # pragma: no cover - compiled
    """SciPy's rescaling of residuals and Jacobian for a robust loss."""
    for j in range(f.shape[0]):
        s = rho1[j] + 2.0 * rho2[j] * f[j] * f[j]
        if s < EPS:
            s = EPS
        s = math.sqrt(s)
        fs[j] = f[j] * rho1[j] / s
        for k in range(3):
            Js[j, k] = J[j, k] * s


@njit(cache=True)
def _norm3(v):  # pragma: no cover - compiled
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


@njit(cache=True)
def _subproblem(m, uf, s, V, Delta, alpha0, p):  # pragma: no cover - compiled
    """Trust-region subproblem min ||J p + f|| s.t. ||p|| <= Delta (Moré 1977), SciPy's
    ``solve_lsq_trust_region`` with rtol 0.01 and 10 iterations. k = len(s) = min(m, 3).
    Writes the step into p; returns the Levenberg-Marquardt parameter."""
    k = s.shape[0]
    full_rank = m >= 3 and s[k - 1] > EPS * m * s[0]
    if full_rank:
        for i in range(3):
            acc = 0.0
            for c in range(k):
                acc += V[i, c] * uf[c] / s[c]
            p[i] = -acc
        if _norm3(p) <= Delta:
            return 0.0
    suf = s * uf

    upper = math.sqrt(np.sum(suf * suf)) / Delta
    lower = 0.0
    if full_rank:
        denom = s * s
        p_norm = math.sqrt(np.sum((suf / denom) ** 2))
        phi = p_norm - Delta
        dphi = -np.sum(suf * suf / denom**3) / p_norm
        lower = -phi / dphi
    if not full_rank and alpha0 == 0.0:
        alpha = max(0.001 * upper, math.sqrt(lower * upper))
    else:
        alpha = alpha0
    for _ in range(10):
        if alpha < lower or alpha > upper:
            alpha = max(0.001 * upper, math.sqrt(lower * upper))
        denom = s * s + alpha
        p_norm = math.sqrt(np.sum((suf / denom) ** 2))
        phi = p_norm - Delta
        dphi = -np.sum(suf * suf / denom**3) / p_norm
        if phi < 0:
            upper = alpha
        ratio = phi / dphi
        lower = max(lower, alpha - ratio)
        alpha -= (phi + Delta) * ratio / Delta
        if abs(phi) < 0.01 * Delta:
            break
    denom = s * s + alpha
    for i in range(3):
        acc = 0.0
        for c in range(k):
            acc += V[i, c] * suf[c] / denom[c]
        p[i] = -acc
    scale = Delta / _norm3(p)
    for i in range(3):
        p[i] *= scale
    return alpha


@njit(cache=True)
def _svd(Js):  # pragma: no cover - compiled
    U, s, Vt = np.linalg.svd(Js, full_matrices=False)
    return U, s, Vt.T.copy()


@njit(cache=True)
def _solve_one(anchors, dists, x0, loss_id, f_scale, ftol, xtol, gtol, max_nfev, out):  # pragma: no cover
    """SciPy's ``trf_no_bounds`` for one problem with m = len(dists) anchors. Writes the
    solution into out[0:3] and returns (cost, nfev, status)."""
    m = anchors.shape[0]
    f = np.empty(m)
    J = np.empty((m, 3))
    fs = np.empty(m)
    Js = np.empty((m, 3))
    rho0 = np.empty(m)
    rho1 = np.empty(m)
    rho2 = np.empty(m)
    f_new = np.empty(m)
    J_new = np.empty((m, 3))
    x = x0.copy()
    x_new = np.empty(3)
    step = np.empty(3)

    _residuals(x, anchors, dists, f, J)
    nfev = 1
    cost = _loss(f, loss_id, f_scale, rho0, rho1, rho2)
    _scale(f, J, rho1, rho2, fs, Js)
    g = Js.T @ fs
    Delta = _norm3(x)
    if Delta == 0.0:
        Delta = 1.0
    alpha = 0.0
    status = -1
    U, s, V = _svd(Js)
    uf = U.T @ fs
    while True:
        if np.max(np.abs(g)) < gtol:
            status = 1
        if status != -1 or nfev == max_nfev:
            break
        actual = -1.0
        cost_new = cost
        while actual <= 0 and nfev < max_nfev:
            alpha = _subproblem(m, uf, s, V, Delta, alpha, step)
            Jstep = Js @ step
            predicted = -(0.5 * np.dot(Jstep, Jstep) + np.dot(g, step))
            for i in range(3):
                x_new[i] = x[i] + step[i]
            _residuals(x_new, anchors, dists, f_new, J_new)
            nfev += 1
            step_norm = _norm3(step)
            cost_new = _loss(f_new, loss_id, f_scale, rho0, rho1, rho2)
            actual = cost - cost_new
            if predicted > 0:
                ratio = actual / predicted
            elif predicted == 0 and actual == 0:
                ratio = 1.0
            else:
                ratio = 0.0
            if ratio < 0.25:
                Delta_new = 0.25 * step_norm
            elif ratio > 0.75 and step_norm > 0.95 * Delta:
                Delta_new = 2.0 * Delta
            else:
                Delta_new = Delta
            ftol_ok = actual < ftol * cost and ratio > 0.25
            xtol_ok = step_norm < xtol * (xtol + _norm3(x))
            if ftol_ok and xtol_ok:
                status = 4
            elif ftol_ok:
                status = 2
            elif xtol_ok:
                status = 3
            if status != -1:
                break
            alpha *= Delta / Delta_new
            Delta = Delta_new
        if actual > 0:
            x[:] = x_new
            f[:] = f_new
            J[:, :] = J_new
            cost = cost_new
            _loss(f, loss_id, f_scale, rho0, rho1, rho2)
            _scale(f, J, rho1, rho2, fs, Js)
            g = Js.T @ fs
            U, s, V = _svd(Js)
            uf = U.T @ fs
    out[0], out[1], out[2] = x[0], x[1], x[2]
    if status == -1:
        status = 0
    return cost, nfev, status


@njit(cache=True)
def _solve_batch(
    anchors,
    dists,
    mask,
    x0,
    loss_id,
    f_scale,
    ftol,
    xtol,
    gtol,
    max_nfev,
    x_out,
    cost_out,
    nfev_out,
    status_out,
):  # pragma: no cover - compiled
    B, M = mask.shape
    for b in range(B):
        m = 0
        for j in range(M):
            if mask[b, j]:
                m += 1
        a = np.empty((m, 3))
        d = np.empty(m)
        k = 0
        for j in range(M):
            if mask[b, j]:
                a[k, :] = anchors[b, j, :]
                d[k] = dists[b, j]
                k += 1
        c, n, st = _solve_one(a, d, x0[b], loss_id, f_scale, ftol, xtol, gtol, max_nfev, x_out[b])
        cost_out[b] = c
        nfev_out[b] = n
        status_out[b] = st


def solve_ranges(
    anchors: np.ndarray,
    dists: np.ndarray,
    mask: np.ndarray,
    x0: np.ndarray,
    *,
    loss: str = "soft_l1",
    f_scale: float = 5.0,
    ftol: float = 1e-8,
    xtol: float = 1e-8,
    gtol: float = 1e-8,
    max_nfev: int | None = None,
) -> SolveResult:
    """Solve B multilateration problems: anchors (B, M, 3), dists (B, M), mask (B, M), x0 (B, 3).

    Defaults are SciPy's ``least_squares`` defaults with the paper's loss (soft_l1, f_scale 5 m).
    A problem with no anchor stays at its start.
    """
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {', '.join(LOSSES)}, not {loss!r}")
    anchors = np.ascontiguousarray(anchors, dtype=float)
    mask = np.ascontiguousarray(mask, dtype=bool)
    dists = np.ascontiguousarray(np.where(mask, dists, 0.0), dtype=float)
    x0 = np.ascontiguousarray(x0, dtype=float)
    B = x0.shape[0]
    x = x0.copy()
    cost, nfev, status = np.zeros(B), np.zeros(B, dtype=np.int64), np.zeros(B, dtype=np.int64)
    solvable = mask.any(axis=1)
    if solvable.all():
        _solve_batch(
            anchors,
            dists,
            mask,
            x0,
            LOSSES.index(loss),
            float(f_scale),
            ftol,
            xtol,
            gtol,
            300 if max_nfev is None else int(max_nfev),
            x,
            cost,
            nfev,
            status,
        )
    elif solvable.any():
        sub = solve_ranges(
            anchors[solvable],
            dists[solvable],
            mask[solvable],
            x0[solvable],
            loss=loss,
            f_scale=f_scale,
            ftol=ftol,
            xtol=xtol,
            gtol=gtol,
            max_nfev=max_nfev,
        )
        x[solvable], cost[solvable], nfev[solvable], status[solvable] = sub.x, sub.cost, sub.nfev, sub.status
    return SolveResult(x=x, cost=cost, nfev=nfev, status=status)


def warm_up() -> None:
    """Compile the kernel now (numba caches it on disk): call before starting worker
    processes so they load the compiled code instead of each compiling it."""
    solve_ranges(np.eye(3)[None] * 10.0, np.full((1, 3), 10.0), np.ones((1, 3), dtype=bool), np.ones((1, 3)))


def linear_multilateration(
    anchors: np.ndarray, dists: np.ndarray, mask: np.ndarray, fast: bool = False
) -> np.ndarray:
    """Closed-form linearised multilateration, batched: (B, M, 3), (B, M), (B, M) -> (B, 3).

    Subtracting the anchor mean from ``||x||^2 - 2 a_j.x + ||a_j||^2 = d_j^2`` gives a linear
    system in x; it is solved in the least-squares sense (minimum norm where it is singular,
    e.g. with 3 anchors, whose mirror ambiguity it cannot resolve). One compiled kernel
    (`_multilateration_kernel`). ``fast``: the 3x3 normal equations by Cholesky where they
    are well conditioned (every pivot above 1e-6 of its diagonal entry), np.linalg.pinv's
    SVD elsewhere: the same solution up to rounding, not the same bits, and no LAPACK call
    for most problems (for starts whose solve only feeds a test).
    """
    anchors = np.ascontiguousarray(anchors, float)
    out = np.empty((anchors.shape[0], 3))
    _multilateration_kernel(
        anchors, np.ascontiguousarray(dists, float), np.ascontiguousarray(mask, np.bool_), out, bool(fast)
    )
    return out


@njit(cache=True)
def _contiguous_dot(a, b):  # pragma: no cover - compiled
    """sum_m a_m b_m summed as numpy's einsum sums a contiguous axis here (two lanes, blocks
    of eight taken last element first, then pairs, then lane 0 + lane 1)."""
    acc0 = 0.0
    acc1 = 0.0
    m = a.shape[0]
    i = 0
    while m - i >= 8:
        acc0 = a[i] * b[i] + (a[i + 2] * b[i + 2] + (a[i + 4] * b[i + 4] + (a[i + 6] * b[i + 6] + acc0)))
        acc1 = a[i + 1] * b[i + 1] + (
            a[i + 3] * b[i + 3] + (a[i + 5] * b[i + 5] + (a[i + 7] * b[i + 7] + acc1))
        )
        i += 8
    while i < m:
        acc0 = a[i] * b[i] + acc0
        if i + 1 < m:
            acc1 = a[i + 1] * b[i + 1] + acc1
        i += 2
    return acc0 + acc1


@njit(cache=True)
def _spd_solve3(M, r, L, out):  # pragma: no cover - compiled
    """out = M^-1 r for a symmetric 3x3 M by Cholesky (L its factor, in place); False, out
    untouched, unless every pivot is above 1e-6 of its diagonal entry (well conditioned)."""
    for j in range(3):
        d = M[j, j]
        for p in range(j):
            d -= L[j, p] * L[j, p]
        if not (d > 1e-6 * M[j, j]):
            return False
        d = np.sqrt(d)
        L[j, j] = d
        for i in range(j + 1, 3):
            v = M[i, j]
            for p in range(j):
                v -= L[i, p] * L[j, p]
            L[i, j] = v / d
    y0 = r[0] / L[0, 0]
    y1 = (r[1] - L[1, 0] * y0) / L[1, 1]
    y2 = (r[2] - L[2, 0] * y0 - L[2, 1] * y1) / L[2, 2]
    y2 = y2 / L[2, 2]
    y1 = (y1 - L[2, 1] * y2) / L[1, 1]
    out[0] = (y0 - L[1, 0] * y1 - L[2, 0] * y2) / L[0, 0]
    out[1] = y1
    out[2] = y2
    return True


@njit(cache=True)
def _multilateration_kernel(anchors, dists, mask, out, fast):  # pragma: no cover - compiled
    """`linear_multilateration` problem by problem into out (B, 3), in the order of operations
    of the numpy expression it replaced (its einsum sums, np.linalg.pinv's SVD, cutoff and
    product), so bit for bit the same: numpy's per-call overhead on these few 3-vectors was
    most of its time. With ``fast``, see `linear_multilateration`."""
    B, M, _ = anchors.shape
    L = np.empty((3, 3))
    w = np.empty(M)
    t = np.empty(M)
    rhs = np.empty(M)
    A = np.empty((M, 3))
    AtA = np.empty((3, 3))
    Atb = np.empty(3)
    R = np.empty((3, 3))
    a_bar = np.empty(3)
    for b in range(B):
        cnt = 0.0
        for m in range(M):
            w[m] = 1.0 if mask[b, m] else 0.0
            cnt += w[m]
        cnt = max(cnt, 1.0)
        for m in range(M):
            d = dists[b, m] if mask[b, m] else 0.0
            a0, a1, a2 = anchors[b, m, 0], anchors[b, m, 1], anchors[b, m, 2]
            t[m] = d * d - ((a0 * a0 + a2 * a2) + a1 * a1)
        for k in range(3):
            acc = 0.0
            for m in range(M):
                acc += w[m] * anchors[b, m, k]
            a_bar[k] = acc / cnt
        mean_t = _contiguous_dot(w, t) / cnt
        for m in range(M):
            rhs[m] = (t[m] - mean_t) * w[m]
            for k in range(3):
                A[m, k] = (-2 * (anchors[b, m, k] - a_bar[k])) * w[m]
        for i in range(3):
            acc = 0.0
            for m in range(M):
                acc += A[m, i] * rhs[m]
            Atb[i] = acc
            for j in range(3):
                acc = 0.0
                for m in range(M):
                    acc += A[m, i] * A[m, j]
                AtA[i, j] = acc
        if fast and _spd_solve3(AtA, Atb, L, out[b]):
            continue
        # np.linalg.pinv: SVD, singular values below 1e-15 of the largest dropped
        u, s, vt = np.linalg.svd(AtA, full_matrices=False)
        cutoff = 1e-15 * s.max()
        for i in range(3):
            inv = 1.0 / s[i] if s[i] > cutoff else 0.0
            for j in range(3):
                R[i, j] = inv * u[j, i]
        P = np.ascontiguousarray(vt.T) @ R
        for i in range(3):
            out[b, i] = (P[i, 0] * Atb[0] + P[i, 2] * Atb[2]) + P[i, 1] * Atb[1]

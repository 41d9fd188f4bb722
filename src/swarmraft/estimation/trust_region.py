"""Batched trust-region least squares for many small multilateration problems at once.

Each problem b finds a point x_b in R^3 minimising a robust cost of the range residuals

    r_bj(x) = ||x - a_bj|| - d_bj     for the anchors j with mask[b, j] true.

The iteration is the trust-region reflective method of SciPy's ``least_squares(method="trf")``
without bounds (trust region solved exactly through an SVD of the scaled Jacobian, Moré's
root finding for the Levenberg-Marquardt parameter, the same radius update and termination
tests, and the same robust-loss rescaling). Run on one problem with the same settings, it
follows the same sequence of iterates as SciPy given an analytic Jacobian, which is what lets
the ``reference`` preset reproduce the paper's code (FACTS.md) without its Python loops: here
every problem of a batch advances together, with an analytic Jacobian, in numpy.

Padding rows (mask false) contribute nothing: zero residual and zero Jacobian row.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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


def range_residuals(
    x: np.ndarray, anchors: np.ndarray, dists: np.ndarray, mask: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Residuals ``||x - a|| - d`` (B, M) and their analytic Jacobian (B, M, 3)."""
    diff = x[:, None, :] - anchors
    norm = np.sqrt(np.einsum("bmk,bmk->bm", diff, diff))
    safe = np.where(norm > 0, norm, 1.0)
    f = np.where(mask, norm - dists, 0.0)
    J = np.where((mask & (norm > 0))[..., None], diff / safe[..., None], 0.0)
    return f, J


def robust_loss(
    f: np.ndarray, loss: str, f_scale: float, cost_only: bool = False
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """rho(f^2) and its first two derivatives, scaled as SciPy does (rho0 * C^2, rho2 / C^2)."""
    z = (f / f_scale) ** 2
    rho1 = rho2 = None
    if loss == "linear":
        rho0 = z
        if not cost_only:
            rho1, rho2 = np.ones_like(z), np.zeros_like(z)
    elif loss == "soft_l1":
        t = 1 + z
        rho0 = 2 * (t**0.5 - 1)
        if not cost_only:
            rho1, rho2 = t**-0.5, -0.5 * t**-1.5
    elif loss == "huber":
        small = z <= 1
        sq = np.sqrt(np.where(small, 1.0, z))
        rho0 = np.where(small, z, 2 * sq - 1)
        if not cost_only:
            rho1 = np.where(small, 1.0, 1 / sq)
            rho2 = np.where(small, 0.0, -0.5 / sq**3)
    elif loss == "cauchy":
        rho0 = np.log1p(z)
        if not cost_only:
            t = 1 + z
            rho1, rho2 = 1 / t, -1 / t**2
    else:
        raise ValueError(f"loss must be one of {', '.join(LOSSES)}, not {loss!r}")
    rho0 = rho0 * f_scale**2
    if rho2 is not None:
        rho2 = rho2 / f_scale**2
    return rho0, rho1, rho2


def _scaled_system(
    f: np.ndarray, J: np.ndarray, loss: str, f_scale: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cost, and residuals and Jacobian rescaled for the robust loss (SciPy's rule)."""
    rho0, rho1, rho2 = robust_loss(f, loss, f_scale)
    cost = 0.5 * rho0.sum(axis=1)
    J_scale = rho1 + 2 * rho2 * f**2
    J_scale = np.sqrt(np.where(J_scale < EPS, EPS, J_scale))
    return cost, f * rho1 / J_scale, J * J_scale[..., None]


def _norm(a: np.ndarray) -> np.ndarray:
    """Row norms of a (B, k) array (cheaper than np.linalg.norm for tiny rows)."""
    return np.sqrt(np.einsum("bi,bi->b", a, a))


def _solve_subproblem(
    uf: np.ndarray,
    s: np.ndarray,
    V: np.ndarray,
    Delta: np.ndarray,
    alpha0: np.ndarray,
    m: np.ndarray,
    rtol: float = 0.01,
    max_iter: int = 10,
) -> tuple[np.ndarray, np.ndarray]:
    """Trust-region subproblem min ||J p + f|| s.t. ||p|| <= Delta, batched (Moré 1977).

    Call under ``np.errstate(all="ignore")``: rank-deficient rows divide by zero in the
    Gauss-Newton candidate, which is then not used."""
    full_rank = (m >= 3) & (s[:, -1] > EPS * m * s[:, 0])
    p = -np.einsum("bij,bj->bi", V, uf / s)
    alpha = np.zeros_like(Delta)
    need = np.flatnonzero(~(full_rank & (_norm(p) <= Delta)))
    if not need.size:
        return p, alpha
    # Levenberg-Marquardt parameter by Moré's root finding, for the rows that need it.
    s, V, D, fr = s[need], V[need], Delta[need], full_rank[need]
    suf = s * uf[need]

    def phi_and_derivative(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        denom = s**2 + a[:, None]
        p_norm = _norm(suf / denom)
        return p_norm - D, -np.sum(suf**2 / denom**3, axis=1) / p_norm

    upper = _norm(suf) / D
    phi, dphi = phi_and_derivative(np.zeros_like(D))
    lower = np.where(fr, -phi / dphi, 0.0)
    a0 = alpha0[need]
    a = np.where(~fr & (a0 == 0), np.maximum(0.001 * upper, np.sqrt(lower * upper)), a0)
    active = np.ones(len(need), dtype=bool)
    for _ in range(max_iter):
        out = (a < lower) | (a > upper)
        a = np.where(active & out, np.maximum(0.001 * upper, np.sqrt(lower * upper)), a)
        phi, dphi = phi_and_derivative(a)
        upper = np.where(active & (phi < 0), a, upper)
        ratio = phi / dphi
        lower = np.where(active, np.maximum(lower, a - ratio), lower)
        a = np.where(active, a - (phi + D) * ratio / D, a)
        active &= ~(np.abs(phi) < rtol * D)
        if not active.any():
            break
    q = -np.einsum("bij,bj->bi", V, suf / (s**2 + a[:, None]))
    p[need] = q * (D / _norm(q))[:, None]
    alpha[need] = a
    return p, alpha


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
    """
    anchors = np.asarray(anchors, dtype=float)
    B, M, _ = anchors.shape
    if M < 3:  # pad so every problem has a 3-column SVD; zero rows change nothing
        pad = 3 - M
        anchors = np.concatenate([anchors, np.zeros((B, pad, 3))], axis=1)
        dists = np.concatenate([dists, np.zeros((B, pad))], axis=1)
        mask = np.concatenate([mask, np.zeros((B, pad), dtype=bool)], axis=1)
    dists = np.where(mask, dists, 0.0)
    m = mask.sum(axis=1)
    max_nfev = 300 if max_nfev is None else max_nfev

    x = np.array(x0, dtype=float, copy=True)
    f, J = range_residuals(x, anchors, dists, mask)
    cost, fs, Js = _scaled_system(f, J, loss, f_scale)
    g = np.einsum("bmk,bm->bk", Js, fs)
    Delta = np.linalg.norm(x, axis=1)
    Delta[Delta == 0] = 1.0
    alpha = np.zeros(B)
    nfev = np.ones(B, dtype=int)
    status = np.full(B, -1)
    status[np.abs(g).max(axis=1) < gtol] = 1
    status[(status < 0) & (nfev >= max_nfev)] = 0
    U, s, Vt = np.linalg.svd(Js, full_matrices=False)
    V = np.swapaxes(Vt, 1, 2)
    uf = np.einsum("bmk,bm->bk", U, fs)

    act = np.flatnonzero(status < 0)
    with np.errstate(all="ignore"):  # see _solve_subproblem
        while act.size:
            xa, Da = x[act], Delta[act]
            step, alpha_a = _solve_subproblem(uf[act], s[act], V[act], Da, alpha[act], m[act])
            Jstep = np.einsum("bmk,bk->bm", Js[act], step)
            predicted = -(0.5 * np.einsum("bm,bm->b", Jstep, Jstep) + np.einsum("bk,bk->b", g[act], step))
            x_new = xa + step
            f_new, J_new = range_residuals(x_new, anchors[act], dists[act], mask[act])
            nfev[act] += 1
            cost_new = 0.5 * robust_loss(f_new, loss, f_scale, cost_only=True)[0].sum(axis=1)
            actual = cost[act] - cost_new
            step_norm = _norm(step)
            ratio = np.where(
                predicted > 0,
                actual / np.where(predicted > 0, predicted, 1.0),
                np.where((predicted == 0) & (actual == 0), 1.0, 0.0),
            )
            Delta_new = np.where(
                ratio < 0.25,
                0.25 * step_norm,
                np.where((ratio > 0.75) & (step_norm > 0.95 * Da), 2.0 * Da, Da),
            )
            ftol_ok = (actual < ftol * cost[act]) & (ratio > 0.25)
            xtol_ok = step_norm < xtol * (xtol + _norm(xa))
            term = np.where(ftol_ok, np.where(xtol_ok, 4, 2), np.where(xtol_ok, 3, -1))
            terminated = term >= 0
            accepted = actual > 0

            alpha[act] = np.where(terminated, alpha_a, alpha_a * Da / Delta_new)
            Delta[act] = np.where(terminated, Da, Delta_new)
            status[act] = term

            take = act[accepted]
            if take.size:
                x[take] = x_new[accepted]
                cost[take] = cost_new[accepted]
                # SciPy re-evaluates the gradient after every accepted step, and its gtol test
                # then takes precedence over a termination found in the same iteration.
                renew = accepted
                upd = act[renew]
                if upd.size:
                    _, fs_u, Js_u = _scaled_system(f_new[renew], J_new[renew], loss, f_scale)
                    Js[upd], fs[upd] = Js_u, fs_u
                    g[upd] = np.einsum("bmk,bm->bk", Js_u, fs_u)
                    U_u, s_u, Vt_u = np.linalg.svd(Js_u, full_matrices=False)
                    s[upd], V[upd] = s_u, np.swapaxes(Vt_u, 1, 2)
                    uf[upd] = np.einsum("bmk,bm->bk", U_u, fs_u)
                    status[upd[np.abs(g[upd]).max(axis=1) < gtol]] = 1
            running = status[act] < 0
            status[act[running & (nfev[act] >= max_nfev)]] = 0
            act = act[status[act] < 0]
    return SolveResult(x=x, cost=cost, nfev=nfev, status=status)


def linear_multilateration(anchors: np.ndarray, dists: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Closed-form linearised multilateration, batched: (B, M, 3), (B, M), (B, M) -> (B, 3).

    Subtracting the anchor mean from ``||x||^2 - 2 a_j.x + ||a_j||^2 = d_j^2`` gives a linear
    system in x; it is solved in the least-squares sense (minimum norm where it is singular,
    e.g. with 3 anchors, whose mirror ambiguity it cannot resolve).
    """
    w = mask.astype(float)
    cnt = np.maximum(w.sum(axis=1), 1.0)
    d2 = np.where(mask, dists, 0.0) ** 2
    a2 = np.einsum("bmk,bmk->bm", anchors, anchors)
    a_bar = np.einsum("bm,bmk->bk", w, anchors) / cnt[:, None]
    rhs = (d2 - a2) - (np.einsum("bm,bm->b", w, d2 - a2) / cnt)[:, None]
    A = -2 * (anchors - a_bar[:, None, :]) * w[..., None]
    rhs = rhs * w
    AtA = np.einsum("bmi,bmj->bij", A, A)
    Atb = np.einsum("bmi,bm->bi", A, rhs)
    return np.einsum("bij,bj->bi", np.linalg.pinv(AtA), Atb)

"""Cramér-Rao bounds on position error (how sweeps and missions report them: docs/files.md).

- `anchor_crb`: one drone located from ranges to K anchors, at known positions or with a
  GNSS covariance S_k each: J = sum_k u_k u_k^T / (sigma_d^2 + u_k^T S_k u_k) (+ P_prior^-1).
- `swarm_crb`: the whole swarm with the faulty set known: GNSS information of the honest
  drones, optional INS priors, and one (1/sigma_d^2) u u^T term per range measurement
  actually made, coupling the two drones (``symmetric``: d_ij and d_ji are one measurement
  stored twice); each drone's bound is its 3x3 block of J^-1.

A GNSS error common to all drones (``common_cov``) is not averaged away by more drones:
the GNSS errors of the honest drones are correlated (covariance I (x) S + 1 1^T (x) C), and
their information is H^T R^-1 H, by the Woodbury identity. Ranges cannot see a common
translation, so for a drone ranged from anchors the common covariance adds to the bound.

RMSE >= sqrt(trace(bound)). Everything is batched over a leading trial axis.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from swarmraft.estimation.blas import one_blas_thread

CHI2_3DOF_999 = 16.266236196238129  # chi-square, 3 dof, 0.999 quantile (catastrophic failure)


def gnss_covariance(sigma_h: float, sigma_v: float) -> np.ndarray:
    """Per-axis GNSS covariance diag(sigma_h^2, sigma_h^2, sigma_v^2)."""
    return np.diag([sigma_h**2, sigma_h**2, sigma_v**2])


def _unit(d: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    return d / np.where(n > 0, n, 1.0)


def anchor_crb(
    x: np.ndarray,
    anchors: np.ndarray,
    range_sigma: float,
    mask: np.ndarray | None = None,
    anchor_cov: np.ndarray | None = None,
    prior_cov: np.ndarray | None = None,
    common_cov: np.ndarray | None = None,
) -> np.ndarray:
    """Bound (B, 3, 3) for drones at x (B, 3) ranged from anchors (B, K, 3); ``anchor_cov``
    (3, 3) or (B, K, 3, 3) for uncertain anchors (each anchor's own error); ``common_cov``
    (3, 3) for an anchor error common to all of them, which moves the solution with it;
    ``prior_cov`` (3, 3) or (B, 3, 3) for an INS prior. Returns inf where the geometry gives
    no bound (fewer than 3 independent directions and no prior)."""
    x, anchors = np.asarray(x, float), np.asarray(anchors, float)
    B, K, _ = anchors.shape
    mask = np.ones((B, K), bool) if mask is None else np.asarray(mask, bool)
    u = _unit(x[:, None, :] - anchors)
    var = np.full((B, K), float(range_sigma) ** 2)
    if anchor_cov is not None:
        S = np.broadcast_to(np.asarray(anchor_cov, float), (B, K, 3, 3))
        var = var + np.einsum("bki,bkij,bkj->bk", u, S, u)
    w = np.where(mask, 1.0 / np.where(var > 0, var, np.inf), 0.0)
    if np.any(mask & (var == 0)):
        raise ValueError("anchor_crb: zero noise (exact ranges and anchors) has no finite bound")
    J = np.einsum("bk,bki,bkj->bij", w, u, u)
    if prior_cov is not None:
        J = J + np.linalg.inv(np.broadcast_to(np.asarray(prior_cov, float), (B, 3, 3)))
    C = _safe_inv(J)
    if common_cov is not None:
        C = C + np.asarray(common_cov, float)  # ranges are blind to a common translation
    return C


def _safe_inv(J: np.ndarray) -> np.ndarray:
    """Inverse of each information matrix; inf where it is singular: where its 2-norm
    condition number is not below `MAX_CONDITION` (or it is not finite).

    The condition number is decided from the inverse the answer needs anyway: for N x N
    matrices cond_2 / N <= cond_1 = |J|_1 |J^-1|_1 <= N cond_2, so cond_1 below
    MAX_CONDITION / N is fixed and above MAX_CONDITION N singular without an SVD; only the
    band between (and a batch LAPACK cannot invert) takes the SVD. The SVD was 3x the
    inverse's cost at n = 17 and 2x at n = 256; the answer is the same, bit for bit."""
    out = np.full_like(J, np.inf)
    N = J.shape[-1]
    finite = np.isfinite(J).all(axis=(-1, -2))
    P = None
    if finite.all():
        try:
            P = np.linalg.inv(J)
        except np.linalg.LinAlgError:  # a singular matrix in the batch: the SVD decides
            P = None
    if P is None:
        ok = finite.copy()
        ok[finite] = np.linalg.cond(J[finite]) < MAX_CONDITION
        if ok.any():
            out[ok] = np.linalg.inv(J[ok])
        return out
    with np.errstate(invalid="ignore", over="ignore"):
        c1 = np.abs(J).sum(axis=-2).max(axis=-1) * np.abs(P).sum(axis=-2).max(axis=-1)
    ok = np.isfinite(c1) & (c1 < MAX_CONDITION / N)
    band = np.isfinite(c1) & ~ok & (c1 <= MAX_CONDITION * N)
    if band.any():
        ok[band] = np.linalg.cond(J[band]) < MAX_CONDITION
    out[ok] = P[ok]
    return out


#: an information matrix at or above this 2-norm condition number is singular (`_safe_inv`)
MAX_CONDITION = 1e12


def swarm_information(
    truth: np.ndarray,
    trusted: np.ndarray,
    measured: np.ndarray,
    gnss_cov: np.ndarray,
    range_sigma: float,
    ins_cov: np.ndarray | None = None,
    common_cov: np.ndarray | None = None,
    symmetric: bool = False,
) -> np.ndarray:
    """Fisher information (T, 3n, 3n) of all positions: GNSS of ``trusted`` drones (T, n),
    their own errors of covariance ``gnss_cov`` plus an error common to all of covariance
    ``common_cov``; one term per range measurement (``measured`` (T, n, n): d_ij and d_ji
    are two independent measurements, or with ``symmetric`` one measurement stored twice);
    INS priors (3, 3) or (T, n, 3, 3) if given."""
    truth = np.asarray(truth, float)
    T, n, _ = truth.shape
    if range_sigma <= 0:
        raise ValueError("swarm_crb: range_sigma must be > 0")
    G = np.linalg.inv(np.asarray(gnss_cov, float))
    J = np.zeros((T, n, 3, n, 3))
    idx = np.arange(n)
    tr = np.asarray(trusted, bool)
    J[:, idx, :, idx, :] += np.where(tr[..., None, None], G, 0.0).transpose(1, 0, 2, 3)
    if common_cov is not None:
        # Woodbury: R^-1 = I (x) G - (1 (x) G) (C^-1 + m G)^-1 (1^T (x) G), written with
        # C (I + m G C)^-1 so that a singular C (no common error on an axis) is allowed
        Cc = np.asarray(common_cov, float)
        m = tr.sum(axis=1).astype(float)  # (T,)
        M = np.einsum("ab,tbc->tac", Cc, np.linalg.inv(np.eye(3) + m[:, None, None] * (G @ Cc)))
        GMG = np.einsum("ab,tbc,cd->tad", G, M, G)
        both = (tr[:, :, None] & tr[:, None, :]).astype(float)
        J -= np.einsum("tij,tab->tiajb", both, GMG)
    if ins_cov is not None:
        P = np.linalg.inv(np.broadcast_to(np.asarray(ins_cov, float), (T, n, 3, 3)))
        J[:, idx, :, idx, :] += P.transpose(1, 0, 2, 3)
    m = np.asarray(measured, bool) & ~np.eye(n, dtype=bool)
    # each ordered measurement (i, j) adds w u u^T to blocks ii, jj and -w u u^T to ij, ji;
    # the two directions share u u^T, so count them together
    mt = np.swapaxes(m, 1, 2)
    if symmetric:  # one measurement per linked pair
        cnt = (m | mt).astype(float) / range_sigma**2
    else:
        cnt = (m.astype(float) + mt.astype(float)) / range_sigma**2  # symmetric in i, j
    _range_information(np.ascontiguousarray(truth), np.ascontiguousarray(cnt), J)
    return J.reshape(T, 3 * n, 3 * n)


@njit(cache=True)
def _range_information(truth, cnt, J):  # pragma: no cover - compiled
    """The ranges' part of `swarm_information` in place on J (T, n, 3, n, 3): with u_ij the
    unit vector from x_j to x_i (`_unit`: 0 where they coincide) and c_ij = cnt[t, i, j], block
    ij less c_ij u_ij u_ij^T for every pair, then block ii plus its sum over j. The numpy
    expression it replaced (a (T, n, n, 3, 3) einsum, c times u_k then times u_l, its sum
    over j in order, two transposed passes over J: 1.0 of the 2.2 ms a 65-drone placement
    covariance took) did the same operations in the same order: the same bits."""
    T, n, _ = truth.shape
    s = np.empty((3, 3))
    u = np.empty(3)
    for t in range(T):
        for i in range(n):
            for j in range(n):
                d0 = truth[t, i, 0] - truth[t, j, 0]
                d1 = truth[t, i, 1] - truth[t, j, 1]
                d2 = truth[t, i, 2] - truth[t, j, 2]
                norm = np.sqrt((d0 * d0 + d1 * d1) + d2 * d2)
                den = norm if norm > 0 else 1.0
                u[0], u[1], u[2] = d0 / den, d1 / den, d2 / den
                c = cnt[t, i, j]
                for k in range(3):
                    for m in range(3):
                        v = (c * u[k]) * u[m]
                        J[t, i, k, j, m] -= v * 1.0
                        s[k, m] = v if j == 0 else s[k, m] + v
            for k in range(3):
                for m in range(3):
                    J[t, i, k, i, m] += s[k, m]


def swarm_crb(
    truth: np.ndarray,
    trusted: np.ndarray,
    measured: np.ndarray,
    gnss_cov: np.ndarray,
    range_sigma: float,
    ins_cov: np.ndarray | None = None,
    common_cov: np.ndarray | None = None,
    symmetric: bool = False,
) -> np.ndarray:
    """Per-drone bound (T, n, 3, 3): the 3x3 blocks of the inverse swarm information (see
    `swarm_information` for the arguments).

    Built CHUNK_BYTES of information matrices at a time, so memory does not grow with the
    number of problems (a 60 s mission of 256 drones is 601 matrices of 768 x 768, 2.8 GB at
    once), and with one BLAS thread: on a busy machine BLAS threads fighting over the cores
    made this 10-60x slower, and the thread count changed the last bits of the result."""
    truth = np.asarray(truth, float)
    T, n, _ = truth.shape
    trusted, measured = np.asarray(trusted, bool), np.asarray(measured, bool)
    ins = None if ins_cov is None else np.asarray(ins_cov, float)
    per = max(1, CHUNK_BYTES // (2 * 8 * (3 * n) ** 2))  # J and its range terms
    out = np.empty((T, n, 3, 3))
    idx = np.arange(n)
    with one_blas_thread():
        for lo in range(0, T, per):
            hi = min(T, lo + per)
            J = swarm_information(
                truth[lo:hi],
                trusted[lo:hi],
                measured[lo:hi],
                gnss_cov,
                range_sigma,
                ins[lo:hi] if ins is not None and ins.ndim == 4 else ins,
                common_cov,
                symmetric,
            )
            C = _safe_inv(J).reshape(hi - lo, n, 3, n, 3)
            out[lo:hi] = C[:, idx, :, idx, :].transpose(1, 0, 2, 3)
    return out


#: information matrices per chunk; the chunk's temporaries (range terms, the condition
#: number's SVD, the inverse) come to about 3x this: 64 MiB added 202 MB to the peak of a 60 s
#: 64-drone mission's bounds, 8 MiB adds 28 MB in the same time, bit for bit the same bounds
CHUNK_BYTES = 8 * 2**20


def error_statistics(err: np.ndarray, bound: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Squared error and NEES e^T C^-1 e for errors (..., 3) against bounds (..., 3, 3)."""
    sq = np.einsum("...i,...i->...", err, err)
    finite = np.isfinite(bound).all(axis=(-1, -2))
    C = np.where(finite[..., None, None], bound, np.eye(3))
    nees = np.einsum("...i,...i->...", err, np.linalg.solve(C, err[..., None])[..., 0])
    return sq, np.where(finite, nees, np.nan)

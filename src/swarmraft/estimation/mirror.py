"""The mirror test of `integrity.assess`: can the data tell an untrusted drone's estimate from
its mirror image across its anchors' best-fit plane?

Near-coplanar (or near-collinear) anchors leave a drone located by ranges alone a second
minimum on the other side of their plane. `mirror_ambiguous` reflects the estimate across the
plane (and across the plane through the anchors' best-fit line), moves the reflection into
the minimum beside it by a few Gauss-Newton steps on the drone's own ranges (anchors fixed),
and calls the drone ambiguous when either point fits as well and lies further away than the
linearised uncertainty covers. Per drone it is a handful of 3x3 solves, so it runs as one
compiled kernel over trials and drones (numpy's per-call overhead was most of its time).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from swarmraft.estimation.noise import NoiseModel, prior_held
from swarmraft.estimation.robust import anchor_planes_of


@njit(cache=True)
def _solve3(H, g, out):  # pragma: no cover - compiled
    """out = H^-1 g for a 3x3 H (Gaussian elimination with partial pivoting)."""
    a = H.copy()
    b = g.copy()
    for c in range(3):
        p = c
        for r in range(c + 1, 3):
            if abs(a[r, c]) > abs(a[p, c]):
                p = r
        if p != c:
            for k in range(3):
                a[c, k], a[p, k] = a[p, k], a[c, k]
            b[c], b[p] = b[p], b[c]
        for r in range(c + 1, 3):
            m = a[r, c] / a[c, c]
            for k in range(c, 3):
                a[r, k] -= m * a[c, k]
            b[r] -= m * b[c]
    for r in range(2, -1, -1):
        s = b[r]
        for k in range(r + 1, 3):
            s -= a[r, k] * out[k]
        out[r] = s / a[r, r]


@njit(cache=True)
def _own_chi2(pos, xt, d, w, inv_s2, pr, p_w):  # pragma: no cover - compiled
    """Chi-square of one drone at pos (3,): its anchors' ranges d (weights w: 0 or 1) to the
    anchors at xt, and its prior (weight p_w)."""
    q = 0.0
    for k in range(xt.shape[0]):
        if w[k] > 0:
            e0 = pos[0] - xt[k, 0]
            e1 = pos[1] - xt[k, 1]
            e2 = pos[2] - xt[k, 2]
            r = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2) - d[k]
            q += r * r * inv_s2
    if p_w > 0:
        q += ((pos[0] - pr[0]) ** 2 + (pos[1] - pr[1]) ** 2 + (pos[2] - pr[2]) ** 2) * p_w
    return q


@njit(cache=True)
def _refine(pos, xt, d, w, inv_s2, pr, p_w, iters):  # pragma: no cover - compiled
    """``iters`` Gauss-Newton steps of one drone on its own ranges (anchors fixed) and prior,
    in place on pos (3,)."""
    H = np.zeros((3, 3))
    g = np.zeros(3)
    step = np.zeros(3)
    for _ in range(iters):
        H[:, :] = 0.0
        g[:] = 0.0
        for k in range(xt.shape[0]):
            if w[k] == 0:
                continue
            e0 = pos[0] - xt[k, 0]
            e1 = pos[1] - xt[k, 1]
            e2 = pos[2] - xt[k, 2]
            dist = max(np.sqrt(e0 * e0 + e1 * e1 + e2 * e2), 1e-9)
            u = (e0 / dist, e1 / dist, e2 / dist)
            r = dist - d[k]
            for a in range(3):
                g[a] += w[k] * inv_s2 * r * u[a]
                for b in range(3):
                    H[a, b] += w[k] * inv_s2 * u[a] * u[b]
        for a in range(3):
            H[a, a] += p_w
            g[a] += p_w * (pos[a] - pr[a])
        ridge = 1e-9 * (H[0, 0] + H[1, 1] + H[2, 2] + 1e-12)
        for a in range(3):
            H[a, a] += ridge
        _solve3(H, g, step)
        for a in range(3):
            pos[a] -= step[a]


@njit(cache=True)
def _info(xt, i, w, inv_s2, p_w, out):  # pragma: no cover - compiled
    """A drone's 3x3 information from its anchors (weights w) and prior (p_w), into out."""
    out[:, :] = 0.0
    for k in range(xt.shape[0]):
        if w[k] == 0:
            continue
        e0 = xt[i, 0] - xt[k, 0]
        e1 = xt[i, 1] - xt[k, 1]
        e2 = xt[i, 2] - xt[k, 2]
        dist = max(np.sqrt(e0 * e0 + e1 * e1 + e2 * e2), 1e-300)
        u = (e0 / dist, e1 / dist, e2 / dist)
        for a in range(3):
            for b in range(3):
                out[a, b] += w[k] * inv_s2 * u[a] * u[b]
    for a in range(3):
        out[a, a] += p_w


@njit(cache=True)
def _inverse3(M, out):  # pragma: no cover - compiled
    """out = M^-1 for a 3x3 M (adjugate over determinant)."""
    c00 = M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1]
    c01 = M[1, 2] * M[2, 0] - M[1, 0] * M[2, 2]
    c02 = M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]
    det = M[0, 0] * c00 + M[0, 1] * c01 + M[0, 2] * c02
    out[0, 0] = c00 / det
    out[1, 0] = c01 / det
    out[2, 0] = c02 / det
    out[0, 1] = (M[0, 2] * M[2, 1] - M[0, 1] * M[2, 2]) / det
    out[1, 1] = (M[0, 0] * M[2, 2] - M[0, 2] * M[2, 0]) / det
    out[2, 1] = (M[0, 1] * M[2, 0] - M[0, 0] * M[2, 1]) / det
    out[0, 2] = (M[0, 1] * M[1, 2] - M[0, 2] * M[1, 1]) / det
    out[1, 2] = (M[0, 2] * M[1, 0] - M[0, 0] * M[1, 2]) / det
    out[2, 2] = (M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]) / det


@njit(cache=True)
def _mirror_kernel(
    x, towards, anchors, cnt, mean, vec, trusted, inv_s2, prior, p_w, has_prior, threshold, out
):  # pragma: no cover - compiled
    T, n, _ = x.shape
    info = np.zeros((3, 3))
    cov = np.zeros((3, 3))
    d = np.zeros(n)
    pos = np.zeros(3)
    refined = np.zeros(3)
    root = np.sqrt(threshold)
    for t in range(T):
        xt = x[t]
        # the ridge of the per-drone inverse: far below the largest information in the trial
        # (the trial's own, so its answer does not depend on the other trials of a batch)
        big = 0.0
        for i in range(n):
            _info(xt, i, anchors[t, i], inv_s2, p_w if has_prior[t, i] else 0.0, info)
            for a in range(3):
                for b in range(3):
                    big = max(big, abs(info[a, b]))
        ridge = 1e-12 * max(big, 1.0)
        for i in range(n):
            if trusted[t, i]:
                continue
            pw = p_w if has_prior[t, i] else 0.0
            if cnt[t, i] < (3 if has_prior[t, i] else 4):
                out[t, i] = True
                continue
            w = anchors[t, i]
            for k in range(n):
                d[k] = 0.0 if np.isnan(towards[t, i, k]) else towards[t, i, k]
            pr = prior[t, i]
            base = _own_chi2(xt[i], xt, d, w, inv_s2, pr, pw)
            _info(xt, i, w, inv_s2, pw, info)
            for a in range(3):
                info[a, a] += ridge
            _inverse3(info, cov)
            for axis in range(2):
                nrm = vec[t, i, :, axis]
                h = 0.0
                var = 0.0
                for a in range(3):
                    h += (xt[i, a] - mean[t, i, a]) * nrm[a]
                    for b in range(3):
                        var += nrm[a] * cov[a, b] * nrm[b]
                sigma_n = np.sqrt(max(var, 0.0))
                for a in range(3):
                    pos[a] = xt[i, a] - 2 * h * nrm[a]
                    refined[a] = pos[a]
                _refine(refined, xt, d, w, inv_s2, pr, pw, 6)
                to_mirror = 0.0
                to_x = 0.0
                apart = 0.0
                apart_r = 0.0
                for a in range(3):
                    to_mirror += (refined[a] - pos[a]) ** 2
                    to_x += (refined[a] - xt[i, a]) ** 2
                    apart += (pos[a] - xt[i, a]) ** 2
                    apart_r += (refined[a] - xt[i, a]) ** 2
                # distinct (beyond what the linearised uncertainty covers) and as good a fit;
                # the refined point only if it stayed on the mirror's side
                if np.sqrt(apart) > root * sigma_n:
                    if _own_chi2(pos, xt, d, w, inv_s2, pr, pw) - base < threshold:
                        out[t, i] = True
                if np.sqrt(to_mirror) < np.sqrt(to_x) and np.sqrt(apart_r) > root * sigma_n:
                    if _own_chi2(refined, xt, d, w, inv_s2, pr, pw) - base < threshold:
                        out[t, i] = True


def mirror_ambiguous(
    x: np.ndarray,
    ranges: np.ndarray,
    trusted: np.ndarray,
    noise: NoiseModel,
    threshold: float,
    prior: np.ndarray | None = None,
    prior_sigma: float | None = None,
) -> np.ndarray:
    """Untrusted drones (T, n) whose position the data cannot tell from a mirror image:
    fewer than 4 anchors (trusted drones ranging with them; 3 with a prior), or the
    reflection of the estimate across the best-fit plane of its anchors (and across the
    plane through their best-fit line, for near-collinear anchors) changes the chi-square of
    its ranges (and prior) by less than ``threshold`` while lying further from it than the
    linearised uncertainty covers (sqrt(threshold) sigma along the plane's normal: closer
    than that, the protection level covers the mirror)."""
    T, n, _ = x.shape
    towards = np.ascontiguousarray(np.swapaxes(ranges, 1, 2))  # d_ki: anchor k's measurement of i
    anchors, cnt, mean, vec = anchor_planes_of(x, ranges, trusted, ~trusted)  # the untrusted drones' planes
    has_prior = prior_held(prior, prior_sigma, (T, n))
    pr = np.zeros((T, n, 3)) if prior is None else np.nan_to_num(prior)
    out = np.zeros((T, n), dtype=bool)
    _mirror_kernel(
        np.ascontiguousarray(x, float),
        towards,
        anchors.astype(float),
        cnt,
        mean,
        np.ascontiguousarray(vec),
        trusted,
        1.0 / noise.range_sigma**2,
        np.ascontiguousarray(pr, float),
        1.0 / prior_sigma**2 if prior_sigma else 0.0,
        has_prior,
        float(threshold),
        out,
    )
    return out

"""The compiled kernels that replaced numpy expressions in the estimators compute what those
expressions computed: each is compared with the expression it replaced (kept here as the
reference) on random batches with unmeasured (nan) and infinite ranges, untrusted drones and
partial priors. Summation order may differ between machines (numpy's einsum vectorises), so
values are compared to 1e-13 relative; nan and inf patterns exactly."""

from __future__ import annotations

import numpy as np
import pytest

from swarmraft.estimation.gnc import geman_mcclure_weights, gnc_estimate
from swarmraft.estimation.integrity import _eigenvalues
from swarmraft.estimation.joint import residuals, weighted_gauss_newton
from swarmraft.estimation.levels import levels_kernel, unfixed_block
from swarmraft.estimation.robust import _own_cost, anchor_planes
from swarmraft.estimation.trust_region import linear_multilateration


def _distances(x: np.ndarray) -> np.ndarray:
    diff = x[:, :, None, :] - x[:, None, :, :]
    return np.sqrt(np.einsum("tijk,tijk->tij", diff, diff))


def residuals_reference(x, reported, ranges, G_half, range_sigma):
    rg = np.einsum("ij,tnj->tni", G_half, x - reported)
    rr = np.where(np.isnan(ranges), 0.0, (_distances(x) - np.nan_to_num(ranges)) / range_sigma)
    return rg, rr


def own_cost_reference(x, ranges, trusted, range_sigma, prior, prior_sigma):
    meas = ~np.isnan(ranges) & trusted[:, :, None]
    r2 = np.where(meas, (_distances(x) - np.nan_to_num(ranges)) ** 2, 0.0).sum(axis=1) / range_sigma**2
    if prior is not None and prior_sigma:
        has = np.isfinite(prior).all(axis=2)
        r2 = r2 + np.where(has, np.sum((x - np.nan_to_num(prior)) ** 2, axis=2) / prior_sigma**2, 0.0)
    return np.where(trusted, 0.0, r2)


def gnc_reference(reported, ranges, gnss_cov, range_sigma, c_gnss, c_range, mu_factor, max_outer, inner):
    """`gnc.gnc_estimate`'s rounds as the numpy loop they were, over the batch's active trials."""
    T, n, _ = reported.shape
    G_half = np.linalg.cholesky(np.linalg.inv(gnss_cov)).T
    meas = ~np.isnan(ranges) & ~np.eye(n, dtype=bool)
    x = weighted_gauss_newton(
        reported, reported, ranges, np.ones((T, n)), meas.astype(float), gnss_cov, range_sigma, inner + 2
    )
    rg, rr = residuals(x, reported, ranges, G_half, range_sigma)
    r2g, r2r = np.einsum("tni,tni->tn", rg, rg), np.where(meas, rr**2, 0.0)
    worst_g, worst_r = r2g.max(axis=1) / c_gnss**2, r2r.max(axis=(1, 2)) / c_range**2
    mu = np.maximum(2 * np.where(worst_r > worst_g, worst_r, worst_g), 1.0)
    active = np.arange(T)
    for _ in range(max_outer):
        sel = slice(None) if active.size == T else active
        m = mu[sel]
        gw = geman_mcclure_weights(r2g[sel], c_gnss**2, m[:, None])
        rw = np.where(meas[sel], geman_mcclure_weights(r2r[sel], c_range**2, m[:, None, None]), 0.0)
        rep, rng_ = reported[sel], ranges[sel]
        xa = weighted_gauss_newton(x[sel], rep, rng_, gw, rw, gnss_cov, range_sigma, iters=inner)
        rg, rr = residuals(xa, rep, rng_, G_half, range_sigma)
        x[sel] = xa
        r2g[sel] = np.einsum("tni,tni->tn", rg, rg)
        r2r[sel] = np.where(meas[sel], rr**2, 0.0)
        settled = m <= 1.0
        m = m / mu_factor
        mu[sel] = np.where(1.0 > m, 1.0, m)
        active = active[~settled]
        if not active.size:
            break
    gnss_w = geman_mcclure_weights(r2g, c_gnss**2, 1.0)
    return x, gnss_w, np.where(meas, geman_mcclure_weights(r2r, c_range**2, 1.0), 0.0)


def batches(seed: int, count: int = 60):
    """Random problems: positions at several scales, ranges with noise, nan (unmeasured) and
    (every fourth batch) inf entries, a trusted set, priors with nan rows (or none)."""
    rng = np.random.default_rng(seed)
    for k in range(count):
        T, n = int(rng.integers(1, 5)), int(rng.integers(2, 19))
        x = rng.normal(0, 50, (T, n, 3)) * rng.uniform(0.01, 100)
        d = np.linalg.norm(x[:, :, None] - x[:, None], axis=3) + rng.normal(0, 0.1, (T, n, n))
        d[rng.random((T, n, n)) < 0.2] = np.nan
        if k % 4 == 0:
            d[rng.random((T, n, n)) < 0.05] = np.inf
        prior = None if k % 3 == 0 else x + rng.normal(0, 2, x.shape)
        if prior is not None:
            prior[rng.random((T, n)) < 0.4] = np.nan
        yield {
            "x": x,
            "reported": x + rng.normal(0, 3, x.shape),
            "ranges": d,
            "trusted": rng.random((T, n)) < 0.7,
            "prior": prior,
            "prior_sigma": None if k % 7 == 0 else float(rng.uniform(0.5, 5)),
            "range_sigma": float(rng.uniform(0.01, 1)),
        }


def same(a: np.ndarray, b: np.ndarray) -> None:
    assert a.shape == b.shape
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    np.testing.assert_array_equal(np.isinf(a), np.isinf(b))
    np.testing.assert_array_equal(a[np.isinf(a)], b[np.isinf(b)])
    finite = np.isfinite(a)
    np.testing.assert_allclose(a[finite], b[finite], rtol=1e-13, atol=0)


@pytest.mark.parametrize("seed", [1, 2])
def test_residuals_kernel_is_the_numpy_expression(seed: int) -> None:
    G_half = np.linalg.cholesky(np.linalg.inv(np.diag([2.25, 2.25, 9.0]))).T
    for b in batches(seed):
        with np.errstate(all="ignore"):
            want = residuals_reference(b["x"], b["reported"], b["ranges"], G_half, b["range_sigma"])
        got = residuals(b["x"], b["reported"], b["ranges"], G_half, b["range_sigma"])
        for w, g in zip(want, got, strict=True):
            same(w, g)


@pytest.mark.parametrize("seed", [1, 2])
def test_own_cost_kernel_is_the_numpy_expression(seed: int) -> None:
    """Each start's untrusted drones with the trusted ones at the anchors: the numpy
    expression on the placed positions, start by start."""
    rng = np.random.default_rng(seed)
    for b in batches(seed):
        X = b["x"][None] + rng.normal(0, 5, (3, *b["x"].shape))  # three starts
        rest = (b["ranges"], b["trusted"], b["range_sigma"], b["prior"], b["prior_sigma"])
        got = _own_cost(b["x"], X, *rest)
        for s in range(3):
            placed = np.where(b["trusted"][..., None], b["x"], X[s])
            with np.errstate(all="ignore"):
                same(own_cost_reference(placed, *rest), got[s])


def test_gnc_kernel_is_the_numpy_loop() -> None:
    """Swarms with up to half their reports spoofed by up to 60 m, random GNC settings."""
    rng = np.random.default_rng(5)
    cov = np.diag([2.25, 2.25, 9.0])
    for _ in range(40):
        T, n = int(rng.integers(1, 5)), int(rng.integers(4, 18))
        x = rng.uniform(0, 100, (T, n, 3))
        d = np.linalg.norm(x[:, :, None] - x[:, None], axis=3) + rng.normal(0, 0.1, (T, n, n))
        d[rng.random((T, n, n)) < 0.15] = np.nan
        rep = x + rng.normal(0, 2, x.shape)
        f = int(rng.integers(0, n // 2 + 1))
        rep[:, :f] += rng.uniform(-60, 60, (T, f, 3))
        kw = {
            "c_gnss": float(rng.uniform(2, 5)),
            "c_range": float(rng.uniform(2, 5)),
            "mu_factor": float(rng.uniform(1.3, 3)),
            "max_outer": int(rng.integers(3, 60)),
            "inner": int(rng.integers(1, 3)),
        }
        want = gnc_reference(rep, d, cov, 0.1, **kw)
        got = gnc_estimate(rep, d, cov, 0.1, **kw)
        for w, g in zip(want, got, strict=True):
            same(w, g)


def eigenvalues_reference(C):
    """`integrity._eigenvalues` in numpy: eigvalsh of the finite blocks, 0, inf, inf elsewhere."""
    finite = np.isfinite(C).all(axis=(-1, -2))
    out = np.full(C.shape[:-1], np.inf)
    out[..., 0] = 0.0
    out[finite] = np.linalg.eigvalsh(C[finite])
    return out


def test_eigenvalues_kernel_gives_numpys_bits() -> None:
    """`integrity._eigenvalues` (compiled, LAPACK from numba) is numpy's eigvalsh bit for bit
    on blocks of condition up to e^40, not exactly symmetric (the lower triangle is read),
    with non-finite blocks among them."""
    rng = np.random.default_rng(1)
    Q = np.linalg.qr(rng.normal(size=(4000, 3, 3)))[0]
    C = (Q * np.exp(rng.uniform(-20, 20, (4000, 1, 3)))) @ np.swapaxes(Q, 1, 2)
    C += rng.normal(0, 1e-14, C.shape) * np.abs(C).max(axis=(1, 2), keepdims=True)
    C[::97, 1, 2] = np.nan
    C[::89, 0, 0] = np.inf
    C = C.reshape(40, 100, 3, 3)
    np.testing.assert_array_equal(_eigenvalues(C), eigenvalues_reference(C))


def unfixed_reference(C, largest0, max_condition):
    """`integrity.assess`'s test before `levels.unfixed_block`: eigenvalues of every block."""
    ev = eigenvalues_reference(C)
    big0 = np.broadcast_to(largest0, ev.shape[:-1])
    return (ev[..., 2] > max_condition * np.maximum(ev[..., 0], 1e-300)) | (
        ev[..., 2] > 1e6 * np.maximum(big0, 1e-300)
    )


def test_unfixed_decides_as_the_eigenvalues_do() -> None:
    """Blocks with eigenvalues from e^-20 to e^20, some negative or zero (indefinite,
    singular), not exactly symmetric, some with inf or nan entries (upper triangle too),
    against several max_condition: the bound skips most eigenvalue problems and decides
    every block as they do."""
    rng = np.random.default_rng(0)
    skipped = total = 0
    for k in range(600):
        m = int(rng.integers(1, 50))
        Q = np.linalg.qr(rng.normal(size=(m, 3, 3)))[0]
        lam = np.exp(rng.uniform(-20, 20, (m, 1, 3)))
        lam *= rng.choice([1, 1, 1, -1], (m, 1, 3)) * rng.choice([1, 0], (m, 1, 3), p=[0.95, 0.05])
        if k % 2:
            lam = np.exp(rng.uniform(0, 4, (m, 1, 3)))  # well conditioned: the common case
        C = (Q * lam) @ np.swapaxes(Q, 1, 2)
        C += rng.normal(0, 1e-14, C.shape) * np.abs(C).max()
        if k % 10 == 0:
            C[rng.integers(m)] = np.inf
        if k % 13 == 0:
            C[rng.integers(m), 0, 1] = np.nan
        l0 = np.exp(rng.uniform(-25, 25, m)) if k % 3 else np.full(m, 1e3)
        mc = float(rng.choice([1e6, 1e3, 10.0, 1e9]))
        with np.errstate(all="ignore"):
            want = unfixed_reference(C, l0, mc)
        got = np.array([unfixed_block(C[i], l0[i], mc) for i in range(m)])
        np.testing.assert_array_equal(want, got)
        total += m
        skipped += int((~want).sum())
    assert skipped > total // 3  # the test saw many fixed blocks, not only unfixed ones


def anchor_planes_reference(x, ranges, trusted):
    n = x.shape[1]
    anchors = ~np.isnan(np.swapaxes(ranges, 1, 2)) & trusted[:, None, :] & ~np.eye(n, dtype=bool)
    w = anchors.astype(float)
    cnt = w.sum(axis=2)
    mean = np.einsum("tik,tkc->tic", w, x) / np.maximum(cnt, 1)[..., None]
    dev = x[:, None, :, :] - mean[:, :, None, :]
    _, vec = np.linalg.eigh(np.einsum("tik,tika,tikb->tiab", w, dev, dev))
    return anchors, cnt, mean, vec


@pytest.mark.parametrize("seed", [1, 2])
def test_anchor_planes_kernel_is_the_numpy_expression(seed: int) -> None:
    for k, b in enumerate(batches(seed)):
        x = b["x"].copy()
        if k % 4 == 0:
            x[..., 2] *= 1e-3  # a flat layer: the plane's normal is well defined
        want = anchor_planes_reference(x, b["ranges"], b["trusted"])
        got = anchor_planes(x, b["ranges"], b["trusted"])
        np.testing.assert_array_equal(want[0], got[0])
        same(want[1], got[1])
        same(want[2], got[2])
        # principal axes: the same LAPACK routine on the same matrix (up to sign elsewhere)
        np.testing.assert_allclose(np.abs(want[3]), np.abs(got[3]), rtol=0, atol=1e-9)


def multilateration_reference(anchors, dists, mask):
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


def test_multilateration_kernel_is_the_numpy_expression() -> None:
    """1 to 39 anchors (fewer than 4: the pseudo-inverse's minimum-norm answer), flat
    anchor sets, masked and unmeasured anchors."""
    rng = np.random.default_rng(4)
    for k in range(200):
        B, M = int(rng.integers(1, 12)), int(rng.integers(1, 40))
        anchors = rng.normal(0, 50, (B, M, 3)) * rng.uniform(0.1, 10)
        if k % 5 == 0:
            anchors[..., 2] *= 1e-6
        dists = np.linalg.norm(anchors - rng.normal(0, 50, (B, 1, 3)), axis=2) + rng.normal(0, 0.1, (B, M))
        dists[rng.random((B, M)) < 0.1] = np.nan
        mask = (rng.random((B, M)) < 0.8) & ~np.isnan(dists)
        same(multilateration_reference(anchors, dists, mask), linear_multilateration(anchors, dists, mask))


def test_a_start_identical_to_an_earlier_one_is_solved_once_to_the_same_estimate(monkeypatch) -> None:
    """`robust_estimate` solves a start that is bit for bit an earlier start of its trial only
    once (every drone trusted: the closed form, its mirror image, the reports and the prior
    are one point), and the estimate is what solving every start gives, bit for bit."""
    import swarmraft.estimation.robust as robust
    from swarmraft.estimation.noise import NoiseModel

    rng = np.random.default_rng(5)
    T, n = 6, 9
    truth = rng.uniform(0, 100, (T, n, 3))
    reported = truth + rng.normal(0, 1.5, truth.shape)
    ranges = _distances(truth) + rng.normal(0, 0.1, (T, n, n))
    trusted = np.ones((T, n), bool)
    trusted[3:, 2] = False  # half the trials with an untrusted drone: its starts differ
    prior = np.where(trusted[..., None], np.nan, truth + rng.normal(0, 1.0, truth.shape))
    noise = NoiseModel(gnss_cov=np.diag([1.5**2, 1.5**2, 3.0**2]), range_sigma=0.1)
    solved = []
    real = robust.weighted_gauss_newton
    monkeypatch.setattr(
        robust, "weighted_gauss_newton", lambda x0, *a, **k: solved.append(len(x0)) or real(x0, *a, **k)
    )
    once = robust.robust_estimate(reported, ranges, trusted, noise, prior, 3.0)
    # 4 starts a trial; with every drone trusted all 4 are the reports (the prior is of
    # untrusted drones only): one solve, against 4 where drone 2 is untrusted
    assert solved[0] == 3 * 1 + 3 * 4
    solved.clear()
    monkeypatch.setattr(robust, "_first_copy", lambda s: np.arange(s.shape[0] * s.shape[1]))
    every = robust.robust_estimate(reported, ranges, trusted, noise, prior, 3.0)
    assert solved[0] == T * 4
    for field in ("x", "cost", "converged", "ambiguous"):
        np.testing.assert_array_equal(getattr(once, field), getattr(every, field))


def placement_reference(x, reported, ranges, faulty, gnss_cov, range_sigma):
    """`joint_detector`'s re-inclusion statistic as numpy computes it (`gnc._placement_statistic`
    where the kernel is not sure)."""
    from swarmraft.estimation.bounds import swarm_crb
    from swarmraft.estimation.noise import gnss_information

    n = x.shape[1]
    tr = ~faulty
    own = ~np.isnan(ranges) & ~np.eye(n, dtype=bool)
    C = swarm_crb(x, tr, own & tr[:, :, None], gnss_cov, range_sigma)
    r = reported - x
    with np.errstate(invalid="ignore"):
        q = np.einsum("tni,tni->tn", r, np.linalg.solve(gnss_cov + C, r[..., None])[..., 0])
    return np.where(np.isfinite(q), q, np.einsum("tni,ij,tnj->tn", r, gnss_information(gnss_cov), r))


@pytest.mark.parametrize("seed", [1, 2])
def test_placement_kernel_decides_as_numpy(seed: int) -> None:
    """The compiled re-inclusion statistic (`gnc._placement_q`) is numpy's (to its rounding)
    wherever it says it is sure; it is not sure of a statistic at the limit itself (there the
    bits decide), and `_placement_statistic`'s decisions q <= limit are numpy's throughout."""
    from swarmraft.estimation.gnc import _placement_q, _placement_statistic
    from swarmraft.estimation.integrity import _hypothesis_information
    from swarmraft.estimation.noise import NoiseModel

    cov = np.diag([1.5**2, 1.5**2, 3.0**2])
    sure_count = 0
    for b in batches(seed):
        x, rep, rng_ = b["x"], b["reported"], b["ranges"]
        faulty = ~b["trusted"]
        T, n, _ = x.shape
        ref = placement_reference(x, rep, rng_, faulty, cov, b["range_sigma"])
        noise = NoiseModel(cov, b["range_sigma"], None)
        with np.errstate(all="ignore"):
            info = _hypothesis_information(x, rep, rng_, ~faulty, noise, np.ones((T, n), dtype=bool))[0]
        q, sure = np.zeros((T, n)), np.zeros(T, dtype=bool)
        _placement_q(info.copy(), rep, x, faulty, cov, 1e300, q, sure)
        sure_count += sure.sum()
        for t in np.flatnonzero(sure):
            np.testing.assert_allclose(q[t][faulty[t]], ref[t][faulty[t]], rtol=1e-6)
            if not faulty[t].any():
                continue
            at = float(ref[t][faulty[t]][0])  # a limit a statistic sits on
            q2, s2 = np.zeros((1, n)), np.zeros(1, dtype=bool)
            one = slice(t, t + 1)
            _placement_q(info[one].copy(), rep[one], x[one], faulty[one], cov, at, q2, s2)
            assert not s2[0]
        noise = NoiseModel(cov, b["range_sigma"], None)
        rows = np.flatnonzero(faulty.any(axis=1))
        for limit in (1.0, 16.27, 100.0):
            got = _placement_statistic(x, rep, rng_, faulty, faulty, rows, noise, limit)
            want = ref[rows]
            np.testing.assert_array_equal((got <= limit) & faulty[rows], (want <= limit) & faulty[rows])
    assert sure_count > 40  # the kernel decides most trials


def hypotheses_reference(x, reported, ranges, trusted, keep, G, range_sigma):
    """`integrity._hypothesis_information` as numpy computed it: J, b and the terms (gnss, u, w)."""
    T, n, _ = x.shape
    w_r = 1.0 / range_sigma**2
    diff = x[:, :, None, :] - x[:, None, :, :]
    dist = np.sqrt(np.einsum("tijk,tijk->tij", diff, diff))
    u = diff / np.where(dist > 0, dist, 1.0)[..., None]
    meas = ~np.isnan(ranges) & ~np.eye(n, dtype=bool) & trusted[:, :, None]
    meas &= keep[:, :, None] & keep[:, None, :]
    r = np.where(meas, dist - np.nan_to_num(ranges), 0.0)
    uu = np.einsum("tjk,tjka,tjkb->tjkab", meas * w_r, u, u)  # (T, j, k, 3, 3)
    idx = np.arange(n)
    # A_j: block (j, j) GNSS + sum_k w u u^T; blocks (k, k) w u u^T; (j, k), (k, j) -w u u^T.
    # In J, block (p, q) (p != q) is -uu[p, q] - uu[q, p]; block (p, p) sums over j the
    # own block (j = p) and uu[j, p] (j != p)
    J = -(uu + np.swapaxes(uu, 1, 2)).transpose(0, 1, 3, 2, 4)  # (T, p, 3, q, 3)
    diag = uu.copy()
    diag[:, idx, idx] = np.where(trusted[..., None, None], G, 0.0) + uu.sum(axis=2)
    J[:, idx, :, idx, :] = diag.sum(axis=1).transpose(1, 0, 2, 3)  # in order of j
    b = np.zeros((T, n, n, 3))
    e = np.where(trusted[..., None], np.einsum("ab,tjb->tja", G, x - reported), 0.0)
    b[:, idx, idx, :] = e + np.einsum("tjk,tjka->tja", w_r * r, u)
    b -= np.einsum("tjk,tjka->tjka", w_r * r, u)  # r_jj = 0: the diagonal is untouched
    return J.reshape(T, 3 * n, 3 * n), b.reshape(T, n, 3 * n), np.where(trusted, 1.0, 0.0), u, meas * w_r


@pytest.mark.parametrize("seed", [1, 2])
def test_hypotheses_kernel_is_the_numpy_expression(seed: int) -> None:
    from swarmraft.estimation.integrity import _hypothesis_information
    from swarmraft.estimation.noise import NoiseModel, gnss_information

    cov = np.diag([1.5**2, 1.5**2, 3.0**2])
    for k, b in enumerate(batches(seed)):
        T, n, _ = b["x"].shape
        keep = np.random.default_rng(k).random((T, n)) < 0.9
        args = (b["x"], b["reported"], b["ranges"], b["trusted"])
        with np.errstate(over="ignore", invalid="ignore"):
            want = hypotheses_reference(*args, keep, gnss_information(cov), b["range_sigma"])
            J, bb, terms = _hypothesis_information(*args, NoiseModel(cov, b["range_sigma"], None), keep)
        for got, ref in zip((J, bb, terms.gnss, terms.u, terms.w), want, strict=True):
            same(got, ref)


def levels_reference(C0, Cj, dj, exact, tr, undetermined, largest0, common, k_fa, k_md, max_condition):
    """`integrity.assess`'s numpy lines from var0 to the levels (`levels.levels_kernel`)."""
    var0 = np.diagonal(C0, axis1=-2, axis2=-1) + common
    sigma = np.sqrt(var0)
    pl = k_md[:, None, None] * np.sqrt(var0)
    dj = np.where(np.isfinite(exact), exact, dj)
    ill = unfixed_reference(Cj, largest0[:, None, :], max_condition)
    ill = (tr[:, :, None] & ill).any(axis=1)
    var_j = np.diagonal(Cj, axis1=-2, axis2=-1)
    var_ss = np.maximum(var_j - np.diagonal(C0, axis1=-2, axis2=-1)[:, None], 0.0)
    thr = k_fa[:, None, None, None] * np.sqrt(var_ss)
    live = tr[:, :, None, None]
    fixed = ~undetermined[:, None, :, None]
    separated = (live & fixed & (np.abs(dj) > thr + 1e-9)).any(axis=(1, 2, 3))
    pl_j = thr + k_md[:, None, None, None] * np.sqrt(var_j + common)
    pl = np.maximum(pl, np.where(live, pl_j, 0.0).max(axis=1))
    return sigma, np.hypot(pl[..., 0], pl[..., 1]), pl[..., 2], separated, ill


def test_levels_kernel_is_the_numpy_expression() -> None:
    """Random covariance blocks (positive definite, some hypotheses with inf or nan blocks or
    variances below the all-in-view ones), separations near their thresholds, exact
    separations in some trials, trusted and undetermined drones: the same levels, sigma,
    separation test and unfixed drones as the numpy lines."""
    rng = np.random.default_rng(3)
    hits = 0
    for k in range(300):
        T, n = int(rng.integers(1, 4)), int(rng.integers(2, 12))
        A = rng.normal(size=(T, n, 3, 3))
        C0 = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(3)
        B = rng.normal(size=(T, n, n, 3, 3))
        Cj = C0[:, None] + B @ np.swapaxes(B, -1, -2) * rng.uniform(0, 3)
        Cj[rng.random((T, n, n)) < 0.05] *= -0.5  # below the all-in-view: var_ss clipped at 0
        if k % 5 == 0:
            Cj[rng.random((T, n, n)) < 0.1] = np.inf
        if k % 7 == 0:
            Cj[rng.random((T, n, n)) < 0.1] = np.nan
        dj = rng.normal(0, 3, (T, n, n, 3))
        exact = np.where(rng.random((T, n, n, 3)) < 0.3 * (k % 2), rng.normal(0, 3, (T, n, n, 3)), np.nan)
        tr = rng.random((T, n)) < 0.7
        und = rng.random((T, n)) < 0.1
        l0 = np.exp(rng.uniform(-3, 3, (T, n)))
        common = np.zeros(3) if k % 3 else np.array([0.5, 0.5, 1.0])
        k_fa, k_md = rng.uniform(2, 5, T), rng.uniform(2, 5, T)
        mc = float(rng.choice([1e6, 1e3, 10.0]))
        with np.errstate(all="ignore"):
            want = levels_reference(C0, Cj, dj, exact, tr, und, l0, common, k_fa, k_md, mc)
        sigma, hpl, vpl = np.empty((T, n, 3)), np.empty((T, n)), np.empty((T, n))
        sep, ill = np.empty(T, dtype=bool), np.empty((T, n), dtype=bool)
        levels_kernel(C0, Cj, dj, exact, tr, und, l0, common, k_fa, k_md, mc, sigma, hpl, vpl, sep, ill)
        for got, ref in zip((sigma, hpl, vpl), want[:3], strict=True):
            same(got, ref)
        np.testing.assert_array_equal(sep, want[3])
        np.testing.assert_array_equal(ill, want[4])
        hits += int(sep.sum()) + int((~sep).sum() > 0)
    assert hits > 100


def initial_positions_reference(reported, ranges, trusted, prior, fast):
    """`joint.initial_positions` as numpy selected its problems."""
    x = np.array(reported, dtype=float, copy=True)
    if prior is not None:
        use = ~trusted & ~np.isnan(prior).any(axis=2)
        x[use] = prior[use]
    n = x.shape[1]
    towards = np.swapaxes(ranges, 1, 2)
    dists = np.where(np.isnan(towards), ranges, towards)
    t_idx, a_idx = np.nonzero(~trusted)
    mask = trusted[t_idx] & ~np.isnan(dists[t_idx, a_idx]) & (np.arange(n)[None, :] != a_idx[:, None])
    ok = mask.sum(axis=1) >= 4
    if ok.any():
        est = linear_multilateration(reported[t_idx[ok]], dists[t_idx[ok], a_idx[ok]], mask[ok], fast)
        x[t_idx[ok], a_idx[ok]] = est
    return x


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("fast", [False, True])
def test_initial_positions_kernel_is_the_numpy_selection(seed: int, fast: bool) -> None:
    from swarmraft.estimation.joint import initial_positions

    for b in batches(seed):
        args = (b["reported"], b["ranges"], b["trusted"], b["prior"], fast)
        with np.errstate(all="ignore"):
            same(initial_positions(*args), initial_positions_reference(*args))


def mirrored_reference(x, ranges, trusted):
    """`robust.mirrored` in numpy: every drone's anchor plane, the untrusted ones reflected."""
    _, _, mean, vec = anchor_planes(x, ranges, trusted)
    normal = vec[..., :, 0]
    h = np.einsum("tia,tia->ti", x - mean, normal)
    return np.where(trusted[..., None], x, x - 2 * h[..., None] * normal)


@pytest.mark.parametrize("seed", [1, 2])
def test_mirrored_kernel_is_the_numpy_expression(seed: int) -> None:
    from swarmraft.estimation.robust import mirrored

    for b in batches(seed):
        args = (b["x"], b["ranges"], b["trusted"])
        with np.errstate(all="ignore"):
            same(mirrored(*args), mirrored_reference(*args))


def test_first_copy_points_each_start_to_its_first_identical_one() -> None:
    """`robust._first_copy`: per trial, a start bit for bit equal to an earlier one takes that
    one's flat index (s T + t), itself otherwise; -0.0 and 0.0 differ in their bits."""
    from swarmraft.estimation.robust import _first_copy

    a, b = np.array([1.0, 2.0]), np.array([1.0, 3.0])
    starts = np.array(
        [
            [a, a, [0.0, 1.0]],  # start 0 of trials 0, 1, 2
            [b, a, [-0.0, 1.0]],  # start 1: a copy of start 0 in trial 1
            [a, b, [0.0, 1.0]],  # start 2: copies of start 0 in trials 0 and 2
            [b, b, [-0.0, 1.0]],  # start 3: of start 1 (trial 0), of 2 (trial 1), of 1 (trial 2)
        ]
    )
    assert _first_copy(starts).tolist() == [0, 1, 2, 3, 1, 5, 0, 7, 2, 3, 7, 5]


def test_best_start_is_numpys_argmin() -> None:
    """`robust._best`: per trial the converged start of lowest cost, or the lowest cost where
    none converged, as np.argmin picks it (ties: the first; a nan: the first nan)."""
    from swarmraft.estimation.robust import _best

    rng = np.random.default_rng(5)
    for _ in range(300):
        S, T = int(rng.integers(1, 7)), int(rng.integers(1, 5))
        cost = rng.choice([1.0, 2.0, 3.0, np.inf, np.nan], (S, T), p=[0.3, 0.3, 0.3, 0.05, 0.05])
        conv = rng.random((S, T)) < 0.5
        score = np.where(conv, cost, np.inf)
        want = np.where(conv.any(axis=0), np.argmin(score, axis=0), np.argmin(cost, axis=0))
        np.testing.assert_array_equal(_best(cost, conv), want)


def test_pairwise_sum_is_numpys_sum() -> None:
    """`joint.pairwise_sum`: numpy's sum of a contiguous row, bit for bit, at every length
    up to PAIRWISE_MAX (its blocks of 128 and the halves and quarters of longer runs)."""
    from swarmraft.estimation.joint import PAIRWISE_MAX, pairwise_sum

    rng = np.random.default_rng(2)
    for n in range(PAIRWISE_MAX + 1):
        a = rng.normal(size=n) * rng.uniform(0.01, 1e6, n)
        a[rng.random(n) < 0.2] = 0.0
        assert pairwise_sum(a, 0, n) == a.sum(), n


def residual_statistics_reference(x, reported, ranges, trusted, noise):
    """`joint.residual_statistics` as numpy computed it."""
    rg, rr = residuals(x, reported, ranges, noise.whitener, noise.range_sigma)
    n = x.shape[1]
    own = ~np.isnan(ranges) & ~np.eye(n, dtype=bool) & trusted[:, :, None]
    gnss_q = np.where(trusted, np.einsum("tni,tni->tn", rg, rg), 0.0)
    per = gnss_q + np.where(own, rr**2, 0.0).sum(axis=2)
    dof = 3 * trusted.sum(axis=1) + own.sum(axis=(1, 2)) - 3 * n
    return per, gnss_q, per.sum(axis=1), dof


@pytest.mark.parametrize("seed", [1, 2])
def test_residual_statistics_kernel_is_the_numpy_expression(seed: int) -> None:
    from swarmraft.estimation.joint import residual_statistics
    from swarmraft.estimation.noise import NoiseModel

    cov = np.diag([1.5**2, 1.5**2, 3.0**2])
    for b in batches(seed):
        args = (b["x"], b["reported"], b["ranges"], b["trusted"], NoiseModel(cov, b["range_sigma"], None))
        with np.errstate(all="ignore"):
            for got, want in zip(
                residual_statistics(*args), residual_statistics_reference(*args), strict=True
            ):
                same(np.asarray(got, float), np.asarray(want, float))


@pytest.mark.parametrize("seed", [1, 2])
def test_too_few_without_one_is_the_numpy_expression(seed: int) -> None:
    """`integrity.too_few_without_one` (compiled): a trusted drone with fewer than 4 trusted
    drones ranging it, an untrusted one that one anchor fewer would leave below 4 (3 with a
    prior), as the numpy expression it replaced decides."""
    from swarmraft.estimation.integrity import too_few_without_one
    from swarmraft.estimation.noise import prior_held

    for b in batches(seed):
        ranges, trusted, prior, ps = b["ranges"], b["trusted"], b["prior"], b["prior_sigma"]
        n = trusted.shape[1]
        anchors = ~np.isnan(np.swapaxes(ranges, 1, 2)) & trusted[:, None, :] & ~np.eye(n, dtype=bool)
        cnt = anchors.sum(axis=2)
        need = np.where(prior_held(prior, ps, trusted.shape) & ~trusted, 3, 4)
        want = np.where(trusted, cnt < 4, (cnt - 1 < need) & (cnt > 0))
        np.testing.assert_array_equal(too_few_without_one(ranges, trusted, prior, ps), want)


@pytest.mark.parametrize("seed", [1, 2])
def test_gnc_flags_kernel_is_the_numpy_expression(seed: int) -> None:
    """`gnc._flags_kernel`: GNC's flags (a whitened GNSS residual squared above flag_chi2, or
    most own ranges down-weighted) as `joint_detector`'s numpy expressions gave them."""
    from swarmraft.estimation.gnc import _flags_kernel
    from swarmraft.estimation.noise import gnss_whitener

    rng = np.random.default_rng(seed)
    Gh = gnss_whitener(np.diag([1.5**2, 1.5**2, 3.0**2]))
    for b in batches(seed):
        x, rep, ranges = b["x"], b["reported"], b["ranges"]
        T, n, _ = x.shape
        range_w = rng.uniform(0, 1, (T, n, n))
        with np.errstate(all="ignore"):
            rg, _ = residuals(x, rep, ranges, Gh, 0.1)
        own = ~np.isnan(ranges) & ~np.eye(n, dtype=bool)
        bad_want = ((range_w < 0.5) & own).sum(axis=2) > 0.5 * own.sum(axis=2)
        q = np.einsum("tni,tni->tn", rg, rg)
        for limit in (1.0, float(np.median(q)), 16.27):
            faulty, bad = np.empty((T, n), dtype=bool), np.empty((T, n), dtype=bool)
            _flags_kernel(x, rep, ranges, Gh, range_w, limit, faulty, bad)
            np.testing.assert_array_equal(bad, bad_want)
            np.testing.assert_array_equal(faulty, (q > limit) | bad_want)


def test_swap_sets_are_the_numpy_construction() -> None:
    """`rivals._swap_sets`: the rival check's swaps (per trial of ``rows``, per flagged drone,
    the trusted drone of each rank up to ``swaps``, or all where ``full``, left out and the
    flagged one trusted) in the order numpy's indexing built them."""
    from swarmraft.estimation.rivals import _swap_count, _swap_sets

    rng = np.random.default_rng(4)
    for _ in range(200):
        T, n = int(rng.integers(1, 6)), int(rng.integers(2, 12))
        trusted = rng.random((T, n)) < 0.6
        rows = np.flatnonzero(rng.random(T) < 0.8).astype(np.int64)
        full = rng.random(T) < 0.4
        swaps = int(rng.integers(1, 4))
        worst = np.argsort(np.where(trusted, -rng.random((T, n)), np.inf), axis=1)
        k = np.where(full[rows], trusted[rows].sum(axis=1), np.minimum(swaps, trusted[rows].sum(axis=1)))
        t_idx, e_idx = np.nonzero(~trusted[rows])
        owner = np.repeat(rows[t_idx], k[t_idx])
        e_idx = np.repeat(e_idx, k[t_idx])
        rank = np.arange(owner.size) - np.repeat(np.cumsum(k[t_idx]) - k[t_idx], k[t_idx])
        want = trusted[owner].copy()
        want[np.arange(owner.size), worst[owner, rank]] = False
        want[np.arange(owner.size), e_idx] = True
        B = _swap_count(trusted, rows, full, swaps)
        got_owner, got = np.empty(B, dtype=np.int64), np.empty((B, n), dtype=bool)
        _swap_sets(trusted, rows, full, swaps, worst.astype(np.int64), got_owner, got)
        np.testing.assert_array_equal(got_owner, owner)
        np.testing.assert_array_equal(got, want)


def _numpy_consistency_graph(reported, ranges, noise, k, tol):  # noqa: ANN001, ANN202
    """`pairwise.consistency_graph` as numpy computed it before its kernel (2026-12-05)."""
    T, n, _ = reported.shape
    diff = reported[:, :, None, :] - reported[:, None, :, :]
    dhat = np.sqrt(np.einsum("tijk,tijk->tij", diff, diff))
    u = diff / np.where(dhat > 0, dhat, 1.0)[..., None]
    fwd, back = ranges, np.swapaxes(ranges, 1, 2)
    both = ~np.isnan(fwd) & ~np.isnan(back)
    cnt = (~np.isnan(fwd)).astype(float) + (~np.isnan(back))
    with np.errstate(over="ignore"):
        dbar = np.where(cnt > 0, (np.nan_to_num(fwd) + np.nan_to_num(back)) / np.maximum(cnt, 1), np.nan)
    s_d2 = noise.range_sigma**2
    var = 2 * noise.los_variance(u) + s_d2 / np.maximum(cnt, 1)
    with np.errstate(invalid="ignore"):
        ok = np.abs(dhat - dbar) <= np.maximum(k * np.sqrt(var), tol)
        agree = np.abs(fwd - back) <= np.maximum(k * np.sqrt(2 * s_d2), tol)
    ok = np.where(cnt > 0, ok & np.where(both, agree, True), True)
    ok[:, np.arange(n), np.arange(n)] = False
    return ok


def test_consistency_graph_kernel_is_the_numpy_expression() -> None:
    """The compiled pairwise consistency graph is the numpy expression's, pair for pair:
    diagonal and correlated GNSS covariances, missing and infinite ranges, coincident and
    missing (nan) reports, with and without ``tol``."""
    from swarmraft.estimation.noise import NoiseModel
    from swarmraft.estimation.pairwise import consistency_graph

    rng = np.random.default_rng(1)
    pairs = 0
    for trial in range(400):
        n, T = int(rng.integers(2, 20)), int(rng.integers(1, 4))
        x = rng.uniform(-30, 30, (T, n, 3))
        rep = x + rng.normal(0, [1.5, 1.5, 3.0], (T, n, 3))
        rep[:, :2] += rng.normal(0, 10, (T, 2, 3))  # two spoofed
        if trial % 7 == 0:
            rep[:, 1] = rep[:, 0]
        if trial % 11 == 0:
            rep[:, -1] = np.nan
        d = np.linalg.norm(x[:, :, None] - x[:, None], axis=3) + rng.normal(0, 0.1, (T, n, n))
        d[rng.random((T, n, n)) < 0.3] = np.nan
        if trial % 13 == 0:
            d[rng.random((T, n, n)) < 0.05] = np.inf
        a = rng.normal(size=(3, 3))
        cov = np.diag([2.25, 2.25, 9.0]) if trial % 2 else a @ a.T + 0.1 * np.eye(3)
        noise = NoiseModel(cov, float(rng.choice([0.05, 0.1, 1.0])))
        k, tol = float(rng.choice([3.0, 5.0])), float(rng.choice([0.0, 0.5]))
        if trial % 3 == 0:  # every measured range on the edge of its test: the last bits decide
            diff = rep[:, :, None] - rep[:, None]
            dh = np.sqrt(np.einsum("tijk,tijk->tij", diff, diff))
            u = diff / np.where(dh > 0, dh, 1.0)[..., None]
            edge = k * np.sqrt(2 * noise.los_variance(u) + noise.range_sigma**2)
            d = np.where(np.isnan(d), np.nan, dh + rng.choice([-1.0, 1.0], dh.shape) * edge)
            d = np.where(np.isnan(np.swapaxes(d, 1, 2)), d, np.nan)  # one way only
        np.testing.assert_array_equal(
            consistency_graph(rep, d, noise, k, tol), _numpy_consistency_graph(rep, d, noise, k, tol)
        )
        pairs += T * n * n
    assert pairs > 50_000

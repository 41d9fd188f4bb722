"""Cramér-Rao bounds against Monte Carlo of an efficient estimator on easy geometry."""

import numpy as np
import pytest

from swarmraft.estimation.bounds import (
    CHI2_3DOF_999,
    anchor_crb,
    error_statistics,
    gnss_covariance,
    swarm_crb,
    swarm_information,
)
from swarmraft.estimation.joint import joint_estimate
from swarmraft.estimation.trust_region import solve_ranges

AXES = np.array([[50, 0, 0], [-50, 0, 0], [0, 50, 0], [0, -50, 0], [0, 0, 50], [0, 0, -50.0]])


def test_anchor_bound_closed_form():
    C = anchor_crb(np.zeros((1, 3)), AXES[None], 0.1)[0]
    np.testing.assert_allclose(C, np.eye(3) * 0.1**2 / 2)  # sum u u^T = 2 I


def test_anchor_bound_matches_monte_carlo_known_anchors():
    rng = np.random.default_rng(1)
    B, sigma = 4000, 0.2
    x = np.array([5.0, -3.0, 2.0])
    d = np.linalg.norm(x - AXES, axis=1) + rng.normal(0, sigma, (B, 6))
    est = solve_ranges(
        np.broadcast_to(AXES, (B, 6, 3)), d, np.ones((B, 6), bool), np.broadcast_to(x, (B, 3)), loss="linear"
    ).x
    emp = np.cov((est - x).T)
    C = anchor_crb(x[None], AXES[None], sigma)[0]
    np.testing.assert_allclose(np.trace(emp), np.trace(C), rtol=0.06)


def test_anchor_bound_with_uncertain_anchors_matches_monte_carlo():
    rng = np.random.default_rng(2)
    B, sigma = 4000, 0.1
    S = gnss_covariance(1.0, 2.0)
    x = np.zeros(3)
    anchors_true = AXES * 2
    d = np.linalg.norm(x - anchors_true, axis=1) + rng.normal(0, sigma, (B, 6))
    reported = anchors_true + rng.multivariate_normal(np.zeros(3), S, (B, 6))
    est = solve_ranges(reported, d, np.ones((B, 6), bool), np.zeros((B, 3)), loss="linear").x
    C = anchor_crb(x[None], anchors_true[None], sigma, anchor_cov=S)[0]
    assert np.mean(np.sum(est**2, axis=1)) == pytest.approx(np.trace(C), rel=0.08)


def test_anchor_bound_prior_and_degenerate_geometry():
    two = anchor_crb(np.zeros((1, 3)), AXES[None, :2], 0.1)  # one direction only
    assert np.isinf(two).all()
    with_prior = anchor_crb(np.zeros((1, 3)), AXES[None, :2], 0.1, prior_cov=np.eye(3))
    assert np.isfinite(with_prior).all() and with_prior[0, 1, 1] == pytest.approx(1.0)


def test_swarm_bound_without_ranges_is_the_gnss_covariance():
    truth = np.random.default_rng(3).uniform(0, 100, (2, 5, 3))
    S = gnss_covariance(1.5, 3.0)
    C = swarm_crb(truth, np.ones((2, 5), bool), np.zeros((2, 5, 5), bool), S, 0.1)
    np.testing.assert_allclose(C, np.broadcast_to(S, C.shape), atol=1e-12)


def test_swarm_bound_matches_monte_carlo_of_the_joint_estimator():
    rng = np.random.default_rng(4)
    T, n = 3000, 6
    S, sigma = gnss_covariance(1.5, 3.0), 0.1
    truth = np.broadcast_to(rng.uniform(0, 60, (1, n, 3)), (T, n, 3)).copy()
    trusted = np.ones((T, n), bool)
    trusted[:, 0] = False  # drone 0 is "faulty": its GNSS is not used
    reported = truth + rng.multivariate_normal(np.zeros(3), S, (T, n))
    d = np.linalg.norm(truth[:, :, None] - truth[:, None], axis=3) + rng.normal(0, sigma, (T, n, n))
    x = joint_estimate(reported, d, trusted, S, sigma)
    C = swarm_crb(truth, trusted, np.ones((T, n, n), bool), S, sigma)
    sq, nees = error_statistics(x - truth, C)
    tr = np.trace(C, axis1=2, axis2=3)
    for i in range(n):
        assert sq[:, i].mean() == pytest.approx(tr[0, i], rel=0.08)
    assert nees.mean() == pytest.approx(3.0, rel=0.05)
    assert np.mean(nees > CHI2_3DOF_999) < 0.004
    # ranges make the honest drones better than their own GNSS
    assert (tr[0, 1:] < np.trace(S)).all()


def test_swarm_bound_where_ranges_dominate_matches_monte_carlo():
    """Where the ranges decide (ranges 0.5 m each direction under GNSS of 1.5/3 m, drones up to
    200 m apart): the distance from an untrusted drone to its neighbour is fixed by the ranges,
    its variance about sigma^2 (the neighbour's range to it: the estimator does not use the
    untrusted drone's own ranges, so neither does this bound) against at least 2 x 1.5^2 m^2
    from GNSS. The bound's variance of it (from the full inverse information, cross terms
    included) matches a Monte Carlo of the joint estimator within 10 % (seeds 11-15: within
    3.2 %; over 60 m instead of 200 the distance's curvature under the GNSS-fixed rotation
    added 5-25 %). The test above uses 0.1 m ranges under metres of GNSS, where a wrong range
    term in the bound (its noise tripled, say) changes little; here it is 8x."""
    rng = np.random.default_rng(11)
    T, n = 3000, 6
    S, sigma = gnss_covariance(1.5, 3.0), 0.5
    truth = np.broadcast_to(rng.uniform(0, 200, (1, n, 3)), (T, n, 3)).copy()
    trusted = np.ones((T, n), bool)
    trusted[:, 0] = False
    reported = truth + rng.multivariate_normal(np.zeros(3), S, (T, n))
    d = np.linalg.norm(truth[:, :, None] - truth[:, None], axis=3) + rng.normal(0, sigma, (T, n, n))
    x = joint_estimate(reported, d, trusted, S, sigma)
    used = ~np.eye(n, dtype=bool)[None]
    used[:, 0, :] = False  # the untrusted drone's own ranges
    J = swarm_information(truth[:1], trusted[:1], used, S, sigma)[0]
    u = (truth[0, 0] - truth[0, 1]) / np.linalg.norm(truth[0, 0] - truth[0, 1])
    w = np.zeros(3 * n)
    w[0:3], w[3:6] = u, -u  # to first order, the distance |x0 - x1|
    bound = w @ np.linalg.solve(J, w)
    err = np.linalg.norm(x[:, 0] - x[:, 1], axis=1) - np.linalg.norm(truth[:, 0] - truth[:, 1], axis=1)
    assert bound < 0.1 * 2 * 1.5**2  # the ranges, not GNSS, fix it
    assert np.mean(err**2) == pytest.approx(bound, rel=0.10)


def test_swarm_bound_in_chunks_is_the_bound_in_one_piece(monkeypatch):
    # memory is bounded by building the information a few problems at a time; a chunk that
    # slices one argument wrongly (per-problem INS priors) or misplaces its result shows here
    from swarmraft.estimation import bounds

    rng = np.random.default_rng(3)
    T, n = 7, 6
    truth = rng.uniform(-30, 30, (T, n, 3))
    trusted = rng.random((T, n)) < 0.7
    measured = rng.random((T, n, n)) < 0.8
    ins = np.eye(3) * rng.uniform(1, 9, (T, n, 1, 1))
    G = gnss_covariance(1.5, 3.0)
    whole = swarm_crb(truth, trusted, measured, G, 0.1, ins_cov=ins, common_cov=np.eye(3))
    monkeypatch.setattr(bounds, "CHUNK_BYTES", 1)  # one problem per chunk
    parts = swarm_crb(truth, trusted, measured, G, 0.1, ins_cov=ins, common_cov=np.eye(3))
    assert np.array_equal(whole, parts)
    assert np.isfinite(whole).all() and len({float(c[0, 0, 0]) for c in whole}) == T


def _svd_rule(J):
    """The singularity rule stated plainly: inverse where the 2-norm condition number (SVD)
    is below MAX_CONDITION and the matrix is finite, inf elsewhere."""
    from swarmraft.estimation.bounds import MAX_CONDITION

    out = np.full_like(J, np.inf)
    for k, A in enumerate(J):
        if np.isfinite(A).all() and np.linalg.cond(A) < MAX_CONDITION:
            out[k] = np.linalg.inv(A)
    return out


def test_singular_information_is_decided_by_the_condition_number_as_the_svd_decides_it():
    # `_safe_inv` decides most matrices from the 1-norm condition number of the inverse it
    # computes anyway, the SVD only in the band where that cannot decide: well conditioned,
    # in the band on both sides of the limit, far beyond it, exactly singular, not finite
    from swarmraft.estimation.bounds import MAX_CONDITION, _safe_inv

    rng = np.random.default_rng(5)
    N = 12
    mats = []
    for cond in (
        10.0,
        1e6,
        MAX_CONDITION / 30,
        MAX_CONDITION / 2,
        MAX_CONDITION * 2,
        MAX_CONDITION * 30,
        1e15,
    ):
        Q, _ = np.linalg.qr(rng.normal(size=(N, N)))
        s = np.geomspace(1.0, 1.0 / cond, N)
        mats.append((Q * s) @ Q.T)
    mats.append(np.diag([1.0] * (N - 1) + [0.0]))  # exactly singular: LAPACK refuses the batch
    bad = np.eye(N)
    bad[0, 1] = np.nan
    mats.append(bad)
    J = np.array(mats)
    expected = _svd_rule(J)
    got = _safe_inv(J)
    assert np.array_equal(np.isinf(got), np.isinf(expected))
    assert np.array_equal(got, expected)  # the same inverse, bit for bit, where there is one
    assert [bool(np.isfinite(g).all()) for g in got] == [
        True,
        True,
        True,
        True,
        False,
        False,
        False,
        False,
        False,
    ]
    # without the singular members the batch inverts at once and decides by the norms
    assert np.array_equal(_safe_inv(J[:7]), expected[:7])


def _numpy_range_information(truth, measured, range_sigma, symmetric, J):  # noqa: ANN001, ANN202
    """The ranges' part of `swarm_information` as numpy computed it before its kernel."""
    T, n, _ = truth.shape
    idx = np.arange(n)
    d = truth[:, :, None, :] - truth[:, None, :, :]
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    u = d / np.where(norm > 0, norm, 1.0)
    m = np.asarray(measured, bool) & ~np.eye(n, dtype=bool)
    mt = np.swapaxes(m, 1, 2)
    cnt = ((m | mt).astype(float) if symmetric else m.astype(float) + mt.astype(float)) / range_sigma**2
    uu = np.einsum("tij,tijk,tijl->tijkl", cnt, u, u)
    J -= uu.transpose(0, 1, 3, 2, 4) * 1.0
    J[:, idx, :, idx, :] += uu.sum(axis=2).transpose(1, 0, 2, 3)
    return J.reshape(T, 3 * n, 3 * n)


def test_swarm_information_kernel_is_the_numpy_expression():
    """`swarm_information`'s range terms, compiled, are the numpy expression's bit for bit
    (signs of zeros too): coincident drones, a drone at nan, one or two measurements per
    pair, with and without the GNSS, common-error and INS parts before them."""
    from swarmraft.estimation.bounds import swarm_information

    rng = np.random.default_rng(3)
    for trial in range(120):
        T, n = int(rng.integers(1, 4)), int(rng.integers(1, 25))
        x = rng.uniform(-50, 50, (T, n, 3))
        if trial % 5 == 0 and n > 1:
            x[:, 1] = x[:, 0]
        if trial % 7 == 0:
            x[:, -1] = np.nan
        tr = rng.random((T, n)) < 0.7
        meas = rng.random((T, n, n)) < 0.6
        cov = np.diag([2.25, 2.25, 9.0])
        sym = bool(trial % 2)
        kw = {"common_cov": np.diag([1.0, 1.0, 4.0])} if trial % 3 == 0 else {}
        got = swarm_information(x, tr, meas, cov, 0.1, symmetric=sym, **kw)
        # the numpy reference on the same GNSS/common part: the kernel's input is that part
        base = swarm_information(x, tr, np.zeros_like(meas), cov, 0.1, symmetric=sym, **kw)
        want = _numpy_range_information(x, meas, 0.1, sym, base.reshape(T, n, 3, n, 3).copy())
        np.testing.assert_array_equal(got, want)
        assert np.array_equal(np.signbit(got), np.signbit(want))

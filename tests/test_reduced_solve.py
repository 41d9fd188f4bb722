"""The reduced solve of the Levenberg-Marquardt kernel (free drones eliminated, the rest by
Cholesky) takes the step LAPACK's LU takes, up to rounding: on well-posed problems (every
untrusted drone ranged by enough trusted drones in general position) both end at the same
minimum, and a problem without free drones is solved by LU bit for bit either way."""

from __future__ import annotations

import numpy as np
import pytest

from swarmraft.estimation.joint import _free_drones, joint_estimate, weighted_gauss_newton
from swarmraft.estimation.trust_region import linear_multilateration

COV = np.diag([2.25, 2.25, 9.0])


def problems(seed: int, count: int = 30):
    """Random swarms of 6-17 drones in a 100 m cube, ranges with 0.1 m noise (some missing),
    about a third untrusted and spoofed by up to 60 m, optional priors for the untrusted."""
    rng = np.random.default_rng(seed)
    for k in range(count):
        T, n = int(rng.integers(1, 4)), int(rng.integers(6, 18))
        x = rng.uniform(0, 100, (T, n, 3))
        d = np.linalg.norm(x[:, :, None] - x[:, None], axis=3) + rng.normal(0, 0.1, (T, n, n))
        d[rng.random((T, n, n)) < 0.1] = np.nan
        rep = x + rng.normal(0, 1.5, x.shape)
        trusted = rng.random((T, n)) > 0.35
        trusted[:, :5] = True  # enough anchors for every untrusted drone
        rep[~trusted] += rng.uniform(-60, 60, ((~trusted).sum(), 3))
        prior = None
        if k % 2:
            prior = np.where(trusted[..., None], np.nan, x + rng.normal(0, 2, x.shape))
        yield rep, d, trusted, prior


@pytest.mark.parametrize("seed", [3, 4])
def test_reduced_solve_reaches_the_lu_minimum(seed: int) -> None:
    for rep, d, trusted, prior in problems(seed):
        kw = {"iters": 30, "prior": prior, "prior_sigma": None if prior is None else 2.0}
        lu = joint_estimate(rep, d, trusted, COV, 0.1, **kw)
        fast = joint_estimate(rep, d, trusted, COV, 0.1, reduced=True, **kw)
        np.testing.assert_allclose(fast, lu, rtol=0, atol=1e-6)


def test_free_drones_are_those_without_own_measurements() -> None:
    rng = np.random.default_rng(1)
    n = 7
    d = rng.uniform(1, 50, (n, n))
    d[2, 5] = np.nan  # drone 2's only weighted range is not measured
    gw = np.array([1.0, 0.0, 0.0, 0.0, 0.5, 0.0, 0.0])
    rw = np.zeros((n, n))
    rw[0] = 1.0
    rw[3, 1] = 0.2  # drone 3 measures a range: not free
    rw[2, 5] = 1.0
    free = np.zeros(n, dtype=np.bool_)
    assert _free_drones(d, gw, rw, free) == 4
    np.testing.assert_array_equal(free, [False, True, True, False, False, True, True])


def test_without_free_drones_reduced_is_lu_bit_for_bit() -> None:
    """Every drone with its own GNSS weight (as in the robust GNC solves): nothing to
    eliminate, so the reduced option changes nothing."""
    for rep, d, _, _ in problems(5, count=10):
        T, n, _ = rep.shape
        meas = (~np.isnan(d) & ~np.eye(n, dtype=bool)).astype(float)
        args = (rep, rep, d, np.ones((T, n)), meas, COV, 0.1, 10)
        np.testing.assert_array_equal(
            weighted_gauss_newton(*args, reduced=True), weighted_gauss_newton(*args)
        )


def test_fast_multilateration_is_the_pinv_solution() -> None:
    """Well-spread anchors: Cholesky's answer within rounding of pinv's; 3 anchors (singular
    normal equations) and coplanar ones: pinv's minimum-norm answer, bit for bit."""
    rng = np.random.default_rng(2)
    B, M = 200, 9
    anchors = rng.uniform(0, 100, (B, M, 3))
    anchors[:50, :, 2] = 7.0  # coplanar: the normal equations are singular
    target = rng.uniform(0, 100, (B, 3))
    dists = np.linalg.norm(anchors - target[:, None], axis=2) + rng.normal(0, 0.1, (B, M))
    mask = rng.random((B, M)) < 0.8
    mask[50:60] = False
    mask[50:60, :3] = True  # 3 anchors
    exact = linear_multilateration(anchors, dists, mask)
    fast = linear_multilateration(anchors, dists, mask, fast=True)
    np.testing.assert_array_equal(fast[:60], exact[:60])
    np.testing.assert_allclose(fast[60:], exact[60:], rtol=1e-9, atol=1e-9)
    assert not np.array_equal(fast[60:], exact[60:])  # the Cholesky path was taken


def test_the_robust_estimate_reports_the_full_solvers_minimum_though_its_starts_are_reduced():
    """`robust.robust_estimate` solves its starts by the reduced solve and the winner again by
    LU: the estimate it reports must be one the full solver returned. Once, the winner's full
    re-solve moved its cost in the last bits and handed the lead to a start that held the
    reduced solver's result (n = 13, 5 untrusted, trial 46 of this draw), which was reported.
    Every trial's estimate is checked against the rows the full solver returned."""
    import swarmraft.estimation.robust as robust
    from swarmraft.estimation.noise import NoiseModel

    rng = np.random.default_rng(1)
    T, n = 100, 13
    truth = rng.uniform(0, 100, (T, n, 3))
    reported = truth + rng.normal(0, 1.5, truth.shape)
    d = np.linalg.norm(truth[:, :, None] - truth[:, None], axis=3)
    ranges = d + rng.normal(0, 0.1, d.shape)
    np.einsum("tii->ti", ranges)[:] = np.nan
    trusted = np.ones((T, n), bool)
    trusted[:, :5] = False
    reported[:, :5] += rng.normal(0, 40, (T, 5, 3))
    noise = NoiseModel(gnss_cov=np.diag([1.5**2, 1.5**2, 3.0**2]), range_sigma=0.1)
    full_rows: set[bytes] = set()
    real = robust.weighted_gauss_newton

    def recording(*args, **kw):
        out = real(*args, **kw)
        if not kw.get("reduced"):
            full_rows.update(np.ascontiguousarray(x).tobytes() for x in out[0])
        return out

    robust.weighted_gauss_newton = recording
    try:
        est = robust.robust_estimate(reported, ranges, trusted, noise)
    finally:
        robust.weighted_gauss_newton = real
    missing = [k for k in range(T) if np.ascontiguousarray(est.x[k]).tobytes() not in full_rows]
    assert missing == []

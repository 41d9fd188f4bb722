"""The envelope Cholesky that solves Levenberg-Marquardt steps on a sparse range graph:
the ordering's envelope holds every coupling, the factor solves the system LU solves, a
matrix that is not positive definite is refused, and a joint fit of a sparse swarm lands
where the dense solver lands."""

from __future__ import annotations

import numpy as np

from swarmraft.estimation.envelope import (
    SPARSE_SHARE,
    coupling_order,
    envelope_cholesky,
    envelope_solve,
    range_share,
)
from swarmraft.estimation.joint import _ranged_pairs, weighted_gauss_newton


def _grid_swarm(rng, n=40, spacing=30.0, max_range=60.0):
    """Drones on a jittered grid two layers deep, ranging only those within max_range."""
    side = int(np.ceil(np.sqrt(n / 2)))
    cells = np.array([(i, j, k) for k in range(2) for i in range(side) for j in range(side)])[:n]
    x = cells * spacing + rng.normal(0, 2.0, (n, 3))
    d = np.linalg.norm(x[:, None] - x[None], axis=2)
    ranges = np.where(d <= max_range, d + rng.normal(0, 0.1, (n, n)), np.nan)
    np.fill_diagonal(ranges, np.nan)
    return x, ranges


def _order(ranges, weights):
    n = ranges.shape[0]
    pi, pj = np.zeros(n * n, dtype=np.int64), np.zeros(n * n, dtype=np.int64)
    E = _ranged_pairs(ranges, weights, pi, pj)
    order, pos, first = (np.zeros(n, dtype=np.int64) for _ in range(3))
    coupling_order(n, pi, pj, E, order, pos, first)
    return range_share(ranges), order, pos, first


def _coupled_matrix(rng, ranges, weights):
    """A symmetric positive definite 3n x 3n matrix with a 3x3 block wherever two drones
    are coupled by a weighted range (either direction)."""
    n = ranges.shape[0]
    A = np.zeros((3 * n, 3 * n))
    link = (~np.isnan(ranges) & (weights > 0)) | (~np.isnan(ranges) & (weights > 0)).T
    for i, j in zip(*np.nonzero(np.tril(link, -1)), strict=True):
        B = rng.normal(size=(3, 3))
        A[3 * i : 3 * i + 3, 3 * j : 3 * j + 3] = B
        A[3 * j : 3 * j + 3, 3 * i : 3 * i + 3] = B.T
    return A + np.eye(3 * n) * (np.abs(A).sum(axis=1).max() + 1.0)


def test_order_is_a_permutation_whose_envelope_holds_every_coupling():
    rng = np.random.default_rng(1)
    _, ranges = _grid_swarm(rng)
    n = ranges.shape[0]
    weights = np.ones((n, n))
    weights[3, :] = 0.0  # drone 3's own ranges unweighted: coupled only by what others measured
    share, order, pos, first = _order(ranges, weights)
    assert sorted(order) == list(range(n))
    assert (pos[order] == np.arange(n)).all()
    link = (~np.isnan(ranges) & (weights > 0)) | (~np.isnan(ranges) & (weights > 0)).T
    for i, j in zip(*np.nonzero(link), strict=True):
        lo, hi = sorted((pos[i], pos[j]))
        assert first[hi] <= lo  # the coupling lies inside the later drone's envelope
    assert (first <= np.arange(n)).all()
    measured = ~np.isnan(ranges) | ~np.isnan(ranges).T
    assert share == measured[np.tril_indices(n, -1)].mean()
    assert share <= SPARSE_SHARE
    # the reverse Cuthill-McKee order keeps the envelope narrow: a 40-drone grid couples each
    # drone within two cells, so no drone reaches back more than half the swarm
    assert (np.arange(n) - first).max() < n // 2


def test_drones_without_a_range_do_not_make_a_swarm_sparse():
    # six drones ranging each other and six outside the swarm (no range at all: not joined
    # yet, or left): the graph of those that range is complete, so LU keeps solving it
    rng = np.random.default_rng(5)
    _, ranges = _grid_swarm(rng, n=12, max_range=1e6)
    ranges[6:, :] = np.nan
    ranges[:, 6:] = np.nan
    share, *_ = _order(ranges, np.ones((12, 12)))
    assert share == 1.0
    ranges[0, 1] = ranges[1, 0] = np.nan
    share, *_ = _order(ranges, np.ones((12, 12)))
    assert share == 14 / 15


def test_envelope_solve_matches_lu():
    rng = np.random.default_rng(2)
    for n in (1, 5, 40):
        _, ranges = _grid_swarm(rng, n=n)
        weights = np.ones((n, n))
        _, order, _, first = _order(ranges, weights)
        A = _coupled_matrix(rng, ranges, weights)
        perm = (3 * order[:, None] + np.arange(3)).ravel()
        Ap = A[np.ix_(perm, perm)]
        b = rng.normal(size=3 * n)
        L = np.tril(Ap)
        L[np.triu_indices(3 * n, 1)] = np.nan  # never read: above the diagonal,
        for p in range(3 * n):
            L[p, : 3 * first[p // 3]] = np.nan  # and left of the envelope
        worst = envelope_cholesky(L, first, n)
        y = b.copy()
        envelope_solve(L, first, n, y)
        assert 0 < worst <= 1
        np.testing.assert_allclose(y, np.linalg.solve(Ap, b), rtol=1e-10, atol=1e-12)


def test_a_matrix_that_is_not_positive_definite_is_refused():
    rng = np.random.default_rng(3)
    _, ranges = _grid_swarm(rng, n=12)
    weights = np.ones((12, 12))
    _, order, _, first = _order(ranges, weights)
    A = _coupled_matrix(rng, ranges, weights)
    A[20, 20] = -1.0
    perm = (3 * order[:, None] + np.arange(3)).ravel()
    assert envelope_cholesky(np.tril(A[np.ix_(perm, perm)]), first, 12) == 0.0


def test_sparse_joint_fit_lands_where_the_dense_solver_lands():
    # the same cost twice: ranges beyond max_range nan (the envelope path), or present but
    # with weight 0 (a complete graph as data: LU), from the same start
    rng = np.random.default_rng(4)
    x, ranges = _grid_swarm(rng, n=40)
    n = x.shape[0]
    reported = x + rng.normal(0, [1.5, 1.5, 3.0], (n, 3))
    reported[:6] += 40.0  # six drones untrusted, placed by the ranges alone
    gnss_w = np.ones(n)
    gnss_w[:6] = 0.0
    d = np.linalg.norm(x[:, None] - x[None], axis=2)
    complete = np.where(np.isnan(ranges), d, ranges)
    np.fill_diagonal(complete, np.nan)
    cov = np.diag([1.5**2, 1.5**2, 3.0**2])
    start = (x + rng.normal(0, 3.0, (n, 3)))[None]
    sparse_fit, cost_s, conv_s = weighted_gauss_newton(
        start, reported[None], ranges[None], gnss_w[None], np.ones((1, n, n)), cov, 0.1, full=True
    )
    dense_fit, cost_d, conv_d = weighted_gauss_newton(
        start,
        reported[None],
        complete[None],
        gnss_w[None],
        (~np.isnan(ranges)).astype(float)[None],
        cov,
        0.1,
        full=True,
    )
    assert conv_s.all() and conv_d.all()
    np.testing.assert_allclose(sparse_fit, dense_fit, atol=1e-6)
    np.testing.assert_allclose(cost_s, cost_d, rtol=1e-9)
    # placed by the ranges (to the swarm's GNSS-level accuracy), not at their reports 40 m off
    assert np.abs(sparse_fit[0, :6] - x[:6]).max() < 5.0

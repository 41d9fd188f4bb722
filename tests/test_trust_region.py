"""The batched solver follows SciPy's least_squares(method="trf") iterate for iterate."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from swarmraft.estimation.trust_region import linear_multilateration, solve_ranges


def _problems(rng, B, M, spread=30.0):
    anchors = rng.uniform(0, 100, (B, M, 3))
    truth = rng.uniform(0, 100, (B, 3))
    d = np.linalg.norm(anchors - truth[:, None], axis=2)
    x0 = truth + rng.uniform(-spread, spread, (B, 3))
    return anchors, d, np.ones((B, M), bool), x0, truth


@pytest.mark.parametrize("M", [2, 3, 4, 9, 16])
@pytest.mark.parametrize("loss", ["soft_l1", "linear", "huber", "cauchy"])
def test_matches_scipy_least_squares(rng, M, loss):
    anchors, d, mask, x0, _ = _problems(rng, 40, M)
    noisy = d + rng.normal(0, 0.5, d.shape)
    sol = solve_ranges(anchors, noisy, mask, x0, loss=loss, f_scale=5.0)
    same_path = 0
    for b in range(len(x0)):

        def fun(p, b=b):
            return np.linalg.norm(p - anchors[b], axis=1) - noisy[b]

        def jac(p, b=b):
            return (p - anchors[b]) / np.linalg.norm(p - anchors[b], axis=1)[:, None]

        ref = least_squares(fun, x0[b], jac=jac, loss=loss, f_scale=5.0)
        np.testing.assert_allclose(sol.x[b], ref.x, atol=1e-6)
        same_path += int(sol.nfev[b] == ref.nfev and sol.status[b] == ref.status)
    # Rounding (einsum against dot) can change the last accepted step near a flat minimum.
    assert same_path >= 0.9 * len(x0)


def test_padding_rows_change_nothing(rng):
    anchors, d, mask, x0, _ = _problems(rng, 30, 5)
    full = solve_ranges(anchors, d, mask, x0)
    padded = solve_ranges(
        np.concatenate([anchors, rng.uniform(0, 100, (30, 4, 3))], axis=1),
        np.concatenate([d, rng.uniform(0, 100, (30, 4))], axis=1),
        np.concatenate([mask, np.zeros((30, 4), bool)], axis=1),
        x0,
    )
    np.testing.assert_array_equal(full.x, padded.x)


def test_linear_multilateration_is_exact_without_noise(rng):
    anchors, d, mask, _, truth = _problems(rng, 50, 6)
    np.testing.assert_allclose(linear_multilateration(anchors, d, mask), truth, atol=1e-6)

"""The pairwise consistency test of two drones' reports against the ranges between them
(`clique`'s graph, and the seed triangles of the rigid registrations).

Two drones are consistent when the distance between their reports agrees with the range
between them within ``k`` sigma, where sigma combines both GNSS errors along the line of
sight and the range noise, and (when both directions are measured) their two ranges agree
within ``k`` sigma."""

from __future__ import annotations

import numpy as np

from swarmraft.estimation.noise import NoiseModel


def report_distances(reported: np.ndarray) -> np.ndarray:
    """||z_A - z_B|| for every pair of reports: (T, n, 3) -> (T, n, n)."""
    diff = reported[:, :, None, :] - reported[:, None, :, :]
    return np.sqrt(np.einsum("tijk,tijk->tij", diff, diff))


def consistency_graph(
    reported: np.ndarray, ranges: np.ndarray, noise: NoiseModel, k: float, tol: float = 0.0
) -> np.ndarray:
    """Adjacency (T, n, n) of the pairwise consistency graph."""
    T, n, _ = reported.shape
    dhat = report_distances(reported)
    diff = reported[:, :, None, :] - reported[:, None, :, :]
    u = diff / np.where(dhat > 0, dhat, 1.0)[..., None]
    fwd, back = ranges, np.swapaxes(ranges, 1, 2)
    both = ~np.isnan(fwd) & ~np.isnan(back)
    cnt = (~np.isnan(fwd)).astype(float) + (~np.isnan(back))
    dbar = np.where(cnt > 0, (np.nan_to_num(fwd) + np.nan_to_num(back)) / np.maximum(cnt, 1), np.nan)
    s_d2 = noise.range_sigma**2
    var = 2 * noise.los_variance(u) + s_d2 / np.maximum(cnt, 1)
    with np.errstate(invalid="ignore"):
        ok = np.abs(dhat - dbar) <= np.maximum(k * np.sqrt(var), tol)
        agree = np.abs(fwd - back) <= np.maximum(k * np.sqrt(2 * s_d2), tol)
    # a pair without a range (out of range, or a link the screening dropped) gives no
    # evidence against either drone: consistent
    ok = np.where(cnt > 0, ok & np.where(both, agree, True), True)
    ok[:, np.arange(n), np.arange(n)] = False
    return ok

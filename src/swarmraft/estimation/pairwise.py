"""The pairwise consistency test of two drones' reports against the ranges between them
(`clique`'s graph, and the seed triangles of the rigid registrations).

Two drones are consistent when the distance between their reports agrees with the range
between them within ``k`` sigma, where sigma combines both GNSS errors along the line of
sight and the range noise, and (when both directions are measured) their two ranges agree
within ``k`` sigma."""

from __future__ import annotations

import numpy as np
from numba import njit

from swarmraft.estimation.joint import pair_distance
from swarmraft.estimation.noise import NoiseModel


def report_distances(reported: np.ndarray) -> np.ndarray:
    """||z_A - z_B|| for every pair of reports: (T, n, 3) -> (T, n, n)."""
    diff = reported[:, :, None, :] - reported[:, None, :, :]
    return np.sqrt(np.einsum("tijk,tijk->tij", diff, diff))


def consistency_graph(
    reported: np.ndarray, ranges: np.ndarray, noise: NoiseModel, k: float, tol: float = 0.0
) -> np.ndarray:
    """Adjacency (T, n, n) of the pairwise consistency graph (one compiled pass,
    `_consistency_kernel`)."""
    reported = np.ascontiguousarray(reported, float)
    out = np.empty(reported.shape[:2] + reported.shape[1:2], dtype=bool)
    s_d2 = float(noise.range_sigma) ** 2
    _consistency_kernel(
        reported,
        np.ascontiguousarray(ranges, float),
        np.ascontiguousarray(noise.gnss_cov, float),
        s_d2,
        float(k),
        float(tol),
        out,
    )
    return out


@njit(cache=True)
def _consistency_kernel(reported, ranges, C, s_d2, k, tol, out):  # pragma: no cover - compiled
    """`consistency_graph` in place on out (T, n, n): for each ordered pair, the distance of
    the reports against the mean of the ranges measured between them (consistent where none
    is), within k sigma with sigma^2 = 2 u^T C u + s_d2 / (ranges measured) along the unit
    vector u between the reports; and the two ranges, where both are measured, within k
    sqrt(2 s_d2) of each other; never below ``tol``. The numpy expression it replaced gives
    the same graph, ranges on the edge of the test included (the distance summed in einsum's
    order, (d0^2 + d2^2) + d1^2: summed in index order, 3,613 edge ranges decided otherwise)."""
    T, n, _ = reported.shape
    agree_lim = max(k * np.sqrt(2 * s_d2), tol)
    for t in range(T):
        z = reported[t]
        r = ranges[t]
        for i in range(n):
            out[t, i, i] = False
            for j in range(n):
                if j == i:
                    continue
                f = r[i, j]
                b = r[j, i]
                mf = not np.isnan(f)
                mb = not np.isnan(b)
                if not (mf or mb):  # no range: no evidence against either drone
                    out[t, i, j] = True
                    continue
                cnt = (1.0 if mf else 0.0) + (1.0 if mb else 0.0)
                dbar = ((f if mf else 0.0) + (b if mb else 0.0)) / cnt
                dh = pair_distance(z, i, j)  # summed as einsum sums three squares
                den = dh if dh > 0 else 1.0
                u0 = (z[i, 0] - z[j, 0]) / den
                u1 = (z[i, 1] - z[j, 1]) / den
                u2 = (z[i, 2] - z[j, 2]) / den
                v = (
                    u0 * C[0, 0] * u0
                    + u0 * C[0, 1] * u1
                    + u0 * C[0, 2] * u2
                    + u1 * C[1, 0] * u0
                    + u1 * C[1, 1] * u1
                    + u1 * C[1, 2] * u2
                    + u2 * C[2, 0] * u0
                    + u2 * C[2, 1] * u1
                    + u2 * C[2, 2] * u2
                )
                ok = abs(dh - dbar) <= max(k * np.sqrt(2 * v + s_d2 / cnt), tol)
                if mf and mb:
                    ok = ok and abs(f - b) <= agree_lim
                out[t, i, j] = ok

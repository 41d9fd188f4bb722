"""The protection levels' Woodbury step on a sparse range graph: `integrity._without_each` as
it is (3 + n columns per hypothesis "drone j is faulty": its GNSS and a range to every drone,
most of them zero weight when j ranges only its neighbours) against the same identity with
each hypothesis' columns limited to the ranges drone j measured (3 + K, K its most measured
ranges), on the benchmark's world (realistic, 30 m grid, max range 60 m, f = n / 4, the
attackers left out of the trusted set). A measurement of a change proposed for
`estimation/integrity.py`, which this script does not change; it reads that module's private
helpers, so it follows them.

Run: .venv/bin/python benchmarks/sparse_woodbury.py [--n 65 129 256]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from swarmraft.estimation import integrity as I  # noqa: N812
from swarmraft.estimation.blas import one_blas_thread
from swarmraft.estimation.joint import joint_estimate
from swarmraft.estimation.noise import NoiseModel
from swarmraft.estimation.snapshot import SnapshotBatch
from swarmraft.experiments import build_config
from swarmraft.experiments.trials import draw


def compact(P0: np.ndarray, b: np.ndarray, t: I.Terms) -> tuple[np.ndarray, np.ndarray, int]:
    """`integrity._without_each` with hypothesis j's columns limited to the ranges drone j
    measured, padded with zero-weight columns to the largest count K: 3 + K columns instead of
    3 + n (a zero column adds an identity row to S_j and nothing to P_j)."""
    T, N, _ = P0.shape
    n = N // 3
    meas = t.w > 0  # (T, j, k)
    K = int(meas.sum(axis=2).max())
    order = np.argsort(~meas, axis=2, kind="stable")[..., :K]  # measured k first
    nb = order  # (T, j, K)
    ti = np.arange(T)[:, None, None]
    ji = np.arange(n)[None, :, None]
    w = t.w[ti, ji, nb]
    u = t.u[ti, ji, nb]  # (T, j, K), (T, j, K, 3)
    m = 3 + K
    Gh = np.linalg.cholesky(t.G)
    sw = np.sqrt(w)
    Pb = P0.reshape(T, N, n, 3).transpose(0, 2, 1, 3)  # (T, drone, N, 3)
    X = np.empty((T, n, N, m))
    X[..., :3] = (Pb @ Gh) * t.gnss[:, :, None, None]
    own = Pb @ np.swapaxes(u, -1, -2)  # (T, j, N, K)
    Pk = Pb[ti, nb]  # (T, j, K, N, 3)
    other = np.einsum("tjkNa,tjka->tjNk", Pk, u)
    X[..., 3:] = sw[:, :, None, :] * (own - other)
    Xr = X.reshape(T, n, n, 3, m)
    Xj = Xr[:, np.arange(n), np.arange(n)]  # (T, j, 3, m)
    Xk = Xr[ti, ji, nb]  # (T, j, K, 3, m): rows of drone k
    UtX = np.empty((T, n, m, m))
    UtX[:, :, :3] = (Gh.T @ Xj) * t.gnss[:, :, None, None]
    UtX[:, :, 3:] = sw[..., None] * (u @ Xj - (u[..., None] * Xk).sum(axis=-2))
    S = np.eye(m) - UtX
    S = 0.5 * (S + np.swapaxes(S, -1, -2))
    Z = np.linalg.solve(S, np.swapaxes(X, -1, -2))
    Zr = Z.reshape(T, n, m, n, 3).transpose(0, 1, 3, 2, 4)
    Cj = I._blocks(P0)[:, None] + Xr @ Zr
    bj = b[:, :, :, None]
    dj = (P0[:, None] @ bj)[..., 0] + (X @ (Z @ bj))[..., 0]
    return Cj, dj.reshape(T, n, n, 3), K


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[65, 129, 256])
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args()
    for n in args.n:
        f = n // 4
        config = build_config(
            "realistic",
            n=(n,),
            f=(f,),
            trials=1,
            ranging={"max_range": 60.0},
            geometry="formation",
            spacing=30.0,
        )
        d = draw(config, np.random.default_rng(21), 1, n, f)
        tr = ~d.attackers
        b = SnapshotBatch(d.reported, d.ranges, gnss_sigma=(1.5, 3.0), range_sigma=0.1)
        noise = NoiseModel.of(b, I.IntegrityParams(), "joint")
        x = joint_estimate(d.reported, d.ranges, tr, noise.gnss_cov, noise.range_sigma, iters=20)
        J, bb, terms = I._hypothesis_information(x, d.reported, d.ranges, tr, noise, np.ones((1, n), bool))
        P0 = I._inverse(J)
        ts, tc = [], []
        with one_blas_thread():  # as `verify_batch` runs every detector
            for _ in range(args.runs):
                t0 = time.perf_counter()
                C1, d1 = I._without_each(P0, bb, terms)
                ts.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                C2, d2, K = compact(P0, bb, terms)
                tc.append(time.perf_counter() - t0)
        live = tr[0]
        dc = np.abs(C1[0, live] - C2[0, live]).max() / np.abs(C1[0, live]).max()
        dd = np.abs(d1[0, live] - d2[0, live]).max() / max(np.abs(d1[0, live]).max(), 1e-12)
        print(
            f"n = {n}: as is {min(ts) * 1e3:.0f} ms (best of {args.runs}; 3 + n = {3 + n} columns per "
            f"hypothesis); limited to measured ranges {min(tc) * 1e3:.0f} ms (3 + {K} columns); "
            f"largest relative difference {max(dc, dd):.1e}",
            flush=True,
        )


if __name__ == "__main__":
    main()

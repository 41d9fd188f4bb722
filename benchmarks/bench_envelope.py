"""One damped Levenberg-Marquardt solve on a sparse range graph: the envelope Cholesky in
reverse Cuthill-McKee order (`swarmraft.estimation.envelope`, what the kernel uses where at
most half of the drone pairs are ranged) against LU on the dense 3n x 3n matrix (what it uses
elsewhere), on the formation of bench_sparse.py (30 m grid, two layers, no range beyond 60 m,
realistic preset), at the true positions. Prints per size the factor's mean reach (drones
back from the diagonal), each solver's best and median time per solve over ``--runs`` runs,
their ratio, and the largest difference between the two steps (they agree in exact
arithmetic).

No target of its own: the targets are the leader step's (bench_sparse.py).

Run: .venv/bin/python benchmarks/bench_envelope.py [--n 65 256] [--runs 7]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from numba import njit

from bench_sparse import formation_draw
from swarmraft.estimation import joint
from swarmraft.estimation.envelope import coupling_order, range_share
from swarmraft.estimation.noise import gnss_information

LAM, RIDGE = 1e-3, 1e-9  # a damping as the kernel's after a rejected step


@njit(cache=True)
def _envelope(k, Hp, g, order, first, L, rhs, step):  # pragma: no cover - compiled
    for _ in range(k):
        joint._envelope_step(Hp, g, LAM, RIDGE, order, first, L, rhs, step)


@njit(cache=True)
def _lu(k, H, g, step):  # pragma: no cover - compiled
    A = np.empty_like(H)
    for _ in range(k):
        for a in range(H.shape[0]):
            for b in range(H.shape[0]):
                A[a, b] = H[a, b]
            A[a, a] += LAM * H[a, a] + RIDGE
        step[:] = np.linalg.solve(A, -g)


def _timed(fn, args, k: int, runs: int) -> list[float]:
    fn(1, *args)  # compile
    out = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn(k, *args)
        out.append((time.perf_counter() - t0) / k * 1e6)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[65, 256])
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    if args.runs < 1:
        ap.error("--runs: need at least 1")
    if min(args.n) < 4:
        ap.error("--n: every size needs at least 4 drones (n // 4 of them attacked)")
    for n in args.n:
        _, d = formation_draw(n, n // 4, 1)
        x, rep, rng = d.truth[0], d.reported[0], d.ranges[0]
        gw, rw = np.ones(n), np.ones((n, n))
        G = gnss_information(np.diag([1.5**2, 1.5**2, 3.0**2]))
        no_prior = np.full((n, 3), np.nan)
        pi, pj = np.zeros(n * n, dtype=np.int64), np.zeros(n * n, dtype=np.int64)
        E = joint._ranged_pairs(rng, rw, pi, pj)
        order, pos, first = (np.zeros(n, dtype=np.int64) for _ in range(3))
        coupling_order(n, pi, pj, E, order, pos, first)
        share = range_share(rng)
        N = 3 * n
        Hp, H, L = np.zeros((N, N)), np.zeros((N, N)), np.zeros((N, N))
        g, rhs, s_env, s_lu = np.zeros(N), np.zeros(N), np.zeros(N), np.zeros(N)
        inv_s2 = 1.0 / 0.1**2
        joint._normal_equations(
            x, rep, rng, gw, rw, G, inv_s2, no_prior, 0.0, Hp, g, True, pos, first, pi, pj, E
        )
        own, none = np.arange(n), np.zeros(n, dtype=np.int64)
        joint._normal_equations(
            x, rep, rng, gw, rw, G, inv_s2, no_prior, 0.0, H, g, False, own, none, pi, pj, E
        )
        k = max(1, 20000 // n)
        env = _timed(_envelope, (Hp, g, order, first, L, rhs, s_env), k, args.runs)
        lu = _timed(_lu, (H, g, s_lu), max(1, k // 10), args.runs)
        reach = float(np.mean(np.arange(n) - first))
        print(
            f"n = {n}: {share:.0%} of the pairs ranged, the factor reaches back {reach:.1f} drones "
            f"on average; envelope best {min(env):.0f} us, median {statistics.median(env):.0f} us; "
            f"LU best {min(lu):.0f} us, median {statistics.median(lu):.0f} us; "
            f"LU / envelope {statistics.median(lu) / statistics.median(env):.1f}x (medians); "
            f"steps differ by at most {np.abs(s_env - s_lu).max():.1e} m"
        )


if __name__ == "__main__":
    main()

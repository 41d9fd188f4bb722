"""Benchmarks of the Raft core in the simulator (issue: Raft core and simulator).

Prints, against the stated targets:
  1. time from a leader crash to a new leader over many seeds, 5 nodes, 150-300 ms
     election timeouts (10 ms ticks, election_tick 15), 50 ms heartbeats, 1-3 ms one-way
     delay (target: median <= 300 ms, p99 <= 600 ms; the Raft paper measured about 290 ms
     median and 510 ms worst case);
  2. simulator speed: simulated seconds per wall second for 17 nodes under steady load
     (one 100-byte proposal every 100 ms, invariants checked after every event)
     (target: one simulated hour in at most 60 s, i.e. >= 60 simulated s per wall s);
  3. Raft messages per committed entry under one 100-byte proposal per ms, 5 and 17 nodes
     (counts, deterministic; target <= 3(n-1), the least being 2(n-1) when each entry travels
     alone: one append and one answer per follower).

Wall-clock measures print the best of 3 runs (the code's speed) and their median (the
machine's noise: on the shared 2-core machine it varies by up to 1.5x).

Run: .venv/bin/python benchmarks/bench_raft.py [--seeds 1000] [--sim-seconds 300] [--load-ms 2000]
"""

from __future__ import annotations

import argparse
import random
import statistics
import time

import numpy as np

from swarmraft.sim import Cluster


def election_time(seed: int) -> float:
    c = Cluster(5, seed=seed, tick_ms=10, election_tick=15, heartbeat_tick=5)
    c.run_until(lambda: c.leader() is not None, 5000)
    c.run(500 + random.Random(seed).uniform(0, 50))  # steady state, random heartbeat phase
    old = c.leader()
    c.crash(old)
    t0 = c.now
    if not c.run_until(lambda: c.leader() not in (None, old), 10_000):
        return float("inf")
    return c.now - t0


def sim_speed(sim_seconds: float, check: bool) -> float:
    c = Cluster(17, seed=1, check_invariants=check)
    c.run_until(lambda: c.leader() is not None, 5000)
    payload = bytes(100)
    t0 = time.perf_counter()
    end = c.now + sim_seconds * 1000
    while c.now < end:
        c.propose(payload)
        c.run(100)
    return sim_seconds / (time.perf_counter() - t0)


def messages_per_commit(n: int, load_ms: int, seed: int = 1) -> tuple[float, int]:
    """Raft messages sent per entry committed at the leader while one 100-byte proposal
    arrives every ms for ``load_ms`` (after the election has settled); and the commits."""
    c = Cluster(n, seed=seed, check_invariants=False)
    c.run_until(lambda: c.leader() is not None, 5000)
    c.run(500)
    lead = c.leader()
    sent0, commit0 = sum(c.sent.values()), c.status(lead).commit
    payload = bytes(100)
    for _ in range(load_ms):
        c.propose(payload)
        c.run(1)
    commits = c.status(lead).commit - commit0
    return (sum(c.sent.values()) - sent0) / max(commits, 1), commits


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=1000)
    ap.add_argument("--sim-seconds", type=float, default=300.0)
    ap.add_argument("--load-ms", type=int, default=2000)
    ap.add_argument("--only-messages", action="store_true", help="print item 3 only")
    args = ap.parse_args()

    for n in (5, 17):
        per, commits = messages_per_commit(n, args.load_ms)
        target = 3 * (n - 1)
        print(
            f"one proposal per ms for {args.load_ms} ms, {n} nodes: {per:.1f} Raft messages per commit "
            f"({commits} commits; least 2(n-1) = {2 * (n - 1)}); "
            f"target <= 3(n-1) = {target}: {'MET' if per <= target else 'NOT MET'}"
        )
    if args.only_messages:
        return

    times = np.array([election_time(s) for s in range(args.seeds)])
    med, p99 = statistics.median(times), float(np.quantile(times, 0.99))
    print(f"leader crash -> new leader, 5 nodes, {args.seeds} seeds:")
    print(
        f"  median {med:.0f} ms   p90 {np.quantile(times, 0.9):.0f} ms   p99 {p99:.0f} ms   "
        f"max {times.max():.0f} ms"
    )
    print(
        f"  target median <= 300 ms: {'MET' if med <= 300 else 'NOT MET'}; "
        f"p99 <= 600 ms: {'MET' if p99 <= 600 else 'NOT MET'}"
    )

    for check in (True, False):
        # This machine's speed drifts by up to 1.5x between minutes: best of 3 measures the
        # code, the median shows the spread.
        runs = sorted(sim_speed(args.sim_seconds, check) for _ in range(3))
        speed = runs[-1]
        label = "with" if check else "without"
        print(
            f"simulator, 17 nodes, one proposal per 100 ms, {label} invariant checks: best of 3 "
            f"{speed:.0f} simulated s per wall s (one hour in {3600 / speed:.0f} s), median {runs[1]:.0f}"
        )
        if check:
            print(f"  target >= 60 simulated s per wall s: {'MET' if speed >= 60 else 'NOT MET'}")


if __name__ == "__main__":
    main()

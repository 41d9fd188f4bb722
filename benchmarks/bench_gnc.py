"""Step time (wall clock and CPU) of the `joint` detector alone (one snapshot, as the leader
verifies it) and per trial in a batch (as a sweep chunk verifies them), n = 17, f = 8,
realistic preset (the snapshots of bench_detectors.py, seed 7).

Run it on two trees to compare two versions in one sitting, alternating, e.g. the code
before a change:
  git archive main src | tar -x -C /tmp/base
  for i in 1 2 3; do
    PYTHONPATH=/tmp/base/src .venv/bin/python benchmarks/bench_gnc.py
    PYTHONPATH=src .venv/bin/python benchmarks/bench_gnc.py
  done
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from swarmraft.estimation import Snapshot, SnapshotBatch, verify, verify_batch
from swarmraft.experiments import build_config
from swarmraft.experiments.trials import draw


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=60, help="snapshots verified one at a time")
    ap.add_argument("--batch", type=int, default=200, help="trials verified as one batch")
    args = ap.parse_args()
    T = max(args.steps, args.batch)
    config = build_config("realistic", n=(17,), f=(8,), trials=T)
    d = draw(config, np.random.default_rng(7), T, 17, 8)
    snaps = [
        Snapshot(reported=d.reported[t], ranges=d.ranges[t], gnss_sigma=(1.5, 3.0), range_sigma=0.1)
        for t in range(args.steps)
    ]
    for s in snaps[:5]:  # warm up (compiled kernels loaded)
        verify(s, "joint")
    times, cpu = [], []
    for s in snaps:
        t0, c0 = time.perf_counter(), time.process_time()
        verify(s, "joint")
        times.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    batch = SnapshotBatch(
        d.reported[: args.batch], d.ranges[: args.batch], gnss_sigma=(1.5, 3.0), range_sigma=0.1
    )
    t0, c0 = time.perf_counter(), time.process_time()
    verify_batch(batch, "joint")
    per_trial = (time.perf_counter() - t0) * 1e3 / args.batch
    cpu_trial = (time.process_time() - c0) * 1e3 / args.batch
    print(
        f"joint n=17 f=8: alone median {statistics.median(times):.2f} ms, best {min(times):.2f} ms "
        f"(CPU median {statistics.median(cpu):.2f}, best {min(cpu):.2f} ms; {args.steps} snapshots); "
        f"in a batch of {args.batch}: {per_trial:.2f} ms per trial (CPU {cpu_trial:.2f} ms)"
    )


if __name__ == "__main__":
    main()

"""A large swarm's 60 s mission, phase by phase: simulate, bounds (the end-of-mission
Cramér-Rao bound of every step), outputs (steps.csv, summary.json) and figures, with the
process's peak memory (issue: Raft for a living swarm).

Targets for 64 drones: the whole mission, outputs and figures included, within 2x real time
(120 s) and 400 MB peak. The mission: formation flight at 10 Hz, 3 drones spoofed by 40 m from
a sixth of the way in, the leader crashed half way, every safety invariant of Raft checked
after every event; a committee of ``--committee`` voters (5; 0: every drone votes), every
other drone a Raft learner.

One run per invocation (a run of 64 drones takes minutes); the machine's speed drifts by up
to 1.5x between minutes, so compare runs taken one after another.

Run: .venv/bin/python benchmarks/bench_scale.py [--drones 64] [--seconds 60] [--committee 5]
[--detector joint]
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path

from pydantic import ValidationError

from swarmraft.cli.missions import mission_figures
from swarmraft.estimation.registry import one_line
from swarmraft.experiments.mission import error_series, write_results
from swarmraft.sim.mission import run_mission
from swarmraft.sim.scenario import Scenario

TARGET_REAL_TIME = 2.0  # wall time / simulated time
TARGET_MB = 400.0


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drones", type=int, default=64)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--committee", type=int, default=5, help="voters (odd, <= 7); 0: every drone")
    ap.add_argument("--detector", default="joint")
    args = ap.parse_args()
    if args.drones < 17:
        ap.error("--drones: at least 17 (drones 3, 9 and 17 are spoofed)")
    try:
        sc = Scenario(
            name=f"scale-{args.drones}",
            drones=args.drones,
            duration_s=args.seconds,
            seed=1,
            spoof=[{"kind": "jump", "drones": [3, 9, 17], "start_s": args.seconds / 6, "magnitude": 40}],
            fault=[{"kind": "crash-leader", "at_s": args.seconds / 2}],
            protocol={"committee": args.committee, "detector": args.detector},
        )
    except ValidationError as exc:
        ap.error(one_line(exc, ""))
    run_mission(Scenario(drones=5, duration_s=0.5, seed=1))  # warm-up (numba, imports)
    phases: list[tuple[str, float, float]] = []

    def timed(name, fn, *a):  # noqa: ANN001, ANN202
        t0 = time.perf_counter()
        out = fn(*a)
        phases.append((name, time.perf_counter() - t0, peak_mb()))
        return out

    log = timed("simulate", run_mission, sc)
    timed("bounds", error_series, log)
    with tempfile.TemporaryDirectory() as tmp:
        result = timed("outputs", write_results, log, Path(tmp))
        timed("figures", mission_figures, result, Path(tmp))
    total = sum(p[1] for p in phases)
    fast = total <= TARGET_REAL_TIME * args.seconds
    voters = f"a committee of {args.committee}" if args.committee else "all voters"
    print(f"{args.seconds:g} s mission, {args.drones} drones ({voters}, {args.detector}):")
    for name, wall, mb in phases:
        print(f"  {name:9s} {wall:7.1f} s   peak so far {mb:6.0f} MB")
    print(
        f"  total     {total:7.1f} s = {total / args.seconds:.2f}x real time "
        f"(target <= {TARGET_REAL_TIME:g}x: {'MET' if fast else 'NOT MET'}); "
        f"peak {peak_mb():.0f} MB (target <= {TARGET_MB:g}: {'MET' if peak_mb() <= TARGET_MB else 'NOT MET'})"
    )
    sk = result.summary["skipped_causes"]
    print(
        f"  steps committed {int(log.committed.sum())}/{len(log.t)}, "
        f"skipped {int((~log.committed).sum())} ({sk['before_first_record']} before the first record, "
        f"{sk['after_fault']} after a fault, {sk['unexplained']} unexplained "
        f"{sk['unexplained_times_s']}), records identical on all nodes: "
        f"{result.summary['records_identical_on_all_nodes']}"
    )


if __name__ == "__main__":
    main()

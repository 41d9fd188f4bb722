"""A large swarm's 60 s mission, phase by phase: simulate, bounds (the end-of-mission
Cramér-Rao bound of every step), outputs (steps.csv, summary.json) and figures, with the
process's peak memory (issue: Raft for a living swarm).

Targets (issue: Raft for a living swarm): 64 drones, the whole mission, outputs and figures
included, within 2x real time (120 s) and 400 MB peak; 256 drones within 10x real time; at
every size records identical on every drone, no step skipped without a fault, and the crashed
voter replaced by a promoted learner within 2 s (read from the mission's events).

The mission: formation flight at 10 Hz, 3 drones spoofed by 40 m from a sixth of the way in,
the leader (a voter) crashed half way, every safety invariant of Raft checked after every
event; a committee of ``--committee`` voters (5; 0: every drone votes), every other drone a
Raft learner; ``--detector`` verifies each step (`joint`, the missions' default; `paper`, the
paper's vote, costs a few ms a step where `joint` costs seconds at 256 drones).

One run per invocation (a run of 64 drones takes minutes); the machine's speed drifts by up
to 1.5x between minutes, so compare runs taken one after another.

Run: .venv/bin/python benchmarks/bench_scale.py [--drones 64] [--seconds 60] [--committee 5]
[--detector joint]
"""

from __future__ import annotations

import argparse
import re
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

#: drones -> (wall time / simulated time, peak MB or None); other sizes have no stated target
TARGETS = {64: (2.0, 400.0), 256: (10.0, None)}
TARGET_REPLACE_S = 2.0  # a crashed voter's replacement: learner promoted, the voter removed


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB


def replacement(events: list[str]) -> str:
    """The crashed voter's replacement, from the mission's events ("30.0 s: leader 1 crashed",
    "31.2 s: committee: promote drone 6", "31.3 s: committee: remove drone 1"): how long after
    the crash a learner was promoted and the crashed voter removed, against the target."""
    crash = next((e for e in events if re.fullmatch(r"[\d.]+ s: leader \d+ crashed", e)), None)
    if crash is None:
        return "no voter crashed"
    t0, drone = float(crash.split()[0]), int(crash.split()[3])
    after = [(float(e.split()[0]), e) for e in events if float(e.split()[0]) >= t0]
    promoted = next(((t, e.split()[-1]) for t, e in after if "committee: promote" in e), None)
    removed = next((t for t, e in after if e.endswith(f"committee: remove drone {drone}")), None)
    if promoted is None or removed is None:
        return (
            f"voter {drone} crashed at {t0:g} s and was NOT replaced (target {TARGET_REPLACE_S:g} s: NOT MET)"
        )
    worst = max(promoted[0], removed) - t0
    met = "MET" if worst <= TARGET_REPLACE_S else "NOT MET"
    return (
        f"voter {drone} crashed at {t0:g} s: learner {promoted[1]} promoted after {promoted[0] - t0:.1f} s, "
        f"drone {drone} removed after {removed - t0:.1f} s (target {TARGET_REPLACE_S:g} s: {met})"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drones", type=int, default=64)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--committee", type=int, default=5, help="voters (odd, <= 7); 0: every drone")
    ap.add_argument("--detector", default="joint")
    args = ap.parse_args()
    if args.drones < 17:
        ap.error("--drones: at least 17 (drones 3, 9 and 17 are spoofed)")
    if not args.seconds > 0:
        ap.error(f"--seconds: must be > 0, got {args.seconds:g}")
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
    errors = timed("bounds", error_series, log)
    with tempfile.TemporaryDirectory() as tmp:  # the outputs from those bounds, as a mission writes them
        result = timed("outputs", write_results, log, Path(tmp), None, errors)
        timed("figures", mission_figures, result, Path(tmp))
    total = sum(p[1] for p in phases)
    target_x, target_mb = TARGETS.get(args.drones, (None, None))
    voters = f"a committee of {args.committee}" if args.committee else "all voters"
    print(f"{args.seconds:g} s mission, {args.drones} drones ({voters}, {args.detector}):")
    for name, wall, mb in phases:
        print(f"  {name:9s} {wall:7.1f} s   peak so far {mb:6.0f} MB")
    verdict = (
        "no target stated"
        if target_x is None
        else f"target <= {target_x:g}x: " + ("MET" if total <= target_x * args.seconds else "NOT MET")
    )
    memory = (
        ""
        if target_mb is None
        else f" (target <= {target_mb:g}: " + ("MET)" if peak_mb() <= target_mb else "NOT MET)")
    )
    print(
        f"  total     {total:7.1f} s = {total / args.seconds:.2f}x real time ({verdict}); "
        f"peak {peak_mb():.0f} MB{memory}"
    )
    print("  " + replacement(result.summary["events"]))
    per_step = result.summary["raft_messages_per_committed_step"]
    floor = result.summary["raft_minimum_per_step"]
    print(f"  Raft messages per committed step {per_step:.2f} (minimum {floor:g}, 1.5x that {1.5 * floor:g})")
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

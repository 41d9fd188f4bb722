"""Acceptance runs of the audit (issue 14, docs/audit.md).

``lying``: for each lying mode (move, clear, accuse, censor), missions of 9 and 17 drones on
seeds 1..10 (drone 3 spoofed by 30 m from 1 s; the leader compromised at 3 s; 8 s long): the
invariant (no honest drone applies a falsified record) is checked by the mission after every
apply, and per mission the script prints the time from the first falsified record (censor:
from the fault) to the first step led by another drone, and the skipped steps outside that
window; then a line per (mode, n) with the worst case against the targets (replaced within
1 s; censorship found within 2 s).

``honest``: every shipped scenario on seeds 1..10 (or ``--seeds``): entries refused and
censorship findings, both of which must be 0.

Run: .venv/bin/python benchmarks/accept_audit.py lying [--drones 9 17] [--seeds 1 .. 10] [--jobs 2]
     .venv/bin/python benchmarks/accept_audit.py honest [--seeds 1 .. 10] [--jobs 2]
"""

from __future__ import annotations

import argparse
import tomllib
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from swarmraft.sim.mission import run_mission
from swarmraft.sim.scenario import Scenario, shipped_scenarios

MODES = ("move", "clear", "accuse", "censor")
LIE_AT_S = 3.0


def lying(mode: str, n: int, seed: int) -> dict:
    sc = Scenario(
        name="lying",
        seed=seed,
        drones=n,
        duration_s=8.0,
        spoof=[{"kind": "jump", "drones": [3], "start_s": 1.0, "magnitude": 30.0}],
        fault=[
            {"kind": "lying-leader", "at_s": LIE_AT_S, "mode": mode, "drone": 3 if mode == "clear" else 5}
        ],
    )
    try:
        log = run_mission(sc)
    except AssertionError as exc:
        return {"mode": mode, "n": n, "seed": seed, "invariant": str(exc)}
    a = log.audit
    start = a["first_lie_s"] if mode != "censor" else LIE_AT_S
    out = {"mode": mode, "n": n, "seed": seed, "invariant": "held", "liar": a["liar"]}
    if start is None:  # nothing falsified (clear: the drone was never flagged)
        out.update(replaced_s=None, outside=0)
        return out
    later = np.flatnonzero((log.t >= start) & (log.leader != 0) & (log.leader != a["liar"]))
    end = float(log.t[later[0]]) if later.size else float("inf")
    skipped = log.t[~log.committed & (log.t > 1.0)]
    out["replaced_s"] = round(end - start, 2)
    out["outside"] = int(((skipped < start - 0.1) | (skipped > end)).sum())
    out["refused"] = a["refused_entries"]
    out["findings"] = a["censorship_findings"]
    out["found_s"] = None if a["first_finding_s"] is None else round(a["first_finding_s"] - start, 2)
    return out


def honest(name: str, seed: int) -> dict:
    data = tomllib.loads(shipped_scenarios()[name].read_text())
    data["seed"] = seed
    log = run_mission(Scenario(**data))
    counts = {k: log.audit[k] for k in ("refused_entries", "censorship_findings", "unchecked_priors")}
    return {"scenario": name, "seed": seed, **counts}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=["lying", "honest"])
    ap.add_argument("--drones", type=int, nargs="+", default=[9, 17])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 11)))
    ap.add_argument("--modes", nargs="+", default=list(MODES))
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args()
    with ProcessPoolExecutor(a.jobs) as ex:
        if a.what == "honest":
            names = list(shipped_scenarios())
            rows = list(ex.map(honest, *zip(*[(nm, s) for nm in names for s in a.seeds], strict=True)))
            for r in rows:
                print(r, flush=True)
            bad = sum(r["refused_entries"] + r["censorship_findings"] for r in rows)
            print(f"{len(rows)} missions: {bad} refused entries or censorship findings (target 0)")
            return
        jobs = [(m, n, s) for m in a.modes for n in a.drones for s in a.seeds]
        rows = list(ex.map(lying, *zip(*jobs, strict=True)))
    for r in rows:
        print(r, flush=True)
    for m in a.modes:
        for n in a.drones:
            rs = [r for r in rows if r["mode"] == m and r["n"] == n]
            broken = [r["seed"] for r in rs if r["invariant"] != "held"]
            times = [r["replaced_s"] for r in rs if r.get("replaced_s") is not None]
            worst = max(times) if times else None
            outside = sum(r.get("outside", 0) for r in rs)
            target = 2.0 if m == "censor" else 1.0
            ok = not broken and worst is not None and worst <= target and outside == 0
            print(
                f"{m:>7} n={n:>2}: {len(rs)} seeds, invariant broken on {broken or 'none'}, "
                f"replaced after {worst} s at worst (target {target} s), "
                f"{outside} skipped steps outside the window: {'met' if ok else 'NOT met'}"
            )


if __name__ == "__main__":
    main()

"""What the audit costs a networked swarm (docs/audit.md, In the networked runtime): n drone
hosts (`net.node.DroneHost`) in this process over UDP on 127.0.0.1 step a scenario without
faults, with the audit on or off; printed per run: the steps committed (of the scenario's),
the process's CPU seconds (every thread, start-up included), the audit's calls and its total
and largest wall time in ms (summed over the drones), the reports fanned out, the last term,
and the audit's refused records and censorship findings (target 0).

The hosts share one process, one event loop and the GIL: a run measures what the audit adds
to the loop's work, more harshly than processes of their own would.

Run: .venv/bin/python benchmarks/bench_net_audit.py [--audit on off on off] [--drones 5]
     [--duration 20] [--detector joint]
"""

from __future__ import annotations

import argparse
import asyncio
import tempfile
import time
from pathlib import Path

from swarmraft.net.launch import prepare_swarm
from swarmraft.net.node import DroneHost
from swarmraft.net.swarmfile import load_swarm

SCENARIO = """
name = "net-audit-cost"
seed = 5
drones = {n}
duration_s = {duration}

[protocol]
detector = "{detector}"
audit = {audit}
"""
#: seconds from writing the swarm file to step 0 (the hosts build their worlds meanwhile)
START_S = 15.0


def run(folder: Path, n: int, duration: float, detector: str, audit: bool) -> dict:
    text = SCENARIO.format(n=n, duration=duration, detector=detector, audit=str(audit).lower())
    (folder / "scenario.toml").write_text(text)
    path, _ = prepare_swarm(folder / "run", folder / "scenario.toml", n, time.time() + START_S)
    hosts = [DroneHost(load_swarm(path), i) for i in range(1, n + 1)]

    async def main() -> None:
        await asyncio.gather(*(h.run() for h in hosts))

    cpu0 = time.process_time()
    asyncio.run(main())
    counts = [h.audit_counts() or {} for h in hosts]
    return {
        "committed": sum(1 for rec in hosts[0]._written.values() if rec),
        "steps": hosts[0].sc.steps + 1,
        "cpu_s": round(time.process_time() - cpu0, 1),
        "audit_calls": sum(h.counters["audit_count"] for h in hosts),
        "audit_ms_total": sum(h.counters["audit_ms_total"] for h in hosts),
        "audit_ms_max": max(h.counters["audit_ms_max"] for h in hosts),
        "fanned_out": sum(h.counters["sent_fanout"] for h in hosts),
        "term": max(h.node.term for h in hosts),
        "refused": sum(c.get("refused_entries", 0) + c.get("refused_applies", 0) for c in counts),
        "censorship": sum(c.get("censorship_findings", 0) for c in counts),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--audit", nargs="+", choices=["on", "off"], default=["on", "off", "on", "off"])
    ap.add_argument("--drones", type=int, default=5)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--detector", default="joint")
    args = ap.parse_args()
    for a in args.audit:
        with tempfile.TemporaryDirectory(prefix="bench-net-audit-") as tmp:
            r = run(Path(tmp), args.drones, args.duration, args.detector, a == "on")
        print(f"audit {a}: " + ", ".join(f"{k} {v}" for k, v in r.items()), flush=True)


if __name__ == "__main__":
    main()

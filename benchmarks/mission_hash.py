"""A hash of what a mission commits, to show a change leaves missions as they were: the
committed positions, flags, missing drones, protection levels, status, leaders, terms and
message counts per step (SHA-256, first 16 hex digits), with the run time.

Run it on two trees and compare the hashes, e.g. the code before a change:
  git archive 4dc8585 src | tar -x -C /tmp/base
  PYTHONPATH=/tmp/base/src .venv/bin/python benchmarks/mission_hash.py demo --duration 35
  PYTHONPATH=src .venv/bin/python benchmarks/mission_hash.py demo --duration 35

``--duration`` cuts the scenario short (spoofs, outages and faults that start later dropped);
``--param KEY=VALUE`` (repeatable) sets one of the detector's parameters, e.g. to see whether a
parameter changes what a mission commits.
"""

from __future__ import annotations

import argparse
import hashlib
import time
import tomllib

import numpy as np

from cli_args import param_values
from swarmraft.sim.mission import run_mission
from swarmraft.sim.scenario import Scenario, find_scenario


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenario")
    ap.add_argument("--duration", type=float, default=None)
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE")
    a = ap.parse_args()
    data = tomllib.loads(find_scenario(a.scenario).read_text())
    if a.param:
        protocol = data.setdefault("protocol", {})
        values = param_values(ap, a.param, protocol.get("detector", "joint"))
        protocol.setdefault("detector_params", {}).update(values)
    if a.duration:
        data["duration_s"] = a.duration
        for key, t in (("spoof", "start_s"), ("outage", "start_s"), ("fault", "at_s")):
            data[key] = [x for x in data.get(key, []) if x[t] < a.duration]
        data["maps_at_s"] = [t for t in data.get("maps_at_s", []) if t <= a.duration]  # maps draw nothing
    t0 = time.time()
    log = run_mission(Scenario(**data))
    h = hashlib.sha256()
    for arr in (
        log.verified,
        log.faulty,
        log.status.astype(str),
        log.leader,
        log.term,
        log.raft_messages,
        log.report_messages,
        log.hpl,
        log.missing,
    ):
        h.update(np.ascontiguousarray(arr).tobytes())
    took = time.time() - t0
    kinds, counts = np.unique(log.status.astype(str), return_counts=True)
    statuses = ", ".join(f"{k} {c}" for k, c in zip(kinds, counts, strict=True))
    committed = int(log.committed.sum())
    print(f"{a.scenario}: {h.hexdigest()[:16]}, {committed} committed ({statuses}), {took:.1f} s")


if __name__ == "__main__":
    main()

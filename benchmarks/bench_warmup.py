"""What a drone process's first steps cost after its detector's warm-up
(`swarmraft.net.node.warm_up_detector`), step by step: a 9-drone world, drone 3 spoofed by
30 m from 1.0 s, one leader verifying steps 8-15 (wall ms each) and whom it flags. The first
step with a flagged drone should cost what the later ones do: first-use costs paid inside a
step by every process at once make a networked swarm miss deadlines.

Run: .venv/bin/python benchmarks/bench_warmup.py [--drones 9]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from swarmraft.net.node import warm_up_detector
from swarmraft.protocol import Keyring, Report, SwarmDrone
from swarmraft.sim.scenario import Scenario
from swarmraft.sim.sensing import ScenarioWorld


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--drones", type=int, default=9)
    n = ap.parse_args().drones
    if n < 5:
        ap.error("--drones: at least 5 (one spoofed drone among them)")
    sc = Scenario(
        name="warmup",
        drones=n,
        duration_s=2,
        seed=1,
        spoof=[{"kind": "jump", "drones": [3], "start_s": 1.0, "magnitude": 30}],
    )
    w = ScenarioWorld.build(sc)
    t0 = time.perf_counter()
    warm_up_detector(w)
    print(f"warm-up {1e3 * (time.perf_counter() - t0):.1f} ms")
    keys = Keyring.generate(n, np.random.default_rng(1))
    leader = SwarmDrone(0, w.protocol, keys)
    for k in range(8, 16):
        ins = w.ins_estimate(k, np.zeros(n), w.traj.positions[0])
        ranges = w.measured_ranges(k, ins)
        for i in range(n):
            leader.receive(keys.sign(Report(k, i, w.fix[k, i], "gnss", ranges[i], w.innovation(k, i))))
        t0 = time.perf_counter()
        rec = leader.verify_step(k, 1)
        ms = 1e3 * (time.perf_counter() - t0)
        leader.apply(leader.seal(rec))
        flagged = [int(i) + 1 for i in np.flatnonzero(rec.faulty)]
        print(f"step {k} ({k / 10:.1f} s): {ms:6.1f} ms, flagged drones {flagged}")


if __name__ == "__main__":
    main()

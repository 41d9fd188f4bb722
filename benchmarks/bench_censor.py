"""How often packet loss alone would make a voter accuse an honest leader of censorship, for
choices of (k, m) (docs/audit.md): a voter finds its leader faulty when one drone's report,
held by the voter by the step's deadline, is left out of more than k of the last m records of
the leader's term.

Missions without a fault (9 drones, a drone spoofed, the detector `paper`: the omissions
depend on the network, not on the detector) at 10 % and 20 % loss; every voter's omissions
are logged (the mission runs with censorship off: k = m - 1, m large) and each (k, m) is
replayed on them. Printed per loss: voter-steps audited, omissions per voter-step, and for
each (k, m) the false triggers (voter findings) over the mission.

Run: .venv/bin/python benchmarks/bench_censor.py [--duration 600] [--losses 0.1 0.2] [--drones 9]
"""

from __future__ import annotations

import argparse
from collections import defaultdict

from swarmraft.protocol import audit
from swarmraft.sim.mission import run_mission
from swarmraft.sim.scenario import Scenario

CHOICES = [(3, 10), (5, 20), (8, 20), (10, 20), (12, 20), (10, 40), (15, 40)]


def omissions(loss: float, duration: float, drones: int, seed: int) -> tuple[int, list]:
    """(records audited by voters, [(voter id, term, step, omitted drones)])."""
    seen: list = []
    count = [0]
    original = audit.Auditor._censorship

    def spy(self: audit.Auditor, rec) -> None:  # noqa: ANN001
        carried = {r.drone for r in rec.reports}
        left = sorted(self.timely.get(rec.step, set()) - carried)
        count[0] += 1
        if left:
            seen.append((self.drone.index, rec.term, rec.step, left))
        original(self, rec)

    audit.Auditor._censorship = spy
    try:
        sc = Scenario(
            name="censor",
            seed=seed,
            drones=drones,
            duration_s=duration,
            network={"loss": loss},
            protocol={"detector": "paper", "censor_k": 999, "censor_m": 1000},
            spoof=[{"kind": "jump", "drones": [2], "start_s": 5.0, "magnitude": 30.0}],
        )
        run_mission(sc)
    finally:
        audit.Auditor._censorship = original
    return count[0], seen


def triggers(seen: list, k: int, m: int) -> int:
    """Findings an auditor with (k, m) would have made on the logged omissions."""
    found = 0
    hist: dict[tuple[int, int, int], list[int]] = defaultdict(list)  # (voter, term, drone)
    for voter, term, step, left in seen:
        for d in left:
            h = hist[(voter, term, d)]
            h.append(step)
            h[:] = [s for s in h if s > step - m]
            if len(h) > k:
                found += 1
                h.clear()  # take_suspicion: the windows restart after a finding
    return found


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--losses", type=float, nargs="+", default=[0.1, 0.2])
    ap.add_argument("--drones", type=int, default=9)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    for loss in a.losses:
        n, seen = omissions(loss, a.duration, a.drones, a.seed)
        events = sum(len(x[3]) for x in seen)
        print(
            f"loss {loss:.0%}: {a.duration:g} s, {a.drones} drones, {n} voter-records audited, "
            f"{events} omissions ({events / max(n, 1):.4f} per voter-record)"
        )
        for k, m in CHOICES:
            print(f"  k={k:>2} m={m:>2}: {triggers(seen, k, m)} false triggers")


if __name__ == "__main__":
    main()

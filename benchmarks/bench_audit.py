"""Benchmark of the audit of a leader's records (docs/audit.md): bytes per record, and CPU per
step for one voter, at n = 9, 17 and 33 drones, against the target

  audit <= 5 ms of CPU per step per voter (median), at n = 17 (issue 14).

A world of n drones in formation (two of them spoofed by 30 m from 1 s) gives each step's
signed reports; a leader verifies them into records (its prior the previous record, as in a
mission) and seals them; a voter that holds the previous records checks each one
(`Auditor.check`: signatures, the re-run, the prior; no shared memo). Printed per n and
detector: the record's bytes (and the bytes of the verdict alone, without the evidence), and
per step the voter's CPU (process time) for the whole check, split into the signature it
verifies (the leader's: the reports' were verified on receiving them directly, and the
voter's own report it signed itself) and the re-run of the verification, and for
the n - 1 reports it receives directly (the censorship fan-out: one signature each), which
come first. Median and best over the steps measured.

Run: .venv/bin/python benchmarks/bench_audit.py [--steps 40] [--drones 9 17 33] [--detectors joint paper]
     [--param KEY=VALUE ...]   (given to every detector, e.g. --detectors joint --param
     registration_rivals=false: the mission's detector_params)
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace

import numpy as np

from cli_args import param_values
from swarmraft.protocol import Keyring, StepRecord, SwarmDrone
from swarmraft.protocol.drone import Prior, compute_record
from swarmraft.protocol.signing import _check
from swarmraft.sim.scenario import Scenario
from swarmraft.sim.sensing import ScenarioWorld

TARGET_MS = 5.0
WARM = 12  # steps before the measured ones (the innovation window and first-call costs)


def cpu_ms(fn) -> tuple[float, object]:  # noqa: ANN001
    t0 = time.process_time()
    out = fn()
    return (time.process_time() - t0) * 1000, out


def parts(rec: StepRecord, keys: Keyring, w: ScenarioWorld) -> tuple[float, float]:
    """CPU ms of the signature the check verifies (the leader's: the reports' were verified on
    receiving them directly, the voter's own when it signed it) and of the re-run. The
    signature is checked again here without the keyring's memo (which holds it by now), so
    its cost is measured, not the memo's."""
    t0 = time.process_time()
    _check(keys.public[rec.leader], rec.body(), rec.signature)
    t1 = time.process_time()
    prior = None
    if rec.prior_step >= 0:
        prior = Prior(rec.prior_step, rec.prior_positions, rec.prior_faulty)
    compute_record(rec.step, rec.term, {r.drone: r for r in rec.reports}, prior, w.protocol)
    t2 = time.process_time()
    return (t1 - t0) * 1000, (t2 - t1) * 1000


def run(n: int, detector: str, steps: int, params: dict | None = None) -> dict[str, object]:
    sc = Scenario(
        name="bench",
        seed=1,
        drones=n,
        duration_s=(WARM + steps + 2) * 0.1,
        protocol={"detector": detector, "detector_params": params or {}},
        spoof=[{"kind": "jump", "drones": [2, 5], "start_s": 1.0, "magnitude": 30.0}],
    )
    w = ScenarioWorld.build(sc)
    keys = Keyring.generate(n, np.random.default_rng(0))
    leader = SwarmDrone(0, w.protocol, keys, audit=True)
    # its own keyring (and so its own memo of checked signatures), as on a real drone
    voter = SwarmDrone(1, w.protocol, Keyring(keys.private, keys.public), audit=True)
    base_t, base_pos = np.zeros(n), w.traj.positions[0].copy()
    rows: dict[str, list[float]] = {"check": [], "signatures": [], "rerun": [], "fanout": []}
    sizes, verdict_sizes = [], []
    for k in range(WARM + steps):
        ins = w.ins_estimate(k, base_t, base_pos)
        ranges = w.measured_ranges(k, ins)
        reports = []
        for i in range(n):
            pos, src = (w.fix[k, i], "gnss") if w.has_fix[k, i] else (ins[i], "ins")
            inn = w.innovation(k, i) if w.has_fix[k, i] else None
            # the voter signs its own report (and so knows it), as a drone does
            maker = voter if i == voter.index else SwarmDrone(i, w.protocol, keys)
            reports.append(maker.make_report(k, pos, src, ranges[i], inn))
        for r in reports:
            leader.receive(r)
        rec = leader.verify_step(k, 1)
        data = leader.seal(rec)
        measured = k >= WARM
        fan = [r for r in reports if r.drone != voter.index]
        t_fan, _ = cpu_ms(lambda fan=fan: [voter.audit.note_report(r) for r in fan])
        t_check, (back, reason) = cpu_ms(lambda data=data: voter.audit.check(data, 1))
        if reason is not None:
            raise SystemExit(f"n={n} {detector} step {k}: an honest record was refused: {reason}")
        t_sig, t_rerun = parts(back, keys, w)
        leader.apply(data)
        voter.apply(data)
        if measured:
            rows["check"].append(t_check)
            rows["signatures"].append(t_sig)
            rows["rerun"].append(t_rerun)
            rows["fanout"].append(t_fan)
            sizes.append(len(data))
            bare = replace(back, reports=(), prior_step=-1, prior_positions=None, prior_faulty=None)
            verdict_sizes.append(len(replace(bare, signature=b"").encode()))
    out: dict[str, object] = {"n": n, "detector": detector, "bytes": int(np.median(sizes))}
    out["verdict_bytes"] = int(np.median(verdict_sizes))
    for name, v in rows.items():
        out[name] = (statistics.median(v), min(v))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--drones", type=int, nargs="+", default=[9, 17, 33])
    ap.add_argument("--detectors", nargs="+", default=["joint", "paper"])
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE", help="a detector parameter")
    a = ap.parse_args()
    params = {}
    for det in a.detectors:
        params = param_values(ap, a.param, det)
    print(
        f"audit CPU per step per voter, ms (median / best over {a.steps} steps); target {TARGET_MS} at n = 17"
    )
    head = f"{'n':>3} {'detector':>8} {'record B':>9} {'verdict B':>9} {'check':>12} {'signatures':>12}"
    print(head + f" {'re-run':>12} {'fan-out':>12} {'check+fan':>10}  target")
    for det in a.detectors:
        for n in a.drones:
            r = run(n, det, a.steps, params)
            total = r["check"][0] + r["fanout"][0]
            cells = " ".join(
                f"{r[c][0]:6.2f}/{r[c][1]:5.2f}" for c in ("check", "signatures", "rerun", "fanout")
            )
            ok = "met" if total <= TARGET_MS else "NOT met"
            print(f"{n:>3} {det:>8} {r['bytes']:>9} {r['verdict_bytes']:>9} {cells} {total:10.2f}  {ok}")


if __name__ == "__main__":
    main()

"""Does an honest record pass an auditor whose CPU differs from the leader's (issue 14,
docs/audit.md)? A voter re-runs the leader's verification and compares flags, missing drones
and status exactly, positions and protection levels within `audit.POSITION_TOL_M`; floating
point differs between machines, and this script measures what that does to honest records.

Each mission (a shipped scenario on a seed, the simulator, audit on) is flown here, and
every record a leader computed is written out (`StepRecord.encode`: its reports, prior,
detector and parameters). A second Python process, told to compute like another x86 CPU,
re-runs each record's verification from those bytes alone (`protocol.drone.compute_record`)
and compares it as the audit does (`protocol.audit.rerun_differs`). "Another CPU" is
numpy, OpenBLAS and numba without AVX-512 (``NPY_DISABLE_CPU_FEATURES``,
``OPENBLAS_CORETYPE=Haswell``, ``NUMBA_CPU_NAME=haswell``: an AVX2 machine such as an Intel
Haswell to Comet Lake or an AMD Zen 1-3, where this machine has AVX-512); ``--same`` runs the
second process like this one (the control: every record must pass). An ARM flight computer
differs further (other libm, no x87, other BLAS kernels); not measured here.

Printed per mission: records re-run, records that would be refused and why (the first
reason of each, with the record's and the re-run's status), and among the records that pass
the largest difference of a position coordinate and of a protection level, with where.

Run: .venv/bin/python benchmarks/cross_cpu_audit.py [--scenarios demo ...] [--seeds 1 2 3] [--same]
"""

from __future__ import annotations

import argparse
import os
import struct
import subprocess
import sys
import tempfile
import tomllib
from collections import Counter
from pathlib import Path

import numpy as np

import swarmraft.protocol.drone as drone_module
from swarmraft.protocol import StepRecord
from swarmraft.protocol.audit import POSITION_TOL_M, rerun_differs
from swarmraft.protocol.drone import Prior, compute_record
from swarmraft.sim.mission import run_mission
from swarmraft.sim.scenario import Scenario, shipped_scenarios
from swarmraft.sim.sensing import ScenarioWorld

#: an AVX2 x86 CPU, where this machine has AVX-512
OTHER_CPU = {
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
    "OPENBLAS_CORETYPE": "Haswell",
    "NUMBA_CPU_NAME": "haswell",
}
_LEN = struct.Struct("<I")


def scenario(name: str, seed: int) -> Scenario:
    data = tomllib.loads(shipped_scenarios()[name].read_text())
    data["seed"] = seed
    return Scenario(**data)


def fly(sc: Scenario, out: Path) -> int:
    """Fly ``sc``, writing every record a leader computed to ``out``; their count."""
    records: list[bytes] = []
    real = drone_module.compute_record

    def keep(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        rec = real(*args, **kwargs)
        records.append(rec.encode())
        return rec

    drone_module.compute_record = keep
    try:
        run_mission(sc)
    finally:
        drone_module.compute_record = real
    out.write_bytes(b"".join(_LEN.pack(len(r)) + r for r in records))
    return len(records)


def records_in(path: Path) -> list[StepRecord]:
    data, off, out = path.read_bytes(), 0, []
    while off < len(data):
        (size,) = _LEN.unpack_from(data, off)
        out.append(StepRecord.decode(data[off + 4 : off + 4 + size]))
        off += 4 + size
    return out


def recheck(name: str, seed: int, path: Path) -> None:
    """In the second process: re-run every record in ``path``; one summary line."""
    config = ScenarioWorld.build(scenario(name, seed)).protocol
    reasons: Counter[str] = Counter()
    worst = {"positions": (0.0, ""), "levels": (0.0, "")}
    recs = records_in(path)
    for rec in recs:
        prior = None if rec.prior_step < 0 else Prior(rec.prior_step, rec.prior_positions, rec.prior_faulty)
        again = compute_record(rec.step, rec.term, {r.drone: r for r in rec.reports}, prior, config)
        why = rerun_differs(again, rec)
        if why is not None:
            reasons[f"{why} ({rec.status} -> {again.status})"] += 1
            continue
        for kind, a, b in (
            ("positions", again.positions, rec.positions),
            ("levels", np.stack([again.hpl, again.vpl]), np.stack([rec.hpl, rec.vpl])),
        ):
            both = np.isfinite(a) & np.isfinite(b)
            if both.any():
                d = np.where(both, np.abs(np.where(both, a, 0.0) - np.where(both, b, 0.0)), 0.0)
                if d.max() > worst[kind][0]:
                    where = np.unravel_index(np.argmax(d), d.shape)[-2 if kind == "levels" else 0]
                    worst[kind] = (float(d.max()), f"step {rec.step} drone {int(where) + 1} {rec.status}")
    refused = sum(reasons.values())
    detail = "; ".join(f"{k}: {v}" for k, v in reasons.most_common()) or "-"
    cells = " ".join(f"{worst[k][0]:8.1e} ({worst[k][1] or '-'})" for k in worst)
    print(f"{name:>28} {seed:>4} {len(recs):>8} {refused:>8}   {cells}   {detail}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=None, help="shipped scenario names (default: all)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--same", action="store_true", help="the second process computes like this one (control)")
    ap.add_argument("--recheck", nargs=3, metavar=("NAME", "SEED", "FILE"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.recheck:
        name, seed, path = a.recheck
        recheck(name, int(seed), Path(path))
        return
    shipped = shipped_scenarios()
    names = a.scenarios or list(shipped)
    unknown = [n for n in names if n not in shipped]
    if unknown:
        have = ", ".join(shipped)
        raise SystemExit(f"--scenarios: no shipped scenario {', '.join(unknown)} (have: {have})")
    env = dict(os.environ)
    if not a.same:
        env.update(OTHER_CPU)
    with tempfile.TemporaryDirectory() as tmp:
        env["NUMBA_CACHE_DIR"] = str(Path(tmp) / "numba")  # its own compiled kernels
        other = ", ".join(f"{k}={v}" for k, v in OTHER_CPU.items())
        what = "this machine's CPU (control)" if a.same else f"an AVX2 CPU ({other})"
        print(f"records re-run on {what}; tolerance {POSITION_TOL_M} m")
        print(
            f"{'scenario':>28} {'seed':>4} {'records':>8} {'refused':>8}   largest difference of a passing"
            " record, m: positions, levels (where)   why refused (record -> re-run status)"
        )
        for name in names:
            for seed in a.seeds:
                path = Path(tmp) / f"{name}-{seed}.bin"
                fly(scenario(name, seed), path)
                cmd = [sys.executable, __file__, "--recheck", name, str(seed), str(path)]
                subprocess.run(cmd, env=env, check=True)


if __name__ == "__main__":
    main()

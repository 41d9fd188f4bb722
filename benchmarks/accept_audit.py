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

``lying-net``: the same lying missions as real processes (`swarmraft launch`'s `LocalSwarm`:
one ``swarmraft node`` per drone over signed UDP on 127.0.0.1, the leader told to lie by
SIGUSR1 at the fault's time), one at a time; the invariant is read from the drones' files
(``falsified_applied``: step-file rows of honest drones holding a record the liar falsified).

``loss-net``: an honest swarm of processes behind the fault relay at ``--loss`` (default 10 %)
for ``--duration`` s (default 600): censorship findings and refused entries (target 0).

``--keep DIR`` (the ``-net`` runs): each swarm's folder (scenario, keys, the drones' step and
event files) is kept under DIR, so a slow mission can be looked at afterwards.

Run: .venv/bin/python benchmarks/accept_audit.py lying [--drones 9 17] [--seeds 1 .. 10] [--jobs 2]
     .venv/bin/python benchmarks/accept_audit.py honest [--seeds 1 .. 10] [--jobs 2]
     .venv/bin/python benchmarks/accept_audit.py lying-net [--drones 9] [--seeds 1 .. 10] [--keep DIR]
     .venv/bin/python benchmarks/accept_audit.py loss-net [--drones 9] [--loss 0.1] [--duration 600]
"""

from __future__ import annotations

import argparse
import contextlib
import tempfile
import tomllib
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from swarmraft.sim.mission import run_mission
from swarmraft.sim.scenario import Scenario, shipped_scenarios

MODES = ("move", "clear", "accuse", "censor")
LIE_AT_S = 3.0
START_DELAY_S = 25.0  # lying-net, loss-net: seconds from launch to step 0 at least


def lying_scenario(mode: str, n: int, seed: int) -> dict:
    return {
        "name": "lying",
        "seed": seed,
        "drones": n,
        "duration_s": 8.0,
        "spoof": [{"kind": "jump", "drones": [3], "start_s": 1.0, "magnitude": 30.0}],
        "fault": [
            {"kind": "lying-leader", "at_s": LIE_AT_S, "mode": mode, "drone": 3 if mode == "clear" else 5}
        ],
    }


def outcome(log, mode: str, n: int, seed: int) -> dict:  # noqa: ANN001 (a MissionLog)
    """From a lying mission's log: the time from the first falsified record (censor: from the
    fault) to the first step another drone led, and the skipped steps outside that window."""
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
    outside = skipped[(skipped < start - 0.1) | (skipped > end)]
    out["outside"] = int(outside.size)
    out["outside_s"] = [round(float(t), 1) for t in outside]
    out["refused"] = a["refused_entries"]
    out["findings"] = a["censorship_findings"]
    out["found_s"] = None if a["first_finding_s"] is None else round(a["first_finding_s"] - start, 2)
    return out


def lying(mode: str, n: int, seed: int) -> dict:
    try:
        log = run_mission(Scenario(**lying_scenario(mode, n, seed)))
    except AssertionError as exc:
        return {"mode": mode, "n": n, "seed": seed, "invariant": str(exc)}
    return outcome(log, mode, n, seed)


def launched(data: dict, folder: Path):  # noqa: ANN201 (a MissionLog)
    """Scenario ``data`` run as processes on 127.0.0.1 (as `swarmraft launch`), its log."""
    from swarmraft.net.launch import default_start_delay_s
    from swarmraft.net.localswarm import LocalSwarm
    from swarmraft.net.results import launch_log
    from swarmraft.sim.sensing import ScenarioWorld

    file = folder / "scenario.toml"
    file.write_text(toml_text(data))
    sc = Scenario(**data)
    # step 0 after every process is up: launch's default (3 s + 2.5 s per drone per core)
    # is too short on a loaded machine, and an 8 s mission then ends before anyone leads
    delay = max(default_start_delay_s(sc.drones), START_DELAY_S)
    run = LocalSwarm(sc, file, folder / "run", start_delay_s=delay, say=lambda _line: None)
    run.prepare()
    run.run()
    return launch_log(ScenarioWorld.build(sc), run.nodes_dir, run.start_unix_s, run.events, run.kills)


def run_folder(keep: Path | None, name: str):  # noqa: ANN201 (a context manager of a Path)
    """Where a swarm of processes runs: ``keep / name`` (kept, a fresh folder) or a temporary
    folder deleted afterwards."""
    if keep is None:
        return tempfile.TemporaryDirectory(prefix="accept-audit-net-")
    folder = keep / name
    if folder.exists():
        raise SystemExit(f"--keep: {folder} exists; give a folder without it")
    folder.mkdir(parents=True)
    return contextlib.nullcontext(str(folder))


def lying_net(mode: str, n: int, seed: int, keep: Path | None = None) -> dict:
    with run_folder(keep, f"lying-{mode}-{n}-{seed}") as tmp:
        log = launched(lying_scenario(mode, n, seed), Path(tmp))
    out = outcome(log, mode, n, seed)
    if log.audit["falsified_applied"]:
        out["invariant"] = f"{log.audit['falsified_applied']} falsified records applied by honest drones"
    out["committed"] = f"{int(log.committed.sum())}/{log.committed.size}"
    return out


def loss_net(n: int, seed: int, loss: float, duration_s: float, keep: Path | None = None) -> dict:
    data = {"name": "loss", "seed": seed, "drones": n, "duration_s": duration_s, "network": {"loss": loss}}
    with run_folder(keep, f"loss-{n}-{seed}") as tmp:
        log = launched(data, Path(tmp))
    a = log.audit
    return {
        "n": n,
        "seed": seed,
        "loss": loss,
        "duration_s": duration_s,
        "committed": f"{int(log.committed.sum())}/{log.committed.size}",
        **{k: a[k] for k in ("refused_entries", "refused_applies", "censorship_findings")},
    }


def toml_text(data: dict) -> str:
    """A scenario dict as TOML (the few shapes these scenarios use: scalars, tables, arrays
    of tables with scalar or list values)."""

    def value(v) -> str:  # noqa: ANN001
        if isinstance(v, bool):
            return str(v).lower()
        if isinstance(v, str):
            return f'"{v}"'
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    lines = [f"{k} = {value(v)}" for k, v in data.items() if not isinstance(v, dict | list)]
    for k, v in data.items():
        if isinstance(v, dict):
            lines += ["", f"[{k}]", *(f"{kk} = {value(vv)}" for kk, vv in v.items())]
        elif isinstance(v, list):
            for item in v:
                lines += ["", f"[[{k}]]", *(f"{kk} = {value(vv)}" for kk, vv in item.items())]
    return "\n".join(lines) + "\n"


def report(rows: list[dict], modes: list[str], drones: list[int]) -> None:
    for r in rows:
        print(r, flush=True)
    for m in modes:
        for n in drones:
            rs = [r for r in rows if r["mode"] == m and r["n"] == n]
            broken = [r["seed"] for r in rs if r["invariant"] != "held"]
            # a seed whose leader never lied (nothing committed, or no one led) proves nothing
            unlied = [r["seed"] for r in rs if r["invariant"] == "held" and r.get("replaced_s") is None]
            times = [r["replaced_s"] for r in rs if r.get("replaced_s") is not None]
            worst = max(times) if times else None
            outside = sum(r.get("outside", 0) for r in rs)
            target = 2.0 if m == "censor" else 1.0
            ok = not broken and not unlied and worst is not None and worst <= target and outside == 0
            print(
                f"{m:>7} n={n:>2}: {len(rs)} seeds, invariant broken on {broken or 'none'}, "
                f"no lie told on {unlied or 'none'}, replaced after {worst} s at worst (target "
                f"{target} s), {outside} skipped steps outside the window: {'met' if ok else 'NOT met'}"
            )


def honest(name: str, seed: int) -> dict:
    data = tomllib.loads(shipped_scenarios()[name].read_text())
    data["seed"] = seed
    log = run_mission(Scenario(**data))
    counts = {k: log.audit[k] for k in ("refused_entries", "censorship_findings")}
    return {"scenario": name, "seed": seed, **counts}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=["lying", "honest", "lying-net", "loss-net"])
    ap.add_argument("--drones", type=int, nargs="+", default=None, help="default 9 17 (net: 9)")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 11)))
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--loss", type=float, default=0.1, help="loss-net: loss probability (default 0.1)")
    ap.add_argument("--duration", type=float, default=600.0, help="loss-net: seconds (default 600)")
    ap.add_argument(
        "--keep", type=Path, default=None, help="-net: keep each swarm's folder (drone files) under this one"
    )
    a = ap.parse_args()
    if a.keep is not None and a.keep.exists() and not a.keep.is_dir():
        ap.error(f"--keep: {a.keep} is not a folder")
    net = a.what.endswith("-net")
    drones = a.drones or ([9] if net else [9, 17])
    if a.what == "loss-net":
        for n in drones:
            for s in a.seeds:
                r = loss_net(n, s, a.loss, a.duration, a.keep)
                print(r, flush=True)
                bad = r["refused_entries"] + r["refused_applies"] + r["censorship_findings"]
                print(f"n={n} seed {s}: {bad} refused entries or censorship findings (target 0)", flush=True)
        return
    if a.what == "lying-net":  # one swarm at a time: its processes share the cores already
        rows = []
        for m in a.modes:
            for n in drones:
                for s in a.seeds:
                    rows.append(lying_net(m, n, s, a.keep))
                    print(rows[-1], flush=True)
        report(rows, a.modes, drones)
        return
    with ProcessPoolExecutor(a.jobs) as ex:
        if a.what == "honest":
            names = list(shipped_scenarios())
            rows = list(ex.map(honest, *zip(*[(nm, s) for nm in names for s in a.seeds], strict=True)))
            for r in rows:
                print(r, flush=True)
            bad = sum(r["refused_entries"] + r["censorship_findings"] for r in rows)
            print(f"{len(rows)} missions: {bad} refused entries or censorship findings (target 0)")
            return
        jobs = [(m, n, s) for m in a.modes for n in drones for s in a.seeds]
        rows = list(ex.map(lying, *zip(*jobs, strict=True)))
    report(rows, a.modes, drones)


if __name__ == "__main__":
    main()

"""The commands of the networked runtime (`swarmraft.net`): keygen (key files), node (one drone
process) and launch (a swarm of drone processes on this machine)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import click

from swarmraft.cli.app import console, err_console, main
from swarmraft.cli.options import OutFolder


def _nearest_existing(path: Path) -> Path:
    for p in (path, *path.parents):
        if p.exists():
            return p
    return Path(".")


@main.command("keygen")
@click.option(
    "--n", "n", type=click.IntRange(min=1), required=True, help="number of drones; their ids are 1..N"
)
@click.option(
    "--out", type=OutFolder(), required=True, help="folder for drone-<id>.key and swarm-keys.toml (created)"
)
@click.option("--force", is_flag=True, help="replace key files that exist already")
def keygen(n: int, out: Path, force: bool) -> None:
    """Write an Ed25519 key pair for each of N drones: OUT/drone-<id>.key, the drone's private
    key (32 raw bytes, mode 0600: copy it to that drone only), and OUT/swarm-keys.toml, every
    drone's public key in hex (every drone needs it). Existing key files are left alone
    unless --force is given.
    """
    from swarmraft.net.keys import key_files, write_keys

    base = _nearest_existing(out)
    if not os.access(base, os.W_OK | os.X_OK):
        raise click.BadParameter(f"{base} is not writable", param_hint="--out")
    if not force and (taken := [p for p in key_files(out, n) if p.exists() or p.is_symlink()]):
        more = f" (and {len(taken) - 1} more)" if len(taken) > 1 else ""
        raise click.BadParameter(f"{taken[0]} exists{more}; give --force to replace it", param_hint="--out")
    try:
        paths = write_keys(out, n, force=force)
    except OSError as exc:
        raise click.BadParameter(
            f"cannot write {exc.filename or out}: {exc.strerror}", param_hint="--out"
        ) from None
    first, last = paths[0], paths[-2]
    keys = str(first) if n == 1 else f"{first} .. {last}"
    console.print(f"wrote {keys} (private keys, mode 0600: copy each to its drone only)", soft_wrap=True)
    console.print(
        f"wrote {paths[-1]} (the public keys of all {n} drones: every drone needs it)", soft_wrap=True
    )


@main.command("node")
@click.option("--id", "drone_id", type=click.IntRange(min=1), required=True, help="this drone's id (1..n)")
@click.option(
    "--swarm",
    "swarm_path",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="the swarm file (swarm.toml: addresses, keys, scenario, start time; docs/net.md)",
)
@click.option("-v", "--verbose", is_flag=True, help="log every dropped datagram and role change (INFO)")
def node(drone_id: int, swarm_path: Path, verbose: bool) -> None:
    """Run drone ID of a networked swarm until its scenario ends, or SIGTERM / Ctrl-C.

    It binds its UDP address from the swarm file, keeps its Raft term, vote and log in
    OUT/drone-<ID>.sqlite (a restart on the same file rejoins with its log), computes its own
    sensor readings from the swarm's scenario and seed, reports to the leader each step, and
    writes one JSON line per applied step to OUT/drone-<ID>.steps.jsonl and its starts, role
    changes and final counters to OUT/drone-<ID>.events.jsonl.
    """
    import logging

    from swarmraft.net.node import run_node

    logging.basicConfig(
        level=logging.INFO if verbose else logging.WARNING,
        format=f"%(asctime)s drone {drone_id} %(levelname)s %(name)s: %(message)s",
    )
    status = run_node(swarm_path, drone_id)
    if status:
        sys.exit(status)


@main.command("launch")
@click.option(
    "--scenario",
    "scenario",
    required=True,
    help="a shipped scenario's name or a scenario TOML file (docs/scenarios.md)",
)
@click.option(
    "--out", type=OutFolder(), required=True, help="folder for keys, swarm.toml, node files, steps.csv"
)
@click.option("--seed", type=click.IntRange(min=0), default=None, help="override the scenario's seed")
@click.option(
    "--start-delay",
    "start_delay",
    type=click.FloatRange(min=0),
    default=None,
    help="seconds from launch to step 0, for the processes to start (default: 3 + 2.5 x drones / cores)",
)
@click.option(
    "--replay",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="a sensor log every drone replays instead of the scenario's model (docs/records.md)",
)
def launch(
    scenario: str, out: Path, seed: int | None, start_delay: float | None, replay: Path | None
) -> None:
    """Run a scenario as a real swarm on this machine: one `swarmraft node` process per drone
    on 127.0.0.1 over UDP. Writes OUT/keys, OUT/scenario.toml and OUT/swarm.toml, starts the
    processes, applies the scenario's crash faults to them (crash and crash-leader: SIGKILL;
    restart: start again on the same SQLite file), waits for the scenario's end, and gathers
    every node's step file into OUT/steps.csv (one row per step: committed or skipped, status,
    flags, and whether every node holds the same record). Partition, heal and loss faults are
    not applied (they need a fault relay). Ctrl-C stops every process. With --replay LOG the
    drones' readings come from LOG (copied to OUT/sensors.csv); the scenario still sets the
    protocol, the steps and the faults.
    """
    import time

    from swarmraft.experiments.mission import load_scenario
    from swarmraft.net.launch import (
        NODES_DIR,
        NodeProcess,
        current_leader,
        default_start_delay_s,
        gather_steps,
        prepare_swarm,
    )
    from swarmraft.sim.scenario import find_scenario

    sc = load_scenario(scenario, seed=seed)
    if (out / "swarm.toml").exists():
        raise click.BadParameter(
            f"{out} holds a swarm already (swarm.toml); choose another folder", param_hint="--out"
        )
    n = sc.drones
    if replay is not None:
        from swarmraft.net.sources.replay import read_sensor_log

        read_sensor_log(replay, n)  # a bad log is one line (file:line: field: problem) before anything starts
    delay = default_start_delay_s(n) if start_delay is None else start_delay
    start = time.time() + delay
    swarm_path, swarm = prepare_swarm(out, find_scenario(scenario), n, start, seed, replay)
    nodes_dir = out / NODES_DIR
    procs = {i: NodeProcess(i, swarm_path, nodes_dir / f"drone-{i}.log") for i in range(1, n + 1)}
    console.print(f"wrote {out / 'keys'} and {swarm_path}", soft_wrap=True)
    console.print(f"starting {n} drone processes; step 0 at +{delay:.1f} s, {sc.duration_s:g} s of scenario")
    applied: list[str] = []
    interrupted = False
    try:
        for p in procs.values():
            p.start()
        for f in sorted(sc.fault, key=lambda f: f.at_s):
            while time.time() < start + f.at_s:
                time.sleep(0.02)
            alive = [i for i, p in procs.items() if p.alive]
            if f.kind == "crash-leader":
                lead = current_leader(nodes_dir, alive)
                if lead is None:
                    applied.append(f"{f.at_s:g} s: crash-leader: no leader known, nothing killed")
                    console.print(applied[-1])
                    continue
                procs[lead[0]].kill()
                applied.append(f"{f.at_s:g} s: leader {lead[0]} (term {lead[1]}) killed (SIGKILL)")
            elif f.kind == "crash":
                procs[f.drone].kill()
                applied.append(f"{f.at_s:g} s: drone {f.drone} killed (SIGKILL)")
            elif f.kind == "restart":
                if procs[f.drone].alive:
                    applied.append(f"{f.at_s:g} s: restart: drone {f.drone} is running")
                    console.print(applied[-1])
                    continue
                procs[f.drone].start()
                applied.append(f"{f.at_s:g} s: drone {f.drone} restarted on its SQLite file")
            else:
                applied.append(f"{f.at_s:g} s: {f.kind}: not applied (no fault relay yet)")
            console.print(applied[-1])
        end = start + sc.steps * sc.dt_s + 15.0
        while any(p.alive for p in procs.values()) and time.time() < end:
            time.sleep(0.1)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        for p in procs.values():
            p.terminate()
        for p in procs.values():
            if p.wait(10) is None:
                p.kill()
    g = gather_steps(nodes_dir, n, sc.steps, sc.dt_s, out / "steps.csv")
    skipped = len(g.rows) - g.committed
    same = "yes" if g.all_identical else "NO"
    console.print(
        f"{g.committed} of {len(g.rows)} steps committed, {skipped} skipped; "
        f"every node's records identical: {same}"
    )
    console.print(
        f"wrote {out / 'steps.csv'} and {nodes_dir}/drone-<id>.(steps.jsonl, events.jsonl, log, sqlite)",
        soft_wrap=True,
    )
    if interrupted:
        err_console.print("interrupted")
        sys.exit(130)
    if not g.all_identical:
        sys.exit(1)

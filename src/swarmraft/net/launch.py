"""A swarm of drone processes on one machine (what ``swarmraft launch`` runs): writing its keys
and swarm file (`prepare_swarm`), starting, killing and restarting ``swarmraft node``
processes (`NodeProcess`), finding the leader from their event files (`current_leader`), and
gathering their step files into one table (`gather_steps`).
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from swarmraft.net.keys import write_keys
from swarmraft.net.swarmfile import SwarmFile, drone_file, swarm_file_text
from swarmraft.provenance import source_sha256

NODES_DIR = "nodes"


def free_udp_ports(n: int, host: str = "127.0.0.1") -> list[int]:
    """n UDP ports that were free a moment ago (bound to port 0, then released together)."""
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind((host, 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def prepare_swarm(
    out: Path,
    scenario_file: Path,
    n: int,
    start_unix_s: float,
    seed: int | None = None,
    ports: list[int] | None = None,
    advertise: dict[int, tuple[str, int]] | None = None,
    replay: Path | None = None,
) -> tuple[Path, SwarmFile]:
    """Keys (``out/keys``), a copy of the scenario (``out/scenario.toml``) and a swarm file
    (``out/swarm.toml``) for n drones on 127.0.0.1, each binding ``ports[i - 1]`` (default:
    free UDP ports) and advertising ``advertise[i]`` (default: the address it binds; a fault
    relay's port otherwise); with ``replay`` (a sensor log), a copy of it (``out/sensors.csv``)
    that every drone replays. The swarm file's path and its contents (paths resolved)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_keys(out / "keys", n)
    shutil.copyfile(scenario_file, out / "scenario.toml")
    source = {"kind": "scenario"}
    if replay is not None:
        shutil.copyfile(replay, out / "sensors.csv")
        source = {"kind": "replay", "log": "sensors.csv"}
    ports = ports or free_udp_ports(n)
    advertise = advertise or {}
    swarm = SwarmFile.model_validate(
        {
            "scenario": "scenario.toml",
            "seed": seed,
            "start_unix_s": start_unix_s,
            "public_keys": "keys/swarm-keys.toml",
            "out": NODES_DIR,
            "code_sha256": source_sha256(),
            "drones": {
                i: {
                    "bind": f"127.0.0.1:{port}",
                    "advertise": "{}:{}".format(*advertise.get(i, ("127.0.0.1", port))),
                    "key": f"keys/drone-{i}.key",
                    "source": source,
                }
                for i, port in enumerate(ports, start=1)
            },
        }
    )
    path = out / "swarm.toml"
    path.write_text(swarm_file_text(swarm))
    (out / NODES_DIR).mkdir(exist_ok=True)
    return path, swarm.resolved(out)


@dataclass
class NodeProcess:
    """``python -m swarmraft node --id ID --swarm SWARM``, its output appended to ``log``."""

    drone: int
    swarm_path: Path
    log: Path
    proc: subprocess.Popen | None = None
    starts: int = 0
    paused: bool = False

    def start(self) -> None:
        cmd = [
            sys.executable,
            "-m",
            "swarmraft",
            "node",
            "--id",
            str(self.drone),
            "--swarm",
            str(self.swarm_path),
        ]
        with self.log.open("a") as f:
            self.proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        self.starts += 1

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def kill(self) -> None:
        """SIGKILL (a crash: nothing is flushed or closed) and reap it."""
        if self.alive:
            assert self.proc is not None
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait()
        self.paused = False

    def pause(self) -> None:
        """SIGSTOP: the process is frozen (its socket still queues what arrives)."""
        if self.alive and not self.paused:
            assert self.proc is not None
            self.proc.send_signal(signal.SIGSTOP)
            self.paused = True

    def resume(self) -> None:
        """SIGCONT after a pause."""
        if self.alive and self.paused:
            assert self.proc is not None
            self.proc.send_signal(signal.SIGCONT)
        self.paused = False

    def compromise(self) -> None:
        """SIGUSR1: the drone lies from now on whenever it leads (its scenario's lying-leader
        fault, docs/audit.md)."""
        if self.alive and not self.paused:
            assert self.proc is not None
            self.proc.send_signal(signal.SIGUSR1)

    def terminate(self) -> None:
        """SIGTERM (a clean stop); a paused process is resumed to receive it."""
        if self.alive:
            assert self.proc is not None
            self.proc.send_signal(signal.SIGTERM)
            self.resume()

    def wait(self, timeout: float) -> int | None:
        if self.proc is None:
            return None
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            return None


def read_jsonl(path: Path) -> list[dict[str, Any]]:
    """The rows of a JSON-lines file (a torn last line, from a killed writer, is left out)."""
    rows = []
    try:
        with Path(path).open() as f:
            for line in f:
                if not line.endswith("\n"):
                    break
                try:
                    rows.append(json.loads(line))
                except ValueError:
                    break
    except FileNotFoundError:
        pass
    return rows


def events(nodes_dir: Path, drone: int) -> list[dict[str, Any]]:
    return read_jsonl(drone_file(nodes_dir, drone, "events.jsonl"))


def current_leader(nodes_dir: Path, alive: list[int]) -> tuple[int, int] | None:
    """(drone, term) of the live drone whose last role event says leader, of the highest term."""
    best = None
    for i in alive:
        roles = [e for e in events(nodes_dir, i) if e["event"] in ("role", "start")]
        last = roles[-1] if roles else None
        if last and last.get("role") == "leader" and (best is None or last["term"] > best[1]):
            best = (i, last["term"])
    return best


STEP_COLUMNS = (
    "step",
    "t_s",
    "committed",
    "status",
    "term",
    "faulty",
    "missing",
    "nodes_with_step",
    "identical",
    "record",
)


@dataclass
class Gathered:
    rows: list[dict[str, Any]] = field(default_factory=list)
    per_node: dict[int, dict[int, dict[str, Any]]] = field(default_factory=dict)

    @property
    def committed(self) -> int:
        return sum(r["committed"] for r in self.rows)

    @property
    def all_identical(self) -> bool:
        return all(r["identical"] for r in self.rows)


def gather_steps(nodes_dir: Path, n: int, steps: int, dt_s: float, out_csv: Path | None = None) -> Gathered:
    """One row per step 0..steps from every node's step file: committed (some node applied a
    record for it) or skipped, the record's status, term, flags (drone ids) and hash, how many
    nodes' files reach the step, and whether they all agree (the same record, or all skipped)."""
    per_node = {
        i: {r["step"]: r for r in read_jsonl(drone_file(nodes_dir, i, "steps.jsonl"))}
        for i in range(1, n + 1)
    }
    g = Gathered(per_node=per_node)
    for k in range(steps + 1):
        seen = [rows[k] for rows in per_node.values() if k in rows]
        recs = {r.get("record") if r["committed"] else None for r in seen}
        first = next((r for r in seen if r["committed"]), None)
        g.rows.append(
            {
                "step": k,
                "t_s": round(k * dt_s, 6),
                "committed": first is not None,
                "status": first["status"] if first else "skipped",
                "term": first["term"] if first else "",
                "faulty": " ".join(map(str, first["faulty"])) if first else "",
                "missing": " ".join(map(str, first["missing"])) if first else "",
                "nodes_with_step": len(seen),
                "identical": len(recs) <= 1,
                "record": first["record"] if first else "",
            }
        )
    if out_csv is not None:
        with Path(out_csv).open("w", newline="") as f:
            w = csv.DictWriter(f, STEP_COLUMNS)
            w.writeheader()
            # booleans as 0/1, as every CSV file of the project writes them (docs/files.md)
            w.writerows({k: int(v) if isinstance(v, bool) else v for k, v in r.items()} for r in g.rows)
    return g


def wait_for(predicate, timeout_s: float, poll_s: float = 0.05) -> bool:  # noqa: ANN001
    """Poll ``predicate()`` until it holds or ``timeout_s`` passes; whether it held."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(poll_s)
    return bool(predicate())


def default_start_delay_s(n: int) -> float:
    """Seconds from launch to step 0: a drone process takes about 2 s of CPU to start
    (imports, its world), and n of them share the machine's cores (measured on a busy 2-core
    machine: 5 processes were up 6-11 s after launch)."""
    return 3.0 + 2.5 * n / max(1, os.cpu_count() or 1)

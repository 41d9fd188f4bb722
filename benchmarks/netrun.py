"""A swarm of drone processes on 127.0.0.1 for the runtime benchmarks (bench_net.py,
bench_hostile.py), and what a stretch of its steps measured.

`LoopbackSwarm` writes keys, a scenario without faults or attacks and a swarm file
(`net.launch.prepare_swarm`), starts one ``python -m swarmraft node`` per drone
(`net.launch.NodeProcess`), and SIGTERMs them at the scenario's end. `window_stats` reads the
drones' step files for a range of steps:

- **committed rate**: records committed in the window per second of the window (10 steps/s
  at 10 Hz if none is skipped); **skipped**: steps of the window no drone applied a record for.
- **commit latency** of step k: from its start, ``start_unix_s + k * step_s``, to the first
  ``applied_unix_s`` of its record on any drone. That is the leader's: it applies a record in
  the Ready in which it learns the record committed, before any follower can hear of it (the
  followers learn the commit index from its next append or heartbeat). So it is the time to
  commit on the leader plus the leader's apply (a JSON line), which is the latency a client
  of the leader sees. **Applied on all**: to the last drone's ``applied_unix_s``.

`usage_stats` reads each drone's ``stop`` event: CPU seconds and bytes sent from step 0 (the
``at_step_0`` snapshot) to the stop, per second of wall clock.
"""

from __future__ import annotations

import math
import os
import statistics
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from swarmraft.net.launch import NodeProcess, default_start_delay_s, events, prepare_swarm, read_jsonl
from swarmraft.net.swarmfile import drone_file

SCENARIO = """name = "bench-net"
seed = {seed}
drones = {n}
duration_s = {duration_s}
"""


class LoopbackSwarm:
    """n drones on 127.0.0.1 (processes for ``running`` of them, default all), step 0 after
    ``start_delay_s`` (default: `net.launch`'s, which the busy 2-core machine needs), the
    scenario ``duration_s`` long; every process is ended on exit."""

    def __init__(
        self,
        out: Path,
        n: int,
        duration_s: float,
        seed: int = 1,
        start_delay_s: float | None = None,
        running: list[int] | None = None,
    ) -> None:
        out.mkdir(parents=True, exist_ok=True)
        scenario = out / "scenario-src.toml"
        scenario.write_text(SCENARIO.format(seed=seed, n=n, duration_s=duration_s))
        delay = default_start_delay_s(n) if start_delay_s is None else start_delay_s
        self.path, self.swarm = prepare_swarm(out / "run", scenario, n, time.time() + delay)
        self.nodes_dir = out / "run" / "nodes"
        self.n, self.duration_s = n, duration_s
        self.step_s = 0.1  # the scenario's dt_s (its default: 10 Hz)
        ids = running or range(1, n + 1)
        self.procs = {i: NodeProcess(i, self.path, drone_file(self.nodes_dir, i, "log")) for i in ids}

    def step_start(self, k: int) -> float:
        """Unix time at which step k starts."""
        return self.swarm.start_unix_s + k * self.step_s

    def __enter__(self) -> LoopbackSwarm:
        for p in self.procs.values():
            p.start()
        return self

    def __exit__(self, *exc: object) -> None:
        for p in self.procs.values():
            p.kill()

    def sleep_until(self, unix_s: float) -> None:
        """Sleep until ``unix_s``; raise if a drone process died meanwhile."""
        while (left := unix_s - time.time()) > 0:
            dead = [i for i, p in self.procs.items() if not p.alive]
            if dead:
                raise RuntimeError(f"drone {dead[0]} exited early; see {self.nodes_dir}/drone-{dead[0]}.log")
            time.sleep(min(left, 0.2))

    def stop(self, timeout_s: float = 20.0) -> dict[int, int | None]:
        """SIGTERM every process; their exit statuses."""
        for p in self.procs.values():
            p.terminate()
        return {i: p.wait(timeout_s) for i, p in self.procs.items()}

    def steps(self, i: int) -> dict[int, dict[str, Any]]:
        return {r["step"]: r for r in read_jsonl(drone_file(self.nodes_dir, i, "steps.jsonl"))}

    def last_event(self, i: int, kind: str) -> dict[str, Any] | None:
        found = [e for e in events(self.nodes_dir, i) if e["event"] == kind]
        return found[-1] if found else None

    def ready_unix_s(self) -> float | None:
        """When every process had started and a leader was first elected (None: not yet)."""
        starts = [self.last_event(i, "start") for i in self.procs]
        leaders = [e["t"] for i in self.procs for e in events(self.nodes_dir, i) if e.get("role") == "leader"]
        if None in starts or not leaders:
            return None
        return max(max(e["t"] for e in starts), min(leaders))

    def elections(self) -> list[tuple[float, int, int]]:
        """Every election won, in time order: (unix time, drone, term). The last one's drone is
        the leader at the end."""
        won = {
            (e["term"], i): e["t"]
            for i in self.procs
            for e in events(self.nodes_dir, i)
            if e.get("role") == "leader"
        }
        return sorted((t, i, term) for (term, i), t in won.items())


def percentile(xs: list[float], q: float) -> float:
    """The q-th percentile (nearest rank) of xs; nan if empty."""
    if not xs:
        return float("nan")
    s = sorted(xs)
    return s[min(len(s), max(1, math.ceil(q / 100 * len(s)))) - 1]


@dataclass
class WindowStats:
    steps: int  # steps in the window
    committed: int
    skipped: int
    rate_per_s: float  # committed records per second of the window
    commit_ms: list[float]  # per committed step: start to the first apply (the leader's)
    all_applied_ms: list[float]  # per committed step: start to the last drone's apply
    identical: bool  # every drone that applied a step holds the same record
    committed_flags: list[bool]  # per step of the window

    def worst_second(self, steps_per_s: int) -> int:
        """The fewest records committed in any whole second of the window (from its start)."""
        f, m = self.committed_flags, steps_per_s
        return min((sum(f[b : b + m]) for b in range(0, len(f) - m + 1, m)), default=0)

    def latency_ms(self, q: float, on_all: bool = False) -> float:
        return percentile(self.all_applied_ms if on_all else self.commit_ms, q)


def window_stats(swarm: LoopbackSwarm, first: int, last: int) -> WindowStats:
    """Steps ``first`` .. ``last`` (inclusive) as the drones' step files record them."""
    per = [swarm.steps(i) for i in swarm.procs]
    commit_ms, all_ms, identical, flags = [], [], True, []
    for k in range(first, last + 1):
        rows = [s[k] for s in per if k in s and s[k]["committed"]]
        flags.append(bool(rows))
        if not rows:
            continue
        identical &= len({r["record"] for r in rows}) == 1
        applied = [r["applied_unix_s"] for r in rows]
        commit_ms.append((min(applied) - swarm.step_start(k)) * 1000)
        all_ms.append((max(applied) - swarm.step_start(k)) * 1000)
    n = last - first + 1
    rate = len(commit_ms) / (n * swarm.step_s)
    return WindowStats(n, len(commit_ms), n - len(commit_ms), rate, commit_ms, all_ms, identical, flags)


@dataclass
class Usage:
    wall_s: float  # from step 0 (or the process's start, if later) to its stop
    cpu_s: float
    bytes_sent: int
    datagrams_sent: int
    datagrams_received: int

    @property
    def cpu_share(self) -> float:
        """CPU seconds per second of wall clock (1.0: one core busy)."""
        return self.cpu_s / self.wall_s


def usage_stats(swarm: LoopbackSwarm) -> dict[int, Usage]:
    """Each drone's use from step 0 to its stop, from its ``stop`` event."""
    out = {}
    for i in swarm.procs:
        stop = swarm.last_event(i, "stop")
        if stop is None or stop.get("at_step_0") is None:
            continue
        a, b = stop["at_step_0"], stop
        out[i] = Usage(
            wall_s=b["unix_s"] - a["unix_s"],
            cpu_s=b["cpu_s"] - a["cpu_s"],
            bytes_sent=b["transport"]["bytes_sent"] - a["transport"]["bytes_sent"],
            datagrams_sent=b["transport"]["sent"] - a["transport"]["sent"],
            datagrams_received=b["transport"]["received"] - a["transport"]["received"],
        )
    return out


def machine() -> str:
    """Cores and load average, for the record."""
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    return f"{os.cpu_count()} cores, load average {load} (1, 5, 15 min)"


def mean(xs: list[float]) -> float:
    return statistics.fmean(xs) if xs else float("nan")

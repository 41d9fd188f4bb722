"""A scenario run as a swarm of real drone processes on this machine (what ``swarmraft launch``
does): keys and swarm file, one ``swarmraft node`` process per drone on 127.0.0.1, a fault
relay between them when the scenario's network needs one, the scenario's faults applied to the
processes and the relay at their times, and the end waited for. Gathering the results is
`net.results`' job.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from swarmraft.net.launch import (
    NODES_DIR,
    NodeProcess,
    current_leader,
    default_start_delay_s,
    events,
    free_udp_ports,
    prepare_swarm,
)
from swarmraft.net.node import warm_up_detector
from swarmraft.net.relay import RelayThread
from swarmraft.net.swarmfile import drone_file
from swarmraft.sim.mission import Idle  # a fault that found nothing to do (as in the simulator)
from swarmraft.sim.network import LinkModel
from swarmraft.sim.scenario import Scenario
from swarmraft.sim.sensing import ScenarioWorld

#: How long after the scenario's end launch waits for the drones to stop by themselves.
END_WAIT_S = 15.0
#: How long a lying-leader fault waits for a leader to be known, if none is at its time.
LIE_WAIT_S = 5.0

RelayMode = Literal["auto", "on", "off"]


def needs_relay(sc: Scenario) -> bool:
    """Whether the scenario's network is more than loopback gives: loss, duplication or
    reordering, or partition, heal or loss faults. (Its delay alone does not count: 1-3 ms
    of radio delay against loopback's tens of microseconds changes little.)"""
    net = sc.network
    return bool(net.loss or net.duplicate or net.reorder) or any(
        f.kind in ("partition", "heal", "loss") for f in sc.fault
    )


#: seconds the drones have, all together, to stop after launch's SIGTERM before a SIGKILL
STOP_WAIT_S = 10.0


@dataclass
class Action:
    at_s: float  # after step 0
    kind: str
    run: Callable[[], str]  # what it did, in words


@dataclass
class LocalSwarm:
    """``sc`` (read from ``scenario_file``) as processes, its files in ``out``."""

    sc: Scenario
    scenario_file: Path
    out: Path
    seed: int | None = None
    start_delay_s: float | None = None
    relay_mode: RelayMode = "auto"
    replay: Path | None = None  # a sensor log every drone replays (net.sources.replay)
    say: Callable[[str], None] = print
    events: list[tuple[float, str]] = field(default_factory=list)  # (s after step 0, what)
    idle_faults: list[tuple[float, str]] = field(default_factory=list)  # faults that did nothing
    kills: dict[int, list[float]] = field(default_factory=dict)  # drone -> unix times of SIGKILL
    unstoppable: list[int] = field(default_factory=list)  # drones SIGKILLed at the end
    exited: list[tuple[int, float, int]] = field(default_factory=list)  # (drone, s, status) on its own
    interrupted: bool = False
    stopped_s: float = 0.0  # s after step 0 at the interrupt
    signal_name: str = "SIGINT"  # what interrupted it (`run_stoppable`)
    effect_at: float | None = None  # unix time the running fault action took effect, if it waited
    liar: int | None = None  # the drone told to lie (lying-leader fault)

    def __post_init__(self) -> None:
        self.out = Path(self.out)
        self.n = self.sc.drones
        self.nodes_dir = self.out / NODES_DIR
        self.relay: RelayThread | None = None
        self.relay_counters: dict[str, int] = {}  # the relay's, when it stops
        self._down: set[int] = set()  # drones launch stopped, or saw exit: not running by design
        if self.relay_mode == "on" or (self.relay_mode == "auto" and needs_relay(self.sc)):
            self.link = LinkModel.of(self.sc.network)
        else:
            self.link = None

    # -- setting up ---------------------------------------------------------------------------
    def prepare(self) -> None:
        n = self.n
        # the drones' compiled kernels loaded here first: on a cold cache (after an install)
        # n drones compiling the same kernels at once took 21 s each to come up, none in
        # time for step 0; compiled once here, each loads them from the disk cache
        t0 = time.perf_counter()
        warm_up_detector(ScenarioWorld.build(self.sc))
        took = time.perf_counter() - t0
        if took > 5.0:
            det = self.sc.protocol.detector
            self.say(
                f"compiled the {det} detector's kernels in {took:.0f} s (once per detector after an install)"
            )
        delay = default_start_delay_s(n) if self.start_delay_s is None else self.start_delay_s
        self.start_delay_s = delay
        ports = free_udp_ports(2 * n)  # the drones' and the relay's, all distinct
        advertise = None
        if self.link is not None:
            targets = {i: ("127.0.0.1", ports[i - 1]) for i in range(1, n + 1)}
            self.relay = RelayThread(targets, self.link, self.sc.seed)
            advertise = self.relay.start(ports={i: ports[n + i - 1] for i in range(1, n + 1)})
        self.start_unix_s = time.time() + delay
        self.swarm_path, self.swarm = prepare_swarm(
            self.out, self.scenario_file, n, self.start_unix_s, self.seed, ports[:n], advertise, self.replay
        )
        self.procs = {
            i: NodeProcess(i, self.swarm_path, drone_file(self.nodes_dir, i, "log")) for i in range(1, n + 1)
        }

    def network_line(self) -> str:
        net = self.sc.network
        if self.link is None:
            why = "--relay off" if self.relay_mode == "off" else "nothing to apply"
            lost = [f"delay {net.delay_ms[0]:g}-{net.delay_ms[1]:g} ms"]
            lost += [
                f"{name} {v:.0%}"
                for name, v in (
                    ("loss", net.loss),
                    ("duplication", net.duplicate),
                    ("reordering", net.reorder),
                )
                if v
            ]
            return (
                f"network: direct loopback, no fault relay ({why}; the scenario's "
                f"{', '.join(lost)} not applied)"
            )
        return (
            f"network: through the fault relay: delay {net.delay_ms[0]:g}-{net.delay_ms[1]:g} ms, "
            f"loss {net.loss:.0%}, duplication {net.duplicate:.0%}, reordering {net.reorder:.0%}"
        )

    # -- faults -------------------------------------------------------------------------------
    def actions(self) -> list[Action]:
        """The scenario's faults as actions on the processes and the relay, in time order."""
        acts: list[Action] = []
        for f in self.sc.fault:
            if f.kind == "crash":
                kill = lambda d=f.drone: self._kill(d, f"drone {d} killed (SIGKILL)")  # noqa: E731
                acts.append(Action(f.at_s, f.kind, kill))
            elif f.kind == "crash-leader":
                acts.append(Action(f.at_s, f.kind, self._kill_leader))
            elif f.kind == "restart":
                acts.append(Action(f.at_s, f.kind, lambda d=f.drone: self._restart(d)))
            elif f.kind == "pause":
                who = [f.drone] if f.drone is not None else list(range(1, self.n + 1))
                acts.append(Action(f.at_s, f.kind, lambda w=who, s=f.for_s: self._pause(w, s)))
                acts.append(Action(f.at_s + f.for_s, "resume", lambda w=who: self._resume(w)))
            elif f.kind == "lying-leader":
                acts.append(Action(f.at_s, f.kind, self._compromise_leader))
            elif f.kind == "transfer-leader":
                note = Idle(
                    "transfer-leader: not applied (the drone processes take no commands; simulator only)"
                )
                acts.append(Action(f.at_s, f.kind, lambda n=note: n))
            elif f.kind in ("join", "leave"):
                note = Idle(
                    f"{f.kind}: not applied (every drone's process runs from the start, in the swarm; "
                    "simulator only)"
                )
                acts.append(Action(f.at_s, f.kind, lambda n=note: n))
            else:
                acts.append(Action(f.at_s, f.kind, lambda f=f: self._network_fault(f)))
        return sorted(acts, key=lambda a: a.at_s)

    def _kill(self, drone: int, what: str) -> str:
        if not self.procs[drone].alive:
            return Idle(f"crash: drone {drone} is not running, nothing killed")
        self.procs[drone].kill()
        self._down.add(drone)
        self.kills.setdefault(drone, []).append(time.time())
        return what

    def _kill_leader(self) -> str:
        alive = [i for i, p in self.procs.items() if p.alive and not p.paused]
        lead = current_leader(self.nodes_dir, alive)
        if lead is None:
            return Idle("crash-leader: no leader known, nothing killed")
        return self._kill(lead[0], f"leader {lead[0]} (term {lead[1]}) killed (SIGKILL)")

    def _compromise_leader(self) -> str:
        """The drone leading now (or, if none is known, the first known to lead within
        LIE_WAIT_S) is told to lie (SIGUSR1, `net.node.DroneHost.compromise`)."""
        lead = None
        end = time.time() + LIE_WAIT_S
        while lead is None and time.time() < end:
            alive = [i for i, p in self.procs.items() if p.alive and not p.paused]
            lead = current_leader(self.nodes_dir, alive)
            if lead is None:
                time.sleep(0.05)
        if lead is None:
            return Idle(f"lying-leader: no leader known within {LIE_WAIT_S:g} s, nobody compromised")
        self.effect_at = time.time()  # after the wait for a leader: when it was told to lie
        self.procs[lead[0]].compromise()
        self.liar = lead[0]
        f = next(f for f in self.sc.fault if f.kind == "lying-leader")
        return f"leader {lead[0]} (term {lead[1]}) compromised (SIGUSR1): lies ({f.mode} drone {f.drone})"

    def _restart(self, drone: int) -> str:
        if self.procs[drone].alive:
            return Idle(f"restart: drone {drone} is running, nothing started")
        self.procs[drone].start()
        self._down.discard(drone)
        return f"drone {drone} restarted on its SQLite file"

    def _names(self, who: list[int]) -> str:
        return "every drone" if len(who) == self.n else ", ".join(f"drone {d}" for d in who)

    def _pause(self, who: list[int], for_s: float) -> str:
        for d in who:
            self.procs[d].pause()
        return f"{self._names(who)} paused (SIGSTOP) for {for_s:g} s"

    def _resume(self, who: list[int]) -> str:
        for d in who:
            self.procs[d].resume()
        return f"{self._names(who)} resumed (SIGCONT)"

    def _network_fault(self, f) -> str:  # noqa: ANN001 (a FaultConfig)
        if self.relay is None:
            return Idle(f"{f.kind}: not applied (no fault relay: --relay off)")
        r = self.relay
        if f.kind == "partition":
            r.call(r.relay.partition, f.groups)
            return f"partition {f.groups} (fault relay)"
        if f.kind == "heal":
            r.call(r.relay.heal)
            return "network healed (fault relay)"
        r.call(r.relay.set_all, loss=f.value)
        return f"loss set to {f.value:.0%} (fault relay)"

    # -- running ------------------------------------------------------------------------------
    def _watch(self) -> None:
        """A drone process that exited without launch stopping it (a crash, a bug, out of
        memory) is said, counted as down from now (``kills``: its steps are not `alive`) and
        put among the events (the steps it then misses are explained), once. Before, launch
        reported such a drone alive to the end and its skipped steps unexplained."""
        now = time.time()
        if now >= self.start_unix_s + self.sc.steps * self.sc.dt_s:
            return  # the scenario is over: the drones stop by themselves
        for d, p in self.procs.items():
            if p.proc is None or p.alive or d in self._down:
                continue
            self._down.add(d)
            at = round(now - self.start_unix_s, 2)
            status = p.proc.returncode
            self.exited.append((d, at, status))
            self.kills.setdefault(d, []).append(now)
            self.events.append((at, f"drone {d} exited on its own (exit status {status})"))
            self.say(f"warning: {at:g} s: drone {d} exited on its own (exit status {status}); log: {p.log}")

    def _sleep_until(self, t: float) -> None:
        """Sleep until unix time ``t``, watching the drones (`_watch`)."""
        while time.time() < t:
            self._watch()
            time.sleep(0.01)

    def run(self) -> None:
        """Start every process, apply the faults at their times, wait for the end (or Ctrl-C:
        ``interrupted``), then stop every process and the relay."""
        sc = self.sc
        try:
            for p in self.procs.values():
                p.start()
            for a in self.actions():
                self._sleep_until(self.start_unix_s + a.at_s)
                # the time the action began: reading who leads, say, takes a tenth of a
                # second, and a fault's skipped steps are counted from its time
                began = time.time()
                self.effect_at = None  # an action that waits first (lying-leader) says when it acted
                what = a.run()
                at = self.effect_at if self.effect_at is not None else began
                # a fault that found nothing to do is said, not an event: an event excuses the
                # skipped steps after it (experiments.mission.skipped_causes)
                done = self.idle_faults if isinstance(what, Idle) else self.events
                done.append((round(at - self.start_unix_s, 2), str(what)))
                self.say(f"{a.at_s:g} s: {what}")
            end = self.start_unix_s + sc.steps * sc.dt_s + END_WAIT_S
            while any(p.alive for p in self.procs.values()) and time.time() < end:
                self._watch()
                time.sleep(0.1)
        except KeyboardInterrupt:
            self.interrupted = True
            self.stopped_s = time.time() - self.start_unix_s
        finally:
            self.stop()

    def steps_flown(self) -> int:
        """The steps the run reached: all of the scenario's, or, after an interrupt, those that
        began before it."""
        S = self.sc.steps + 1
        if not self.interrupted:
            return S
        if self.stopped_s < 0:
            return 0
        return min(S, int(self.stopped_s // self.sc.dt_s) + 1)

    @property
    def exit_status(self) -> int:
        """An interrupted run's exit status: 128 + the signal's number (130 Ctrl-C, 143 SIGTERM)."""
        return 128 + int(getattr(signal, self.signal_name))

    def run_stoppable(self) -> None:
        """`run`, with SIGTERM handled as Ctrl-C is (every drone stopped, the results written,
        ``interrupted``), so that `kill`, `timeout` or a CI runner stopping launch leaves no
        drone process behind; ``signal_name`` says which signal it was."""

        def on_term(signum: int, frame: object) -> None:  # noqa: ARG001
            self.signal_name = "SIGTERM"
            raise KeyboardInterrupt

        before = signal.signal(signal.SIGTERM, on_term)
        try:
            self.run()
        finally:
            signal.signal(signal.SIGTERM, before)

    def up_after_step0(self) -> dict[int, float | None]:
        """For each drone, seconds from step 0 to its first start event (negative: up before
        step 0; None: never up)."""
        out: dict[int, float | None] = {}
        for d in range(1, self.n + 1):
            starts = [e["t"] for e in events(self.nodes_dir, d) if e["event"] == "start"]
            out[d] = round(starts[0] - self.start_unix_s, 2) if starts else None
        return out

    def stop(self) -> None:
        """SIGTERM to every drone, then SIGKILL to those not stopped 10 s later (one deadline
        for all, not 10 s each in turn: a hung swarm of 5 took 50 s), each said and listed
        in ``unstoppable``."""
        for p in self.procs.values():
            p.terminate()
        deadline = time.monotonic() + STOP_WAIT_S
        for d, p in self.procs.items():
            if p.wait(max(0.0, deadline - time.monotonic())) is None and p.alive:
                p.kill()
                self.unstoppable.append(d)
                self.say(f"warning: drone {d} did not stop within {STOP_WAIT_S:g} s of SIGTERM: SIGKILLed")
        if self.relay is not None:
            self.relay_counters = dict(self.relay.counters())
            self.relay.stop()
